#pragma once
// The haptic local model (docs/design.md, "The haptic local model"): the simulation's last contact
// problem, re-solved for the devices' current poses. One implementation, used by the haptic loop,
// tactus-bench, the accuracy study and tactus-jitter. No segment, no device: it takes a snapshot
// view (shared/messages.h) and device poses, and returns the wrench on each instrument and what
// it did.
//
// Two halves, so that a real-time caller does all per-snapshot work off its thread:
//
//  - SnapshotPreparation::prepare (not real-time; allocates nothing after construction but takes
//    milliseconds): copies the snapshot into a PreparedSnapshot and checks everything it reads
//    (counts within the capacity, row offsets stepping by 1 or 3 up to the rows, instruments,
//    finiteness of every number, mu >= 0), chooses W's storage (dense or blocks), finds the
//    contacts a device can reach, solves the problem to a tight tolerance at the devices'
//    latest poses (warm-started from the previous snapshot's solution carried by contact id;
//    NSGS to the tick's tolerance, then Newton steps on the solution's active set through the
//    linearisation's inverse, LocalModelSettings::prepare_coarse_factor), and linearises that
//    solution in the device displacement (below).
//  - LocalModel::adopt (real-time, O(rows)) takes a PreparedSnapshot; LocalModel::solve
//    (real-time, allocation-free) evaluates the model for the devices' poses under an absolute
//    deadline.
//
// Models (LocalModelKind):
//  - kFull: warm-started NSGS on the whole problem every tick (the paper's local model).
//  - kLinearized: the solution's derivative with respect to the device displacements at a fixed
//    active set (handle-space linearisation, Garre and Otaduy 2009, computed here from W and J
//    rather than by the simulation). With the contacts split into separated (f = 0), sticking
//    (delta = 0) and sliding (delta_n = 0, f_t = mu f_n u, u = -delta_t / |delta_t|), the
//    change of f for a change dq = J dx of delta_free solves one linear system A df = B dx,
//    factored once per snapshot: F = df/dx (rows x 6 per instrument) and
//    G = d delta/dx = W F + J. A tick evaluates f = f0 + F (dx - dx0) in O(6 rows) and keeps it
//    only when the active set still holds: sticking contacts inside their cone with f_n >= 0,
//    sliding ones with f_n >= 0 and still sliding against their force, separated ones with
//    delta_n >= 0, and the displacement from the linearisation point within range. Otherwise it
//    falls back to the full re-solve, warm-started from the linear prediction (whose
//    W f + delta_free is G's, so the entry pass over W is saved). Exact for a fixed active set of
//    sticking and separated contacts (the problem is then linear), first order for sliding ones.
//    The fallback's re-solve is reduced (LocalModelSettings::reduced_fallback): the preparation
//    orders the reached contacts by the device displacement at which each can first carry force
//    (the loaded ones first, at zero; a separated one at its gap over its linearised closing
//    rate) and copies W in that order; the tick solves the leading contacts whose displacement
//    is within kReducedReachFactor x its own, and then checks that every contact left out is
//    still open at the solution (delta_n >= 0), taking in the first that is not and solving on.
//    A contact left out and open has f = 0 and no natural-map residual, so a converged reduced
//    solve is a converged solve of the whole problem.
//    Before falling back, the tick corrects the active set (LocalModelSettings::
//    active_set_correction): where a few contacts change state (a separated one closes, an
//    active one lifts, a sticking one starts to slide, a sliding one sticks), the linear system
//    of the new active set differs from the prepared one in those contacts' equations only, and
//    its solution is the prediction plus a correction through the prepared inverse A^-1
//    (Sherman-Morrison-Woodbury: with Z the columns of the prepared system's inverse for the
//    replaced equations and R their new rows, df = df_pred + Z (R Z)^-1 (residual of the new
//    equations at the prediction); a contact that closes adds its rows as unknowns, whose
//    columns cost one product with A^-1). A contact that starts to slide slides in the direction
//    of its predicted tangential force (re-aimed along its slip when that disagrees). The
//    corrected solution is checked as the linearisation is, and states are switched again for
//    up to kMaxCorrectionRounds rounds and kMaxCorrectedContacts contacts; it is rendered when
//    every check holds (LocalModelUsed::kCorrected), else the tick falls back as above. A
//    round's check of a separated contact skips the product W(row, active) dy when its gap stays
//    above the tolerance's slack by |W(row, active)| |dy| (Cauchy-Schwarz; the norms are
//    prepared), which is most of them. The new unknowns of contacts that close share one pass
//    over A^-1, and with W marked symmetric their coefficients are rows of the prepared W(reached,
//    active) rather than strided columns of W.
//  Kernels: the preparation's Gauss-Jordan inversion and the correction's dot products run AVX2
//    with fused multiply-add where the CPU has both (chosen at load; TACTUS_NSGS_KERNEL=generic
//    forces the generic ones, as for NSGS), so their results differ in the last bits by CPU.
//  - kAutomatic: linearized for problems of at least LocalModelSettings::automatic_min_rows
//    rows, full below (where a warm re-solve costs a few microseconds).
//
// Thread use: a PreparedSnapshot is written by one SnapshotPreparation and then only read, by
// any number of LocalModels (the haptic loop hands it over through a triple buffer).

#include <array>
#include <cstdint>
#include <optional>
#include <span>
#include <string_view>
#include <utility>
#include <vector>

#include "tactus/shared/delassus_blocks.h"
#include "tactus/shared/messages.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"
#include "tactus/shared/warm_start.h"

namespace tactus::haptic {

/// Which local model the tick solves (scene key haptics.local_model, haptic_server
/// --local-model): "full", "linearized" or "automatic".
enum class LocalModelKind : std::uint8_t { kFull, kLinearized, kAutomatic };
std::string_view toString(LocalModelKind kind) noexcept;
/// "full", "linearized", "automatic"; nullopt for anything else.
std::optional<LocalModelKind> parseLocalModelKind(std::string_view name) noexcept;

/// What one solve did.
enum class LocalModelUsed : std::uint8_t {
  kNone,        ///< nothing solved (no problem, or it was rejected)
  kFull,        ///< the full re-solve (kFull, or kAutomatic on a small problem)
  kLinearized,  ///< the linearisation, valid at this pose
  kFallback,    ///< the linearisation was not valid here (or not available): full re-solve
  kCorrected,   ///< the linearisation with its active set corrected in a few contacts
};
std::string_view toString(LocalModelUsed used) noexcept;

/// Why the linearisation did not hold at a pose (LocalModelResult::fallback).
enum class FallbackReason : std::uint8_t {
  kNone,
  kNotLinearized,  ///< the snapshot has no linearisation (its solve did not converge, or kFull)
  kOutOfRange,     ///< the device is beyond the validity range from the linearisation point
  kContactCloses,  ///< a separated contact would penetrate
  kContactLifts,   ///< an active contact's normal force would turn negative
  kLeavesCone,     ///< a sticking contact's force would leave its friction cone
  kSlipTurns,      ///< a sliding contact would stop or turn against its force
};
std::string_view toString(FallbackReason reason) noexcept;

/// Accepted ranges of LocalModelSettings (validate()).
struct LocalModelLimits {
  static constexpr int kMaxSweeps = 100'000;
  static constexpr double kMaxTolerance = 1.0;
  static constexpr int kMaxAutomaticMinRows = 1'000'000;
  static constexpr double kMaxTranslationM = 0.1;
  static constexpr double kMaxRotationRad = 1.0;
  static constexpr double kMaxPrepareCoarseFactor = 1000.0;
};

struct LocalModelSettings {
  LocalModelKind kind = LocalModelKind::kAutomatic;
  double tolerance = 1e-6;   ///< NSGS tolerance of the tick's re-solve (natural-map error)
  int max_sweeps = 50;       ///< NSGS sweep budget of one solve
  int anderson_depth = 0;    ///< NSGS Anderson depth of the tick's re-solve (shared/nsgs.h)
  /// kAutomatic: linearized from this many rows on. Below it a warm-started re-solve costs a
  /// few sweeps of a W that fits the cache (docs/design.md, "The haptic local model").
  int automatic_min_rows = 96;
  /// Validity range of the linearisation: the device's translation [m] and rotation [rad] away
  /// from the pose it was linearised at.
  double max_translation_m = 2e-3;
  double max_rotation_rad = 0.05;
  /// The preparation's solve: tolerance x this factor, at most prepare_max_sweeps sweeps.
  double prepare_tolerance_factor = 0.1;
  int prepare_max_sweeps = 3000;
  /// Where a linearisation is wanted, the preparation's NSGS stops at tolerance x this factor
  /// and a Newton step on the solution's active set, through the linear system's inverse the
  /// linearisation computes anyway, takes it to tolerance x prepare_tolerance_factor (checked
  /// by the natural-map error; where it does not get there, NSGS goes on to that tolerance and
  /// its solution is linearised). 0, or at most prepare_tolerance_factor: NSGS to the tight
  /// tolerance (docs/design.md, "The preparation's Newton step").
  double prepare_coarse_factor = 1.0;
  /// The linearisation's fallback re-solves only the contacts that can carry force (above);
  /// false: all the reached contacts.
  bool reduced_fallback = true;
  /// Where the linearisation does not hold, first correct its active set in a few contacts
  /// (above); false: fall back at once.
  bool active_set_correction = true;
  /// Throws tactus::Error naming the first setting that is not finite or out of range.
  void validate() const;
};

/// The devices' poses a problem is solved or linearised at: device i drives instrument i;
/// nullptr (or past the span) means no pose, the device stays where the snapshot has it.
using DevicePoses = std::span<const shared::Pose* const>;

/// A reduced fallback solves the contacts that could carry force at kReducedReachFactor times
/// the device's displacement from the linearisation point (local_model.h, top).
inline constexpr double kReducedReachFactor = 2.0;
/// The active-set correction (top) changes the state of at most this many contacts, in at most
/// this many rounds of solve and check (on liver_grasp_23k's replayed hold no corrected tick
/// needed more than 3 or 4; the rounds beyond only delayed the fallback).
inline constexpr int kMaxCorrectedContacts = 16;
inline constexpr int kMaxCorrectionRounds = 4;

/// Per contact of a prepared snapshot: its state in the linearised solution.
enum class ContactState : std::uint8_t { kSeparated, kSticking, kSliding, kNormalOnly };

/// Why a snapshot cannot be solved (PreparedSnapshot::status()).
enum class PrepareStatus : std::uint8_t {
  kEmpty,        ///< nothing to solve: not valid, shutting down, or no contacts
  kReady,        ///< copied and checked; solve() may run on it
  kTooLarge,     ///< more rows or contacts than the capacity
  kInconsistent, ///< row offsets, counts or instruments that do not form a problem
  kNonFinite,    ///< a NaN or Inf in a number the model reads, or mu < 0
  kIllPosed,     ///< W has a diagonal NSGS cannot use (corrupt snapshot): no force from it
};
std::string_view toString(PrepareStatus status) noexcept;

/// One snapshot's problem copied out of shared memory, checked, and prepared for the tick.
/// Sized once for a capacity; prepare() overwrites it (SnapshotPreparation).
class PreparedSnapshot {
 public:
  PreparedSnapshot() = default;
  PreparedSnapshot(int max_rows, int max_contacts);   ///< allocates

  int maxRows() const noexcept { return max_rows_; }
  int maxContacts() const noexcept { return max_contacts_; }

  PrepareStatus status() const noexcept { return status_; }
  /// The snapshot's header as copied (seq, t_ns, flags, instrument poses...).
  const shared::ContactSnapshotHeader& header() const noexcept { return header_; }
  std::uint64_t seq() const noexcept { return header_.seq; }
  /// Counts preparations by its SnapshotPreparation: a snapshot prepared again at newer poses
  /// keeps its seq() but gets a new generation.
  std::uint64_t generation() const noexcept { return generation_; }
  int rows() const noexcept { return rows_; }
  int contacts() const noexcept { return contacts_; }
  int instruments() const noexcept { return tools_; }
  /// The preparation's solve at its poses converged (to tolerance x prepare_tolerance_factor).
  bool preparedConverged() const noexcept { return prepared_converged_; }
  int preparedSweeps() const noexcept { return prepared_sweeps_; }
  /// The solution is the Newton step's from the coarse solve (LocalModelSettings::
  /// prepare_coarse_factor), not NSGS's at the tight tolerance.
  bool preparedPolished() const noexcept { return prepared_polished_; }
  /// A linearisation is available (kind is not kFull, the solve converged, the system solved).
  bool linearized() const noexcept { return linearized_; }
  /// Contacts sliding in the linearisation, and the active rows of its system.
  int slidingContacts() const noexcept { return sliding_; }
  int activeRows() const noexcept { return active_rows_; }
  /// Contacts a device can move (all but shared::kContactUnreachable): solved alone when they
  /// are fewer than all and contiguous (see reachOnly()).
  bool reachOnly() const noexcept { return reach_only_; }
  int reachBegin() const noexcept { return reach_begin_; }
  int reachEnd() const noexcept { return reach_end_; }
  /// W is solved on its block form (shared::chooseStorage) instead of dense.
  bool usesBlocks() const noexcept { return use_blocks_; }
  const shared::DelassusBlocks& blocks() const noexcept { return blocks_; }
  /// Time the preparation took [ns] and its phases: copy and checks, storage and reach, solve,
  /// linearisation.
  std::int64_t prepareNs() const noexcept { return prepare_ns_; }
  std::int64_t copyNs() const noexcept { return copy_ns_; }
  std::int64_t storageNs() const noexcept { return storage_ns_; }
  std::int64_t solveNs() const noexcept { return solve_ns_; }
  std::int64_t linearizeNs() const noexcept { return linearize_ns_; }
  /// The solution at the preparation's poses (rows()), and the contact states.
  const double* preparedForces() const noexcept { return f0_.data(); }
  const ContactState* contactStates() const noexcept { return state_.data(); }
  /// The problem with the snapshot's own delta_free (W dense, ld = rows()).
  shared::ContactProblemView problem() const noexcept;
  /// The reduced fallback's order (with linearized()): the reached contacts, position i holding
  /// contact orderedContacts()[i], which can first carry force at a device displacement of
  /// orderedReach()[i] [m] (nondecreasing; 0 for the loaded ones; a rotation counts as its angle
  /// times max_translation_m / max_rotation_rad).
  int orderedCount() const noexcept { return ordered_count_; }
  const int* orderedContacts() const noexcept { return order_.data(); }
  const double* orderedReach() const noexcept { return order_reach_.data(); }

 private:
  friend class SnapshotPreparation;
  friend class LocalModel;
  void resize(int max_rows, int max_contacts);

  int max_rows_ = 0;
  int max_contacts_ = 0;
  PrepareStatus status_ = PrepareStatus::kEmpty;
  std::uint64_t generation_ = 0;
  shared::ContactSnapshotHeader header_{};
  int rows_ = 0;
  int contacts_ = 0;
  int tools_ = 1;
  shared::NsgsCoupling coupling_ = shared::NsgsCoupling::kColumnUpdate;
  // the problem (ld = rows_)
  std::vector<int> row_offset_;
  std::vector<std::uint64_t> contact_id_;
  std::vector<double> mu_, W_, delta_free_, f_star_, J_;
  std::vector<double> point_, normal_, tangent_;
  std::vector<int> contact_tool_;   ///< instrument or -1 (none) per contact
  std::vector<int> row_tool_;       ///< the same per row
  std::array<shared::Pose, shared::kMaxInstruments> device_pose_{};   ///< x_h* per instrument
  std::array<shared::Pose, shared::kMaxInstruments> tool_pose_{};
  // storage and reach
  shared::DelassusBlocks blocks_;
  bool use_blocks_ = false;
  bool reach_only_ = false;
  int reach_begin_ = 0, reach_end_ = 0;
  // the preparation's solve, at displacements dx0_ (6 per instrument) from x_h*
  std::array<double, 6 * shared::kMaxInstruments> dx0_{};
  std::vector<double> f0_;        ///< solution at dx0_
  std::vector<double> delta0_;    ///< W f0 + delta_free + J dx0
  bool prepared_converged_ = false;
  int prepared_sweeps_ = 0;
  bool prepared_polished_ = false;
  // the linearisation
  bool linearized_ = false;
  std::vector<ContactState> state_;
  std::vector<double> F_;         ///< rows x 6 instruments, row-major: d f / d dx
  std::vector<double> G_;         ///< rows x 6 instruments, row-major: d delta / d dx
  int sliding_ = 0;
  // the reduced fallback's order (valid with linearized_): ordered contact i is order_[i]; its
  // rows are ordered_row_[ordered_row_offset_[i] ...]; Wo_ is W on the ordered rows
  // (ordered_rows_ x ordered_rows_, ld = ordered_rows_)
  int ordered_count_ = 0;
  int ordered_rows_ = 0;
  double ordered_lever_m_ = 0.0;   ///< a rotation's displacement per radian in orderedReach()
  std::vector<int> order_;
  std::vector<double> order_reach_;
  std::vector<int> ordered_row_offset_;
  std::vector<int> ordered_row_;
  std::vector<double> ordered_mu_;
  std::vector<double> Wo_;
  int active_rows_ = 0;
  // the tick's active-set correction (valid with linearized_): the active rows (position ->
  // row), each row's position among them (-1: not active), the linear system's inverse A^-1
  // (active_rows_ x active_rows_, column-major) and W on the reached rows and the active columns
  // (row r_begin + i at WA_[i * active_rows_])
  std::vector<int> active_row_;
  std::vector<int> active_pos_;
  std::vector<double> Ainv_;
  std::vector<double> WA_;
  std::vector<double> wa_norm_;   ///< |WA_ row| per reached row (the correction's bound)
  std::int64_t prepare_ns_ = 0, copy_ns_ = 0, storage_ns_ = 0, solve_ns_ = 0, linearize_ns_ = 0;
};

/// Prepares snapshots one after the other (not real-time). Keeps the last solution to carry the
/// warm start into the next snapshot by contact id, and the scratch of the linear system.
class SnapshotPreparation {
 public:
  SnapshotPreparation() = default;
  SnapshotPreparation(int max_rows, int max_contacts);   ///< allocates
  /// Copies and checks `snap` into `out` (sized for at least the capacity given here) and, when
  /// it is solvable, solves it at `poses` and linearises it (settings.kind != kFull). Returns
  /// out.status(). Allocation-free; not real-time (a dense inversion of the active rows' system).
  PrepareStatus prepare(const shared::SnapshotView& snap, const LocalModelSettings& settings,
                        DevicePoses poses, PreparedSnapshot& out) noexcept;
  /// Forgets the carried solution (a new segment, a restarted simulation).
  void reset() noexcept;

 private:
  bool copyAndCheck(const shared::SnapshotView& snap, PreparedSnapshot& out) noexcept;
  /// With `polish`, first the Newton step from the coarse solution to `tolerance`
  /// (polishSolution); when it does not get there, nothing is linearised.
  void linearize(const LocalModelSettings& settings, PreparedSnapshot& out,
                 const shared::ContactProblemView* polish, double tolerance) noexcept;
  bool polishSolution(const shared::ContactProblemView& problem, double tolerance,
                      PreparedSnapshot& out) noexcept;
  void orderForReducedFallback(const LocalModelSettings& settings, PreparedSnapshot& out) noexcept;

  int max_rows_ = 0;
  int max_contacts_ = 0;
  std::uint64_t generation_ = 0;
  std::uint64_t last_seq_ = 0;   ///< the snapshot last prepared (a repeat is not carried twice)
  shared::SnapshotWarmStart warm_start_;
  std::vector<double> last_f_;   ///< the last prepared solution (its snapshot's rows)
  bool have_last_ = false;
  shared::NsgsWorkspace workspace_;
  std::vector<int> reach_offset_;
  std::vector<double> dq_;       ///< moved delta_free
  std::vector<double> A_, B_;    ///< the linear system A df = B dx (row-major, active rows)
  std::vector<double> X_;        ///< its solution df/dx (active rows x 6 instruments)
  std::vector<double> Xt_;       ///< the same transposed (6 instruments x active rows)
  std::vector<double> f_coarse_;   ///< the coarse solve's solution (reached rows)
  std::vector<double> polish_res_, polish_y_;   ///< the Newton step's residual and A^-1 r
  std::vector<int> swap_;        ///< the inversion's row swaps
  std::vector<std::pair<double, int>> sort_;   ///< (reach, contact) while ordering
};

/// What LocalModel::solve did, and the wrench on each instrument.
struct LocalModelResult {
  LocalModelUsed used = LocalModelUsed::kNone;
  FallbackReason fallback = FallbackReason::kNone;   ///< when used == kFallback
  /// NSGS's status; kConverged also for a linearisation that held (its linear system is solved
  /// exactly). kEmpty when nothing was solved.
  shared::NsgsStatus status = shared::NsgsStatus::kEmpty;
  int sweeps = 0;
  double error = 0.0;           ///< NSGS's natural-map error (the preparation's for kLinearized)
  /// Contacts the re-solve solved: all reached ones, or fewer with a reduced fallback
  int solved_contacts = 0;
  /// Contacts whose state the active-set correction changed (kCorrected; or when it was tried
  /// and gave up, before the fallback), and its rounds
  int corrected_contacts = 0;
  int correction_rounds = 0;
  int rows = 0;
  int contacts = 0;
  int ill_posed_contacts = 0;
  int instruments = 0;          ///< entries of force_n / torque_nm
  std::int64_t elapsed_ns = 0;  ///< wall time in solve()
  /// Contact wrench on each instrument (world frame; torque about its god-object origin moved by
  /// the device translation).
  std::array<std::array<double, 3>, shared::kMaxInstruments> force_n{};
  std::array<std::array<double, 3>, shared::kMaxInstruments> torque_nm{};
  bool solved() const noexcept { return used != LocalModelUsed::kNone; }
  bool converged() const noexcept { return status == shared::NsgsStatus::kConverged; }
};

/// The real-time half: adopts prepared snapshots and solves them for the devices' poses.
class LocalModel {
 public:
  LocalModel() = default;
  LocalModel(int max_rows, int max_contacts);   ///< allocates

  /// Uses `prepared` from now on (nullptr: none). The snapshot must stay unchanged while
  /// adopted. O(rows), allocation-free.
  void adopt(const PreparedSnapshot* prepared) noexcept;
  const PreparedSnapshot* adopted() const noexcept { return prepared_; }

  /// The model at `poses` (device i drives instrument i; nullptr: at x_h*). deadline_ns: absolute
  /// CLOCK_MONOTONIC time (0: none) at which the re-solve stops, checked within sweeps.
  /// Allocation-free, lock-free, noexcept.
  LocalModelResult solve(DevicePoses poses, const LocalModelSettings& settings,
                         std::int64_t deadline_ns) noexcept;

  /// Forces of the last solve (rows of the adopted snapshot).
  const double* forces() const noexcept { return f_.data(); }
  int maxRows() const noexcept { return max_rows_; }

 private:
  void displacements(DevicePoses poses) noexcept;
  void moveDeltaFree() noexcept;
  FallbackReason evaluateLinearization(const LocalModelSettings& settings) noexcept;
  bool correctActiveSet(std::int64_t deadline_ns, LocalModelResult& out) noexcept;
  int correctionSolve() noexcept;
  int correctionCheck() noexcept;
  shared::NsgsResult resolve(const LocalModelSettings& settings, std::int64_t deadline_ns,
                             bool delta_current) noexcept;
  shared::NsgsResult resolveReduced(const LocalModelSettings& settings, std::int64_t deadline_ns,
                                    int& solved_contacts) noexcept;
  void wrenches(LocalModelResult& out) const noexcept;

  int max_rows_ = 0;
  const PreparedSnapshot* prepared_ = nullptr;
  shared::NsgsWorkspace workspace_;
  std::vector<double> f_;
  std::vector<double> delta_free_;
  std::vector<double> last_delta_free_;
  std::vector<int> reach_offset_;
  std::vector<double> fo_, qo_, scratch_;   ///< the reduced fallback's f, delta_free (ordered)
  std::array<double, 6 * shared::kMaxInstruments> dx_{};
  bool delta_valid_ = false;   ///< workspace_.delta holds W f + last_delta_free_
  double slack_ = 0.0;         ///< the last evaluation's slack (evaluateLinearization)
  // the active-set correction (local_model.cpp): each contact's state in it (CorrectionMode),
  // the direction a contact that started to slide slides in (2 per contact), the new unknowns
  // (rows of contacts that close: row and index), the replaced equations, and its scratch
  std::vector<std::uint8_t> mode_;
  std::vector<std::uint8_t> tried_;   ///< per contact: the modes tried in this tick (bits)
  std::vector<double> slide_u_;
  std::vector<int> new_row_;
  std::vector<int> new_index_;
  std::vector<int> eq_index_, eq_kind_, eq_row_, eq_contact_;
  std::vector<double> Z_, RZ_, rhs_, dy_;
  std::vector<double> cnew_;   ///< the new unknowns' C_j (active rows each)
  std::vector<int> znew_;      ///< their columns of Z_
  std::vector<double> fc_, dc_;   ///< the corrected f and delta on the reached rows
};

/// Prepares and solves in one object, for tools and offline studies (not real-time): what the
/// haptic loop does, with the preparation in the caller's thread.
class OfflineLocalModel {
 public:
  OfflineLocalModel(int max_rows, int max_contacts, const LocalModelSettings& settings);
  /// Prepares `snap` at `poses` (the devices' latest poses) and adopts it. Returns its status.
  PrepareStatus adopt(const shared::SnapshotView& snap, DevicePoses poses) noexcept;
  LocalModelResult solve(DevicePoses poses, std::int64_t deadline_ns = 0) noexcept {
    return model_.solve(poses, settings_, deadline_ns);
  }
  const PreparedSnapshot& prepared() const noexcept { return prepared_; }
  LocalModel& model() noexcept { return model_; }
  LocalModelSettings& settings() noexcept { return settings_; }
  void reset() noexcept { preparation_.reset(); }

 private:
  LocalModelSettings settings_;
  SnapshotPreparation preparation_;
  PreparedSnapshot prepared_;
  LocalModel model_;
};

}  // namespace tactus::haptic

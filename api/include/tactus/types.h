#pragma once
// Plain data of the public API (docs/api.md): the device target that drives an instrument, what
// one step did, the contact problem a step assembled and solved (what the haptic local model
// re-solves), and the reaction forces. Units are SI and in the names; frames are the world's
// (z up in the bundled scenes); quaternions are Eigen's (w, x, y, z); twists and wrenches are
// [linear; angular] (tactus/shared/pose.h).

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "tactus/shared/grow_only_matrix.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/pose.h"

namespace tactus {

using shared::Matrix6d;
using shared::Pose;
using shared::Vector6d;

/// What drives an instrument's god object for the next steps: the pose of the device's tool
/// point, its twist [v; w] and the jaw opening.
struct DeviceTarget {
  Pose pose;
  Vector6d twist = Vector6d::Zero();
  double gripper_opening = 1.0;      ///< 0 closed .. 1 open
};

/// Wall time per stage of the last step [s], named after the stages of a step (docs/design.md
/// section 2). With contact passes every pass adds to the stages it runs.
struct StageTimes {
  double free_motion_s = 0.0;          ///< freeMotion: tissues and god object, no contact force
  double detect_collisions_s = 0.0;    ///< detectCollisions: BVH refit and proximity queries
  double update_compliance_s = 0.0;    ///< updateCompliance: C ~ R C0 R^T (or the exact C)
  double build_w_s = 0.0;              ///< buildW: contact rows H, delta_free, W = H C H^T
  double solve_contacts_s = 0.0;       ///< solveContacts: warm start and NSGS
  double constrained_motion_s = 0.0;   ///< constrainedMotion: dq = C H^T f, tool dx = C6 H^T f
  /// VTK output: not part of a step nor of total_s; 0 unless the caller fills it (sim_server's
  /// runner times its output into it; tactus-bench writes no output).
  double output_s = 0.0;
  double total_s = 0.0;                ///< the whole step
};

/// What one step did.
struct StepReport {
  int contacts = 0;
  int rows = 0;
  int contacts_dropped = 0;          ///< over max_contacts (deepest kept)
  shared::NsgsResult nsgs;
  /// Groups of coupled bodies the last solve split the problem into (solver.split_contact_groups;
  /// 1: solved whole, 0: no contact); nsgs then holds the largest sweep count over the groups
  int contact_groups = 0;
  /// Of those problems, how many NSGS swept on W's blocks (shared::chooseStorage's rule: at most
  /// kBlockSparseMaxFill of their contact blocks non-zero; with solver.split_contact_groups)
  int solved_on_blocks = 0;
  double max_penetration_m = 0.0;    ///< max(-gap) after the constrained motion, >= 0
  double complementarity = 0.0;      ///< max_i |f_n,i * delta_n,i| after the correction [N m]
  int contact_passes = 0;            ///< contact passes run (solver.contact_iterations caps it)
  /// max(-gap) by a fresh collision query at the corrected state, >= 0; measured only when
  /// solver.contact_iterations > 1 (else 0)
  double geometric_penetration_m = 0.0;
  /// The same query's largest penetration beyond the contact compliance's give,
  /// max(0, -(gap + c f_n)) (what the passes compare with solver.penetration_tolerance_m)
  double excess_penetration_m = 0.0;
  /// Tissue nodes with a non-zero weight in some contact (a vertex contact's node, a face
  /// contact's triangle nodes), over all tissues, in the last assembled problem
  int distinct_tissue_nodes = 0;
  double total_normal_force_n = 0.0; ///< sum of the normal forces of the last solve [N]
  /// Contact wrench on the tool of the last solve [force_n; torque_nm about the tool origin]
  /// (the first instrument's)
  Vector6d tool_wrench = Vector6d::Zero();
  /// The same per instrument (empty without instrument)
  std::vector<Vector6d> tool_wrenches;
  bool finite = true;                ///< every state value finite
  /// Tetrahedra inverted (det F <= 0) at the start of the step, over all tissues
  int inverted_elements = 0;
  /// Tetrahedra the strain limiter found below tissues[i].strain_limit.min_volume_ratio after
  /// the constrained motion and lifted back (over all tissues and the step's contact passes), and
  /// those it left below after the last pass
  int strain_limited_elements = 0;
  int strain_limit_unresolved = 0;
  /// The free motions' linear solves, over all tissues: CHOLMOD factorisations of the step's
  /// system matrix and PCG iterations
  int fem_factorisations = 0;
  int fem_cg_iterations = 0;
  /// The nodes of the free motions' PCG local corrections (FemSolverOptions::
  /// pcg_local_correction_threshold), over all tissues
  int fem_pcg_local_nodes = 0;
  StageTimes times;
};

/// One instrument's part of the last contact problem.
struct InstrumentProblemData {
  Pose device_pose;                  ///< x_h* of this instrument's device
  double device_gripper = 1.0;       ///< opening (0..1) used for this step
  Pose tool_pose;                    ///< its god object after the step
  /// The jaw angle of a full opening [rad] (the scene's; a snapshot carries openings as angles)
  double max_opening_rad = 1.0;
};

/// A frictional contact problem delta = W f + delta_free (shared/nsgs.h: Coulomb's law per
/// contact, one row n or three rows n, t1, t2), with what the haptic local model needs to move
/// it with the devices (docs/design.md, "The haptic local model"). Filled by a simulation step
/// (the problem it solved last: f is its solution), read from an FCLIB or a snapshot file, or
/// built by hand (contacts, rows, row_offset, mu, W, delta_free and f are enough to solve it).
/// With several instruments, J's row r is d delta_free_r / d x_h of the device of instrument
/// contact_instrument[c] (c the row's contact), and the wrench on instrument i is the sum over
/// its own contacts.
struct ContactProblem {
  int contacts = 0;
  int rows = 0;
  std::int64_t step = 0;                       ///< the simulation step that made it (its index)
  double h_s = 0.0;                            ///< that simulation's time step
  std::vector<int> row_offset;                 ///< contacts + 1
  std::vector<std::uint64_t> contact_id;       ///< stable across steps (warm starts)
  std::vector<double> mu;                      ///< per contact
  /// Row-major, rows x rows; an Eigen::Map of storage that only grows (grow_only_matrix.h): a
  /// simulation reserves it for its largest problem at set-up, so that a step whose problem
  /// changes size neither allocates nor touches fresh memory. Read and written as an Eigen
  /// matrix; assigning an expression resizes it.
  shared::GrowOnlyMatrix<Eigen::RowMajor> W;
  Eigen::VectorXd delta_free;                  ///< gaps and tangential motions without force
  Eigen::VectorXd f;                           ///< forces in the local frames (n, t1, t2) [N]
  Eigen::Matrix<double, Eigen::Dynamic, 6, Eigen::RowMajor> J;   ///< d delta_free / d x_h
  /// d gap / d phi per row: the jaw angle's column of H (dynamic grip; zeros otherwise). The
  /// contact torque on the jaw angle is grip . f.
  Eigen::VectorXd grip;
  std::vector<Eigen::Vector3d> point_m;        ///< per contact, on the tissue
  std::vector<Eigen::Vector3d> normal;         ///< per contact (row n), tissue -> tool
  std::vector<Eigen::Vector3d> tangent1;       ///< per contact (row t1)
  std::vector<Eigen::Vector3d> tangent2;       ///< per contact (row t2)
  std::vector<int> contact_instrument;         ///< per contact: its instrument (-1: none)
  /// per contact: 1 when its group of coupled bodies has no instrument contact (no device can
  /// change its force); filled by the simulation's solve
  std::vector<std::uint8_t> unreachable;
  std::vector<InstrumentProblemData> instruments;   ///< per instrument
  Pose device_pose;                            ///< x_h* used for this step (instrument 0)
  double device_gripper = 1.0;                 ///< opening (0..1) used for this step (idem)
  Pose tool_pose;                              ///< god object after the step (idem)
  shared::NsgsResult solve;                    ///< the NSGS result (kEmpty: no solve)

  /// The solver's view of this problem (pointers into this object).
  shared::ContactProblemView view() const {
    return shared::denseProblemView(contacts, rows, row_offset.data(), W.data(), rows,
                                    delta_free.data(), mu.data());
  }
  /// The force contact c applies to the tissue, in world axes [N]: -(n f_n + t1 f_t1 + t2 f_t2)
  /// (a one-row contact: -n f_n). Needs the contact frames (a simulation's or a snapshot's
  /// problem; zero without them).
  Eigen::Vector3d forceOnTissue(int c) const {
    const auto k = static_cast<std::size_t>(c);
    if (k >= normal.size()) return Eigen::Vector3d::Zero();
    const int r0 = row_offset[k];
    Eigen::Vector3d out = -normal[k] * f[r0];
    if (row_offset[k + 1] - r0 == 3) out -= tangent1[k] * f[r0 + 1] + tangent2[k] * f[r0 + 2];
    return out;
  }
};

/// Reactions of one tissue (ReactionForces).
struct TissueReactions {
  Eigen::Matrix3Xd fixed_reaction_n;   ///< per node: R_i at fixed nodes, 0 elsewhere
  Eigen::Matrix3Xd contact_force_n;    ///< per node: H^T f
  Eigen::Vector3d fixed_total_n = Eigen::Vector3d::Zero();   ///< sum of R_i
  Eigen::Vector3d weight_n = Eigen::Vector3d::Zero();        ///< sum of m_i g (all nodes)
  /// From the other tissues (and itself, self-contact: 0 in sum) through tissue contacts
  Eigen::Vector3d from_tissues_n = Eigen::Vector3d::Zero();
};

/// What holds the tissues (docs/design.md, "Reaction forces"), all forces applied TO the tissues
/// [N]: the fixed nodes' static reactions R_i = -(f_el,i(q) + m_i g + c_i + l_i), the contact
/// force per node (H^T f of the last step), per obstacle and from the instrument the sum over
/// their contacts, and the loads. At rest: weight + loads + fixed reactions + obstacles +
/// instrument = 0.
struct ReactionForces {
  std::vector<TissueReactions> tissues;
  std::vector<std::string> obstacle_names;
  std::vector<Eigen::Vector3d> obstacle_force_n;            ///< per obstacle, on the tissues
  Eigen::Vector3d instrument_force_n = Eigen::Vector3d::Zero();   ///< on the tissues
  Eigen::Vector3d weight_n = Eigen::Vector3d::Zero();       ///< all tissues
  Eigen::Vector3d applied_load_n = Eigen::Vector3d::Zero(); ///< force and pressure loads
  Eigen::Vector3d fixed_total_n = Eigen::Vector3d::Zero();  ///< all tissues
  /// weight + loads + fixed + obstacles + instrument: 0 at rest
  Eigen::Vector3d imbalance_n() const {
    Eigen::Vector3d sum = weight_n + applied_load_n + fixed_total_n + instrument_force_n;
    for (const Eigen::Vector3d& f : obstacle_force_n) sum += f;
    return sum;
  }
};

}  // namespace tactus

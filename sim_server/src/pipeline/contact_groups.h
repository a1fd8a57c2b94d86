#pragma once
// The contact problem split by groups of coupled bodies (docs/design.md, "Bodies that do not
// couple").
//
// W = sum_t H_t C_t H_t^T + sum_i H_i C6_i H_i^T: two contacts couple only through a body they
// share, a tissue or an instrument (an obstacle is fixed and couples nothing). So the contacts
// fall into groups, the connected components of "shares a body": a tissue with its instrument's
// and its obstacles' contacts; two tissues become one group when an instrument touches both or
// a tissue_contact pair links them. Between groups W is exactly zero (buildW never writes
// there), so the problem is block diagonal after a permutation, and each group is a problem of
// its own: solved alone it needs the sweeps its own contacts need (a hard grasp does not make
// a resting organ sweep with it), and a sweep costs its own rows^2, not all rows^2.
//
// The dense W stays assembled as before (the shared segment carries it; the haptic loop
// re-solves what a device can move, see haptic_loop.h), so a group whose contacts are contiguous
// is solved in place on W's diagonal block (leading dimension = all rows); another is gathered
// into a compact copy first and its forces scattered back.
//
// Inside a group W can still be sparse by blocks (a chain of organs, each touching the next:
// the first's own contacts and the last's do not couple). Each problem solved (the whole, or a
// group) goes through shared::chooseStorage, as in the haptic loop: when at most
// kBlockSparseMaxFill of its contact blocks are non-zero NSGS sweeps the blocks
// (delassus_blocks.h), else the dense W.
//
// Tolerance: the result must meet the whole problem's tolerance on the whole problem's
// normalised error, sqrt(sum_k r_k^2) / max(|q|, |f|, |delta|) (nsgs.h naturalMapError; r_k
// group k's residual, the norms over all rows; W being zero between groups, it is computed from
// the groups' parts without another W pass). Each group is first solved to the tolerance on its
// own scale, which meets it as soon as one group dominates the scale (the usual case: a grasp
// beside a light touch). When it does not, the groups above an equal share of the residual
// budget (tolerance * scale / sqrt(K)) are solved on, warm, to that share (at most kMaxPasses
// passes in all); asking every group for tolerance / sqrt(K) up front cost 15 % more sweeps on
// liver_stomach_two_hands.yaml.

#include <cstdint>
#include <vector>

#include "tactus/shared/delassus_blocks.h"
#include "tactus/shared/nsgs.h"

namespace tactus::sim {

struct SimulationState;
struct StepScratch;

class ContactGroups {
 public:
  /// Groups the contacts of the problem just assembled (buildW): tissue t's own contacts
  /// (instrument and obstacle, from scratch.tissues[t].contact_begin) link t and their
  /// instrument; the contacts between tissues link their pair's two tissues.
  void find(const SimulationState& state, const StepScratch& scratch);
  /// Sets the grouping directly: contact c is in group label[c] (any non-negative labels; groups
  /// are renumbered by their first contact). find() ends with it; tests call it.
  void assign(const std::vector<int>& label);

  /// The block storage of problems up to max_rows / max_contacts written now (the Simulation's
  /// set-up; DelassusBlocks::reserveStorage): a grasp whose problem grows step by step then
  /// takes no fresh page for it (on liver_grasp_23k about 1300 over its closing). Which problems
  /// are swept on blocks is unchanged.
  void reserveStorage(int max_rows, int max_contacts) {
    blocks_.reserveStorage(max_rows, max_contacts);
  }
  int count() const { return count_; }
  /// Problems of the last solve() NSGS swept on W's blocks (chooseStorage's rule).
  int solvedOnBlocks() const { return solved_on_blocks_; }
  /// Marks the contacts (out[c] = 1) whose group has no contact with an instrument (instrument
  /// c: contact c's, -1 for none); 0 for the others.
  void markUnreachable(const std::vector<int>& instrument, std::vector<std::uint8_t>& out);
  /// Contacts of group g, in increasing order.
  const int* groupContacts(int g) const {
    return members_.data() + start_[static_cast<std::size_t>(g)];
  }
  int groupSize(int g) const {
    return start_[static_cast<std::size_t>(g) + 1] - start_[static_cast<std::size_t>(g)];
  }

  /// Solves `problem` (the assembled one, the grouping of the last find()) group by group,
  /// warm-started from and writing to f. One group: solveNsgs on the whole problem, unchanged.
  /// Returns the worst status over the groups (any failure beats kConverged), the largest
  /// sweep count, the summed relaxations, ill-posed contacts and time, the smallest sor, and the
  /// whole problem's error. With several groups workspace.delta holds only the last group's
  /// W f + q on exit.
  shared::NsgsResult solve(const shared::ContactProblemView& problem,
                           const shared::NsgsSettings& settings, shared::NsgsWorkspace& workspace,
                           double* f);

 private:
  int root(int body);
  /// Solves group g (in place or gathered) and records its part of the whole error.
  shared::NsgsResult solveGroup(const shared::ContactProblemView& problem, int g,
                                const shared::NsgsSettings& settings,
                                shared::NsgsWorkspace& workspace, double* f);
  shared::NsgsResult solveGathered(const shared::ContactProblemView& problem, int g,
                                   const shared::NsgsSettings& settings,
                                   shared::NsgsWorkspace& workspace, double* f);

  static constexpr int kMaxPasses = 3;
  struct GroupNorms {
    double residual2 = 0.0, q2 = 0.0, f2 = 0.0, delta2 = 0.0;   // squared, over its rows
    double scale = 0.0;      // max(|q|, |f|, |delta|) over its rows
    int sweeps = 0;          // over the passes
  };

  /// solveNsgs on `view`, on W's blocks when chooseStorage picks them.
  shared::NsgsResult solveChosen(shared::ContactProblemView view,
                                 const shared::NsgsSettings& settings,
                                 shared::NsgsWorkspace& workspace, double* f);

  int count_ = 0;
  int solved_on_blocks_ = 0;
  shared::DelassusBlocks blocks_;
  int blocks_rows_ = 0, blocks_contacts_ = 0;   // what blocks_ is reserved for
  std::vector<GroupNorms> norms_;
  std::vector<int> parent_;        // union-find over bodies: tissues, then instruments
  std::vector<int> label_;         // per contact: the root of one of its bodies
  std::vector<int> group_of_label_;
  std::vector<int> group_;         // per contact
  std::vector<int> start_;         // count + 1
  std::vector<int> members_;       // contacts grouped
  std::vector<int> fill_;          // scratch of find()
  // a gathered group
  std::vector<int> sub_row_offset_;
  std::vector<int> sub_rows_;      // the group's global rows
  std::vector<double> sub_w_, sub_delta_free_, sub_mu_, sub_f_;
};

}  // namespace tactus::sim

// buildW: the contact problem of the detected contacts, W = H C H^T (paper eq. 11).
#include <algorithm>

#include "obstacle_stage.h"
#include "step_stages.h"
#include "tactus/shared/clock.h"

namespace tactus::sim {
namespace {

// The jaw angle's column of one tissue's rows: a row's gap grows by dir . dp/dphi per radian of
// opening (dynamic grip; zeros otherwise).
void gripColumn(const std::vector<Contact>& found, const Instrument& detected, bool dynamic_grip,
                TissueScratch& tx) {
  tx.grip.assign(static_cast<std::size_t>(tx.rows.rows()), 0.0);
  if (!dynamic_grip) return;
  for (std::size_t c = 0; c < found.size(); ++c) {
    const Contact& k = found[c];
    const Eigen::Vector3d dp = detected.gripJacobian(k.feature, k.tool_point_m);
    const int r0 = tx.rows.row_offset[c];
    tx.grip[static_cast<std::size_t>(r0)] = k.n.dot(dp);
    if (tx.rows.row_offset[c + 1] - r0 == 3) {
      tx.grip[static_cast<std::size_t>(r0 + 1)] = k.t1.dot(dp);
      tx.grip[static_cast<std::size_t>(r0 + 2)] = k.t2.dot(dp);
    }
  }
}

// delta_free of one tissue's rows. n rows: with kFreeState the detected gap; otherwise the gap
// carried to the free state along the row (gap - H (x_detected - x_free)). t1, t2 rows: the
// relative tangential displacement of the tool point over the free motion.
void freeGaps(const SimulationModel& model, const StepScratch& scratch, const TissueState& ts,
              TissueScratch& tx, const Instrument& detected, FoundAt found_at) {
  const bool relinearise = found_at != FoundAt::kFreeState;
  const Instrument& tool_free = *scratch.tool_free;
  const shared::Pose& free_pose = tool_free.pose();
  const shared::Pose& tool_begin = scratch.tool_begin;
  const Eigen::VectorXd& q = found_at == FoundAt::kStepStart ? tx.q_begin : ts.body->positions();
  const std::vector<Contact>& found = *ts.found;
  for (std::size_t c = 0; c < found.size(); ++c) {
    const Contact& k = found[c];
    const int r0 = tx.rows.row_offset[c];
    Eigen::Vector3d tissue_free = Eigen::Vector3d::Zero();
    Eigen::Vector3d tissue_detected = Eigen::Vector3d::Zero();
    Eigen::Vector3d tissue_begin = Eigen::Vector3d::Zero();
    for (int j = 0; j < 3; ++j) {
      const int n = k.nodes[j];
      if (n < 0) continue;
      tissue_free += k.weights[j] * tx.q_free.segment<3>(3 * n);
      tissue_detected += k.weights[j] * q.segment<3>(3 * n);
      tissue_begin += k.weights[j] * tx.q_begin.segment<3>(3 * n);
    }
    Eigen::Vector3d tool_free_point = free_pose.pos_m + free_pose.rot * k.tool_local_m;
    if (relinearise && detected.dynamicGrip()) {
      // the jaw point at the free opening (first order in the opening change)
      const double dphi = (detected.gripperOpening() - tool_free.gripperOpening()) *
                          model.spec.instrument.max_opening_rad;
      tool_free_point -= dphi * tool_free.gripJacobian(k.feature, tool_free_point);
    }
    if (relinearise) {
      const Eigen::Vector3d moved =
          (k.tool_point_m - tool_free_point) - (tissue_detected - tissue_free);
      tx.rows.delta_free[r0] = k.gap_m - k.n.dot(moved);
    }
    if (tx.rows.row_offset[c + 1] - r0 == 3) {
      const Eigen::Vector3d slip =
          (tool_free_point - (tool_begin.pos_m + tool_begin.rot * k.tool_local_m)) -
          (tissue_free - tissue_begin);
      tx.rows.delta_free[r0 + 1] = slip.dot(k.t1);
      tx.rows.delta_free[r0 + 2] = slip.dot(k.t2);
    }
  }
}

// Tissue nodes with a non-zero weight in some contact of the last assembled problem.
int countDistinctNodes(const SimulationState& state, StepScratch& scratch) {
  std::vector<std::int64_t>& keys = scratch.node_keys;
  keys.clear();
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    for (const auto* list : {state.tissues[t].found, &state.tissues[t].obstacle_found}) {
      for (const Contact& k : *list) {
        for (int j = 0; j < 3; ++j) {
          if (k.nodes[j] >= 0 && k.weights[j] != 0.0) {
            keys.push_back((static_cast<std::int64_t>(t) << 32) | k.nodes[j]);
          }
        }
      }
    }
  }
  std::sort(keys.begin(), keys.end());
  return static_cast<int>(std::unique(keys.begin(), keys.end()) - keys.begin());
}

// W = sum_tissue H C H^T + H_tool C6 H_tool^T (+ c_g g g^T, + c I), delta_free, J and the
// per-contact data of the problem, from the rows of every tissue.
void assembleProblem(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                     PipelineCounters& counters, int contacts, int rows) {
  const double h = model.h_s;
  ContactProblemData& p = scratch.problem;
  p.contacts = contacts;
  p.rows = rows;
  p.row_offset.assign(1, 0);
  p.contact_id.resize(contacts);
  p.mu.resize(contacts);
  p.point_m.resize(contacts);
  p.normal.resize(contacts);
  p.tangent1.resize(contacts);
  p.tangent2.resize(contacts);
  p.W.setZero(rows, rows);
  p.delta_free.resize(rows);
  p.J.resize(rows, 6);
  scratch.h_tool.resize(rows, 6);
  p.grip.resize(rows);
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    TissueState& ts = state.tissues[t];
    const TissueScratch& tx = scratch.tissues[t];
    const int m = tx.rows.rows();
    const int nc = static_cast<int>(tx.rows.row_offset.size()) - 1;
    for (int c = 1; c <= nc; ++c) p.row_offset.push_back(tx.row_begin + tx.rows.row_offset[c]);
    if (m == 0) continue;
    // the tissue's block in place: W is symmetric, so the transposed view of the row-major block
    // (column-major for the model) is the same matrix
    auto block = p.W.block(tx.row_begin, tx.row_begin, m, m).transpose();
    ts.compliance->addW(tx.rows.tissue, block);
    scratch.h_tool.middleRows(tx.row_begin, m) = tx.rows.tool;
    for (int r = 0; r < m; ++r) p.grip[tx.row_begin + r] = tx.grip[static_cast<std::size_t>(r)];
    for (int r = 0; r < m; ++r) p.delta_free[tx.row_begin + r] = tx.rows.delta_free[r];
    ++counters.w_builds;
  }
  const std::vector<Contact>& all = scratch.all_contacts;
  for (int c = 0; c < contacts; ++c) {
    p.mu[c] = contactFriction(state, all[c], model.spec.instrument.friction_mu);
    p.contact_id[c] = all[c].id;
    p.point_m[c] = all[c].tissue_point_m;
    p.normal[c] = all[c].n;
    p.tangent1[c] = all[c].t1;
    p.tangent2[c] = all[c].t2;
  }
  if (rows == 0) return;
  if (!state.instrument) {
    p.J.setZero();
    return;
  }
  // + H_tool C6 H_tool^T = B B^T with B = H_tool L (C6 = L L^T), each pair (i, j) computed
  // once and written to both halves: W stays symmetric to the bit (the tissue blocks are), so
  // NSGS may use its symmetric sweep
  // (+ c_g g g^T for a dynamic grip, g the jaw angle's column)
  const Instrument& tool = *state.instrument;
  const shared::Matrix6d c6 = tool.compliance6(h);
  const shared::Matrix6d l6 = c6.llt().matrixL();
  scratch.b_tool.noalias() = scratch.h_tool * l6;
  const double c_grip = tool.gripCompliance(h);
  for (int i = 0; i < rows; ++i) {
    const auto bi = scratch.b_tool.row(i);
    double* wi = p.W.row(i).data();
    const double gi = c_grip * p.grip[i];
    for (int j = i; j < rows; ++j) {
      const double w = bi.dot(scratch.b_tool.row(j)) + gi * p.grip[j];
      wi[j] += w;
      if (j != i) p.W(j, i) += w;
    }
  }
  p.J.noalias() = scratch.h_tool * scratch.tool_free->freeMotionSensitivity(h);
  // contact compliance (collision.h): W + c I, penetration c f_n per instrument contact
  for (int c = 0; c < contacts; ++c) {
    if (all[c].kind == ContactKind::kObstacleVertex) continue;
    for (int r = p.row_offset[c]; r < p.row_offset[c + 1]; ++r) {
      p.W(r, r) += model.spec.instrument.contact_compliance_mpn;
    }
  }
}

}  // namespace

void buildW(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
            StepReport& report, PipelineCounters& counters, FoundAt found_at) {
  const double mu = model.spec.instrument.friction_mu;
  const Instrument* detected =   // where the contacts were found (null without an instrument)
      found_at == FoundAt::kStepStart ? scratch.tool_start.get() : state.instrument.get();
  const std::int64_t t0 = shared::monotonicNs();
  int rows = 0;
  int contacts = 0;
  scratch.all_contacts.clear();
  report.contacts_dropped = 0;
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    const TissueState& ts = state.tissues[t];
    TissueScratch& tx = scratch.tissues[t];
    const std::vector<Contact>& found = *ts.found;
    if (ts.collision) report.contacts_dropped += ts.collision->stats().overflow;
    buildContactRows(found, mu, detected ? detected->pose().pos_m : Eigen::Vector3d::Zero(),
                     tx.rows);
    tx.grip.assign(static_cast<std::size_t>(tx.rows.rows()), 0.0);
    if (detected) {
      gripColumn(found, *detected, state.instrument->dynamicGrip(), tx);
      freeGaps(model, scratch, ts, tx, *detected, found_at);
    }
    scratch.all_contacts.insert(scratch.all_contacts.end(), found.begin(), found.end());
    const int obstacle_contacts = appendObstacleRows(state, scratch, t, found_at);
    report.contacts_dropped += ts.obstacle_overflow;
    tx.row_begin = rows;
    tx.contact_begin = contacts;
    rows += tx.rows.rows();
    contacts += static_cast<int>(found.size()) + obstacle_contacts;
  }
  assembleProblem(model, state, scratch, counters, contacts, rows);
  report.distinct_tissue_nodes = countDistinctNodes(state, scratch);
  counters.tangential_rows += rows - contacts;
  report.contacts = contacts;
  report.rows = rows;
  report.times.build_w_s += shared::secondsSinceNs(t0);
}

}  // namespace tactus::sim

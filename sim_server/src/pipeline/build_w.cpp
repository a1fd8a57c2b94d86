// buildW: the contact problem of the detected contacts, W = H C H^T (paper eq. 11).
#include <algorithm>
#include <array>
#include <span>

#include "obstacle_stage.h"
#include "step_stages.h"
#include "tissue_contact_stage.h"
#include "tool_terms.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/grow_only_matrix.h"

namespace tactus::sim {
namespace {

// The jaw angle's column of one tissue's rows: a row's gap grows by dir . dp/dphi per radian of
// opening (dynamic grip; zeros otherwise).
void gripColumn(const std::vector<Contact>& found, const std::vector<Instrument>& detected,
                TissueScratch& tx) {
  tx.grip.assign(static_cast<std::size_t>(tx.rows.rows()), 0.0);
  for (std::size_t c = 0; c < found.size(); ++c) {
    const Contact& k = found[c];
    const Instrument& tool = detected[static_cast<std::size_t>(k.instrument)];
    if (!tool.dynamicGrip()) continue;
    const Eigen::Vector3d dp = tool.gripJacobian(k.feature, k.tool_point_m);
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
              TissueScratch& tx, const std::vector<Instrument>& detected_tools,
              FoundAt found_at) {
  const bool relinearise = found_at != FoundAt::kFreeState;
  const Eigen::VectorXd& q = found_at == FoundAt::kStepStart ? tx.q_begin : ts.body->positions();
  const std::vector<Contact>& found = *ts.found;
  for (std::size_t c = 0; c < found.size(); ++c) {
    const Contact& k = found[c];
    const auto inst = static_cast<std::size_t>(k.instrument);
    const Instrument& tool_free = scratch.tool_free[inst];
    const Instrument& detected = detected_tools[inst];
    const shared::Pose& free_pose = tool_free.pose();
    const shared::Pose& tool_begin = scratch.tool_begin[inst];
    const int r0 = tx.rows.row_offset[c];
    const Eigen::Vector3d tissue_free = tissuePointAt(k, tx.q_free);
    const Eigen::Vector3d tissue_detected = tissuePointAt(k, q);
    const Eigen::Vector3d tissue_begin = tissuePointAt(k, tx.q_begin);
    Eigen::Vector3d tool_free_point = free_pose.pos_m + free_pose.rot * k.tool_local_m;
    if (relinearise && detected.dynamicGrip()) {
      // the jaw point at the free opening (first order in the opening change)
      const double dphi = (detected.gripperOpening() - tool_free.gripperOpening()) *
                          instrumentSpec(model.spec, k.instrument).max_opening_rad;
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

// B = H_i L_i (C6_i = L_i L_i^T) and J's rows (= H_i G_i) over instrument i's rows; returns
// its grip compliance c_g (0 for kinematic jaws). The rows of one instrument are found through
// scratch.row_instrument (-1 for an obstacle's rows, which belong to no instrument).
double prepareToolRows(const SimulationModel& model, const SimulationState& state,
                       StepScratch& scratch, int instrument, int rows) {
  const double h = model.h_s;
  ContactProblemData& p = scratch.problem;
  const Instrument& tool = state.instruments[static_cast<std::size_t>(instrument)];
  const shared::Matrix6d c6 = tool.compliance6(h);
  const shared::Matrix6d l6 = c6.llt().matrixL();
  const shared::Matrix6d g6 =
      scratch.tool_free[static_cast<std::size_t>(instrument)].freeMotionSensitivity(h);
  if (state.instruments.size() == 1) {
    scratch.b_tool.noalias() = scratch.h_tool * l6;
    p.J.noalias() = scratch.h_tool * g6;
  } else {
    scratch.b_tool.resize(rows, 6);
    for (int r = 0; r < rows; ++r) {
      if (scratch.row_instrument[static_cast<std::size_t>(r)] != instrument) continue;
      scratch.b_tool.row(r).noalias() = scratch.h_tool.row(r) * l6;
      p.J.row(r).noalias() = scratch.h_tool.row(r) * g6;
    }
  }
  return tool.gripCompliance(h);
}

// + H_i C6_i H_i^T (+ c_g g g^T) over instrument i's rows, J's rows of instrument i (= H_i G_i)
// and its contact compliance on their diagonal. With upper_only the pairs (i, j > i) go to W's
// upper triangle alone (the caller mirrors it). With terms_added the caller has added B, J and
// the terms already (ToolTerms, one row of W at a time): only the contact compliance is left.
void addToolCompliance(const SimulationModel& model, const SimulationState& state,
                       StepScratch& scratch, int instrument, int rows, bool upper_only,
                       bool terms_added) {
  ContactProblemData& p = scratch.problem;
  // (an obstacle's rows, instrument -1, belong to none)
  const auto owns = [&](int r) {
    return scratch.row_instrument[static_cast<std::size_t>(r)] == instrument;
  };
  if (!terms_added) {
    const double c_grip = prepareToolRows(model, state, scratch, instrument, rows);
    for (int i = 0; i < rows; ++i) {
      if (!owns(i)) continue;
      const double* bi = scratch.b_tool.row(i).data();
      double* wi = p.W.row(i).data();
      const double gi = c_grip * p.grip[i];
      for (int j = i; j < rows; ++j) {
        if (!owns(j)) continue;
        const double w = toolDot(bi, scratch.b_tool.row(j).data()) + gi * p.grip[j];
        wi[j] += w;
        if (j != i && !upper_only) p.W(j, i) += w;
      }
    }
  }
  // contact compliance (collision.h): W + c I, penetration c f_n per contact
  const double c = instrumentSpec(model.spec, instrument).contact_compliance_mpn;
  for (int r = 0; r < rows; ++r) {
    if (owns(r)) p.W(r, r) += c;
  }
}

// setWLower's WColumnsDone in the fused assembly: the instrument's terms on the rows of W just
// written (the block's columns are W's rows: the block is W's transposed view)
struct ToolRowsContext {
  const ToolTerms* terms;
  double* w;
  Eigen::Index ld;
};
void addToolTermsToRows(void* context, int first, int count) {
  const auto& ctx = *static_cast<const ToolRowsContext*>(context);
  for (int i = first; i < first + count; ++i) ctx.terms->addRow(i, ctx.w + i * ctx.ld);
}

// W = sum_tissue H C H^T + H_tool C6 H_tool^T (+ c_g g g^T, + c I), delta_free, J and the
// per-contact data of the problem, from the rows of every tissue.
void assembleProblem(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
                     PipelineCounters& counters, int contacts, int rows) {
  ContactProblemData& p = scratch.problem;
  p.contacts = contacts;
  p.rows = rows;
  p.row_offset.assign(1, 0);
  p.contact_id.resize(contacts);
  p.mu.resize(contacts);
  p.contact_instrument.resize(contacts);
  p.point_m.resize(contacts);
  p.normal.resize(contacts);
  p.tangent1.resize(contacts);
  p.tangent2.resize(contacts);
  // Without rows between tissues every tissue's block is its own, and W is assembled in its
  // upper triangle (row-major: each row's part right of the diagonal, contiguous), the tissue
  // blocks set in place (TissueCompliance::setWLower), the instruments' terms added there, then
  // mirrored once: the bits of the sum of both halves (the tissue blocks are symmetric to the
  // bit, and each term went to both halves alike), for a single write of W's storage instead of
  // a zeroing, a scratch block, its mirror, its sum into W and the instruments' column writes.
  const PairRowsScratch& pairs = scratch.pair_rows;
  bool upper_only = pairs.rows() == 0;
  for (const TissueScratch& tx : scratch.tissues) upper_only = upper_only && tx.pair_parts.empty();
  if (upper_only) {
    p.W.resize(rows, rows);
  } else {
    p.W.setZero(rows, rows);
  }
  p.delta_free.resize(rows);
  p.J.resize(rows, 6);
  scratch.h_tool.resize(rows, 6);
  p.grip.resize(rows);
  // the rows' tool part, grip column and free gaps, and the per-contact data, before W
  for (const TissueScratch& tx : scratch.tissues) {
    const int m = tx.rows.rows();
    const int nc = static_cast<int>(tx.rows.row_offset.size()) - 1;
    for (int c = 1; c <= nc; ++c) p.row_offset.push_back(tx.row_begin + tx.rows.row_offset[c]);
    if (m == 0) continue;
    scratch.h_tool.middleRows(tx.row_begin, m) = tx.rows.tool;
    for (int r = 0; r < m; ++r) p.grip[tx.row_begin + r] = tx.grip[static_cast<std::size_t>(r)];
    for (int r = 0; r < m; ++r) p.delta_free[tx.row_begin + r] = tx.rows.delta_free[r];
  }
  // the rows between tissues, last: no tool part, their pair's contact compliance on the
  // diagonal (added once W's tissue blocks are in, below)
  if (pairs.rows() > 0) {
    const int r0 = pairs.row_begin;
    const int nc = static_cast<int>(pairs.row_offset.size()) - 1;
    for (int c = 1; c <= nc; ++c) p.row_offset.push_back(r0 + pairs.row_offset[c]);
    scratch.h_tool.middleRows(r0, pairs.rows()).setZero();
    for (int r = 0; r < pairs.rows(); ++r) {
      p.grip[r0 + r] = 0.0;
      p.delta_free[r0 + r] = pairs.delta_free[static_cast<std::size_t>(r)];
    }
  }
  const std::vector<Contact>& all = scratch.all_contacts;
  scratch.row_instrument.resize(static_cast<std::size_t>(rows));
  for (int c = 0; c < contacts; ++c) {
    // -1: an obstacle's contact (Obstacles::detect), whose rows have no tool part
    const int tool = all[c].instrument;
    p.contact_instrument[c] = tool;
    p.mu[c] = tool >= 0 ? instrumentSpec(model.spec, tool).friction_mu
              : all[c].kind == ContactKind::kTissueTissue ? tissueContactFriction(state, all[c])
                                                          : obstacleFriction(state, all[c]);
    for (int r = p.row_offset[c]; r < p.row_offset[c + 1]; ++r) {
      scratch.row_instrument[static_cast<std::size_t>(r)] = tool;
    }
    p.contact_id[c] = all[c].id;
    p.point_m[c] = all[c].tissue_point_m;
    p.normal[c] = all[c].n;
    p.tangent1[c] = all[c].t1;
    p.tangent2[c] = all[c].t2;
  }
  // One tissue's block is all of W and one instrument owns every row (the grasps): the
  // instrument's terms go into each row of W as the tissue's block completes it, while the row
  // is in cache, instead of in a second pass over W's upper triangle (the same sums in the same
  // order: the same bits)
  bool fused = upper_only && rows > 0 && state.instruments.size() == 1;
  for (const TissueScratch& tx : scratch.tissues) {
    const int m = tx.rows.rows();
    fused = fused && (m == 0 || (tx.row_begin == 0 && m == rows));
  }
  for (int r = 0; r < rows && fused; ++r) {
    fused = scratch.row_instrument[static_cast<std::size_t>(r)] == 0;
  }
  ToolRowsContext tool_rows{&scratch.tool_terms, p.W.data(), p.W.outerStride()};
  WColumnsDone done;
  if (fused) {
    const double c_grip = prepareToolRows(model, state, scratch, 0, rows);
    scratch.tool_terms.prepare(scratch.b_tool, p.grip.data(), c_grip);
    done = WColumnsDone{&addToolTermsToRows, &tool_rows};
  }
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    TissueState& ts = state.tissues[t];
    const TissueScratch& tx = scratch.tissues[t];
    const int m = tx.rows.rows();
    if (!tx.pair_parts.empty()) {
      // with its parts of the rows between tissues (tissue_contact_stage.h)
      addCoupledTissueW(ts, scratch.tissues[t], p.W);
      ++counters.w_builds;
    }
    if (m == 0) continue;
    if (tx.pair_parts.empty()) {
      // the tissue's block in place: W is symmetric, so the transposed view of the row-major
      // block (column-major for the model) is the same matrix
      auto block = p.W.block(tx.row_begin, tx.row_begin, m, m).transpose();
      if (upper_only) {
        // its lower triangle is the block's upper one in W; right of the block, in its rows,
        // the other tissues' columns (no coupling)
        ts.compliance->setWLower(tx.rows.tissue, block, done);
        p.W.block(tx.row_begin, tx.row_begin + m, m, rows - tx.row_begin - m).setZero();
      } else {
        ts.compliance->addW(tx.rows.tissue, block);
      }
      ++counters.w_builds;
    }
  }
  if (pairs.rows() > 0) {
    const int r0 = pairs.row_begin;
    for (int r = 0; r < pairs.rows(); ++r) {
      p.W(r0 + r, r0 + r) += pairs.compliance_mpn[static_cast<std::size_t>(r)];
    }
  }
  if (rows == 0) return;
  if (state.instruments.empty()) {
    p.J.setZero();
    if (upper_only) shared::mirrorUpperToLower(p.W.map());
    return;
  }
  // + H_tool C6 H_tool^T = B B^T with B = H_tool L (C6 = L L^T), each pair (i, j) computed
  // once and written to both halves: W stays symmetric to the bit (the tissue blocks are), so
  // NSGS may use its symmetric sweep
  // (+ c_g g g^T for a dynamic grip, g the jaw angle's column). Several instruments: each
  // couples only its own rows (H_i C6_i H_i^T); the tissue blocks couple them all.
  // several instruments: each writes its own rows of J; the others' (obstacles', between
  // tissues) stay 0
  if (state.instruments.size() > 1) p.J.setZero();
  for (std::size_t i = 0; i < state.instruments.size(); ++i) {
    addToolCompliance(model, state, scratch, static_cast<int>(i), rows, upper_only, fused);
  }
  if (upper_only) shared::mirrorUpperToLower(p.W.map());
}

}  // namespace

void ToolTerms::prepare(const ToolRows& b, const double* grip, double c_grip) {
  b_ = &b;
  grip_ = grip;
  c_grip_ = c_grip;
  rows_ = b.rows();
  columns_.resize(static_cast<std::size_t>(6 * rows_));
  for (Eigen::Index k = 0; k < 6; ++k) {
    double* col = columns_.data() + k * rows_;
    for (Eigen::Index r = 0; r < rows_; ++r) col[r] = b(r, k);
  }
}

void ToolTerms::addRow(Eigen::Index i, double* wi) const {
  const Eigen::Index m = rows_;
  const double* c0 = columns_.data();
  const double* c1 = c0 + m;
  const double* c2 = c1 + m;
  const double* c3 = c2 + m;
  const double* c4 = c3 + m;
  const double* c5 = c4 + m;
  const double* bi = b_->row(i).data();
  const double a0 = bi[0], a1 = bi[1], a2 = bi[2], a3 = bi[3], a4 = bi[4], a5 = bi[5];
  const double gi = c_grip_ * grip_[i];
  const double* g = grip_;
  // toolDot(B_i, B_j) + gi g_j term by term (a_k c_k[j] is c_k[j] a_k: the same product)
  for (Eigen::Index j = i; j < m; ++j) {
    wi[j] += (a0 * c0[j] + (a2 * c2[j] + a4 * c4[j])) + (a1 * c1[j] + (a3 * c3[j] + a5 * c5[j])) +
             gi * g[j];
  }
}

void buildW(const SimulationModel& model, SimulationState& state, StepScratch& scratch,
            StepReport& report, PipelineCounters& counters, FoundAt found_at) {
  const std::vector<Instrument>& detected =   // where the contacts were found
      found_at == FoundAt::kStepStart ? scratch.tool_start : state.instruments;
  // per instrument: friction and the tool origin of its rows (stack buffers: at most
  // kMaxInstruments)
  std::array<double, shared::kMaxInstruments> mu{};
  std::array<Eigen::Vector3d, shared::kMaxInstruments> origin;
  const std::size_t tools = detected.size();
  for (std::size_t i = 0; i < tools; ++i) {
    mu[i] = instrumentSpec(model.spec, static_cast<int>(i)).friction_mu;
    origin[i] = detected[i].pose().pos_m;
  }
  const std::int64_t t0 = shared::monotonicNs();
  int rows = 0;
  int contacts = 0;
  scratch.all_contacts.clear();
  report.contacts_dropped = 0;
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    const TissueState& ts = state.tissues[t];
    TissueScratch& tx = scratch.tissues[t];
    const std::vector<Contact>& found = *ts.found;
    for (const auto& collision : ts.collisions) {
      report.contacts_dropped += collision->stats().overflow;
    }
    buildContactRows(found, std::span<const double>(mu.data(), tools),
                     std::span<const Eigen::Vector3d>(origin.data(), tools), tx.rows);
    gripColumn(found, detected, tx);
    freeGaps(model, scratch, ts, tx, detected, found_at);
    scratch.all_contacts.insert(scratch.all_contacts.end(), found.begin(), found.end());
    const int obstacle_contacts = appendObstacleRows(state, scratch, t, found_at);
    report.contacts_dropped += ts.obstacle_overflow;
    tx.row_begin = rows;
    tx.contact_begin = contacts;
    rows += tx.rows.rows();
    contacts += static_cast<int>(found.size()) + obstacle_contacts;
  }
  // the contacts between tissues after every tissue's own (tissue_contact_stage.h)
  contacts += appendTissueContactRows(state, scratch, found_at, rows, contacts);
  rows += scratch.pair_rows.rows();
  if (state.tissue_contacts) {
    for (int k = 0; k < state.tissue_contacts->directionCount(); ++k) {
      report.contacts_dropped += state.tissue_contacts->overflow(k);
    }
  }
  // the compliance at the free state, the first time a pass of this step has rows (timed as
  // update_compliance, not here)
  double update_s = 0.0;
  if (rows > 0 && scratch.compliance_pending) {
    const double before = report.times.update_compliance_s;
    ensureCompliance(state, scratch, &report);
    update_s = report.times.update_compliance_s - before;
  }
  assembleProblem(model, state, scratch, counters, contacts, rows);
  report.distinct_tissue_nodes = countDistinctNodes(state, scratch);
  counters.tangential_rows += rows - contacts;   // 0 without friction
  report.contacts = contacts;
  report.rows = rows;
  report.times.build_w_s += shared::secondsSinceNs(t0) - update_s;
}

}  // namespace tactus::sim

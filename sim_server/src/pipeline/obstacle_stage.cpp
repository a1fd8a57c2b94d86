// The static obstacles' part of a step: detection and rows (obstacle_stage.h).
#include "obstacle_stage.h"
#include "tissue_contact_stage.h"

#include <algorithm>
#include <limits>

namespace tactus::sim {

int obstacleRowCapacity(const SceneSpec& spec) {
  if (spec.obstacles.empty()) return 0;
  const bool friction = std::any_of(spec.obstacles.begin(), spec.obstacles.end(),
                                    [](const ObstacleSpec& o) { return o.friction_mu > 0.0; });
  return (friction ? 3 : 1) * spec.obstacle_contact.max_contacts *
         static_cast<int>(spec.tissues.size());
}

shared::SegmentCapacity problemCapacity(const SceneSpec& spec) {
  const bool obstacle_friction =
      std::any_of(spec.obstacles.begin(), spec.obstacles.end(),
                  [](const ObstacleSpec& o) { return o.friction_mu > 0.0; });
  const int obstacle_contacts =
      spec.obstacles.empty()
          ? 0
          : spec.obstacle_contact.max_contacts * static_cast<int>(spec.tissues.size());
  // and the contacts between tissues (tissue_contact_stage.h)
  return shared::SegmentCapacity::forContacts(
      problemContactCapacity(spec) + obstacle_contacts + tissueContactCapacity(spec),
      anyFriction(spec) || obstacle_friction || anyTissueContactFriction(spec));
}

double detectObstacleContacts(const SimulationModel& model, SimulationState& state) {
  double min_gap = std::numeric_limits<double>::infinity();
  if (!state.obstacles) return min_gap;
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    TissueState& ts = state.tissues[t];
    state.obstacles->detect(static_cast<int>(t), model.tissues[t].surface.nodes,
                            ts.body->positions(), ts.obstacle_found, ts.obstacle_overflow);
    // (obstacle_contact.edges: the obstacles' corners and sharp edges against its faces)
    state.obstacles->detectEdges(static_cast<int>(t), ts.body->positions(), ts.obstacle_found,
                                 ts.obstacle_overflow);
    for (const Contact& k : ts.obstacle_found) min_gap = std::min(min_gap, k.gap_m);
  }
  return min_gap;
}

double obstacleFriction(const SimulationState& state, const Contact& contact) {
  if (contact.kind != ContactKind::kObstacleVertex || !state.obstacles) return 0.0;
  return state.obstacles->spec(contact.feature).friction_mu;
}

int appendObstacleRows(const SimulationState& state, StepScratch& scratch, std::size_t t,
                       FoundAt found_at) {
  const TissueState& ts = state.tissues[t];
  TissueScratch& tx = scratch.tissues[t];
  const std::vector<Contact>& found = ts.obstacle_found;
  if (found.empty()) return 0;
  ContactRows& rows = tx.rows;
  const Eigen::VectorXd& q_detected =
      found_at == FoundAt::kStepStart ? tx.q_begin : ts.body->positions();
  int total = rows.rows();
  for (const Contact& k : found) total += obstacleFriction(state, k) > 0.0 ? 3 : 1;
  const int first_new = rows.rows();
  rows.tissue.resize(static_cast<std::size_t>(total));
  rows.tool.conservativeResize(total, 6);
  rows.tool.bottomRows(total - first_new).setZero();
  rows.delta_free.resize(static_cast<std::size_t>(total));
  tx.grip.resize(static_cast<std::size_t>(total), 0.0);
  int r = first_new;
  for (const Contact& k : found) {
    // the tissue point: a vertex (weights 1, 0, 0) or, for an edge's contact, a face point
    const Eigen::Vector3d x_free = tissuePointAt(k, tx.q_free);
    const Eigen::Vector3d x_detected = tissuePointAt(k, q_detected);
    const Eigen::Vector3d x_begin = tissuePointAt(k, tx.q_begin);
    const int per = obstacleFriction(state, k) > 0.0 ? 3 : 1;
    for (int d = 0; d < per; ++d) {
      const Eigen::Vector3d& dir = d == 0 ? k.n : (d == 1 ? k.t1 : k.t2);
      TissueRow& row = rows.tissue[static_cast<std::size_t>(r + d)];
      row.node = k.nodes;
      row.weight = {-k.weights[0], -k.weights[1], -k.weights[2]};
      row.dir = dir;
    }
    // the obstacle is still: the gap closes by the tissue point's own motion along n
    rows.delta_free[static_cast<std::size_t>(r)] = k.gap_m + k.n.dot(x_detected - x_free);
    if (per == 3) {
      const Eigen::Vector3d slip = -(x_free - x_begin);
      rows.delta_free[static_cast<std::size_t>(r + 1)] = slip.dot(k.t1);
      rows.delta_free[static_cast<std::size_t>(r + 2)] = slip.dot(k.t2);
    }
    r += per;
    rows.row_offset.push_back(r);
  }
  scratch.all_contacts.insert(scratch.all_contacts.end(), found.begin(), found.end());
  return static_cast<int>(found.size());
}

}  // namespace tactus::sim

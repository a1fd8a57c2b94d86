// Reaction forces at the fixed nodes, per obstacle and from the instrument (reactions.h).
#include "reactions_stage.h"

#include <algorithm>

namespace tactus::sim {

ReactionForces computeReactions(const SimulationModel& model, SimulationState& state,
                                const StepScratch& scratch) {
  ReactionForces out;
  const int obstacles = state.obstacles ? state.obstacles->count() : 0;
  out.obstacle_force_n.assign(static_cast<std::size_t>(obstacles), Eigen::Vector3d::Zero());
  for (int i = 0; i < obstacles; ++i) out.obstacle_names.push_back(state.obstacles->spec(i).name);
  const Eigen::Vector3d g =
      model.spec.gravity_mps2 ? *model.spec.gravity_mps2 : Eigen::Vector3d::Zero();
  const ContactProblemData& p = scratch.problem;
  Eigen::VectorXd elastic;
  for (std::size_t t = 0; t < state.tissues.size(); ++t) {
    FemBody& body = *state.tissues[t].body;
    const int n = body.nodeCount();
    TissueReactions r;
    r.fixed_reaction_n.setZero(3, n);
    r.contact_force_n.setZero(3, n);
    // one row's H^T f on its nodes, also added to `sum`
    const auto addRowForce = [&r](const TissueRow& tr, double f, Eigen::Vector3d& sum) {
      for (int j = 0; j < 3; ++j) {
        if (tr.node[j] < 0) continue;
        const Eigen::Vector3d force = tr.weight[j] * f * tr.dir;
        r.contact_force_n.col(tr.node[j]) += force;
        sum += force;
      }
    };
    // H^T f of this tissue's rows, and the sums per obstacle and for the instrument
    if (t < scratch.tissues.size() && model.has_contacts && p.rows > 0) {
      const TissueScratch& tx = scratch.tissues[t];
      const int nc = static_cast<int>(tx.rows.row_offset.size()) - 1;
      for (int c = 0; c < nc; ++c) {
        const int global = tx.contact_begin + c;
        if (global >= p.contacts) break;
        const Contact& k = scratch.all_contacts[static_cast<std::size_t>(global)];
        Eigen::Vector3d on_tissue = Eigen::Vector3d::Zero();
        for (int row = tx.rows.row_offset[c]; row < tx.rows.row_offset[c + 1]; ++row) {
          addRowForce(tx.rows.tissue[static_cast<std::size_t>(row)], p.f[tx.row_begin + row],
                      on_tissue);
        }
        if (k.kind == ContactKind::kObstacleVertex) {
          out.obstacle_force_n[static_cast<std::size_t>(k.feature)] += on_tissue;
        } else {
          out.instrument_force_n += on_tissue;
        }
      }
      // its parts of the rows between tissues (tissue_contact_stage.h)
      for (std::size_t k = 0; k < tx.pair_parts.size(); ++k) {
        const int row = tx.pair_part_row[k];
        if (row >= p.rows) break;
        addRowForce(tx.pair_parts[k], p.f[row], r.from_tissues_n);
      }
    }
    const Eigen::VectorXd& mass = body.lumpedMass();
    for (int i = 0; i < n; ++i) r.weight_n += mass[3 * i] * g;
    const bool loaded = t < scratch.tissues.size() && scratch.tissues[t].has_load_force;
    const Eigen::VectorXd* load = loaded ? &scratch.tissues[t].load_force : nullptr;
    if (load) {
      for (int i = 0; i < n; ++i) out.applied_load_n += load->segment<3>(3 * i);
    }
    const std::vector<bool>& fixed = body.fixedMask();
    if (std::find(fixed.begin(), fixed.end(), true) != fixed.end()) {
      body.elasticForce(body.positions(), elastic);
      for (int i = 0; i < n; ++i) {
        if (!fixed[static_cast<std::size_t>(i)]) continue;
        r.fixed_reaction_n.col(i) =
            -(elastic.segment<3>(3 * i) + mass[3 * i] * g + r.contact_force_n.col(i));
        if (load) r.fixed_reaction_n.col(i) -= load->segment<3>(3 * i);
        r.fixed_total_n += r.fixed_reaction_n.col(i);
      }
    }
    out.weight_n += r.weight_n;
    out.fixed_total_n += r.fixed_total_n;
    out.tissues.push_back(std::move(r));
  }
  return out;
}

}  // namespace tactus::sim

// The tissue-against-tissue part of a step (tissue_contact_stage.h).
#include "tissue_contact_stage.h"

#include "tactus/shared/error.h"

#include <fmt/format.h>

#include <algorithm>
#include <limits>

namespace tactus::sim {

std::unique_ptr<TissueContacts> makeTissueContacts(const SimulationModel& model) {
  if (model.spec.tissue_contacts.empty()) return nullptr;
  std::vector<const TetMesh*> meshes;
  std::vector<const SurfaceMesh*> surfaces;
  for (const TissueModel& t : model.tissues) {
    meshes.push_back(&t.mesh);
    surfaces.push_back(&t.surface);
  }
  auto pairs = std::make_unique<TissueContacts>(meshes, surfaces, model.spec.tissue_contacts);
  // Self-contact finds a surface folding onto itself. In the rest shape nothing is folded: a
  // contact found there means the alarm distance or the depth reaches across the tissue (a
  // vertex "behind" another part of its own surface that is only the far side of the body), and
  // every step would push those parts apart (a 7 cm cube inflated to 14 cm with depth 0.1 m).
  std::vector<Eigen::VectorXd> rest(model.tissues.size());
  std::vector<const Eigen::VectorXd*> q;
  for (std::size_t t = 0; t < model.tissues.size(); ++t) {
    const Eigen::Matrix3Xd& x = model.tissues[t].mesh.nodes;
    rest[t] = Eigen::Map<const Eigen::VectorXd>(x.data(), x.size());
    q.push_back(&rest[t]);
  }
  pairs->detect(q);
  for (int k = 0; k < pairs->directionCount(); ++k) {
    const TissueContacts::Direction& d = pairs->direction(k);
    if (d.vertex_tissue != d.surface_tissue) continue;   // two bodies may well touch at rest
    const std::vector<Contact>& found = pairs->contacts(k);
    if (found.empty() && pairs->overflow(k) == 0) continue;
    const TissueContactSpec& spec = pairs->spec(d.pair);
    double deepest = 0.0;
    for (const Contact& c : found) deepest = std::min(deepest, c.gap_m);
    throw SceneError(fmt::format(
        "{}: the self-contact of tissue '{}' finds {} contacts in its rest shape, where nothing "
        "is folded (the deepest {:.3g} m behind its own surface): its alarm_distance ({} m) or "
        "depth ({} m) reaches across the tissue, and every step would push its sides apart; "
        "lower them below the tissue's thickness",
        spec.where, model.tissues[static_cast<std::size_t>(d.vertex_tissue)].name,
        found.size() + static_cast<std::size_t>(pairs->overflow(k)), -deepest,
        spec.alarm_distance_m, spec.depth_m));
  }
  return pairs;
}

double tissueContactFriction(const SimulationState& state, const Contact& contact) {
  if (contact.kind != ContactKind::kTissueTissue || !state.tissue_contacts) return 0.0;
  return state.tissue_contacts->spec(TissueContacts::pairOfId(contact.id)).friction_mu;
}

double detectTissueContacts(SimulationState& state, StepScratch& scratch) {
  double min_gap = std::numeric_limits<double>::infinity();
  if (!state.tissue_contacts) return min_gap;
  scratch.tissue_positions.clear();
  for (const TissueState& ts : state.tissues) {
    scratch.tissue_positions.push_back(&ts.body->positions());
  }
  TissueContacts& pairs = *state.tissue_contacts;
  pairs.detect(scratch.tissue_positions);
  for (int k = 0; k < pairs.directionCount(); ++k) {
    const double c = pairs.spec(pairs.direction(k).pair).contact_compliance_mpn;
    for (const Contact& contact : pairs.contacts(k)) {
      min_gap = std::min(min_gap, contact.gap_m);
      scratch.min_excess_gap =
          std::min(scratch.min_excess_gap, gapBeyondCompliance(state, contact, c));
    }
  }
  return min_gap;
}

int appendTissueContactRows(const SimulationState& state, StepScratch& scratch, FoundAt found_at,
                            int row_begin, int contact_begin) {
  PairRowsScratch& out = scratch.pair_rows;
  out.row_begin = row_begin;
  out.contact_begin = contact_begin;
  out.row_offset.assign(1, 0);
  out.delta_free.clear();
  out.compliance_mpn.clear();
  for (TissueScratch& tx : scratch.tissues) {
    tx.pair_parts.clear();
    tx.pair_part_row.clear();
  }
  if (!state.tissue_contacts) return 0;
  const TissueContacts& pairs = *state.tissue_contacts;
  int added = 0;
  for (int k = 0; k < pairs.directionCount(); ++k) {
    const TissueContacts::Direction& d = pairs.direction(k);
    const TissueContactSpec& spec = pairs.spec(d.pair);
    const auto a = static_cast<std::size_t>(d.vertex_tissue);
    const auto b = static_cast<std::size_t>(d.surface_tissue);
    TissueScratch& ta = scratch.tissues[a];
    TissueScratch& tb = scratch.tissues[b];
    const Eigen::VectorXd& qa_detected =
        found_at == FoundAt::kStepStart ? ta.q_begin : state.tissues[a].body->positions();
    const Eigen::VectorXd& qb_detected =
        found_at == FoundAt::kStepStart ? tb.q_begin : state.tissues[b].body->positions();
    const int per = spec.friction_mu > 0.0 ? 3 : 1;
    for (const Contact& c : pairs.contacts(k)) {
      const int v = c.feature;
      const Eigen::Vector3d s_free = tissuePointAt(c, tb.q_free);
      const Eigen::Vector3d s_detected = tissuePointAt(c, qb_detected);
      const Eigen::Vector3d s_begin = tissuePointAt(c, tb.q_begin);
      const Eigen::Vector3d v_free = ta.q_free.segment<3>(3 * v);
      const Eigen::Vector3d v_detected = qa_detected.segment<3>(3 * v);
      const Eigen::Vector3d v_begin = ta.q_begin.segment<3>(3 * v);
      const int r0 = row_begin + out.rows();
      for (int dir = 0; dir < per; ++dir) {
        const Eigen::Vector3d& axis = dir == 0 ? c.n : (dir == 1 ? c.t1 : c.t2);
        TissueRow on_surface;   // B: the triangle point, as an instrument's tissue row
        on_surface.node = c.nodes;
        on_surface.weight = {-c.weights[0], -c.weights[1], -c.weights[2]};
        on_surface.dir = axis;
        tb.pair_parts.push_back(on_surface);
        tb.pair_part_row.push_back(r0 + dir);
        TissueRow on_vertex;    // A: the vertex, in the tool's role
        on_vertex.node = {v, -1, -1};
        on_vertex.weight = {1.0, 0.0, 0.0};
        on_vertex.dir = axis;
        ta.pair_parts.push_back(on_vertex);
        ta.pair_part_row.push_back(r0 + dir);
        out.compliance_mpn.push_back(spec.contact_compliance_mpn);
      }
      const Eigen::Vector3d moved = (v_detected - v_free) - (s_detected - s_free);
      out.delta_free.push_back(c.gap_m - c.n.dot(moved));
      if (per == 3) {
        const Eigen::Vector3d slip = (v_free - v_begin) - (s_free - s_begin);
        out.delta_free.push_back(slip.dot(c.t1));
        out.delta_free.push_back(slip.dot(c.t2));
      }
      out.row_offset.push_back(out.rows());
      scratch.all_contacts.push_back(c);
      ++added;
    }
  }
  return added;
}

void addCoupledTissueW(TissueState& ts, TissueScratch& tx,
                       shared::GrowOnlyMatrix<Eigen::RowMajor>& W) {
  const int own = tx.rows.rows();
  tx.coupled_rows.assign(tx.rows.tissue.begin(), tx.rows.tissue.end());
  tx.coupled_rows.insert(tx.coupled_rows.end(), tx.pair_parts.begin(), tx.pair_parts.end());
  tx.coupled_global.resize(tx.coupled_rows.size());
  for (int i = 0; i < own; ++i) tx.coupled_global[static_cast<std::size_t>(i)] = tx.row_begin + i;
  std::copy(tx.pair_part_row.begin(), tx.pair_part_row.end(), tx.coupled_global.begin() + own);
  const auto m = static_cast<Eigen::Index>(tx.coupled_rows.size());
  tx.coupled_w.setZero(m, m);
  ts.compliance->addW(tx.coupled_rows, tx.coupled_w);
  // scatter into W. A self-contact row has two parts here, adjacent in coupled_rows: group them
  // (group g = coupled rows [group_begin[g], group_begin[g + 1])) and add, for each pair of
  // groups a <= b, the one sum of their entries to W(a, b) and W(b, a), so W stays symmetric to
  // the bit (NSGS's symmetric sweep relies on it)
  tx.group_begin.clear();
  for (Eigen::Index i = 0; i < m; ++i) {
    if (i == 0 || tx.coupled_global[static_cast<std::size_t>(i)] !=
                      tx.coupled_global[static_cast<std::size_t>(i - 1)]) {
      tx.group_begin.push_back(static_cast<int>(i));
    }
  }
  tx.group_begin.push_back(static_cast<int>(m));
  const std::size_t groups = tx.group_begin.size() - 1;
  for (std::size_t a = 0; a < groups; ++a) {
    const int ga = tx.coupled_global[static_cast<std::size_t>(tx.group_begin[a])];
    for (std::size_t b = a; b < groups; ++b) {
      const int gb = tx.coupled_global[static_cast<std::size_t>(tx.group_begin[b])];
      double sum = 0.0;
      for (int i = tx.group_begin[a]; i < tx.group_begin[a + 1]; ++i) {
        for (int j = tx.group_begin[b]; j < tx.group_begin[b + 1]; ++j) sum += tx.coupled_w(i, j);
      }
      W(ga, gb) += sum;
      if (b != a) W(gb, ga) += sum;
    }
  }
}

void coupledTissueCorrection(TissueState& ts, TissueScratch& tx, const Eigen::VectorXd& f) {
  tx.coupled_f.resize(tx.coupled_global.size());
  for (std::size_t i = 0; i < tx.coupled_global.size(); ++i) {
    tx.coupled_f[i] = f[tx.coupled_global[i]];
  }
  ts.compliance->correction(*ts.body, tx.coupled_rows, tx.coupled_f.data(), tx.dq);
}

}  // namespace tactus::sim

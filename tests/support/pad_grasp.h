#pragma once
// Test support for the flat-pad grasp (scenes/liver_grasp.yaml, liver_grasp_20k.yaml, _23k.yaml):
// runs the scripted grasp (approach, close, lift 2 cm, hold) with an optional perturbation of
// the approach and measures what pad_grasp_test asserts.
//  * held nodes: the tissue nodes with a non-zero weight in some contact when the jaws have
//    closed (t = 2.95 s, before the lift); their mean rise from then to the end of the hold
//    (5.8 s) against the tool's rise.
//  * the smallest volume ratio (det of the deformed / rest edge matrix) over the tets that
//    touch a node in contact, every step from the closing (2 s) to the end of the hold.
//  * per contact step: NSGS status and sweeps, contacts, distinct tissue nodes, total normal
//    force, the contact force the tool carries against gravity, and the geometric penetration
//    after the step (fresh query).

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/pipeline.h"

namespace tactus::test_support {

/// A perturbed approach: every trajectory key after the settling (t > 1 s) moved by `offset_m`
/// and rolled by `roll_deg` about the instrument's own axis (tool z).
struct ApproachPerturbation {
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
  double roll_deg = 0.0;
};

struct PadGraspResult {
  double tool_rise_m = 0.0;
  double held_rise_m = 0.0;
  int held_nodes = 0;
  double min_volume_ratio = 1.0;   ///< over the tets touching a node in contact
  double min_volume_ratio_t_s = 0.0;   ///< when min_volume_ratio was reached
  int min_volume_tet = -1;             ///< which tet (index in the mesh)
  /// over the nodes in contact: the volume of the node's tets (its one-ring patch), deformed /
  /// rest. Unlike the per-tet ratio it does not follow a sliver (liver_23k has tets of quality
  /// 0.004 in the lobe, 0.015 mm^3, that invert under gravity alone), only crushing
  double min_patch_volume_ratio = 1.0;
  int contact_steps = 0;
  int unconverged_steps = 0;       ///< NSGS did not reach its tolerance
  std::vector<double> sweeps;      ///< per contact step
  int max_contacts = 0;
  int max_distinct_nodes = 0;      ///< at the step with max_contacts
  int max_distinct_points = 0;     ///< distinct (jaw, tissue point at 1 um) at that step
  int max_points_held_by_both_jaws = 0;   ///< tissue points with a contact from each jaw
  /// while held (jaws closed, t >= 3 s: the lift and the hold): the most contacts of one step
  /// and that step's distinct tissue nodes
  int max_contacts_held = 0;
  int max_distinct_nodes_held = 0;
  double max_total_normal_n = 0.0;
  double max_load_n = 0.0;         ///< largest contact force on the tool against gravity
  double max_geometric_penetration_m = 0.0;
  std::vector<double> geometric_penetration_m;   ///< after each contact step
};

/// Six times the signed volume of tet t at the positions p (3n).
inline double tetVolume6(const Eigen::VectorXd& p, const std::array<int, 4>& t) {
  const Eigen::Vector3d a = p.segment<3>(3 * t[0]);
  return (p.segment<3>(3 * t[1]) - a).dot((p.segment<3>(3 * t[2]) - a).cross(p.segment<3>(3 * t[3]) - a));
}

inline double tetVolumeRatio(const sim::FemBody& body, const std::array<int, 4>& t) {
  return tetVolume6(body.positions(), t) / tetVolume6(body.restPositions(), t);
}

/// The five perturbed approaches pad_grasp_test asserts (grasp point moved by up to 3 mm, jaw
/// roll by up to 15 deg); tools/pad_grasp_study/pad_grasp_study runs them after the nominal one.
inline std::vector<ApproachPerturbation> testApproaches() {
  return {{Eigen::Vector3d(0.0, 0.003, 0.0), 0.0},
          {Eigen::Vector3d(0.0, -0.003, 0.0), 15.0},
          {Eigen::Vector3d(0.0, 0.0, 0.003), -15.0},
          {Eigen::Vector3d(0.003, 0.0, -0.003), 0.0},
          {Eigen::Vector3d(-0.003, 0.002, 0.0), 10.0}};
}

inline sim::SceneSpec perturbedScene(sim::SceneSpec spec, const ApproachPerturbation& p) {
  const Eigen::Quaterniond roll(
      Eigen::AngleAxisd(p.roll_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
  for (sim::TrajectoryKey& k : spec.instrument.trajectory) {
    if (k.t_s <= 1.0) continue;
    k.pose.position_m += p.offset_m;
    k.pose.orientation = (k.pose.orientation * roll).normalized();
  }
  return spec;
}

inline PadGraspResult runPadGrasp(const sim::SceneSpec& scene, const ApproachPerturbation& p,
                                  double end_s = 5.8) {
  sim::SceneSpec spec = perturbedScene(scene, p);
  spec.haptics.enabled = false;
  sim::Simulation sim(spec);
  const sim::FemBody& body = sim.tissue(0);
  const Eigen::Vector3d up = -spec.gravity_mps2.value_or(Eigen::Vector3d(0, 0, -1)).normalized();
  PadGraspResult out;
  // node -> tets (CSR) for the tets in the jaws
  const auto& tets = body.mesh().tets;
  std::vector<int> node_tet_offset(static_cast<std::size_t>(body.nodeCount()) + 1, 0);
  for (const auto& tet : tets) {
    for (int v : tet) ++node_tet_offset[static_cast<std::size_t>(v) + 1];
  }
  for (std::size_t i = 1; i < node_tet_offset.size(); ++i) node_tet_offset[i] += node_tet_offset[i - 1];
  std::vector<int> node_tet(static_cast<std::size_t>(node_tet_offset.back()));
  {
    std::vector<int> fill(node_tet_offset.begin(), node_tet_offset.end() - 1);
    for (std::size_t t = 0; t < tets.size(); ++t) {
      for (int v : tets[t]) node_tet[static_cast<std::size_t>(fill[static_cast<std::size_t>(v)]++)] = static_cast<int>(t);
    }
  }
  std::vector<int> held;
  double held_z0 = 0.0, tool_z0 = 0.0;
  auto heldZ = [&] {
    double z = 0.0;
    for (int i : held) z += body.positions()[3 * i + 2];
    return held.empty() ? 0.0 : z / static_cast<double>(held.size());
  };
  auto contactNodes = [&] {
    std::set<int> nodes;
    for (const sim::Contact& c : sim.contacts(0)) {
      for (int j = 0; j < 3; ++j) {
        if (c.nodes[j] >= 0 && c.weights[j] != 0.0) nodes.insert(c.nodes[j]);
      }
    }
    return nodes;
  };
  const int steps = static_cast<int>(std::lround(end_s / spec.time_step_s));
  for (int k = 0; k < steps; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const sim::StepReport r = sim.step();
    if (r.contacts > 0) {
      ++out.contact_steps;
      if (r.nsgs.status != shared::NsgsStatus::kConverged) ++out.unconverged_steps;
      out.sweeps.push_back(r.nsgs.sweeps);
      out.max_total_normal_n = std::max(out.max_total_normal_n, r.total_normal_force_n);
      out.max_load_n = std::max(out.max_load_n, -r.tool_wrench.head<3>().dot(up));
      out.max_geometric_penetration_m =
          std::max(out.max_geometric_penetration_m, r.geometric_penetration_m);
      out.geometric_penetration_m.push_back(r.geometric_penetration_m);
      if (sim.time() >= 3.0 - 0.5 * spec.time_step_s && r.contacts > out.max_contacts_held) {
        out.max_contacts_held = r.contacts;
        out.max_distinct_nodes_held = r.distinct_tissue_nodes;
      }
      if (r.contacts > out.max_contacts) {
        out.max_contacts = r.contacts;
        out.max_distinct_nodes = r.distinct_tissue_nodes;
        // tissue points at 1 um, per jaw; and the vertices both jaws hold
        std::set<std::array<long, 4>> points;
        std::set<std::array<long, 3>> any_jaw;
        const auto features = sim.instrument()->features();
        const sim::ContactProblemData& prob = sim.lastProblem();
        for (int c = 0; c < prob.contacts; ++c) {
          const Eigen::Vector3d& p = prob.point_m[static_cast<std::size_t>(c)];
          const std::array<long, 3> q{std::lround(p.x() * 1e6), std::lround(p.y() * 1e6),
                                      std::lround(p.z() * 1e6)};
          // the feature id is bits 32..55 of the contact id (collision.h)
          const auto feature = static_cast<std::size_t>((prob.contact_id[static_cast<std::size_t>(c)] >> 32) & 0xFFFFFFu);
          points.insert({features[feature].part, q[0], q[1], q[2]});
          any_jaw.insert(q);
        }
        out.max_distinct_points = static_cast<int>(points.size());
        out.max_points_held_by_both_jaws = static_cast<int>(points.size() - any_jaw.size());
      }
    }
    const double t = sim.time();
    if (t > 2.0) {   // closing and after: the tets at the nodes in contact
      for (int v : contactNodes()) {
        double patch = 0.0, patch_rest = 0.0;
        for (int i = node_tet_offset[static_cast<std::size_t>(v)]; i < node_tet_offset[static_cast<std::size_t>(v) + 1]; ++i) {
          const auto& tet = tets[static_cast<std::size_t>(node_tet[static_cast<std::size_t>(i)])];
          const double ratio = tetVolumeRatio(body, tet);
          if (ratio < out.min_volume_ratio) {
            out.min_volume_ratio = ratio;
            out.min_volume_ratio_t_s = t;
            out.min_volume_tet = node_tet[static_cast<std::size_t>(i)];
          }
          patch += tetVolume6(body.positions(), tet);
          patch_rest += tetVolume6(body.restPositions(), tet);
        }
        if (patch_rest > 0.0) out.min_patch_volume_ratio = std::min(out.min_patch_volume_ratio, patch / patch_rest);
      }
    }
    if (std::abs(t - 2.95) < 0.5 * spec.time_step_s) {   // jaws closed, before the lift
      const std::set<int> nodes = contactNodes();
      held.assign(nodes.begin(), nodes.end());
      out.held_nodes = static_cast<int>(held.size());
      held_z0 = heldZ();
      tool_z0 = sim.instrument()->pose().pos_m.z();
    }
  }
  out.held_rise_m = heldZ() - held_z0;
  out.tool_rise_m = sim.instrument()->pose().pos_m.z() - tool_z0;
  return out;
}

}  // namespace tactus::test_support

#pragma once
// Test support for the flat-pad grasp (scenes/liver_grasp.yaml, liver_grasp_20k.yaml, _23k.yaml):
// runs the scripted grasp (approach, close, lift 2 cm, hold) with an optional perturbation of
// the approach and measures what pad_grasp_test asserts.
//  * held nodes: the tissue nodes with a non-zero weight in some contact when the jaws have
//    closed (t = 2.95 s, before the lift); their mean rise from then to the end of the hold
//    (5.8 s) against the tool's rise.
//  * the smallest volume ratio (det of the deformed / rest edge matrix) over the tets that
//    touch a node in contact, every step from the closing (2 s) to the end of the hold; and over
//    every tet of the mesh, every step from the start (an inversion anywhere).
//  * the held nodes' rise against the tool's at each 0.1 s from the start of the lift (3 s), to
//    see when a slip shows (what decides how long a run must be).
//  * per contact step: NSGS status and sweeps, contacts, distinct tissue nodes, total normal
//    force, the contact force the tool carries against gravity, and the geometric penetration
//    after the step (fresh query).

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/runner.h"

namespace tactus::test_support {

/// A perturbed approach: every trajectory key after the settling (t > 1 s) moved by `offset_m`
/// and rolled by `roll_deg` about the instrument's own axis (tool z, the jaws' axis); with
/// grip_k_nmprad >= 0 the grasper's grip stiffness replaced (the scene's when negative).
struct ApproachPerturbation {
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
  double roll_deg = 0.0;
  double grip_k_nmprad = -1.0;
};

struct PadGraspResult {
  double tool_rise_m = 0.0;
  double held_rise_m = 0.0;
  int held_nodes = 0;
  double min_volume_ratio = 1.0;   ///< over the tets touching a node in contact
  double min_volume_ratio_t_s = 0.0;   ///< when min_volume_ratio was reached
  int min_volume_tet = -1;             ///< which tet (index in the mesh)
  /// that tet's centroid then, in the tool's frame (z along the jaws, 0 at the hinge end) [m]
  Eigen::Vector3d min_volume_tet_in_tool_m = Eigen::Vector3d::Zero();
  /// over every tet of the mesh, every step from the start: the smallest volume ratio, which tet
  /// and when; inverted_steps counts the steps that ended with a tet at a ratio <= 0
  double min_volume_ratio_anywhere = 1.0;
  int min_volume_tet_anywhere = -1;
  double min_volume_ratio_anywhere_t_s = 0.0;
  int inverted_steps = 0;
  /// (t, held nodes' rise / tool's rise) at each 0.1 s from the start of the lift
  std::vector<std::pair<double, double>> rise_ratio_trace;
  /// why a grasp slips: the jaws' opening (0..1 of the full one) when they have closed (2.95 s);
  /// from then to the end, the fewest contacts one jaw had at a step, and over the steps the
  /// largest share of the friction cone used (sum |f_t| / sum mu f_n; 1: every contact slides)
  /// and the largest fraction of contacts on their cone's boundary (|f_t| >= 0.99 mu f_n)
  double opening_closed = 0.0;
  int min_contacts_one_jaw_held = -1;
  double max_friction_use_held = 0.0;
  double max_sliding_fraction_held = 0.0;
  /// the steps' own time (StepReport's total) in the script's phases: settling (to 1 s), approach
  /// (to 2 s), closing (to 3 s), lift (to 4.5 s), hold (to the end) [s]
  std::array<double, 5> step_s_by_phase{};
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
  /// from the closing (2 s), per 0.1 s: its end, the jaws' opening then (0..1), the smallest tet
  /// ratio in the jaws and the largest total normal force [N] within it
  struct Tenth {
    double t_s = 0.0, opening = 0.0, min_jaw_ratio = 1.0, max_normal_n = 0.0;
  };
  std::vector<Tenth> trace;
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

/// The grasp-anywhere grid on liver_grasp_20k and liver_grasp_23k (pad_grasp_study --grid;
/// pad_grasp_test runs some of its approaches): the grasp point moved over the lobe's free edge by
/// up to 5 mm along the jaws (world x; + backs the jaws out, - pushes them deeper) and sideways
/// along the edge (world y), the jaws rolled by up to 20 deg about their axis, at the scenes'
/// grip (0.015 N m/rad) and at twice it (liver_grasp's 0.03). A central composite design per
/// grip: the 8 corners (x, y, roll at +-5 mm, +-20 deg), the 6 axial points (one of them at its
/// extreme, the others 0) and the centre: 30 approaches.
inline constexpr double kGridOffsetM = 0.005;
inline constexpr double kGridRollDeg = 20.0;
inline constexpr double kGridGripsNmprad[2] = {0.015, 0.03};

inline std::vector<ApproachPerturbation> gridApproaches() {
  std::vector<ApproachPerturbation> out;
  const double d = kGridOffsetM, r = kGridRollDeg;
  for (double grip : kGridGripsNmprad) {
    for (double sx : {-1.0, 1.0}) {
      for (double sy : {-1.0, 1.0}) {
        for (double sr : {-1.0, 1.0}) out.push_back({Eigen::Vector3d(sx * d, sy * d, 0.0), sr * r, grip});
      }
    }
    for (double s : {-1.0, 1.0}) {
      out.push_back({Eigen::Vector3d(s * d, 0.0, 0.0), 0.0, grip});
      out.push_back({Eigen::Vector3d(0.0, s * d, 0.0), 0.0, grip});
      out.push_back({Eigen::Vector3d::Zero(), s * r, grip});
    }
    out.push_back({Eigen::Vector3d::Zero(), 0.0, grip});
  }
  return out;
}

inline sim::SceneSpec perturbedScene(sim::SceneSpec spec, const ApproachPerturbation& p) {
  const Eigen::Quaterniond roll(
      Eigen::AngleAxisd(p.roll_deg * M_PI / 180.0, Eigen::Vector3d::UnitZ()));
  for (sim::TrajectoryKey& k : spec.instrument.trajectory) {
    if (k.t_s <= 1.0) continue;
    k.pose.position_m += p.offset_m;
    k.pose.orientation = (k.pose.orientation * roll).normalized();
  }
  if (p.grip_k_nmprad >= 0.0) spec.instrument.grip_k_nmprad = p.grip_k_nmprad;
  return spec;
}

/// A run's state at the end of the settling (t = 1 s) and what was measured until then: every
/// perturbed approach of the scene starts from it (a perturbation changes the script after 1 s
/// only, and the grip only acts once the jaws touch), which saves each the settling's 100 steps.
struct SettledStart {
  std::string state;          ///< Simulation::saveState at 1 s
  PadGraspResult so_far;
};

PadGraspResult runPadGrasp(const sim::SceneSpec& scene, const ApproachPerturbation& p,
                           double end_s = 5.8, const SettledStart* start = nullptr,
                           std::string* end_state = nullptr);

/// The scene's settling, once (see SettledStart).
inline SettledStart settle(const sim::SceneSpec& scene) {
  SettledStart s;
  s.so_far = runPadGrasp(scene, {}, 1.0, nullptr, &s.state);
  return s;
}

/// Calls f(field) on every field of a PadGraspResult, in one fixed order: what a settled start's
/// file (writeSettledStart) holds of it. A new field must be added here too (the static_assert
/// on the struct's size below says so).
template <class Result, class F>
void forEachField(Result& r, F&& f) {
  f(r.tool_rise_m), f(r.held_rise_m), f(r.held_nodes), f(r.min_volume_ratio);
  f(r.min_volume_ratio_t_s), f(r.min_volume_tet), f(r.min_volume_tet_in_tool_m);
  f(r.min_volume_ratio_anywhere), f(r.min_volume_tet_anywhere);
  f(r.min_volume_ratio_anywhere_t_s), f(r.inverted_steps), f(r.rise_ratio_trace);
  f(r.opening_closed), f(r.min_contacts_one_jaw_held), f(r.max_friction_use_held);
  f(r.max_sliding_fraction_held), f(r.step_s_by_phase), f(r.min_patch_volume_ratio);
  f(r.contact_steps), f(r.unconverged_steps), f(r.sweeps), f(r.max_contacts);
  f(r.max_distinct_nodes), f(r.max_distinct_points), f(r.max_points_held_by_both_jaws);
  f(r.max_contacts_held), f(r.max_distinct_nodes_held), f(r.max_total_normal_n), f(r.max_load_n);
  f(r.max_geometric_penetration_m), f(r.geometric_penetration_m), f(r.trace);
}
static_assert(sizeof(PadGraspResult) == 336,
              "PadGraspResult changed: list its new field in forEachField (pad_grasp.h)");

namespace settled_detail {
constexpr char kMagic[8] = {'T', 'A', 'C', 'T', 'S', 'E', 'T', '1'};

// The small composite values a result holds, stored as their parts in this order.
template <class T>
constexpr bool kIsComposite = std::is_same_v<T, Eigen::Vector3d> ||
                              std::is_same_v<T, std::pair<double, double>> ||
                              std::is_same_v<T, PadGraspResult::Tenth>;
template <class V, class F>
void forEachPart(V& v, F& f) {
  using T = std::remove_const_t<V>;
  if constexpr (std::is_same_v<T, Eigen::Vector3d>) {
    f(v.coeffRef(0)), f(v.coeffRef(1)), f(v.coeffRef(2));
  } else if constexpr (std::is_same_v<T, std::pair<double, double>>) {
    f(v.first), f(v.second);
  } else {
    f(v.t_s), f(v.opening), f(v.min_jaw_ratio), f(v.max_normal_n);
  }
}

// Plain values as their bytes, vectors as their length then their elements.
struct Writer {
  std::string& out;
  template <class T>
  void operator()(const T& v) {
    if constexpr (std::is_same_v<T, std::string>) {
      (*this)(static_cast<std::uint64_t>(v.size()));
      out.append(v);
    } else if constexpr (kIsComposite<T>) {
      forEachPart(v, *this);
    } else if constexpr (requires { v.size(); v.begin(); }) {
      (*this)(static_cast<std::uint64_t>(v.size()));
      for (const auto& x : v) (*this)(x);
    } else {
      static_assert(std::is_arithmetic_v<T>);
      out.append(reinterpret_cast<const char*>(&v), sizeof(v));
    }
  }
};

struct Reader {
  std::string_view in;
  std::size_t at = 0;
  void bytes(void* p, std::size_t n) {
    if (in.size() - at < n) throw std::runtime_error("truncated");
    std::memcpy(p, in.data() + at, n);
    at += n;
  }
  std::uint64_t length() {
    std::uint64_t n = 0;
    (*this)(n);
    if (n > in.size() - at) throw std::runtime_error("corrupt length");
    return n;
  }
  template <class T>
  void operator()(T& v) {
    if constexpr (std::is_same_v<T, std::string>) {
      v.resize(length());
      bytes(v.data(), v.size());
    } else if constexpr (kIsComposite<T>) {
      forEachPart(v, *this);
    } else if constexpr (requires { v.resize(0); }) {
      v.resize(length());
      for (auto& x : v) (*this)(x);
    } else if constexpr (requires { v.size(); v.begin(); }) {
      if (length() != v.size()) throw std::runtime_error("corrupt length");
      for (auto& x : v) (*this)(x);
    } else {
      static_assert(std::is_arithmetic_v<T>);
      bytes(&v, sizeof(v));
    }
  }
};
}  // namespace settled_detail

/// Writes a settled start (the state and what the settling measured) to `path`, through a
/// temporary file and a rename; false (with `why`) if it could not.
inline bool writeSettledStart(const std::filesystem::path& path, const SettledStart& s,
                              std::string& why) {
  std::string bytes(settled_detail::kMagic, sizeof(settled_detail::kMagic));
  settled_detail::Writer w{bytes};
  forEachField(s.so_far, w);
  w(s.state);
  const std::filesystem::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) {
      why = tmp.string() + ": write failed";
      return false;
    }
  }
  std::error_code ec;
  std::filesystem::rename(tmp, path, ec);
  if (ec) why = path.string() + ": " + ec.message();
  return !ec;
}

/// Reads what writeSettledStart wrote; false (with `why`) for a missing, truncated or foreign
/// file. (Simulation::restoreState checks that the state is one of the scene's model.)
inline bool readSettledStart(const std::filesystem::path& path, SettledStart& s,
                             std::string& why) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    why = path.string() + ": cannot be read";
    return false;
  }
  const std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (bytes.compare(0, sizeof(settled_detail::kMagic),
                    std::string_view(settled_detail::kMagic, sizeof(settled_detail::kMagic))) != 0) {
    why = path.string() + ": not a settled start";
    return false;
  }
  try {
    settled_detail::Reader r{bytes, sizeof(settled_detail::kMagic)};
    forEachField(s.so_far, r);
    r(s.state);
    if (r.at != bytes.size()) throw std::runtime_error("trailing bytes");
  } catch (const std::runtime_error& e) {
    why = path.string() + ": " + e.what();
    return false;
  }
  return true;
}

/// The scripted grasp with the perturbation `p` to end_s; from `start` (settle(scene)) instead of
/// t = 0 when given; the simulation's state at the end into `end_state` when given.
inline PadGraspResult runPadGrasp(const sim::SceneSpec& scene, const ApproachPerturbation& p,
                                  double end_s, const SettledStart* start,
                                  std::string* end_state) {
  sim::SceneSpec spec = perturbedScene(scene, p);
  spec.haptics.enabled = false;
  sim::Simulation sim(spec);
  PadGraspResult out;
  if (start != nullptr) {
    sim.restoreState(start->state, "the settled state");
    out = start->so_far;
  }
  const sim::FemBody& body = sim.tissue(0);
  const Eigen::Vector3d up = -spec.gravity_mps2.value_or(Eigen::Vector3d(0, 0, -1)).normalized();
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
  std::vector<double> rest_volume6(tets.size());   // all positive in a valid mesh
  for (std::size_t i = 0; i < tets.size(); ++i) rest_volume6[i] = tetVolume6(body.restPositions(), tets[i]);
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
  // the scripted grasp through the headless runner (tactus/sim/runner.h), measured each step
  double t_before = sim.time();   // the step's start
  const auto measure = [&](long, const sim::StepReport& r) {
    out.step_s_by_phase[t_before < 1.0 - 1e-9   ? 0
                        : t_before < 2.0 - 1e-9 ? 1
                        : t_before < 3.0 - 1e-9 ? 2
                        : t_before < 4.5 - 1e-9 ? 3
                                                : 4] += r.times.total_s;
    const double t_now = sim.time();
    if (t_now > 2.0 + 0.5 * spec.time_step_s) {
      const double end = 0.1 * std::ceil(10.0 * t_now - 1e-6);
      if (out.trace.empty() || out.trace.back().t_s < end - 1e-9) out.trace.push_back({end});
      PadGraspResult::Tenth& tenth = out.trace.back();
      tenth.opening = sim.instrument()->gripperOpening();
      tenth.max_normal_n = std::max(tenth.max_normal_n, r.total_normal_force_n);
    }
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
          if (!out.trace.empty()) out.trace.back().min_jaw_ratio = std::min(out.trace.back().min_jaw_ratio, ratio);
          if (ratio < out.min_volume_ratio) {
            out.min_volume_ratio = ratio;
            out.min_volume_ratio_t_s = t;
            out.min_volume_tet = node_tet[static_cast<std::size_t>(i)];
            Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
            for (int n : tet) centroid += 0.25 * body.positions().segment<3>(3 * n);
            const shared::Pose& tool = sim.instrument()->pose();
            out.min_volume_tet_in_tool_m = tool.rot.conjugate() * (centroid - tool.pos_m);
          }
          patch += tetVolume6(body.positions(), tet);
          patch_rest += tetVolume6(body.restPositions(), tet);
        }
        if (patch_rest > 0.0) out.min_patch_volume_ratio = std::min(out.min_patch_volume_ratio, patch / patch_rest);
      }
    }
    if (t > 2.95 - 0.5 * spec.time_step_s && sim.instrument() != nullptr) {   // the grip's contacts
      const sim::ContactProblemData& prob = sim.lastProblem();
      const auto features = sim.instrument()->features();
      std::array<int, 2> per_jaw{0, 0};
      double ft_sum = 0.0, cone_sum = 0.0;
      int sliding = 0;
      for (int c = 0; c < prob.contacts; ++c) {
        const auto cs = static_cast<std::size_t>(c);
        const auto feature = static_cast<std::size_t>((prob.contact_id[cs] >> 32) & 0xFFFFFFu);
        if (feature < features.size() && features[feature].part >= 0 && features[feature].part < 2) {
          ++per_jaw[static_cast<std::size_t>(features[feature].part)];
        }
        const int row = prob.row_offset[cs];
        if (prob.row_offset[cs + 1] - row < 3) continue;
        const double fn = prob.f[row];
        const double ft = std::hypot(prob.f[row + 1], prob.f[row + 2]);
        ft_sum += ft;
        cone_sum += prob.mu[cs] * fn;
        if (fn > 0.0 && ft >= 0.99 * prob.mu[cs] * fn) ++sliding;
      }
      const int fewest = std::min(per_jaw[0], per_jaw[1]);
      if (out.min_contacts_one_jaw_held < 0 || fewest < out.min_contacts_one_jaw_held) {
        out.min_contacts_one_jaw_held = fewest;
      }
      if (cone_sum > 0.0) out.max_friction_use_held = std::max(out.max_friction_use_held, ft_sum / cone_sum);
      if (prob.contacts > 0) {
        out.max_sliding_fraction_held = std::max(
            out.max_sliding_fraction_held, static_cast<double>(sliding) / prob.contacts);
      }
    }
    bool inverted = false;   // every tet, every step
    for (std::size_t i = 0; i < tets.size(); ++i) {
      const double v6 = tetVolume6(body.positions(), tets[i]);
      if (v6 < out.min_volume_ratio_anywhere * rest_volume6[i]) {
        out.min_volume_ratio_anywhere = v6 / rest_volume6[i];
        out.min_volume_tet_anywhere = static_cast<int>(i);
        out.min_volume_ratio_anywhere_t_s = t;
      }
      inverted = inverted || v6 <= 0.0;
    }
    if (inverted) ++out.inverted_steps;
    if (t > 3.0 - 0.5 * spec.time_step_s && !held.empty()) {
      const long tenth = std::lround(10.0 * t);
      if (std::abs(t - 0.1 * static_cast<double>(tenth)) < 0.5 * spec.time_step_s) {
        const double tool_rise = sim.instrument()->pose().pos_m.z() - tool_z0;
        out.rise_ratio_trace.emplace_back(t, tool_rise > 1e-4 ? (heldZ() - held_z0) / tool_rise : 0.0);
      }
    }
    if (std::abs(t - 2.95) < 0.5 * spec.time_step_s) {   // jaws closed, before the lift
      const std::set<int> nodes = contactNodes();
      held.assign(nodes.begin(), nodes.end());
      out.held_nodes = static_cast<int>(held.size());
      out.opening_closed = sim.instrument()->gripperOpening();
      held_z0 = heldZ();
      tool_z0 = sim.instrument()->pose().pos_m.z();
    }
    t_before = sim.time();
  };
  const long steps = std::lround(end_s / spec.time_step_s);
  sim::runHeadless(sim, {.steps = steps - sim.stepIndex(), .after_step = measure});
  if (end_state != nullptr) *end_state = sim.saveState();
  out.held_rise_m = heldZ() - held_z0;
  out.tool_rise_m = sim.instrument()->pose().pos_m.z() - tool_z0;
  return out;
}

}  // namespace tactus::test_support

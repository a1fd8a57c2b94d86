// The hard-case stability suite, simulation side: each case runs a scene of
// tests/hard_cases/scenes and asserts no NaN/Inf anywhere, the penetration of the solved problem
// (and, where stated, the geometric one) below its bound, every NSGS solve converged below its
// tolerance or stopped exactly at its sweep budget, and no energy growth where nothing drives the
// scene (kinetic + elastic + gravity + the coupling spring's energy).
// Budget stops are bounded per case (expectHealthy's third and fourth arguments): the measured
// count plus a small margin, and the largest residual a budget stop may leave. Measured
// (2026-11-24, 500-sweep budget, tolerance 1e-6): big sphere 7 stops (residual <= 4.61e-6),
// mu 0 7 (1.03e-5), mu 2 2 (3.44e-6), press_through 69 (1.09e-5), every other case 0.
#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <vector>

#include "hard_case_support.h"
#include "tactus/sim/collision.h"
#include "../support/liver_lobe.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::hard_cases {
namespace {

using sim::DeviceTarget;
using sim::FemBody;
using sim::SceneSpec;
using sim::Simulation;
using sim::StepReport;

/// Steps the scene's script until `until_s`; calls `each(report)` after every step.
template <class Each>
void runScript(Simulation& sim, double until_s, Each&& each) {
  const double h = sim.spec().time_step_s;
  while (sim.time() < until_s - 0.5 * h) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time() + h));
    const StepReport r = sim.step();
    each(r);
  }
}

/// Sum of the contact forces of the last solved problem on the tool [N].
Eigen::Vector3d contactForce(const sim::ContactProblemData& p) {
  Eigen::Vector3d F = Eigen::Vector3d::Zero();
  for (int c = 0; c < p.contacts; ++c) {
    const int r0 = p.row_offset[c];
    F += p.f[r0] * p.normal[c];
    if (p.row_offset[c + 1] - r0 == 3) {
      F += p.f[r0 + 1] * p.tangent1[c] + p.f[r0 + 2] * p.tangent2[c];
    }
  }
  return F;
}

/// Volume of the body at its current positions [m^3] and the number of inverted tets.
double meshVolume(const FemBody& body, int* inverted = nullptr) {
  const Eigen::VectorXd& q = body.positions();
  double v = 0.0;
  int bad = 0;
  for (const auto& t : body.mesh().tets) {
    const Eigen::Vector3d a = q.segment<3>(3 * t[0]);
    const double v6 = (q.segment<3>(3 * t[1]) - a)
                          .dot((q.segment<3>(3 * t[2]) - a).cross(q.segment<3>(3 * t[3]) - a));
    v += v6 / 6.0;
    if (v6 <= 0.0) ++bad;
  }
  if (inverted != nullptr) *inverted = bad;
  return v;
}

double restVolume(const FemBody& body) {
  double v = 0.0;
  const Eigen::VectorXd& q = body.restPositions();
  for (const auto& t : body.mesh().tets) {
    const Eigen::Vector3d a = q.segment<3>(3 * t[0]);
    v += (q.segment<3>(3 * t[1]) - a)
             .dot((q.segment<3>(3 * t[2]) - a).cross(q.segment<3>(3 * t[3]) - a)) / 6.0;
  }
  return v;
}

std::string fmt(const char* f, double a, double b = 0.0, double c = 0.0, double d = 0.0) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), f, a, b, c, d);
  return buf;
}

// --- grasp and lift, mu = 0.8 (the paper's scene) -----------------------------------------------

TEST(HardCases, GraspAndLiftWithHighFriction) {
  const SceneSpec spec = loadCase("grasp_lift.yaml");
  Simulation sim(spec);
  const test_support::LiverLobe lobe(sim.tissue(0));
  auto lobe_z = [&] { return lobe.meanZ(); };
  StepWatch watch(spec);
  EnergyWatch rest;
  double z_closed = 0.0;
  double tool_closed = 0.0;
  double lobe_rise = 0.0;
  double tool_rise = 0.0;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    const double t = sim.time();
    watch.add(sim, r, /*geometric=*/t > 4.6 && t < 6.0 && r.contacts > 0);
    if (std::abs(t - 2.95) < 0.005) {
      z_closed = lobe_z();
      tool_closed = sim.instrument()->pose().pos_m.z();
    }
    if (std::abs(t - 5.8) < 0.005) {
      lobe_rise = lobe_z() - z_closed;
      tool_rise = sim.instrument()->pose().pos_m.z() - tool_closed;
    }
    if (t > 7.6) {   // released and gone: nothing drives the scene
      EXPECT_EQ(r.contacts, 0) << "t = " << t;
      rest.add(systemEnergy(sim));
    }
  });
  printCase("grasp_lift_mu0.8", watch.summary() +
                                    fmt(" lobe_rise=%.4g m tool_rise=%.4g m E_rest=%.5g J "
                                        "growth=%.3g J",
                                        lobe_rise, tool_rise, rest.start_j, rest.growth()));
  watch.expectHealthy("grasp_lift", 1e-5, 2, 1.2e-5);
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4) << "penetration beyond 0.5 mm while holding";
  EXPECT_GT(watch.max_contacts, 4);
  EXPECT_GT(tool_rise, 0.018);
  EXPECT_GT(lobe_rise, 0.75 * tool_rise) << "the lobe slipped out of the jaws";
  EXPECT_LE(rest.growth(), 1e-6) << "energy grew after the release";
}

// --- 300+ contacts, redundant W -------------------------------------------------------------------

TEST(HardCases, ThreeHundredContactsWithARedundantContactMatrix) {
  const auto dir = scratchDir("many_contacts");
  writeMesh(sim::makeBoxTetMesh(18, 18, 2, Eigen::Vector3d(0.02, 0.02, 0.004)),
            dir / "fine_slab.vtu");
  const SceneSpec spec = loadGeneratedCase("many_contacts.yaml", dir);
  Simulation sim(spec);
  std::filesystem::remove_all(dir);
  const FemBody& slab = sim.tissue(0);
  // free nodes on the top face: an upper bound on the nodes the contacts can touch
  int top_nodes = 0;
  for (int i = 0; i < slab.nodeCount(); ++i) {
    if (slab.restPositions()[3 * i + 2] > 0.004 - 1e-6 && !slab.fixedMask()[i]) ++top_nodes;
  }
  StepWatch watch(spec);
  EnergyWatch hold;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, /*geometric=*/sim.time() > 0.25);
    if (sim.time() > 0.25 + 1e-9) hold.add(systemEnergy(sim));
  });
  // the DOFs of the contact zone (the touched nodes are top-face nodes); W also carries the
  // tool's 6 DOFs through its rank-6 term
  const double top_dofs = 3.0 * top_nodes;
  printCase("many_contacts", watch.summary() +
                                 fmt(" top_nodes=%.0f rows/dofs=%.3g E_hold=%.4g J growth=%.3g J",
                                     top_nodes, watch.max_rows / top_dofs, hold.start_j,
                                     hold.growth()));
  watch.expectHealthy("many_contacts", 1e-5, 2, 1.2e-5);
  EXPECT_GE(watch.max_contacts, 300);
  EXPECT_EQ(watch.contacts_dropped, 0);
  EXPECT_GT(watch.max_rows, top_dofs) << "fewer rows than the contact zone's DOFs";
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4);
  EXPECT_LE(hold.growth(), 1e-3 * std::abs(hold.start_j) + 1e-9);
}

// A 5 cm sphere flattening a fine surface: sphere/triangle contacts are one per local minimum of
// the distance, so the surface between them is not constrained.
TEST(HardCases, BigSphereOnAFineSurface) {
  const SceneSpec spec = loadCase("big_sphere_fine_surface.yaml");
  Simulation sim(spec);
  StepWatch watch(spec);
  EnergyWatch hold;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, /*geometric=*/sim.time() > 0.25);
    if (sim.time() > 0.25 + 1e-9) hold.add(systemEnergy(sim));
  });
  printCase("big_sphere_fine_surface",
            watch.summary() + fmt(" E_hold=%.4g J growth=%.3g J", hold.start_j, hold.growth()));
  watch.expectHealthy("big sphere", 1e-5, 9, 6e-6);
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4);
  EXPECT_LE(hold.growth(), 1e-3 * std::abs(hold.start_j) + 1e-9);
}

// --- E = 1 kPa against a 1e5 N/m coupling -------------------------------------------------------

// The scene runs exact compliance, contacts detected at the start of the step and vertex contacts
// only (see its comment for why each is needed). Since the scene turns the face contacts off, the
// penetration is also measured by a query with both contact kinds (the tip's sphere against the
// triangles too), under the same bound.
TEST(HardCases, SoftTissueUnderAVeryStiffCoupling) {
  const SceneSpec spec = loadCase("stiff_coupling.yaml");
  Simulation sim(spec);
  StepWatch watch(spec);
  sim::CollisionOptions all_kinds;
  all_kinds.alarm_distance_m = spec.instrument.alarm_distance_m;
  all_kinds.max_contacts = 1000;
  sim::Collision faces_too(sim::extractSurface(sim.tissue(0).mesh()), sim.tissue(0).positions(),
                           all_kinds);
  double min_gap_faces_too = std::numeric_limits<double>::infinity();
  EnergyWatch hold;
  double ratio = 0.0;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, /*geometric=*/true);
    faces_too.refit(sim.tissue(0).positions());
    for (const sim::Contact& c : faces_too.detect(*sim.instrument())) {
      min_gap_faces_too = std::min(min_gap_faces_too, c.gap_m);
    }
    if (sim.time() > 0.5 + 1e-9) hold.add(systemEnergy(sim));
    const auto& p = sim.lastProblem();
    if (r.contacts > 0) {
      // W_nn = tissue + tool; the tool's part is the linear compliance c_l (normal row)
      const double h = spec.time_step_s;
      const auto& in = spec.instrument;
      const double c_tool =
          1.0 / (in.mass_kg / (h * h) + in.coupling_b_nspm / h + in.coupling_k_npm);
      for (int c = 0; c < p.contacts; ++c) {
        const int r0 = p.row_offset[c];
        ratio = std::max(ratio, (p.W(r0, r0) - c_tool) / c_tool);
      }
    }
  });
  const Eigen::Vector3d F = contactForce(sim.lastProblem());
  const Eigen::Vector3d coupling = sim.renderedWrench().head<3>();
  printCase("stiff_coupling", watch.summary() +
                                  fmt(" tissue/tool compliance=%.3g F_contact_z=%.4g N "
                                      "F_hand_z=%.4g N growth=%.3g J",
                                      ratio, F.z(), coupling.z(), hold.growth()));
  watch.expectHealthy("stiff_coupling", 1e-5, 2, 1.2e-5);
  // (the ratio is bounded by the element size: a single surface node of this 0.8 mm mesh has a
  // compliance ~0.25 m/N at 1 kPa; 1e6 would take ~20 um elements)
  EXPECT_GT(ratio, 1e4) << "the case is meant to have a tissue/tool compliance ratio >= 1e4";
  // static stiffness: tissue force per indentation against the coupling's 1e5 N/m
  const double indentation = 0.004 + spec.instrument.tip_radius_m -
                             (sim.instrument()->pose().pos_m.z());
  const double k_tissue = F.z() / indentation;
  printCase("stiff_coupling", fmt("indentation=%.4g m k_tissue=%.4g N/m k_c/k_tissue=%.3g "
                                  "geom_gap(vertices+faces)>=%.3g m",
                                  indentation, k_tissue, spec.instrument.coupling_k_npm / k_tissue,
                                  min_gap_faces_too));
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4);
  EXPECT_GT(min_gap_faces_too, -5e-4);
  // at rest the hand feels the contact force (the god object is in equilibrium)
  EXPECT_GT(F.z(), 1e-3);
  EXPECT_NEAR(coupling.z(), F.z(), 0.02 * F.z());
  EXPECT_LE(hold.growth(), 1e-3 * std::abs(hold.start_j) + 1e-9);
}

// --- 180 degree twist ---------------------------------------------------------------------------
// The twist is prescribed through the Dirichlet nodes: the fixed nodes of the +y end are rotated
// about the rod's axis (y) by theta(t), written into the state before each step (the FEM keeps a
// fixed node where it is and never integrates it). The rest state is untouched, so the linear
// material sees the rotation as strain (its known spurious growth) while the corotational one
// extracts it.

struct TwistResult {
  double volume_ratio = 1.0;       ///< V / V0 at the end
  double max_volume_error = 0.0;   ///< max |V/V0 - 1| during the run
  double max_volume_ratio = 0.0;   ///< max V/V0 during the run
  double mid_angle_deg = 0.0;      ///< mean rotation of the mid-length section's nodes
  int inverted = 0;
  double energy_growth = 0.0;
  double hold_energy = 0.0;
  long nonfinite = 0;
};

TwistResult runTwist(const std::string& file) {
  const SceneSpec spec = loadCase(file);
  Simulation sim(spec);
  FemBody& rod = sim.tissue(0);
  const Eigen::VectorXd& X = rod.restPositions();
  std::vector<int> end;
  std::vector<int> mid;
  for (int i = 0; i < rod.nodeCount(); ++i) {
    const double y = X[3 * i + 1];
    if (rod.fixedMask()[i] && y > 0.0) end.push_back(i);
    const double r = std::hypot(X[3 * i], X[3 * i + 2]);
    if (std::abs(y) < 1.5e-3 && r > 2.5e-3) mid.push_back(i);
  }
  EXPECT_GT(end.size(), 10u);
  EXPECT_GT(mid.size(), 4u);
  const double v0 = restVolume(rod);
  const double h = spec.time_step_s;
  TwistResult out;
  EnergyWatch hold;
  StepWatch watch(spec);
  while (sim.time() < spec.duration_s - 0.5 * h) {
    const double theta = std::numbers::pi * std::min(1.0, (sim.time() + h) / 0.5);
    const Eigen::Matrix3d R = Eigen::AngleAxisd(theta, Eigen::Vector3d::UnitY()).toRotationMatrix();
    for (int i : end) rod.positions().segment<3>(3 * i) = R * X.segment<3>(3 * i);
    watch.add(sim, sim.step());
    const double ratio = meshVolume(rod) / v0;
    out.max_volume_ratio = std::max(out.max_volume_ratio, ratio);
    out.max_volume_error = std::max(out.max_volume_error, std::abs(ratio - 1.0));
    if (sim.time() > 0.5 + 1e-9) hold.add(systemEnergy(sim));
  }
  out.volume_ratio = meshVolume(rod, &out.inverted) / v0;
  double angle = 0.0;
  for (int i : mid) {
    const Eigen::Vector3d x = rod.positions().segment<3>(3 * i);
    const double a0 = std::atan2(X[3 * i], X[3 * i + 2]);
    const double a1 = std::atan2(x[0], x[2]);
    angle += std::remainder(a1 - a0, 2.0 * std::numbers::pi);
  }
  out.mid_angle_deg = std::abs(angle / static_cast<double>(mid.size())) * 180.0 / std::numbers::pi;
  out.energy_growth = hold.growth();
  out.hold_energy = hold.start_j;
  out.nonfinite = watch.nonfinite_steps;
  return out;
}

TEST(HardCases, TwistOf180DegreesKeepsTheVolumeOnlyWithCorotation) {
  const TwistResult co = runTwist("twist_corotational.yaml");
  const TwistResult lin = runTwist("twist_linear.yaml");
  printCase("twist180_corotational",
            fmt("V/V0=%.4f max|dV/V0|=%.4f mid_angle=%.1f deg energy_growth=%.3g J",
                co.volume_ratio, co.max_volume_error, co.mid_angle_deg, co.energy_growth) +
                " inverted=" + std::to_string(co.inverted));
  printCase("twist180_linear",
            fmt("V/V0=%.4f max V/V0=%.4f mid_angle=%.1f deg energy_growth=%.3g J",
                lin.volume_ratio, lin.max_volume_ratio, lin.mid_angle_deg, lin.energy_growth) +
                " inverted=" + std::to_string(lin.inverted));
  EXPECT_EQ(co.nonfinite, 0);
  EXPECT_EQ(lin.nonfinite, 0);
  // corotational: volume within 3% throughout, no inverted element, the middle turned ~90 deg
  EXPECT_LT(co.max_volume_error, 0.03);
  EXPECT_EQ(co.inverted, 0);
  EXPECT_NEAR(co.mid_angle_deg, 90.0, 10.0);
  // linear: the rotation reads as strain; the sections move along chords instead of arcs and the
  // rod inflates (measured: +33% near 95 degrees); at 180 degrees the middle has collapsed
  // through the axis (inverted elements, mid-section not turned) so the net volume says little
  EXPECT_GT(lin.max_volume_ratio - 1.0, 0.2) << "the linear model's spurious growth is missing";
  EXPECT_GT(lin.inverted, 0);
  EXPECT_LT(lin.mid_angle_deg, 10.0);
  // nothing drives the scene once the end stops: no energy growth
  EXPECT_LE(co.energy_growth, 1e-3 * std::abs(co.hold_energy) + 1e-12);
  EXPECT_LE(lin.energy_growth, 1e-3 * std::abs(lin.hold_energy) + 1e-12);
}

// --- slivers and near-inverted elements ---------------------------------------------------------

// A box with a flat cell layer (height 1e-3 of nominal) under the top face and interior nodes
// pushed until one adjacent tet keeps 1e-3 of its nominal volume. Returns the smallest volume
// ratio (tet volume / nominal) found.
sim::TetMesh makeSliverMesh(double* min_ratio) {
  const int nx = 8, ny = 8, nz = 4;
  const Eigen::Vector3d size(0.04, 0.04, 0.02);
  sim::TetMesh mesh = sim::makeBoxTetMesh(nx, ny, nz, size);
  const double dz = size.z() / nz;
  auto id = [&](int i, int j, int k) { return i + (nx + 1) * (j + (ny + 1) * k); };
  // flat layer: the nodes just below the top move up to 1e-3 dz under it
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) mesh.nodes(2, id(i, j, nz - 1)) = size.z() - 1e-3 * dz;
  }
  const double v_nominal = size.prod() / (nx * ny * nz) / 6.0;
  std::vector<std::vector<int>> node_tets(mesh.nodeCount());
  for (int t = 0; t < mesh.tetCount(); ++t) {
    for (int k : mesh.tets[t]) node_tets[k].push_back(t);
  }
  auto volume = [&](int t) {
    const auto& e = mesh.tets[t];
    const Eigen::Vector3d a = mesh.nodes.col(e[0]);
    return (mesh.nodes.col(e[1]) - a)
               .dot((mesh.nodes.col(e[2]) - a).cross(mesh.nodes.col(e[3]) - a)) / 6.0;
  };
  // near-inverted: interior nodes of layer 1 walk along a fixed direction until the smallest
  // adjacent tet is at 1e-3 of nominal (bisection on the step)
  const Eigen::Vector3d dir = Eigen::Vector3d(0.7, 0.5, 0.51).normalized();
  for (int j = 1; j < ny; j += 2) {
    for (int i = 1; i < nx; i += 2) {
      const int n = id(i, j, 1);
      const Eigen::Vector3d x0 = mesh.nodes.col(n);
      auto min_adjacent = [&](double s) {
        mesh.nodes.col(n) = x0 + s * dir;
        double m = 1e300;
        for (int t : node_tets[n]) m = std::min(m, volume(t));
        return m;
      };
      double lo = 0.0, hi = 0.0;
      while (min_adjacent(hi + 1e-4) > 1e-3 * v_nominal) hi += 1e-4;
      hi += 1e-4;
      lo = hi - 1e-4;
      for (int it = 0; it < 60; ++it) {
        const double s = 0.5 * (lo + hi);
        (min_adjacent(s) > 1e-3 * v_nominal ? lo : hi) = s;
      }
      min_adjacent(lo);
    }
  }
  double m = 1e300;
  for (int t = 0; t < mesh.tetCount(); ++t) m = std::min(m, volume(t) / v_nominal);
  *min_ratio = m;
  return mesh;
}

// The scene corrects with the exact compliance (compliance.correction: exact). Measured with the
// paper's warped correction: +1.05e-5 J while holding (bound 3.7e-6 J), and the same on the regular
// 8x8x4 box (+5.2e-6 J): the warped W is 15 % off the exact one under this coarse probe contact,
// a model error that slivers do not cause. Before node rotations were shared across short edges
// (FemBody::nodeRotations), the warped correction inverted 289 slivers and gained 0.26 J.
TEST(HardCases, SliversAndNearInvertedElements) {
  double min_ratio = 0.0;
  const sim::TetMesh mesh = makeSliverMesh(&min_ratio);
  ASSERT_GT(min_ratio, 0.0);
  ASSERT_LT(min_ratio, 2e-3);
  const auto dir = scratchDir("slivers");
  writeMesh(mesh, dir / "slivers.vtu");
  const SceneSpec spec = loadGeneratedCase("slivers.yaml", dir);
  Simulation sim(spec);
  StepWatch watch(spec);
  EnergyWatch hold;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, /*geometric=*/true);
    if (sim.time() > 0.4 + 1e-9) hold.add(systemEnergy(sim));
  });
  int inverted = 0;
  const double volume_ratio = meshVolume(sim.tissue(0), &inverted) / restVolume(sim.tissue(0));
  const Eigen::Vector3d F = contactForce(sim.lastProblem());
  printCase("slivers", watch.summary() +
                           fmt(" min_tet_ratio=%.3g V/V0=%.4f F_z=%.4g N growth=%.3g J",
                               min_ratio, volume_ratio, F.z(), hold.growth()) +
                           " inverted=" + std::to_string(inverted));
  std::filesystem::remove_all(dir);
  watch.expectHealthy("slivers", 1e-5, 2, 1.2e-5);
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4);
  EXPECT_GT(F.z(), 0.1);
  EXPECT_NEAR(volume_ratio, 1.0, 0.03);
  EXPECT_LE(hold.growth(), 1e-3 * std::abs(hold.start_j) + 1e-9);
}

// --- time steps 1e-4 s and 0.04 s ---------------------------------------------------------------

struct PressResult {
  double force_z = 0.0;
  double growth = 0.0;
  double hold_energy = 0.0;
};

PressResult runPress(const std::string& file, StepWatch* watch_out) {
  const SceneSpec spec = loadCase(file);
  Simulation sim(spec);
  StepWatch watch(spec);
  EnergyWatch hold;
  // geometric gap every 10 ms of simulated time (the query costs a refit)
  const long every = std::max(1L, std::lround(0.01 / spec.time_step_s));
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, sim.stepIndex() % every == 0);
    if (sim.time() > 0.4 + 1e-9) hold.add(systemEnergy(sim));
  });
  *watch_out = watch;
  return {sim.renderedWrench()[2], hold.growth(), hold.start_j};
}

TEST(HardCases, TimeSteps1e4And004HoldTheSameForce) {
  StepWatch fine(loadCase("press_dt_1e-4.yaml"));
  StepWatch coarse(loadCase("press_dt_0.04.yaml"));
  const PressResult a = runPress("press_dt_1e-4.yaml", &fine);
  const PressResult b = runPress("press_dt_0.04.yaml", &coarse);
  printCase("dt_1e-4", fine.summary() + fmt(" F_z=%.4g N growth=%.3g J", a.force_z, a.growth));
  printCase("dt_0.04", coarse.summary() + fmt(" F_z=%.4g N growth=%.3g J", b.force_z, b.growth));
  fine.expectHealthy("dt 1e-4", 1e-5, 2, 1.2e-5);
  coarse.expectHealthy("dt 0.04", 1e-5, 2, 1.2e-5);
  EXPECT_GT(fine.min_geometric_gap_m, -5e-4);
  EXPECT_GT(coarse.min_geometric_gap_m, -5e-4);
  EXPECT_GT(a.force_z, 0.3);
  EXPECT_NEAR(b.force_z, a.force_z, 0.05 * a.force_z) << "the rest force depends on h";
  EXPECT_LE(a.growth, 1e-3 * std::abs(a.hold_energy) + 1e-9);
  EXPECT_LE(b.growth, 1e-3 * std::abs(b.hold_energy) + 1e-9);
}

// --- mu = 0 and mu = 2 --------------------------------------------------------------------------

struct DragResult {
  Eigen::Vector3d hand = Eigen::Vector3d::Zero();   ///< coupling force at the end
  double worst_cone = 0.0;     ///< max over contacts/steps of ||f_t|| - mu f_n (>0: violated)
  long tangential_rows = 0;
  bool rows_equal_contacts = true;
  double growth = 0.0;
  double hold_energy = 0.0;
};

DragResult runDrag(const std::string& file, StepWatch* watch_out) {
  const SceneSpec spec = loadCase(file);
  Simulation sim(spec);
  StepWatch watch(spec);
  EnergyWatch hold;
  DragResult out;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, /*geometric=*/true);
    if (r.rows != r.contacts) out.rows_equal_contacts = false;
    const auto& p = sim.lastProblem();
    for (int c = 0; c < p.contacts; ++c) {
      const int r0 = p.row_offset[c];
      if (p.row_offset[c + 1] - r0 != 3) continue;
      const double ft = std::hypot(p.f[r0 + 1], p.f[r0 + 2]);
      out.worst_cone = std::max(out.worst_cone, ft - p.mu[c] * p.f[r0] * (1.0 + 1e-9));
    }
    if (sim.time() > 0.7 + 1e-9) hold.add(systemEnergy(sim));
  });
  out.hand = sim.renderedWrench().head<3>();
  out.tangential_rows = sim.counters().tangential_rows;
  out.growth = hold.growth();
  out.hold_energy = hold.start_j;
  *watch_out = watch;
  return out;
}

// (mu = 2 used to stop at the sweep budget: plain Gauss-Seidel cycled on one step's redundant
// contacts; NsgsSettings::stall_sweeps lowers the relaxation on such a cycle.)
TEST(HardCases, FrictionlessAndMuTwo) {
  StepWatch w0(loadCase("drag_mu0.yaml"));
  StepWatch w2(loadCase("drag_mu2.yaml"));
  const DragResult a = runDrag("drag_mu0.yaml", &w0);
  const DragResult b = runDrag("drag_mu2.yaml", &w2);
  printCase("mu0", w0.summary() + fmt(" F_hand=(%.3g, %.3g, %.3g) N growth=%.3g J", a.hand.x(),
                                      a.hand.y(), a.hand.z(), a.growth));
  printCase("mu2", w2.summary() + fmt(" F_hand=(%.3g, %.3g, %.3g) N cone_excess=%.3g N", b.hand.x(),
                                      b.hand.y(), b.hand.z(), b.worst_cone) +
                       fmt(" growth=%.3g J", b.growth));
  w0.expectHealthy("mu 0", 1e-5, 9, 1.2e-5);
  w2.expectHealthy("mu 2", 1e-5, 4, 5e-6);
  EXPECT_GT(w0.min_geometric_gap_m, -5e-4);
  EXPECT_GT(w2.min_geometric_gap_m, -5e-4);
  // mu = 0: one row per contact, no tangential rows, no lateral force at rest
  EXPECT_EQ(a.tangential_rows, 0);
  EXPECT_TRUE(a.rows_equal_contacts);
  EXPECT_GT(a.hand.z(), 0.02);
  EXPECT_LT(std::abs(a.hand.x()), 0.05 * a.hand.z());
  // mu = 2: the tissue sticks and resists the drag; Coulomb's cone holds at every contact
  EXPECT_GT(b.tangential_rows, 0);
  EXPECT_LE(b.worst_cone, 1e-9);
  EXPECT_LT(b.hand.x(), -0.2 * b.hand.z()) << "no frictional resistance to the drag";
  EXPECT_LE(a.growth, 1e-3 * std::abs(a.hold_energy) + 1e-9);
  EXPECT_LE(b.growth, 1e-3 * std::abs(b.hold_energy) + 1e-9);
}

// --- the tool pressed through the organ ---------------------------------------------------------

// The device target goes 4 mm below the disc's bottom face, at a load the disc carries (the
// scene's header gives the margin and why the case needs exact compliance and step-start
// detection). Asserted: the tip is pressed through the disc's rest thickness, the disc stays
// between the tip and the far side (no top node under the tip above its centre, no inverted
// tet), the tent touches the tool from opposite sides, the contact force holds the god object
// against the coupling, and the hold neither gains energy nor drifts.
TEST(HardCases, ToolPressedThroughTheOrganDoesNotTunnel) {
  const SceneSpec spec = loadCase("press_through.yaml");
  Simulation sim(spec);
  const FemBody& disc = sim.tissue(0);
  const double tip_r = spec.instrument.tip_radius_m;
  const auto [disc_bottom_z, disc_top_z] = restZRange(disc);
  const double target_z = spec.instrument.trajectory.back().pose.position_m.z();
  StepWatch watch(spec);
  EnergyWatch hold;
  double most_opposed = 1.0;   // min over steps and contact pairs of n_i . n_j
  long tunnel_steps = 0;
  long crushed_steps = 0;      // steps that end with an inverted tet
  double first_tunnel_t = -1.0;
  runScript(sim, spec.duration_s, [&](const StepReport& r) {
    watch.add(sim, r, /*geometric=*/true);
    const auto& p = sim.lastProblem();
    for (int i = 0; i < p.contacts; ++i) {
      for (int j = i + 1; j < p.contacts; ++j) {
        most_opposed = std::min(most_opposed, p.normal[i].dot(p.normal[j]));
      }
    }
    // no tunnelling: the top-face nodes right under the tip stay below the tip's centre
    const Eigen::Vector3d c = sim.instrument()->pose().pos_m;
    for (int n = 0; n < disc.nodeCount(); ++n) {
      if (disc.restPositions()[3 * n + 2] < disc_top_z - 1e-6) continue;
      const Eigen::Vector3d x = disc.positions().segment<3>(3 * n);
      if (std::hypot(x.x() - c.x(), x.y() - c.y()) < 0.5 * tip_r && x.z() > c.z()) {
        ++tunnel_steps;
        if (first_tunnel_t < 0.0) first_tunnel_t = sim.time();
        break;
      }
    }
    int inverted = 0;
    meshVolume(disc, &inverted);
    if (inverted > 0) ++crushed_steps;
    if (sim.time() > 0.8 + 1e-9) hold.add(systemEnergy(sim));
  });
  const Eigen::Vector3d tool = sim.instrument()->pose().pos_m;
  const Eigen::Vector3d F = contactForce(sim.lastProblem());
  const Eigen::Vector3d hand = sim.renderedWrench().head<3>();
  printCase("press_through",
            watch.summary() +
                fmt(" tool_z=%.4g m tip_below_bottom=%.3g m min(n_i.n_j)=%.3g", tool.z(),
                    disc_bottom_z - (tool.z() - tip_r), most_opposed) +
                fmt(" F_contact_z=%.4g N F_hand_z=%.4g N growth=%.3g J", F.z(), hand.z(),
                    hold.growth()) +
                " tunnel_steps=" + std::to_string(tunnel_steps) +
                fmt(" first_at=%.2f s", first_tunnel_t) +
                " crushed_steps=" + std::to_string(crushed_steps));
  watch.expectHealthy("press_through", 1e-5, 76, 1.2e-5);
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4);
  EXPECT_EQ(tunnel_steps, 0);
  EXPECT_EQ(crushed_steps, 0) << "tets inverted under the tip";
  EXPECT_LT(most_opposed, -0.3) << "no contacts on opposite sides of the tool";
  // pressed through: the tip's lowest point is below the disc's rest bottom face ...
  EXPECT_LT(tool.z() - tip_r, disc_bottom_z);
  // ... and the disc, not the device, holds the god object: it lags the target by the coupling's
  // stretch and the contact force balances the hand's at rest
  EXPECT_GT(tool.z() - target_z, 0.005) << "the god object followed the device through";
  EXPECT_GT(F.z(), 0.1);
  EXPECT_NEAR(hand.z(), F.z(), 0.02 * F.z());
  EXPECT_LE(hold.growth(), 1e-3 * std::abs(hold.start_j) + 1e-9);
}

// --- NaN and infinity from the device, simulation side ------------------------------------------

TEST(HardCases, NonFiniteDeviceTargetsDoNotCorruptTheSimulation) {
  SceneSpec spec = loadCase("haptic_cube.yaml");
  spec.haptics.enabled = false;
  Simulation sim(spec);
  DeviceTarget good = sim.scriptedTarget(0.0);
  good.pose.pos_m.z() = 0.037;      // 3 mm into the cube
  StepWatch watch(spec);
  auto run = [&](const DeviceTarget& t, int steps) {
    for (int k = 0; k < steps; ++k) {
      sim.setDeviceTarget(t);
      watch.add(sim, sim.step(), /*geometric=*/true);
    }
  };
  run(good, 100);
  const double f_before = sim.renderedWrench()[2];
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  std::vector<DeviceTarget> bad(6, good);
  bad[0].pose.pos_m.x() = nan;
  bad[1].pose.pos_m.z() = -inf;
  bad[2].pose.rot.coeffs() << nan, 0.0, 0.0, 1.0;
  bad[3].twist[2] = inf;
  bad[4].twist[4] = nan;
  bad[5].gripper_opening = nan;
  for (const DeviceTarget& t : bad) {
    run(t, 5);
    EXPECT_TRUE(sim.instrument()->pose().pos_m.allFinite());
    EXPECT_TRUE(sim.instrument()->twist().allFinite());
  }
  run(good, 50);
  const double f_after = sim.renderedWrench()[2];
  printCase("nan_device_sim", watch.summary() +
                                  fmt(" F_before=%.4g N F_after=%.4g N", f_before, f_after));
  watch.expectHealthy("nan target", 1e-5, 2, 1.2e-5);
  EXPECT_GT(watch.min_geometric_gap_m, -5e-4);
  EXPECT_GT(f_before, 0.1);
  EXPECT_NEAR(f_after, f_before, 0.02 * f_before);
}

}  // namespace
}  // namespace tactus::hard_cases

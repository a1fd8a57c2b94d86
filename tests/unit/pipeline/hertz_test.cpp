// Hertz contact through the whole pipeline: a rigid sphere (the probe's tip, radius R, held by a
// very stiff coupling, mu = 0) pressed into a soft block (fixed at its base, no gravity) settles
// at a force F = 4/3 E* sqrt(R) d^(3/2), E* = E / (1 - nu^2), for indentations d <= 5% of R.
//
// The block is 12 contact radii thick (a = sqrt(R d) at d = 5% R) and meshed by a graded tensor
// grid (uniform cells of size h_c under the contact, growing geometrically away from it), each
// cell split into 6 tets; linear material (small strain). Each depth is held until the force is
// steady (static equilibrium reached through heavily damped dynamics); the force is the sum of
// the contact forces. On the finest of three meshes the fitted exponent is within 0.15 of 1.5
// and the force within 15% of Hertz; the force error shrinks with refinement.
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <vector>

#include "tactus/sim/instrument.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/vtk_writer.h"
#include "tactus/sim/pipeline.h"

namespace tactus::sim {
namespace {

constexpr double kR = 0.01;          // sphere radius [m]
constexpr double kE = 10000.0;       // Young's modulus [Pa]
constexpr double kNu = 0.3;
constexpr double kAMax = 0.002236;   // contact radius at d = 5% R: sqrt(R * 0.05 R)

// 0 .. length: uniform cells of size h up to `core`, then cells growing by `growth`.
std::vector<double> gradedAxis(double core, double length, double h, double growth) {
  std::vector<double> x{0.0};
  while (x.back() < core - 1e-12) x.push_back(x.back() + h);
  double step = h;
  while (x.back() < length - 1e-12) {
    step *= growth;
    x.push_back(std::min(length, x.back() + step));
    if (length - x.back() < 0.3 * step * growth) x.back() = length;
  }
  return x;
}

// Block [-W, W]^2 x [-T, 0], fine around the origin of the top face, cells split into 6 tets.
TetMesh gradedBlock(double h, double half_width, double depth, double growth) {
  const std::vector<double> half = gradedAxis(1.4 * kAMax, half_width, h, growth);
  std::vector<double> xs;
  for (auto it = half.rbegin(); it != half.rend(); ++it) xs.push_back(-*it);
  for (std::size_t i = 1; i < half.size(); ++i) xs.push_back(half[i]);
  const std::vector<double> down = gradedAxis(1.4 * kAMax, depth, h, growth);
  std::vector<double> zs;
  for (auto it = down.rbegin(); it != down.rend(); ++it) zs.push_back(-*it);
  const int nx = static_cast<int>(xs.size());
  const int nz = static_cast<int>(zs.size());
  TetMesh m;
  m.nodes.resize(3, nx * nx * nz);
  auto id = [&](int i, int j, int k) { return i + nx * (j + nx * k); };
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < nx; ++j) {
      for (int i = 0; i < nx; ++i) m.nodes.col(id(i, j, k)) = Eigen::Vector3d(xs[i], xs[j], zs[k]);
    }
  }
  // Kuhn split: the 6 monotone paths from corner (0,0,0) to (1,1,1)
  const int perms[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  for (int k = 0; k + 1 < nz; ++k) {
    for (int j = 0; j + 1 < nx; ++j) {
      for (int i = 0; i + 1 < nx; ++i) {
        for (const auto& p : perms) {
          int c[3] = {0, 0, 0};
          std::array<int, 4> tet{};
          tet[0] = id(i, j, k);
          for (int s = 0; s < 3; ++s) {
            c[p[s]] = 1;
            tet[s + 1] = id(i + c[0], j + c[1], k + c[2]);
          }
          const Eigen::Vector3d a = m.nodes.col(tet[0]);
          const double v6 = (m.nodes.col(tet[1]) - a)
                                .dot((m.nodes.col(tet[2]) - a).cross(m.nodes.col(tet[3]) - a));
          if (v6 < 0) std::swap(tet[2], tet[3]);
          m.tets.push_back(tet);
        }
      }
    }
  }
  return m;
}

double hertzForce(double d) {
  const double e_star = kE / (1.0 - kNu * kNu);
  return 4.0 / 3.0 * e_star * std::sqrt(kR) * std::pow(d, 1.5);
}

struct HertzResult {
  std::vector<double> d_m, f_n;
  std::vector<double> min_gap_m;   ///< geometric, by a fresh collision query
  std::vector<int> contacts;
  int nodes = 0;
};

// The sphere: the probe's tip sphere (sphere/triangle contacts), or, with `vertex_contacts`, the
// far end cap of its shaft (capsule/vertex contacts: one contact per surface node under it),
// obtained by turning the probe upside down so that the shaft points down from the tool origin.
HertzResult pressSphere(double h_cell, const std::vector<double>& depths, bool vertex_contacts) {
  const bool flip = vertex_contacts;
  const double shaft = vertex_contacts ? 0.005 : 0.0;
  const auto dir = std::filesystem::temp_directory_path() /
                   ("tactus_hertz_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const double half_width = 6.0 * kAMax;
  const double depth = 12.0 * kAMax;
  const TetMesh mesh = gradedBlock(h_cell, half_width, depth, 1.45);
  writeVtu(dir / "block.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
  char yaml[2048];
  std::snprintf(yaml, sizeof(yaml),
                "time_step: 0.004\n"
                "tissues:\n"
                "  - name: block\n"
                "    mesh: block.vtu\n"
                "    material: {law: linear, young_modulus: %g, poisson_ratio: %g, density: 1000}\n"
                "    damping: {rayleigh_mass: 250}\n"
                "    fixed: {boxes: [{min: [-1, -1, -1], max: [1, 1, %g]}]}\n"
                "    compliance: {model: exact}\n"
                "instrument:\n"
                "  type: probe\n"
                "  mass: 0.01\n"
                "  coupling: {stiffness: 1.0e6, damping: 0, rotational_stiffness: 10,"
                " rotational_damping: 0}\n"
                "  friction: 0\n"
                "  alarm_distance: 0.0002\n"
                "  probe: {tip_radius: %g, shaft_length: %g}\n"
                "  initial_pose: {position: [0, 0, %g], rotation_deg: [%g, 0, 0]}\n"
                "solver: {nsgs_tolerance: 1.0e-8, nsgs_max_sweeps: 2000, max_contacts: 400}\n",
                kE, kNu, -depth + 1e-6, kR, shaft, kR + 1e-4 + shaft, flip ? 180.0 : 0.0);
  Simulation sim(parseScene(yaml, "hertz.yaml", dir));
  std::filesystem::remove_all(dir);
  HertzResult out;
  out.nodes = mesh.nodeCount();
  DeviceTarget target = sim.scriptedTarget(0.0);
  auto force = [&] {
    const ContactProblemData& p = sim.lastProblem();
    double fz = 0.0;
    for (int c = 0; c < p.contacts; ++c) fz += p.f[p.row_offset[c]] * p.normal[c].z();
    return fz;
  };
  for (double d : depths) {
    // ramp to the depth in a few steps, then hold until the force is steady
    const double z_from = target.pose.pos_m.z();
    const double z_to = kR - d + shaft;
    for (int k = 1; k <= 5; ++k) {
      target.pose.pos_m.z() = z_from + (z_to - z_from) * k / 5.0;
      sim.setDeviceTarget(target);
      EXPECT_TRUE(sim.step().finite);
    }
    double last = force();
    for (int k = 0; k < 60; ++k) {
      sim.setDeviceTarget(target);
      EXPECT_TRUE(sim.step().finite);
      const double f = force();
      if (std::abs(f - last) < 5e-4 * std::abs(f) && k > 2) break;
      last = f;
    }
    out.contacts.push_back(sim.lastProblem().contacts);
    out.min_gap_m.push_back(sim.geometricMinGap());
    out.d_m.push_back(kR + shaft - sim.instrument()->pose().pos_m.z());
    out.f_n.push_back(force());
  }
  return out;
}

// Least-squares slope of log F against log d.
double fittedExponent(const HertzResult& r) {
  const int n = static_cast<int>(r.d_m.size());
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (int i = 0; i < n; ++i) {
    const double x = std::log(r.d_m[i]);
    const double y = std::log(r.f_n[i]);
    sx += x;
    sy += y;
    sxx += x * x;
    sxy += x * y;
  }
  return (n * sxy - sx * sy) / (n * sxx - sx * sx);
}

TEST(HertzTest, ForceGrowsLikeTheIndentationToTheThreeHalvesAndConvergesWithRefinement) {
  const std::vector<double> depths = {0.02 * kR, 0.035 * kR, 0.05 * kR};
  const std::vector<double> cells = {1.1e-3, 0.85e-3, 0.65e-3};
  std::vector<double> errors;
  std::vector<double> exponents;
  for (double h : cells) {
    const HertzResult r = pressSphere(h, depths, /*vertex_contacts=*/true);
    double worst = 0.0;
    for (std::size_t i = 0; i < r.d_m.size(); ++i) {
      const double rel = r.f_n[i] / hertzForce(r.d_m[i]) - 1.0;
      std::printf("[hertz] cell %.2f mm (%d nodes): d = %.4f mm  F = %.5g N  Hertz %.5g N  "
                  "error %+.1f%%  contacts %d  min gap %.2g m\n",
                  1e3 * h, r.nodes, 1e3 * r.d_m[i], r.f_n[i], hertzForce(r.d_m[i]), 100 * rel,
                  r.contacts[i], r.min_gap_m[i]);
      EXPECT_GT(r.min_gap_m[i], -0.02 * r.d_m[i]) << "the sphere sank into the surface";
      worst = std::max(worst, std::abs(rel));
    }
    errors.push_back(worst);
    exponents.push_back(fittedExponent(r));
    std::printf("[hertz] cell %.2f mm: exponent %.3f, worst force error %.1f%%\n", 1e3 * h,
                exponents.back(), 100 * worst);
  }
  EXPECT_NEAR(exponents.back(), 1.5, 0.15);
  EXPECT_LT(errors.back(), 0.15);
  // refinement improves the force (finest better than coarsest, never much worse step to step)
  EXPECT_LT(errors.back(), errors.front());
  EXPECT_LE(std::abs(exponents.back() - 1.5), std::abs(exponents.front() - 1.5) + 0.02);
}

// The same press with the probe's tip sphere itself (the brief's "large tip radius"): its
// contacts are sphere/surface-triangle pairs, one per local minimum of the distance, so a sphere
// flattening a fine surface gets a handful of contacts and the nodes between them sink into it
// (measured on the 0.8 mm mesh at d = 0.5 mm: 6 contacts, 0.33 mm geometric penetration, force
// 71% below Hertz, exponent 1.05). Kept as the reproduction of that collision limitation.
TEST(HertzTest, TipSphereContactsKeepTheSurfaceOutOfTheSphere) {
  const HertzResult r = pressSphere(0.8e-3, {0.05 * kR}, /*vertex_contacts=*/false);
  const double rel = r.f_n[0] / hertzForce(r.d_m[0]) - 1.0;
  std::printf("[hertz] tip sphere, cell 0.80 mm: d = %.4f mm  F = %.5g N  Hertz %.5g N  error "
              "%+.1f%%  contacts %d  min gap %.2g m\n",
              1e3 * r.d_m[0], r.f_n[0], hertzForce(r.d_m[0]), 100 * rel, r.contacts[0],
              r.min_gap_m[0]);
  EXPECT_GT(r.min_gap_m[0], -0.1 * r.d_m[0]) << "the sphere sank into the surface";
  EXPECT_LT(std::abs(rel), 0.15);
}

}  // namespace
}  // namespace tactus::sim

// The hard-case suite, beam part: a clamped beam under a large dead tip load
// (scenes/beam_large_load.yaml, material.tangent: consistent) holds its equilibrium for 5 s at
// h = 0.01 s and 0.05 s: no growing out-of-plane mode, the vertical deflection steady and within
// 1 % of L of the elastica, no inverted element. The mesh is the five-tet split, symmetric about
// the load's plane in bending (the six-tet split tilts the bending axes: a static lateral offset
// of 5 % of the deflection even in linear elasticity), so any lateral offset is a mode.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "hard_case_support.h"
#include "tactus/sim/mesh_gen.h"

namespace tactus::hard_cases {
namespace {

constexpr double kLength = 0.1, kSide = 0.01;
// Elastica of a cantilever under a dead tip load P L^2 / (E I) = 10 (shooting on
// EI theta'' = -P cos theta): vertical tip deflection 0.81061 L, tip at x = 0.44500 L.
constexpr double kElasticaDeflection = 0.81061;

struct BeamRun {
  double lateral_max = 0.0;           // largest |mean tip y| over the run [m]
  double deflection_end = 0.0;        // mean tip deflection (down) at the end [m]
  double wander = 0.0;                // max - min of the deflection over the last 2 s [m]
  int inverted_end = 0;
  bool finite = true;
};

BeamRun runBeam(double h, const std::string& tangent) {
  const auto dir = scratchDir("beam");
  writeMesh(sim::makeBoxTetMesh(40, 4, 4, Eigen::Vector3d(kLength, kSide, kSide),
                                Eigen::Vector3d(0, -kSide / 2, -kSide / 2), sim::HexSplit::kFive),
            dir / "beam.vtu");
  sim::SceneSpec spec = loadGeneratedCase("beam_large_load.yaml", dir);
  spec.time_step_s = h;
  spec.tissues[0].tangent =
      tangent == "consistent" ? sim::TangentKind::kConsistent : sim::TangentKind::kCorotated;
  sim::Simulation sim(spec);
  const sim::FemBody& body = sim.tissue(0);
  std::vector<int> tip;
  for (int i = 0; i < body.nodeCount(); ++i)
    if (body.restPositions()[3 * i] > kLength - 1e-9) tip.push_back(i);
  BeamRun run;
  double lo = 1e9, hi = -1e9;
  const int steps = static_cast<int>(std::lround(5.0 / h));
  for (int k = 1; k <= steps; ++k) {
    run.finite = sim.step().finite && run.finite;
    double y = 0.0, z = 0.0;
    for (int i : tip) {
      y += body.positions()[3 * i + 1];
      z += body.restPositions()[3 * i + 2] - body.positions()[3 * i + 2];
    }
    y /= static_cast<double>(tip.size());
    z /= static_cast<double>(tip.size());
    if (!std::isfinite(y) || !std::isfinite(z)) {
      run.finite = false;
      break;
    }
    run.lateral_max = std::max(run.lateral_max, std::abs(y));
    if (k * h > 3.0 - 1e-9) {
      lo = std::min(lo, z);
      hi = std::max(hi, z);
    }
    run.deflection_end = z;
  }
  run.wander = hi - lo;
  run.inverted_end = body.invertedElementCount();
  std::filesystem::remove_all(dir);
  std::printf("[hard-case] beam k = 10, h = %.2f s, tangent %s: deflection %.5f L (elastica "
              "%.5f L), wander over the last 2 s %.2e L, largest lateral tip offset %.2e L, "
              "inverted %d\n",
              h, tangent.c_str(), run.deflection_end / kLength, kElasticaDeflection,
              run.wander / kLength, run.lateral_max / kLength, run.inverted_end);
  return run;
}

void expectHeld(const BeamRun& run) {
  EXPECT_TRUE(run.finite);
  // no out-of-plane mode: the tip stays in the load's plane (the mesh is symmetric about it: the
  // offset is rounding, 1e-14 L; with R K0 R^T it grows to 8 % of L at h = 0.01 s)
  EXPECT_LT(run.lateral_max, 1e-6 * kLength);
  // steady: the deflection moves by less than 1e-5 L over the last 2 s (12 % of L with R K0 R^T)
  EXPECT_LT(run.wander, 1e-5 * kLength);
  // the elastica's deflection within 1 % of L (measured 0.24 % below it)
  EXPECT_NEAR(run.deflection_end / kLength, kElasticaDeflection, 0.01);
  EXPECT_EQ(run.inverted_end, 0);
}

TEST(HardCases, ABeamUnderALargeTipLoadHoldsItsEquilibriumAtTheSceneTimeStep) {
  expectHeld(runBeam(0.01, "consistent"));
}

TEST(HardCases, ABeamUnderALargeTipLoadHoldsItsEquilibriumAtFiveTimesTheTimeStep) {
  expectHeld(runBeam(0.05, "consistent"));
}

// The defect the consistent tangent removes, for the record (not in the test command; run with
// --gtest_also_run_disabled_tests): with R K0 R^T the out-of-plane mode grows at h = 0.01 s and
// the ramp diverges at 0.05 s.
TEST(HardCases, DISABLED_WithTheCorotatedTangentTheBeamsOutOfPlaneModeGrows) {
  for (const double h : {0.01, 0.05}) {
    const BeamRun run = runBeam(h, "corotated");
    EXPECT_GT(run.lateral_max, 1e-2 * kLength);
    EXPECT_GT(run.wander, 1e-2 * kLength);
  }
}

}  // namespace
}  // namespace tactus::hard_cases

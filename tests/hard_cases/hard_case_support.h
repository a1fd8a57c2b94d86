#pragma once
// Shared helpers of the hard-case stability suite: scene loading, generated meshes, per-step
// watchdogs (finite state, penetration, NSGS residual or sweep budget) and the energy of the
// scene including the god object's coupling spring.
//
// Every case prints one line "[hard-case] <name>: ..." with its measured figures.

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>
#include <string>
#include <utility>

#include "tactus/shared/nsgs.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/vtk_writer.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace tactus::hard_cases {

inline const std::filesystem::path kSceneDir =
    std::filesystem::path(TACTUS_HARD_CASES_DIR) / "scenes";

/// A case's scene file (tests/hard_cases/scenes/<file>).
inline sim::SceneSpec loadCase(const std::string& file) {
  return sim::loadScene(kSceneDir / file);
}

/// A case whose mesh the test generates: the scene text is parsed with relative paths resolved
/// against `base_dir` (where the test wrote the mesh).
inline sim::SceneSpec loadGeneratedCase(const std::string& file,
                                        const std::filesystem::path& base_dir) {
  std::ifstream in(kSceneDir / file);
  std::stringstream text;
  text << in.rdbuf();
  return sim::parseScene(text.str(), (kSceneDir / file).string(), base_dir);
}

/// A scratch folder unique to this process (removed by the caller if it wants).
inline std::filesystem::path scratchDir(const std::string& tag) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("tactus_hard_" + tag + "_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return dir;
}

/// Writes a mesh at its rest positions as a .vtu file (read back exactly by loadTetMesh).
inline void writeMesh(const sim::TetMesh& mesh, const std::filesystem::path& path) {
  sim::writeVtu(path, mesh, mesh.nodes, Eigen::Matrix3Xd(), Eigen::VectorXd());
}

/// Lowest and highest z of a body's rest positions [m].
inline std::pair<double, double> restZRange(const sim::FemBody& body) {
  const auto z = body.restPositions()(Eigen::seqN(2, body.nodeCount(), 3));
  return {z.minCoeff(), z.maxCoeff()};
}

/// Kinetic + elastic + gravity energy of the scene plus the potential energy stored in the god
/// object's PD coupling spring (the part of the mechanical energy the engine does not count) [J].
inline double systemEnergy(sim::Simulation& sim) {
  double e = sim.totalEnergy();
  if (sim::Instrument* tool = sim.instrument()) {
    const auto& spec = tool->spec();
    const shared::Vector6d d = shared::poseDifference(tool->targetPose(), tool->pose());
    e += 0.5 * spec.coupling_k_npm * d.head<3>().squaredNorm() +
         0.5 * spec.coupling_k_rot_nmprad * d.tail<3>().squaredNorm();
  }
  return e;
}

/// Per-step checks accumulated over a run.
struct StepWatch {
  double nsgs_tolerance = 1e-6;
  int nsgs_max_sweeps = 500;
  long steps = 0;
  long nonfinite_steps = 0;          ///< report.finite false, or energy/wrench/problem non-finite
  long bad_solves = 0;               ///< neither converged nor stopped at the sweep budget
  long budget_stops = 0;             ///< stopped at nsgs_max_sweeps (budget honoured)
  double max_linear_penetration_m = 0.0;   ///< of the solved (linearised) problem
  double min_geometric_gap_m = std::numeric_limits<double>::infinity();
  double max_residual = 0.0;         ///< of converged solves
  double max_budget_residual = 0.0;  ///< of solves stopped by the budget
  int max_contacts = 0;
  int max_rows = 0;
  int max_sweeps = 0;
  long contacts_dropped = 0;

  explicit StepWatch(const sim::SceneSpec& spec)
      : nsgs_tolerance(spec.solver.nsgs_tolerance), nsgs_max_sweeps(spec.solver.nsgs_max_sweeps) {}

  /// Checks one step; `geometric` also measures the gap by a fresh collision query.
  void add(sim::Simulation& sim, const sim::StepReport& r, bool geometric = false) {
    ++steps;
    bool finite = r.finite && std::isfinite(sim.totalEnergy()) &&
                  sim.renderedWrench().allFinite() && std::isfinite(r.max_penetration_m);
    const sim::ContactProblemData& p = sim.lastProblem();
    if (r.rows > 0) {
      finite = finite && p.W.allFinite() && p.f.allFinite() && p.delta_free.allFinite() &&
               p.J.allFinite();
    }
    if (!finite) ++nonfinite_steps;
    contacts_dropped += r.contacts_dropped;
    max_contacts = std::max(max_contacts, r.contacts);
    max_rows = std::max(max_rows, r.rows);
    if (r.rows > 0) {
      max_linear_penetration_m = std::max(max_linear_penetration_m, r.max_penetration_m);
      max_sweeps = std::max(max_sweeps, r.nsgs.sweeps);
      if (r.nsgs.status == shared::NsgsStatus::kConverged && r.nsgs.error <= nsgs_tolerance) {
        max_residual = std::max(max_residual, r.nsgs.error);
      } else if (r.nsgs.status == shared::NsgsStatus::kMaxSweeps &&
                 r.nsgs.sweeps <= nsgs_max_sweeps && std::isfinite(r.nsgs.error)) {
        ++budget_stops;
        max_budget_residual = std::max(max_budget_residual, r.nsgs.error);
      } else {
        ++bad_solves;
      }
    }
    if (geometric && sim.hasInstrument()) {
      min_geometric_gap_m = std::min(min_geometric_gap_m, sim.geometricMinGap());
    }
  }

  /// The assertions every case shares. A solve stopped at the sweep budget is only tolerated
  /// up to `max_budget_stops` times in the run (each case states its measured count with a small
  /// margin: more means the solver got worse), and each such stop must have left a residual at
  /// most `max_budget_residual` (a finite but useless iterate is not healthy).
  void expectHealthy(const std::string& name, double linear_penetration_bound_m,
                     long max_budget_stops, double max_budget_residual_bound) const {
    EXPECT_EQ(nonfinite_steps, 0) << name << ": non-finite state";
    EXPECT_EQ(bad_solves, 0) << name << ": NSGS neither converged nor stopped at its budget";
    EXPECT_LE(max_linear_penetration_m, linear_penetration_bound_m) << name;
    EXPECT_LE(max_residual, nsgs_tolerance) << name;
    EXPECT_LE(budget_stops, max_budget_stops) << name << ": NSGS stopped at its sweep budget ("
                                              << nsgs_max_sweeps << ") more often than measured";
    EXPECT_LE(max_budget_residual, max_budget_residual_bound)
        << name << ": a solve stopped at the sweep budget left a large residual";
  }

  std::string summary() const {
    char buf[512];
    std::snprintf(buf, sizeof(buf),
                  "steps=%ld contacts<=%d rows<=%d lin_pen=%.3g m geom_gap>=%.3g m "
                  "residual<=%.3g sweeps<=%d budget_stops=%ld (residual<=%.3g) dropped=%ld",
                  steps, max_contacts, max_rows, max_linear_penetration_m, min_geometric_gap_m,
                  max_residual, max_sweeps, budget_stops, max_budget_residual, contacts_dropped);
    return buf;
  }
};

/// Energy watch over a phase in which nothing drives the scene (device target fixed).
struct EnergyWatch {
  double start_j = 0.0;
  double max_j = -std::numeric_limits<double>::infinity();
  double end_j = 0.0;
  bool started = false;
  void add(double e) {
    if (!started) {
      start_j = e;
      started = true;
    }
    max_j = std::max(max_j, e);
    end_j = e;
  }
  double growth() const { return max_j - start_j; }   ///< > 0: energy rose above the start
};

inline void printCase(const std::string& name, const std::string& figures) {
  std::printf("[hard-case] %s: %s\n", name.c_str(), figures.c_str());
  std::fflush(stdout);
}

}  // namespace tactus::hard_cases

#pragma once
// Test support shared by the hanging-liver test and study: a liver mesh fixed at its lowest 10 %
// (by height) hangs under gravity, then the load is removed and it springs back. Counts the
// inverted tetrahedra while it hangs and at the end (docs/design.md, "Inverted elements").

#include <algorithm>
#include <filesystem>
#include <vector>

#include "tactus/sim/fem.h"
#include "tactus/sim/mesh.h"

namespace tactus::test_support {

struct HangingLiverOptions {
  sim::MaterialLaw law = sim::MaterialLaw::kInvertibleNeoHookean;
  sim::TangentKind tangent = sim::TangentKind::kCorotated;
  sim::ElementKind element = sim::ElementKind::kLinearTet;
  double young_pa = 3000.0;
  double poisson = 0.45;
  double density_kgpm3 = 1000.0;
  double mass_damping_per_s = 2.0;     ///< Rayleigh alpha
  double stiffness_damping_s = 0.01;   ///< Rayleigh beta
  double scale = 0.1;                  ///< mesh units to metres (the liver meshes are in dm)
  double fixed_fraction = 0.1;         ///< nodes within this fraction of the height range
  double h_s = 0.01;
  double hang_s = 3.0;                 ///< under gravity
  double release_s = 3.0;              ///< then without
};

struct HangingLiverResult {
  int tets = 0;
  int inverted_max_hanging = 0;        ///< the most inverted at a step start while hanging
  int inverted_end_hanging = 0;        ///< inverted when the load is removed
  int inverted_max_released = 0;       ///< the most after the release
  int inverted_end = 0;                ///< at the end
  double min_ratio_hanging = 1.0;      ///< smallest det F while hanging (sampled every step)
  double min_ratio_end = 1.0;          ///< at the end
  double kinetic_end_j = 0.0;
  bool ok = true;                      ///< every step solved and finite
};

inline HangingLiverResult hangLiver(const std::filesystem::path& mesh_path,
                                    const HangingLiverOptions& o) {
  sim::TetMesh mesh = sim::loadTetMesh(mesh_path);
  sim::transformMesh(mesh, o.scale, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero());
  const double z_lo = mesh.nodes.row(2).minCoeff(), z_hi = mesh.nodes.row(2).maxCoeff();
  std::vector<int> fixed;
  for (int i = 0; i < mesh.nodeCount(); ++i)
    if (mesh.nodes(2, i) <= z_lo + o.fixed_fraction * (z_hi - z_lo)) fixed.push_back(i);
  sim::TissueSpec tissue;
  tissue.law = o.law;
  tissue.tangent = o.tangent;
  tissue.element = o.element;
  tissue.young_pa = o.young_pa;
  tissue.poisson = o.poisson;
  tissue.density_kgpm3 = o.density_kgpm3;
  tissue.damping = sim::RayleighSpec{o.mass_damping_per_s, o.stiffness_damping_s};
  sim::FemBody body(mesh, sim::femMaterial(tissue), fixed, nullptr);
  Eigen::VectorXd weight = Eigen::VectorXd::Zero(body.dofCount());
  for (int i = 0; i < body.nodeCount(); ++i) weight[3 * i + 2] = -9.81 * body.lumpedMass()[3 * i];
  const Eigen::VectorXd none = Eigen::VectorXd::Zero(body.dofCount());
  HangingLiverResult r;
  r.tets = mesh.tetCount();
  Eigen::VectorXd ratio;
  const int hang_steps = static_cast<int>(o.hang_s / o.h_s + 0.5);
  const int release_steps = static_cast<int>(o.release_s / o.h_s + 0.5);
  for (int k = 0; k < hang_steps + release_steps && r.ok; ++k) {
    const bool hanging = k < hang_steps;
    const sim::FemStepStats s = body.freeMotion(o.h_s, hanging ? &weight : &none);
    r.ok = s.ok && body.positions().allFinite();

    if (hanging) {
      r.inverted_max_hanging = std::max(r.inverted_max_hanging, s.inverted_elements);
      body.volumeRatios(ratio);
      r.min_ratio_hanging = std::min(r.min_ratio_hanging, ratio.minCoeff());
      if (k == hang_steps - 1) r.inverted_end_hanging = body.invertedElementCount();
    } else {
      r.inverted_max_released = std::max(r.inverted_max_released, s.inverted_elements);
    }
  }
  r.inverted_end = body.invertedElementCount();
  body.volumeRatios(ratio);
  r.min_ratio_end = ratio.minCoeff();
  r.kinetic_end_j = body.kineticEnergy();
  return r;
}

}  // namespace tactus::test_support

// FemBody's queries of the current state: node rotations, stresses, volume ratios, energies.
#include <cmath>

#include "fem_body_impl.h"
#include "fem_constitutive.h"
#include "tactus/shared/error.h"

namespace tactus::sim {

void FemBody::nodeRotations(std::vector<Eigen::Matrix3d>& out, std::vector<double>* coherence,
                            int smoothing_passes) const {
  Impl& m = *impl_;
  if (smoothing_passes < 0) throw Error("nodeRotations: smoothing_passes must be >= 0");
  out.assign(m.n, Eigen::Matrix3d::Identity());
  if (coherence != nullptr) coherence->assign(m.n, 1.0);
  if (!m.corotational) return;
  std::vector<Eigen::Matrix3d>& element_rot = m.query_element_rot;
  element_rot.resize(static_cast<std::size_t>(m.mesh.tetCount()));
  if (!m.general_loop && !m.rotation.empty()) {
    // each element's polar factor by the element loop's Newton steps from the rotation the last
    // element loop kept (the step's linearisation point q + h v, close to q): two or three
    // steps instead of a cold decomposition, the same factors (the reference path where F is
    // ill-conditioned or the steps do not converge); summed in the mesh's order as the cold path
    // does (docs/design.md, "The rotation, warm-started")
    m.rotationsAt(m.q, m.query_rotation);
    for (std::size_t slot = 0; slot < m.assembly_elems.size(); ++slot) {
      const FemBody::Impl::RotationBatch& b = m.query_rotation[slot / 4];
      Eigen::Matrix3d& r = element_rot[static_cast<std::size_t>(m.assembly_elems[slot].index)];
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) r(i, j) = b.r[i][j][slot % 4];
    }
  } else {
    for (int e = 0; e < m.mesh.tetCount(); ++e)
      element_rot[e] = fem_detail::polarRotation(m.elementF(e, m.q));
  }
  m.counters.rotation_extractions += m.mesh.tetCount();
  std::vector<Eigen::Matrix3d> acc;
  std::vector<double> weight;
  m.sumNodeRotations(&element_rot, acc, weight);
  m.finishNodeRotations(acc, weight, out, smoothing_passes);
  if (coherence == nullptr) return;
  // |sum v_e R_e|_F / (sqrt(3) sum v_e) over the same elements (groups, passes) as the average
  for (int i = 0; i < m.n; ++i)
    (*coherence)[i] = weight[i] > 0.0 ? acc[i].norm() / (std::sqrt(3.0) * weight[i]) : 1.0;
}

void FemBody::stepNodeRotations(std::vector<Eigen::Matrix3d>& out,
                                std::vector<double>* coherence, int smoothing_passes) const {
  Impl& m = *impl_;
  if (smoothing_passes < 0) throw Error("stepNodeRotations: smoothing_passes must be >= 0");
  if (!m.corotational || !m.rotation_current) {
    nodeRotations(out, coherence, smoothing_passes);
    return;
  }
  m.ensureStepNodeSums();
  m.work_acc = m.step_acc;
  m.work_w = m.step_w;
  m.finishNodeRotations(m.work_acc, m.work_w, out, smoothing_passes);
  if (coherence == nullptr) return;
  coherence->resize(static_cast<std::size_t>(m.n));
  for (int i = 0; i < m.n; ++i)
    (*coherence)[i] =
        m.work_w[i] > 0.0 ? m.work_acc[i].norm() / (std::sqrt(3.0) * m.work_w[i]) : 1.0;
}

void FemBody::fittedNodeRotations(std::vector<Eigen::Matrix3d>& out, int smoothing_passes) const {
  Impl& m = *impl_;
  if (smoothing_passes < 0) throw Error("fittedNodeRotations: smoothing_passes must be >= 0");
  if (!m.corotational) {
    out.assign(m.n, Eigen::Matrix3d::Identity());
    return;
  }
  m.sumNodeGradients(m.q, m.work_acc, m.work_w);
  m.finishNodeRotations(m.work_acc, m.work_w, out, smoothing_passes);
}

void FemBody::stresses(std::vector<Eigen::Matrix3d>& out) const {
  const Impl& m = *impl_;
  out.resize(m.mesh.tetCount());
  for (int e = 0; e < m.mesh.tetCount(); ++e) {
    const Eigen::Matrix3d f = m.elementF(e, m.q);
    const Eigen::Matrix3d r =
        m.corotational ? fem_detail::polarRotation(f) : Eigen::Matrix3d::Identity();
    if (m.material.law == MaterialLaw::kInvertibleNeoHookean) {
      // P R^T = U diag(P^) U^T: the corotational law's R sigma R^T for any law
      Eigen::Matrix3d u, vf;
      Eigen::Vector3d st;
      fem_detail::rotationSvd(f, r, u, st, vf);
      fem_detail::PrincipalResponse resp;
      fem_detail::principalResponse(m.material.law, m.lambda, m.mu, st, false, resp);
      out[e] = u * resp.stress.asDiagonal() * u.transpose();
      continue;
    }
    const Eigen::Matrix3d fl = r.transpose() * f;
    const Eigen::Matrix3d s =
        m.sigma(0.5 * (fl + fl.transpose()) - Eigen::Matrix3d::Identity());
    out[e] = r * s * r.transpose();
  }
}

void FemBody::volumeRatios(Eigen::VectorXd& out) const {
  const Impl& m = *impl_;
  out.resize(m.mesh.tetCount());
  for (int e = 0; e < m.mesh.tetCount(); ++e) out[e] = m.elementF(e, m.q).determinant();
}

int FemBody::invertedElementCount() const {
  const Impl& m = *impl_;
  int count = 0;
  for (int e = 0; e < m.mesh.tetCount(); ++e) {
    if (!(m.elementF(e, m.q).determinant() > 0.0)) ++count;
  }
  return count;
}

void FemBody::vonMises(Eigen::VectorXd& out) const {
  std::vector<Eigen::Matrix3d> s;
  stresses(s);
  out.resize(static_cast<Eigen::Index>(s.size()));
  for (std::size_t e = 0; e < s.size(); ++e) {
    const Eigen::Matrix3d dev = s[e] - s[e].trace() / 3.0 * Eigen::Matrix3d::Identity();
    out[static_cast<Eigen::Index>(e)] = std::sqrt(1.5 * dev.squaredNorm());
  }
}

double FemBody::kineticEnergy() const {
  return 0.5 * impl_->v.dot(impl_->mass.cwiseProduct(impl_->v));
}

double FemBody::elasticEnergy() const {
  const Impl& m = *impl_;
  if (m.general_loop) return m.generalEnergy(m.q);
  double energy = 0.0;
  for (int e = 0; e < m.mesh.tetCount(); ++e) {
    const Eigen::Matrix3d f = m.elementF(e, m.q);
    const Eigen::Matrix3d fl =
        m.corotational ? Eigen::Matrix3d(fem_detail::polarRotation(f).transpose() * f) : f;
    const Eigen::Matrix3d eps = 0.5 * (fl + fl.transpose()) - Eigen::Matrix3d::Identity();
    energy += m.volume[e] * (m.mu * eps.squaredNorm() + 0.5 * m.lambda * eps.trace() * eps.trace());
  }
  return energy;
}

double FemBody::gravityEnergy() const {
  const Impl& m = *impl_;
  if (!m.has_gravity) return 0.0;
  double energy = 0.0;
  for (int i = 0; i < m.n; ++i) energy -= m.mass[3 * i] * m.gravity.dot(m.q.segment<3>(3 * i));
  return energy;
}

}  // namespace tactus::sim

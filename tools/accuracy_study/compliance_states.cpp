// Part 1b of the accuracy study: the compliance models on the same states of one exact reference
// trajectory (see study.h, StateComparison).

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "study.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"

namespace tactus::study {

void save(sim::Simulation& sim, SavedState& s) {
  s.q.resize(static_cast<std::size_t>(sim.tissueCount()));
  s.v.resize(s.q.size());
  for (int i = 0; i < sim.tissueCount(); ++i) {
    s.q[static_cast<std::size_t>(i)] = sim.tissue(i).positions();
    s.v[static_cast<std::size_t>(i)] = sim.tissue(i).velocities();
  }
  if (!s.tool) {
    s.tool = std::make_unique<sim::Instrument>(*sim.instrument());
  } else {
    *s.tool = *sim.instrument();
  }
}

void restore(sim::Simulation& sim, const SavedState& s) {
  for (int i = 0; i < sim.tissueCount(); ++i) {
    sim.tissue(i).positions() = s.q[static_cast<std::size_t>(i)];
    sim.tissue(i).velocities() = s.v[static_cast<std::size_t>(i)];
  }
  *sim.instrument() = *s.tool;
}

sim::SceneSpec referenceSpec(const Options& o, const sim::SceneSpec& base, const std::string& mesh,
                             double h_s) {
  sim::SceneSpec s = configure(o, base, mesh, h_s, sim::ComplianceKind::kExact, o.ref_tolerance,
                               o.ref_sweeps);
  s.solver.linear = sim::LinearSolverKind::kCholmod;
  return s;
}

namespace {

// Element quality and rotation coherence at the nodes nearest the tool (the probe's nodes).
struct NearDiagnostics {
  int inverted = 0;                        // elements with det F <= 0 touching those nodes
  double min_det = 1.0;                    // smallest det F among them
  double min_coherence = 1.0;              // smallest |sum v_e R_e|_F / (sqrt(3) sum v_e)
};

NearDiagnostics diagnose(const sim::FemBody& body, const Eigen::Vector3d& tool, int k_nodes) {
  const sim::TetMesh& mesh = body.mesh();
  const Eigen::VectorXd& q = body.positions();
  const Eigen::VectorXd& x0 = body.restPositions();
  std::vector<std::pair<double, int>> near;
  for (int n = 0; n < body.nodeCount(); ++n) {
    if (body.fixedMask()[static_cast<std::size_t>(n)]) continue;
    near.emplace_back((q.segment<3>(3 * n) - tool).norm(), n);
  }
  const std::size_t k = std::min<std::size_t>(static_cast<std::size_t>(k_nodes), near.size());
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(k), near.end());
  std::vector<char> is_near(static_cast<std::size_t>(body.nodeCount()), 0);
  for (std::size_t i = 0; i < k; ++i) is_near[static_cast<std::size_t>(near[i].second)] = 1;
  std::vector<Eigen::Matrix3d> acc(static_cast<std::size_t>(body.nodeCount()),
                                   Eigen::Matrix3d::Zero());
  std::vector<double> wsum(acc.size(), 0.0);
  NearDiagnostics d;
  for (const auto& t : mesh.tets) {
    bool touches = false;
    for (int a : t) touches = touches || is_near[static_cast<std::size_t>(a)];
    if (!touches) continue;
    Eigen::Matrix3d dm, ds;
    for (int c = 0; c < 3; ++c) {
      dm.col(c) = x0.segment<3>(3 * t[c + 1]) - x0.segment<3>(3 * t[0]);
      ds.col(c) = q.segment<3>(3 * t[c + 1]) - q.segment<3>(3 * t[0]);
    }
    const Eigen::Matrix3d f = ds * dm.inverse();
    const double det = f.determinant();
    d.min_det = std::min(d.min_det, det);
    if (!(det > 0.0)) ++d.inverted;
    Eigen::JacobiSVD<Eigen::Matrix3d> svd(f, Eigen::ComputeFullU | Eigen::ComputeFullV);
    Eigen::Matrix3d u = svd.matrixU();
    if ((u * svd.matrixV().transpose()).determinant() < 0.0) u.col(2) *= -1.0;
    const Eigen::Matrix3d r = u * svd.matrixV().transpose();
    const double vol = std::abs(dm.determinant()) / 6.0;
    for (int a : t) {
      acc[static_cast<std::size_t>(a)] += vol * r;
      wsum[static_cast<std::size_t>(a)] += vol;
    }
  }
  for (std::size_t i = 0; i < k; ++i) {
    const auto n = static_cast<std::size_t>(near[i].second);
    if (wsum[n] > 0.0) {
      d.min_coherence = std::min(d.min_coherence, acc[n].norm() / (std::sqrt(3.0) * wsum[n]));
    }
  }
  return d;
}

}  // namespace

StateComparison compareStates(const Options& o, const sim::SceneSpec& base,
                              const std::string& mesh, double duration_s, int every_steps) {
  StateComparison sc;
  sc.mesh = mesh;
  const double h = base.time_step_s;
  sim::Simulation ref(referenceSpec(o, base, mesh, h));
  struct Model {
    sim::ComplianceKind kind;
    double bound;
    std::string name;
  };
  const Model models[] = {{sim::ComplianceKind::kExact, 0.0, "exact"},
                          {sim::ComplianceKind::kWarped, 0.0, "warped"},
                          {sim::ComplianceKind::kWarped, o.coherence_bound, "warped_bounded"},
                          {sim::ComplianceKind::kRest, 0.0, "rest"},
                          {sim::ComplianceKind::kUncoupled, 0.0, "uncoupled"}};
  // one probe simulation per model: a single contact pass, so the problem it assembles from the
  // restored state has the reference's rows and delta_free and differs only by W
  std::vector<std::unique_ptr<sim::Simulation>> probes;
  for (const Model& md : models) {
    sim::SceneSpec s = configure(o, base, mesh, h, md.kind, o.ref_tolerance, o.ref_sweeps);
    s.solver.linear = sim::LinearSolverKind::kCholmod;
    s.solver.contact_iterations = 1;
    s.tissues.at(0).exact_below_coherence = md.bound;
    probes.push_back(std::make_unique<sim::Simulation>(s));
    sc.models.push_back(md.name);
  }
  std::vector<std::unique_ptr<sim::TissueCompliance>> probe_models;
  SimRun probe_run;
  SimConfig cfg{mesh, h, sim::ComplianceKind::kExact, o.ref_tolerance, o.ref_sweeps};
  SavedState before;
  const long steps = std::lround(duration_s / h);
  bool in_contact = false;
  for (long k = 0; k < steps; ++k) {
    const sim::DeviceTarget d = ref.scriptedTarget(ref.time());
    const bool sample = in_contact && k % every_steps == 0;
    if (sample) save(ref, before);
    ref.setDeviceTarget(d);
    const sim::StepReport r = ref.step();
    if (!r.finite) throw NumericalError("compliance states: the exact reference diverged");
    in_contact = r.contacts > 0;
    if (!sample) continue;
    StateRow row;
    row.t_s = ref.time() - h;
    std::vector<sim::ContactProblemData> problems;
    for (std::size_t m = 0; m < probes.size(); ++m) {
      restore(*probes[m], before);
      probes[m]->setDeviceTarget(d);
      const long fallbacks = probes[m]->compliance(0)->buildInfo().exact_fallbacks;
      const sim::StepReport pr = probes[m]->step();
      row.fallback.push_back(probes[m]->compliance(0)->buildInfo().exact_fallbacks > fallbacks);
      if (!pr.finite) throw NumericalError("compliance states: a probe step diverged");
      problems.push_back(probes[m]->lastProblem());
      row.step_s.push_back(pr.times.total_s);
      row.wbuild_s.push_back(pr.times.update_compliance_s + pr.times.build_w_s);
    }
    const sim::ContactProblemData& ex = problems[0];
    bool same_rows = ex.rows > 0;
    for (const auto& p : problems) {
      same_rows = same_rows && p.rows == ex.rows && p.contact_id == ex.contact_id &&
                  (p.delta_free - ex.delta_free).norm() <= 1e-12 * (1.0 + ex.delta_free.norm());
    }
    if (!same_rows) {
      ++sc.skipped;
      continue;
    }
    row.contacts = ex.contacts;
    const Eigen::Vector3d f_ex = contactWrench(ex, ex.f.data(), ex.tool_pose.pos_m).head<3>();
    row.force_exact_n = f_ex.norm();
    for (int c = 0; c < ex.contacts; ++c) row.normal_sum_n += ex.f[ex.row_offset[c]];
    for (const auto& p : problems) {
      row.w_err.push_back((p.W - ex.W).norm() / ex.W.norm());
      const Eigen::Vector3d f = contactWrench(p, p.f.data(), p.tool_pose.pos_m).head<3>();
      row.force_err.push_back((f - f_ex).norm() / std::max(f_ex.norm(), 1e-9));
    }
    // the tissue-only W on the 24 nodes nearest the tool, at the probe's (exact) state
    probe_run.w_error.clear();
    probeCompliance(o, *probes[0], cfg, probe_models, probe_run);
    for (std::size_t m = 0; m < sc.models.size(); ++m) {
      const std::string& name = sc.models[m];
      double e = 0.0;
      if (name == "warped_bounded") {
        // its W is the warped one, or the exact one (the same code path) when it fell back
        e = row.fallback[m] ? 0.0 : probe_run.w_error.at("warped").back();
      } else if (name != "exact") {
        e = probe_run.w_error.at(name).back();
      }
      row.probe_w_err.push_back(e);
    }
    const NearDiagnostics dg =
        diagnose(probes[0]->tissue(0), probes[0]->instrument()->pose().pos_m, 24);
    row.inverted_near = dg.inverted;
    row.min_det_near = dg.min_det;
    row.min_coherence_near = dg.min_coherence;
    sc.rows.push_back(std::move(row));
  }
  return sc;
}

std::string statesCsv(const StateComparison& sc) {
  std::ostringstream out;
  out << "mesh,t_s,model,contacts,force_exact_n,normal_force_sum_n,w_rel_err,force_rel_err,probe_w_rel_err,"
         "exact_fallback,step_ms,update_compliance_build_w_ms,inverted_near,min_det_near,"
         "min_rotation_coherence_near\n";
  for (const StateRow& r : sc.rows) {
    for (std::size_t m = 0; m < sc.models.size(); ++m) {
      out << sc.mesh << ',' << fmtG(r.t_s) << ',' << sc.models[m] << ',' << r.contacts << ','
          << fmtG(r.force_exact_n) << ',' << fmtG(r.normal_sum_n) << ',' << fmtG(r.w_err[m]) << ',' << fmtG(r.force_err[m])
          << ',' << fmtG(r.probe_w_err[m]) << ',' << (r.fallback[m] ? 1 : 0) << ','
          << fmtG(1e3 * r.step_s[m]) << ','
          << fmtG(1e3 * r.wbuild_s[m]) << ',' << r.inverted_near << ','
          << fmtG(r.min_det_near) << ',' << fmtG(r.min_coherence_near) << '\n';
    }
  }
  return out.str();
}

}  // namespace tactus::study

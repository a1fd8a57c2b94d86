// Part 1 of the accuracy study: simulation runs, their errors against a reference, and the
// compliance models' W compared with the exact one along a run (see study.h).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <sstream>

#include "study.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"

namespace tactus::study {

// Probes the compliance models at the run's current state: rows = the x, y, z directions at
// the (up to 24) surface nodes nearest the instrument; W of each model against the exact W.
void probeCompliance(const Options& o, sim::Simulation& sim, const SimConfig& cfg,
                     std::vector<std::unique_ptr<sim::TissueCompliance>>& models,
                     SimRun& run) {
  sim::FemBody& body = sim.tissue(0);
  const Eigen::Vector3d tool = sim.instrument()->pose().pos_m;
  std::vector<std::pair<double, int>> near;
  for (const int n : body.surfaceNodes()) {
    if (body.fixedMask()[static_cast<std::size_t>(n)]) continue;
    near.emplace_back((body.positions().segment<3>(3 * n) - tool).norm(), n);
  }
  const std::size_t k = std::min<std::size_t>(24, near.size());
  std::partial_sort(near.begin(), near.begin() + static_cast<std::ptrdiff_t>(k), near.end());
  std::vector<sim::TissueRow> rows;
  for (std::size_t i = 0; i < k; ++i) {
    for (int d = 0; d < 3; ++d) {
      sim::TissueRow r;
      r.node = {near[i].second, -1, -1};
      r.weight = {1.0, 0.0, 0.0};
      r.dir = Eigen::Vector3d::Unit(d);
      rows.push_back(r);
    }
  }
  const int m = static_cast<int>(rows.size());
  Eigen::MatrixXd w_exact = Eigen::MatrixXd::Zero(m, m);
  sim.compliance(0)->addW(rows, w_exact);   // the run's own (exact) model, current factor
  if (models.empty()) {
    sim::ComplianceOptions co;
    co.h_s = cfg.h_s;
    co.cache_dir = o.cache_dir;
    co.cache_name = fmt::format("{}_h{:.3f}ms", cfg.mesh, 1e3 * cfg.h_s);
    co.show_progress = false;
    for (const auto kind : {sim::ComplianceKind::kWarped, sim::ComplianceKind::kRest,
                            sim::ComplianceKind::kUncoupled}) {
      models.push_back(sim::makeCompliance(kind, body, co));
    }
  }
  for (auto& model : models) {
    model->update(body);
    Eigen::MatrixXd w = Eigen::MatrixXd::Zero(m, m);
    model->addW(rows, w);
    run.w_error[complianceName(model->kind())].push_back((w - w_exact).norm() /
                                                         w_exact.norm());
  }
}

SimRun runSim(const Options& o, const sim::SceneSpec& base, const SimConfig& cfg,
              double duration_s, bool probe_w) {
  const sim::SceneSpec spec =
      configure(o, base, cfg.mesh, cfg.h_s, cfg.compliance, cfg.tol, cfg.sweeps);
  SimRun run;
  run.cfg = cfg;
  const std::int64_t t_setup = shared::monotonicNs();
  sim::Simulation sim(spec);
  run.setup_s = shared::secondsSinceNs(t_setup);
  run.tets = static_cast<int>(sim.tissue(0).mesh().tets.size());
  run.nodes = sim.tissue(0).nodeCount();
  const long steps = std::lround(duration_s / cfg.h_s);
  std::vector<std::unique_ptr<sim::TissueCompliance>> probe_models;
  double probe_s = 0.0;
  const long probe_every = std::max(1L, std::lround(0.1 / cfg.h_s));
  const std::int64_t t_run = shared::monotonicNs();
  for (long k = 0; k < steps; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    const sim::StepReport r = sim.step();
    if (!r.finite) {
      throw NumericalError(fmt::format("{}: step {}: the state became non-finite", cfg.key(), k));
    }
    const sim::ContactProblemData& p = sim.lastProblem();
    run.t.push_back(sim.time());
    run.force.push_back(contactWrench(p, p.f.data(), p.tool_pose.pos_m).head<3>());
    run.energy.push_back(sim.totalEnergy());
    const double gap = sim.geometricMinGap();
    run.penetration.push_back(std::isfinite(gap) ? std::max(0.0, -gap) : 0.0);
    run.complementarity.push_back(r.complementarity);
    run.step_s.push_back(r.times.total_s);
    if (r.contacts > 0) {
      run.solve_s.push_back(r.times.solve_contacts_s);
      run.wbuild_s.push_back(r.times.update_compliance_s + r.times.build_w_s);
      run.nsgs_error.push_back(r.nsgs.error);
      run.contacts.push_back(r.contacts);
      run.sweeps.push_back(r.nsgs.sweeps);
      if (probe_w && k % probe_every == 0) {
        const std::int64_t tp = shared::monotonicNs();
        probeCompliance(o, sim, cfg, probe_models, run);
        probe_s += shared::secondsSinceNs(tp);
      }
    }
  }
  run.wall_s = shared::secondsSinceNs(t_run) - probe_s;
  return run;
}

namespace {

// Linear interpolation of a run's series at time t (clamped at the ends).
template <class T>
T sampleAt(const std::vector<double>& ts, const std::vector<T>& v, double t) {
  if (t <= ts.front()) return v.front();
  if (t >= ts.back()) return v.back();
  const auto it = std::lower_bound(ts.begin(), ts.end(), t);
  const std::size_t i = static_cast<std::size_t>(it - ts.begin());
  if (std::abs(ts[i] - t) < 1e-12) return v[i];
  const double u = (t - ts[i - 1]) / (ts[i] - ts[i - 1]);
  return (1.0 - u) * v[i - 1] + u * v[i];
}

}  // namespace

Errors compare(const SimRun& run, const SimRun& ref, double early_until_s) {
  Errors e;
  double num = 0.0, den = 0.0, num_early = 0.0, den_early = 0.0;
  double e_min = std::numeric_limits<double>::infinity(), e_max = -e_min, e_dev = 0.0;
  // the reference's samples inside the run's span (a coarser run is interpolated)
  for (std::size_t i = 0; i < ref.t.size(); ++i) {
    const double t = ref.t[i];
    if (t < run.t.front() - 1e-12 || t > run.t.back() + 1e-12) continue;
    const Eigen::Vector3d f = sampleAt(run.t, run.force, t);
    const double d = (f - ref.force[i]).norm();
    num += d * d;
    den += ref.force[i].squaredNorm();
    e.force_peak_n = std::max(e.force_peak_n, d);
    if (t <= early_until_s + 1e-12) {
      num_early += d * d;
      den_early += ref.force[i].squaredNorm();
      e.early_peak_n = std::max(e.early_peak_n, d);
    }
    e.force_ref_peak_n = std::max(e.force_ref_peak_n, ref.force[i].norm());
    e_min = std::min(e_min, ref.energy[i]);
    e_max = std::max(e_max, ref.energy[i]);
    e_dev = std::max(e_dev, std::abs(sampleAt(run.t, run.energy, t) - ref.energy[i]));
  }
  e.force_rel_rms = den > 0.0 ? std::sqrt(num / den) : 0.0;
  e.early_rel_rms = den_early > 0.0 ? std::sqrt(num_early / den_early) : 0.0;
  e.energy_dev_rel = e_max > e_min ? e_dev / (e_max - e_min) : 0.0;
  return e;
}

std::string simCsv(const std::vector<SimRow>& rows, double early_until_s) {
  std::ostringstream out;
  out << "study,label,mesh,tets,h_ms,compliance,nsgs_tol,nsgs_max_sweeps,is_reference,reference,"
         "steps,force_rel_rms,force_peak_err_n,force_ref_peak_n,force_rel_rms_early,"
         "force_peak_err_early_n,max_penetration_mm,"
         "complementarity_max_nm,nsgs_error_max,energy_dev_rel,step_ms_median,"
         "solve_contacts_ms_median,update_compliance_build_w_ms_median,contacts_median,sweeps_median,setup_s,wall_s\n";
  for (const SimRow& row : rows) {
    const SimRun& r = *row.run;
    const bool is_ref = row.run == row.ref;
    const Errors e = compare(r, *row.ref, early_until_s);
    const double pen = r.penetration.empty()
                           ? 0.0
                           : *std::max_element(r.penetration.begin(), r.penetration.end());
    const double comp = r.complementarity.empty() ? 0.0
                                                  : *std::max_element(r.complementarity.begin(),
                                                                      r.complementarity.end());
    out << row.study << ',' << row.label << ',' << r.cfg.mesh << ',' << r.tets << ','
        << fmtG(1e3 * r.cfg.h_s) << ',' << complianceName(r.cfg.compliance) << ','
        << fmtG(r.cfg.tol) << ',' << r.cfg.sweeps << ',' << (is_ref ? 1 : 0) << ','
        << fmt::format("{}/h{}ms/{}/tol{:.0e}", row.ref->cfg.mesh, 1e3 * row.ref->cfg.h_s,
                       complianceName(row.ref->cfg.compliance), row.ref->cfg.tol)
        << ',' << r.t.size() << ',' << fmtG(e.force_rel_rms) << ',' << fmtG(e.force_peak_n)
        << ',' << fmtG(e.force_ref_peak_n) << ',' << fmtG(e.early_rel_rms) << ','
        << fmtG(e.early_peak_n) << ',' << fmtG(1e3 * pen) << ',' << fmtG(comp) << ','
        << fmtG(r.nsgs_error.empty()
                    ? 0.0
                    : *std::max_element(r.nsgs_error.begin(), r.nsgs_error.end()))
        << ',' << fmtG(e.energy_dev_rel) << ','
        << fmtG(1e3 * median(r.step_s)) << ',' << fmtG(1e3 * median(r.solve_s)) << ','
        << fmtG(1e3 * median(r.wbuild_s)) << ',' << fmtG(median(r.contacts)) << ','
        << fmtG(median(r.sweeps)) << ',' << fmtG(r.setup_s) << ',' << fmtG(r.wall_s) << '\n';
  }
  return out.str();
}

}  // namespace tactus::study

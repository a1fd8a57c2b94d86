// Part 2 of the accuracy study: the haptic local model against the full model re-simulated at
// the haptic rate (see study.h).
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <sstream>

#include "study.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/nsgs.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"

namespace tactus::study {

void TickSeries::pushInvalid() {
  force.push_back(Eigen::Vector3d::Zero());
  penetration.push_back(0.0);
  complementarity.push_back(0.0);
  time_s.push_back(0.0);
  sweeps.push_back(0.0);
  residual.push_back(0.0);
  valid.push_back(false);
}

namespace {

struct Tremor {
  double amp_m = 0.0;
  double freq_hz = 6.0;
  Eigen::Vector3d dir = Eigen::Vector3d(0.5, 0.3, 0.8).normalized();
};

// The device: the scripted target plus a sinusoidal tremor (position and its velocity).
sim::DeviceTarget deviceAt(const sim::Simulation& sim, const Tremor& tr, double t_s) {
  sim::DeviceTarget d = sim.scriptedTarget(t_s);
  const double w = 2.0 * M_PI * tr.freq_hz;
  d.pose.pos_m += tr.amp_m * std::sin(w * t_s) * tr.dir;
  d.twist.head<3>() += tr.amp_m * w * std::cos(w * t_s) * tr.dir;
  return d;
}

struct WindowState {
  std::vector<Eigen::VectorXd> q, v;
  shared::Pose tool_pose;
  double opening = 1.0;
};

void seed(sim::Simulation& sim, const WindowState& s) {
  for (int i = 0; i < sim.tissueCount(); ++i) {
    sim.tissue(i).positions() = s.q[static_cast<std::size_t>(i)];
    sim.tissue(i).velocities() = s.v[static_cast<std::size_t>(i)];
  }
  sim.instrument()->reset(s.tool_pose, s.opening);
}

struct LocalModel {
  int budget = 0;                          // sweeps per tick (0: hold)
  double tol = 1e-6;
  shared::NsgsWorkspace ws;
  std::vector<double> f, df, delta;
  long snapshot = -1;
};

// One tick of the local model on `p` (a copy of the snapshot) at device pose x_h, mirroring
// HapticLoop::solveLocalModel without the safety chain. Returns the force; fills metrics.
void localTick(LocalModel& lm, const sim::ContactProblemData& p, long snapshot,
               const shared::Pose& x_h, TickSeries& out) {
  const int m = p.rows;
  const std::int64_t t0 = shared::monotonicNs();
  Eigen::Vector3d force = Eigen::Vector3d::Zero();
  int sweeps = 0;
  if (m > 0) {
    if (lm.snapshot != snapshot) {
      // a new snapshot: warm start from the simulation's forces
      lm.snapshot = snapshot;
      std::copy_n(p.f.data(), m, lm.f.begin());
    }
    const shared::Vector6d dx = shared::poseDifference(x_h, p.device_pose);
    for (int r = 0; r < m; ++r) lm.df[r] = p.delta_free[r] + p.J.row(r).dot(dx);
    shared::ContactProblemView view = p.view();
    view.delta_free = lm.df.data();
    if (lm.budget > 0) {
      shared::NsgsSettings ns;
      ns.tolerance = lm.tol;
      ns.max_sweeps = lm.budget;
      ns.time_budget_ns = 0;
      const shared::NsgsResult res = shared::solveNsgs(view, ns, lm.ws, lm.f.data());
      if (res.status == shared::NsgsStatus::kNonFinite) std::fill_n(lm.f.begin(), m, 0.0);
      sweeps = res.sweeps;
    }
    force = contactWrench(p, lm.f.data(), p.tool_pose.pos_m + dx.head<3>()).head<3>();
  }
  out.time_s.push_back(shared::secondsSinceNs(t0));
  out.force.push_back(force);
  out.sweeps.push_back(sweeps);
  // metrics outside the timed part
  double pen = 0.0, comp = 0.0, res = 0.0;
  if (m > 0) {
    shared::ContactProblemView view = p.view();
    view.delta_free = lm.df.data();
    res = shared::naturalMapError(view, lm.f.data(), lm.delta.data());
    for (int c = 0; c < p.contacts; ++c) {
      const int r0 = p.row_offset[c];
      pen = std::max(pen, -lm.delta[r0]);
      comp = std::max(comp, std::abs(lm.delta[r0] * lm.f[r0]));
    }
  }
  out.penetration.push_back(pen);
  out.complementarity.push_back(comp);
  out.residual.push_back(res);
  out.valid.push_back(true);
}

}  // namespace

// Runs the window for every rate, budget and simulation step.
std::vector<HapticRow> runHaptic(const Options& o, const HapticPlan& plan) {
  const sim::SceneSpec base = meshScene(o, plan.mesh);
  const sim::ComplianceKind scene_kind = base.tissues.at(0).compliance;
  const sim::ComplianceKind ref_kind = o.haptic_ref_compliance == "scene"
                                           ? scene_kind
                                           : parseCompliance(o.haptic_ref_compliance);
  Tremor tremor;
  tremor.amp_m = 1e-3 * o.tremor_mm;
  tremor.freq_hz = o.tremor_hz;
  const double h_scene = base.time_step_s;

  // prefix at the scene's step up to t0 (scripted device, no tremor before t0)
  spdlog::info("haptic: prefix 0 .. {} s", plan.t0_s);
  WindowState state;
  {
    sim::Simulation sim(configure(o, base, plan.mesh, h_scene, scene_kind,
                                  base.solver.nsgs_tolerance, base.solver.nsgs_max_sweeps));
    const long steps = std::lround(plan.t0_s / h_scene);
    Tremor still;
    still.amp_m = 0.0;
    for (long k = 0; k < steps; ++k) {
      sim.setDeviceTarget(deviceAt(sim, still, sim.time()));
      sim.step();
    }
    for (int i = 0; i < sim.tissueCount(); ++i) {
      state.q.push_back(sim.tissue(i).positions());
      state.v.push_back(sim.tissue(i).velocities());
    }
    state.tool_pose = sim.instrument()->pose();
    state.opening = sim.instrument()->gripperOpening();
  }

  std::vector<HapticRow> rows;
  for (const double rate : plan.rates_hz) {
    const double dt = 1.0 / rate;
    const long ticks = std::lround(plan.window_s * rate);
    // reference: the full model re-simulated at every tick
    spdlog::info("haptic: reference at {} Hz ({} steps)", rate, ticks);
    HapticRow ref;
    ref.kind = "reference";
    ref.rate_hz = rate;
    ref.sim_h_s = dt;
    {
      sim::Simulation sim(configure(o, base, plan.mesh, dt, ref_kind, o.ref_tolerance,
                                    o.ref_sweeps));
      seed(sim, state);
      for (long j = 0; j < ticks; ++j) {
        const double t = plan.t0_s + static_cast<double>(j) * dt;
        sim.setDeviceTarget(deviceAt(sim, tremor, t));
        const sim::StepReport r = sim.step();
        if (!r.finite) throw NumericalError(fmt::format("haptic reference {} Hz diverged", rate));
        const sim::ContactProblemData& p = sim.lastProblem();
        ref.series.force.push_back(contactWrench(p, p.f.data(), p.tool_pose.pos_m).head<3>());
        ref.series.penetration.push_back(r.max_penetration_m);
        ref.series.complementarity.push_back(r.complementarity);
        ref.series.time_s.push_back(r.times.total_s);
        ref.series.sweeps.push_back(r.nsgs.sweeps);
        ref.series.residual.push_back(r.nsgs.error);
        ref.series.valid.push_back(true);
        ref.series.device_pos.push_back(deviceAt(sim, tremor, t).pose.pos_m);
      }
    }
    rows.push_back(std::move(ref));

    for (const double h_sim : plan.sim_h_s) {
      const long n = std::lround(h_sim * rate);
      if (n < 1 || std::abs(static_cast<double>(n) - h_sim * rate) > 1e-9) {
        throw Error(fmt::format("haptic: the simulation step {} ms is not a multiple of the tick "
                                "{} ms",
                                1e3 * h_sim, 1e3 * dt));
      }
      // the multi-rate model: one simulation, every budget on its snapshots
      std::vector<LocalModel> models(plan.budgets.size());
      std::vector<HapticRow> local(plan.budgets.size());
      for (std::size_t b = 0; b < plan.budgets.size(); ++b) {
        const int cap_rows = 3 * base.solver.max_contacts;
        models[b].budget = plan.budgets[b];
        models[b].tol = base.haptics.nsgs_tolerance;
        models[b].ws.reserve(cap_rows, base.solver.max_contacts);
        models[b].f.assign(static_cast<std::size_t>(cap_rows), 0.0);
        models[b].df.assign(static_cast<std::size_t>(cap_rows), 0.0);
        models[b].delta.assign(static_cast<std::size_t>(cap_rows), 0.0);
        local[b].kind = plan.budgets[b] == 0 ? "hold" : "local";
        local[b].rate_hz = rate;
        local[b].sim_h_s = h_sim;
        local[b].sweeps = plan.budgets[b];
      }
      sim::Simulation sim(configure(o, base, plan.mesh, h_sim, scene_kind,
                                    base.solver.nsgs_tolerance, base.solver.nsgs_max_sweeps));
      seed(sim, state);
      const long sim_steps = ticks / n;
      const long lat = o.latency_steps;
      // ticks before the first snapshot arrives are not compared
      for (auto& row : local) {
        for (long j = 0; j < std::min(ticks, lat * n); ++j) {
          row.series.pushInvalid();
        }
      }
      for (long k = 0; k < sim_steps; ++k) {
        const double t_k = plan.t0_s + static_cast<double>(k) * h_sim;
        sim.setDeviceTarget(deviceAt(sim, tremor, t_k));
        const sim::StepReport r = sim.step();
        if (!r.finite) throw NumericalError("haptic multi-rate simulation diverged");
        const sim::ContactProblemData snap = sim.lastProblem();
        for (long j = (k + lat) * n; j < std::min(ticks, (k + lat + 1) * n); ++j) {
          const double t = plan.t0_s + static_cast<double>(j) * dt;
          const shared::Pose x_h = deviceAt(sim, tremor, t).pose;
          for (std::size_t b = 0; b < models.size(); ++b) {
            localTick(models[b], snap, k, x_h, local[b].series);
          }
        }
      }
      for (auto& row : local) {
        // pad to the reference's length (ticks after the last snapshot's span)
        while (static_cast<long>(row.series.force.size()) < ticks) {
          row.series.pushInvalid();
        }
        rows.push_back(std::move(row));
      }
    }
  }
  return rows;
}

std::string hapticCsv(const std::vector<HapticRow>& rows, const HapticPlan& plan) {
  std::ostringstream out;
  out << "kind,mesh,rate_hz,sim_h_ms,sweeps_per_tick,is_reference,ticks_compared,force_rel_rms,"
         "force_peak_err_n,force_ref_peak_n,max_penetration_mm,complementarity_max_nm,"
         "residual_median,work_ref_mj,work_dev_mj,tick_us_median,sweeps_median\n";
  std::map<double, const HapticRow*> refs;
  for (const HapticRow& r : rows) {
    if (r.kind == "reference") refs[r.rate_hz] = &r;
  }
  for (const HapticRow& r : rows) {
    const HapticRow& ref = *refs.at(r.rate_hz);
    const bool is_ref = &r == &ref;
    double num = 0.0, den = 0.0, peak = 0.0, ref_peak = 0.0, pen = 0.0, comp = 0.0;
    double work = 0.0, work_ref = 0.0;  // [J]
    long compared = 0;
    std::vector<double> times, sweeps, resid;
    // ticks compared: those every row of this rate has (the latest first-snapshot tick)
    long first = 0;
    for (const HapticRow& other : rows) {
      if (other.rate_hz != r.rate_hz) continue;
      long j = 0;
      while (j < static_cast<long>(other.series.valid.size()) &&
             !other.series.valid[static_cast<std::size_t>(j)])
        ++j;
      first = std::max(first, j);
    }
    const long n = static_cast<long>(r.series.force.size());
    for (long j = first; j < n; ++j) {
      const auto i = static_cast<std::size_t>(j);
      if (!r.series.valid[i] || !ref.series.valid[i]) continue;
      ++compared;
      const double d = (r.series.force[i] - ref.series.force[i]).norm();
      num += d * d;
      den += ref.series.force[i].squaredNorm();
      peak = std::max(peak, d);
      ref_peak = std::max(ref_peak, ref.series.force[i].norm());
      pen = std::max(pen, r.series.penetration[i]);
      comp = std::max(comp, r.series.complementarity[i]);
      times.push_back(r.series.time_s[i]);
      sweeps.push_back(r.series.sweeps[i]);
      resid.push_back(r.series.residual[i]);
      // work of the force on the hand over the tick's device motion: F_j . (x_{j+1} - x_j)
      if (j + 1 < n) {
        const Eigen::Vector3d dp = ref.series.device_pos[i + 1] - ref.series.device_pos[i];
        work += r.series.force[i].dot(dp);
        work_ref += ref.series.force[i].dot(dp);
      }
    }
    out << r.kind << ',' << plan.mesh << ',' << fmtG(r.rate_hz) << ',' << fmtG(1e3 * r.sim_h_s)
        << ',' << r.sweeps << ',' << (is_ref ? 1 : 0) << ',' << compared << ','
        << fmtG(den > 0.0 ? std::sqrt(num / den) : 0.0) << ',' << fmtG(peak) << ','
        << fmtG(ref_peak) << ',' << fmtG(1e3 * pen) << ',' << fmtG(comp) << ','
        << fmtG(median(resid)) << ',' << fmtG(1e3 * work_ref) << ','
        << fmtG(1e3 * (work - work_ref))
        << ',' << fmtG(1e6 * median(times)) << ',' << fmtG(median(sweeps)) << '\n';
  }
  return out.str();
}

}  // namespace tactus::study

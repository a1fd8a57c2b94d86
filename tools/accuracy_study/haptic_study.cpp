// Part 2 of the accuracy study: the haptic loop's methods against R1 (the exact step at the
// tick's pose from the snapshot's state) and R2 (the full model at the haptic rate); see study.h.
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>

#include "study.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/haptic/local_model.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"

namespace tactus::study {

void MethodSeries::push(const Eigen::Vector3d& f, double pen, double t_s) {
  force.push_back(f);
  penetration.push_back(pen);
  time_s.push_back(t_s);
  valid.push_back(true);
}

void MethodSeries::pushInvalid() {
  force.push_back(Eigen::Vector3d::Zero());
  penetration.push_back(0.0);
  time_s.push_back(0.0);
  valid.push_back(false);
}

Eigen::Vector3d DeviceMotion::offset(double t_s) const {
  const double u = (t_s - lead_in_s) / motion_s;
  if (u <= 0.0 || u >= 1.0) return Eigen::Vector3d::Zero();
  if (name == "tremor") return amplitude_m * std::sin(2.0 * M_PI * freq_hz * motion_s * u) * dir;
  return amplitude_m * 0.5 * (1.0 - std::cos(2.0 * M_PI * u)) * dir;
}

Eigen::Vector3d DeviceMotion::velocity(double t_s) const {
  const double u = (t_s - lead_in_s) / motion_s;
  if (u <= 0.0 || u >= 1.0) return Eigen::Vector3d::Zero();
  if (name == "tremor") {
    const double w = 2.0 * M_PI * freq_hz;
    return amplitude_m * w * std::cos(w * motion_s * u) * dir;
  }
  return amplitude_m * M_PI / motion_s * std::sin(2.0 * M_PI * u) * dir;
}

namespace {

struct Anchor {
  sim::DeviceTarget target;                // scripted pose and opening at t0, at rest
};

sim::DeviceTarget deviceAt(const Anchor& a, const DeviceMotion& m, double t_rel_s) {
  sim::DeviceTarget d = a.target;
  d.pose.pos_m += m.offset(t_rel_s);
  d.twist.setZero();
  d.twist.head<3>() = m.velocity(t_rel_s);
  return d;
}

Eigen::Vector3d stepForce(sim::Simulation& sim, const sim::DeviceTarget& d, double& pen_m,
                          double& step_s) {
  sim.setDeviceTarget(d);
  const sim::StepReport r = sim.step();
  if (!r.finite) throw NumericalError("haptic study: a reference step diverged");
  const sim::ContactProblemData& p = sim.lastProblem();
  pen_m = r.max_penetration_m;
  step_s = r.times.total_s;
  return contactWrench(p, p.f.data(), p.tool_pose.pos_m).head<3>();
}

// The haptic loop's local model (haptic/local_model.h), fed the snapshot as sim_server publishes
// it: a slot in process memory, prepared at the device's pose of the first tick on it.
struct LocalModel {
  int budget = 0;                          // sweeps per tick
  double tol = 1e-6;
  haptic::LocalModelKind kind = haptic::LocalModelKind::kFull;
  shared::SnapshotLayout layout;
  std::vector<unsigned char> slot_bytes;
  std::unique_ptr<haptic::OfflineLocalModel> model;
  std::vector<double> df, delta;
  long snapshot = -1;
  void reserve(int rows, int contacts) {
    layout = shared::SnapshotLayout::forCapacity(rows, contacts);
    slot_bytes.assign(layout.total_bytes + shared::kCacheLineBytes, 0);
    haptic::LocalModelSettings s;
    s.kind = kind;
    s.tolerance = tol;
    s.max_sweeps = budget;
    model = std::make_unique<haptic::OfflineLocalModel>(rows, contacts, s);
    df.assign(static_cast<std::size_t>(rows), 0.0);
    delta.assign(static_cast<std::size_t>(rows), 0.0);
  }
  shared::SnapshotWriter slot() {
    const auto misalign =
        reinterpret_cast<std::uintptr_t>(slot_bytes.data()) % shared::kCacheLineBytes;
    return shared::SnapshotWriter(
        slot_bytes.data() + (shared::kCacheLineBytes - misalign) % shared::kCacheLineBytes,
        layout);
  }
};

// One tick of the local model on the snapshot `p` (of simulation `sim`) at device pose x_h, as
// the haptic loop (safety chain aside). Returns the force; the penetration of the linearised
// problem after the solve goes to pen_m, the timed part (the solve) to tick_s.
Eigen::Vector3d localTick(LocalModel& lm, const sim::Simulation& sim,
                          const sim::ContactProblemData& p, long snapshot,
                          const shared::Pose& x_h, double max_opening_rad, double& pen_m,
                          double& tick_s) {
  const int m = p.rows;
  pen_m = 0.0;
  tick_s = 0.0;
  if (m == 0) return Eigen::Vector3d::Zero();
  const shared::Pose* poses[] = {&x_h};
  if (lm.snapshot != snapshot) {
    lm.snapshot = snapshot;   // a new snapshot: prepared (off the tick in the haptic loop)
    shared::SnapshotWriter slot = lm.slot();
    if (!sim::writeSnapshot(sim, max_opening_rad, static_cast<std::uint64_t>(snapshot + 1), 1, 0,
                            slot)) {
      throw Error("haptic study: the snapshot does not fit its slot");
    }
    (void)lm.model->adopt(slot.view(), poses);
  }
  const haptic::LocalModelResult res = lm.model->solve(poses);
  tick_s = 1e-9 * static_cast<double>(res.elapsed_ns);
  if (!res.solved()) return Eigen::Vector3d::Zero();
  const Eigen::Vector3d force(res.force_n[0][0], res.force_n[0][1], res.force_n[0][2]);
  const shared::Vector6d dx = shared::poseDifference(x_h, p.device_pose);
  for (int r = 0; r < m; ++r) lm.df[r] = p.delta_free[r] + p.J.row(r).dot(dx);
  shared::ContactProblemView view = p.view();
  view.delta_free = lm.df.data();
  shared::naturalMapError(view, lm.model->model().forces(), lm.delta.data());
  for (int c = 0; c < p.contacts; ++c) pen_m = std::max(pen_m, -lm.delta[p.row_offset[c]]);
  return force;
}

// Penetration of the linearised problem of snapshot `p` at device pose x_h with forces f held.
double heldPenetration(const sim::ContactProblemData& p, const shared::Pose& x_h) {
  if (p.rows == 0) return 0.0;
  const shared::Vector6d dx = shared::poseDifference(x_h, p.device_pose);
  double pen = 0.0;
  for (int c = 0; c < p.contacts; ++c) {
    const int r = p.row_offset[c];
    const double d = p.W.row(r).dot(p.f) + p.delta_free[r] + p.J.row(r).dot(dx);
    pen = std::max(pen, -d);
  }
  return pen;
}

struct Prefix {
  SavedState state;
  Anchor anchor;
  Eigen::Vector3d force = Eigen::Vector3d::Zero();   // contact force at t0
};

// The scene's script at its own step up to t0: the state every run of the window starts from.
Prefix runPrefix(const Options& o, const sim::SceneSpec& base, const HapticPlan& plan) {
  const sim::ComplianceKind kind = base.tissues.at(0).compliance;
  sim::Simulation sim(configure(o, base, plan.mesh, base.time_step_s, kind,
                                base.solver.nsgs_tolerance, base.solver.nsgs_max_sweeps));
  const long steps = std::lround(plan.t0_s / base.time_step_s);
  for (long k = 0; k < steps; ++k) {
    sim.setDeviceTarget(sim.scriptedTarget(sim.time()));
    if (!sim.step().finite) throw NumericalError("haptic study: the prefix diverged");
  }
  Prefix p;
  save(sim, p.state);
  p.anchor.target = sim.scriptedTarget(plan.t0_s);
  p.anchor.target.twist.setZero();
  const sim::ContactProblemData& pr = sim.lastProblem();
  p.force = contactWrench(pr, pr.f.data(), pr.tool_pose.pos_m).head<3>();
  return p;
}

// R2: the full model at the haptic rate along the motion.
MethodSeries runR2(const Options& o, const sim::SceneSpec& base, const HapticPlan& plan,
                   const Prefix& pre, const DeviceMotion& m, double rate) {
  MethodSeries s;
  s.method = "r2";
  s.label = "R2: full model at the haptic rate";
  const double dt = 1.0 / rate;
  sim::Simulation sim(referenceSpec(o, base, plan.mesh, dt));
  restore(sim, pre.state);
  const long ticks = std::lround(m.duration_s() * rate);
  for (long j = 0; j < ticks; ++j) {
    double pen = 0.0, step_s = 0.0;
    const Eigen::Vector3d f =
        stepForce(sim, deviceAt(pre.anchor, m, static_cast<double>(j) * dt), pen, step_s);
    s.push(f, pen, step_s);
  }
  return s;
}

// R1 and every method of one (motion, rate, step) case; case_.series[1] (R2) is given.
void runCase(const Options& o, const sim::SceneSpec& base, const HapticPlan& plan,
             const Prefix& pre, const DeviceMotion& m, HapticCase& hc) {
  const double rate = hc.rate_hz;
  const double dt = 1.0 / rate;
  const double h = hc.sim_h_s;
  const long n = std::lround(h * rate);
  if (n < 1 || std::abs(static_cast<double>(n) - h * rate) > 1e-9) {
    throw Error(fmt::format("haptic: the simulation step {} ms is not a multiple of the tick {} ms",
                            1e3 * h, 1e3 * dt));
  }
  const long ticks = std::lround(m.duration_s() * rate);
  const long lat = o.latency_steps;
  const sim::ComplianceKind kind =
      hc.snapshot_w == "exact" ? sim::ComplianceKind::kExact : base.tissues.at(0).compliance;
  sim::Simulation sim(configure(o, base, plan.mesh, h, kind, base.solver.nsgs_tolerance,
                                base.solver.nsgs_max_sweeps));
  restore(sim, pre.state);
  sim::Simulation r1sim(referenceSpec(o, base, plan.mesh, h));
  const sim::InstrumentSpec& ins = base.instrument;

  // series: r1, r2 (given), hold, extrapolate, coupling, local per budget
  MethodSeries r1;
  r1.method = "r1";
  r1.label = "R1: exact step at the tick's pose";
  std::vector<MethodSeries> out(3);
  out[0].method = "hold";
  out[0].label = "hold the snapshot's force";
  out[1].method = "extrapolate";
  out[1].label = "linear extrapolation of the force";
  out[2].method = "coupling";
  out[2].label = fmt::format("virtual coupling to the god object ({} N/m)", ins.coupling_k_npm);
  // the local model: the full re-solve per sweep budget (0: converged), then the linearised
  // model (haptic/local_model.h) with the scene's tolerance and the largest budget
  std::vector<LocalModel> models(plan.budgets.size() + 1);
  const shared::SegmentCapacity cap = sim::problemCapacity(base);
  int largest = 1;
  for (const int b : plan.budgets) largest = std::max(largest, b);
  for (std::size_t b = 0; b < models.size(); ++b) {
    const bool linear = b == plan.budgets.size();
    const bool converged = !linear && plan.budgets[b] <= 0;
    models[b].kind = linear ? haptic::LocalModelKind::kLinearized : haptic::LocalModelKind::kFull;
    models[b].budget = converged ? std::max(1000, o.ref_sweeps)
                       : linear  ? largest
                                 : plan.budgets[b];
    models[b].tol = converged ? o.ref_tolerance : base.haptics.nsgs_tolerance;
    models[b].reserve(cap.max_rows, cap.max_contacts);
    MethodSeries s;
    s.method = linear ? "linearized" : "local";
    s.sweeps = linear ? largest : plan.budgets[b];
    s.label = linear      ? std::string("local model linearised (re-solve where it fails)")
              : converged ? std::string("local model converged")
                          : fmt::format("local model {} sweep{}", plan.budgets[b],
                                        plan.budgets[b] == 1 ? "" : "s");
    out.push_back(std::move(s));
  }
  const long first = std::min(ticks, lat * n);   // no snapshot yet
  hc.snapshot.assign(static_cast<std::size_t>(ticks), -1);
  for (long j = 0; j < first; ++j) {
    r1.pushInvalid();
    for (auto& s : out) s.pushInvalid();
  }
  SavedState before;
  Eigen::Vector3d f_prev = Eigen::Vector3d::Zero();
  for (long k = 0; (k + lat) * n < ticks; ++k) {
    const double t_k = static_cast<double>(k) * h;
    save(sim, before);
    sim.setDeviceTarget(deviceAt(pre.anchor, m, t_k));
    if (!sim.step().finite) throw NumericalError("haptic multi-rate simulation diverged");
    const sim::ContactProblemData& snap = sim.lastProblem();
    const Eigen::Vector3d f_k = contactWrench(snap, snap.f.data(), snap.tool_pose.pos_m).head<3>();
    if (k == 0) f_prev = f_k;
    const sim::Instrument& god = *sim.instrument();
    const double snap_pen = heldPenetration(snap, snap.device_pose);
    for (long j = (k + lat) * n; j < std::min(ticks, (k + lat + 1) * n); ++j) {
      const double t = static_cast<double>(j) * dt;
      const sim::DeviceTarget d = deviceAt(pre.anchor, m, t);
      hc.snapshot[static_cast<std::size_t>(j)] = k;
      // R1: the full step from the snapshot's pre-step state at the tick's pose
      restore(r1sim, before);
      double pen = 0.0, step_s = 0.0;
      const Eigen::Vector3d f_r1 = stepForce(r1sim, d, pen, step_s);
      r1.push(f_r1, pen, step_s);
      const double held_pen = heldPenetration(snap, d.pose);
      std::int64_t t0 = shared::monotonicNs();
      const Eigen::Vector3d f_hold = f_k;
      out[0].push(f_hold, held_pen, shared::secondsSinceNs(t0));
      t0 = shared::monotonicNs();
      const Eigen::Vector3d f_ex = f_k + (f_k - f_prev) * ((t - t_k) / h);
      out[1].push(f_ex, held_pen, shared::secondsSinceNs(t0));
      t0 = shared::monotonicNs();
      const Eigen::Vector3d f_vc = ins.coupling_k_npm * (god.pose().pos_m - d.pose.pos_m) +
                                   ins.coupling_b_nspm * (god.twist().head<3>() -
                                                          d.twist.head<3>());
      out[2].push(f_vc, snap_pen, shared::secondsSinceNs(t0));
      for (std::size_t b = 0; b < models.size(); ++b) {
        double lpen = 0.0, tick_s = 0.0;
        const Eigen::Vector3d f = localTick(models[b], sim, snap, k, d.pose,
                                            base.instrument.max_opening_rad, lpen, tick_s);
        out[3 + b].push(f, lpen, tick_s);
      }
    }
    f_prev = f_k;
  }
  hc.device_pos.resize(static_cast<std::size_t>(ticks));
  for (long j = 0; j < ticks; ++j) {
    hc.device_pos[static_cast<std::size_t>(j)] =
        deviceAt(pre.anchor, m, static_cast<double>(j) * dt).pose.pos_m;
  }
  std::vector<MethodSeries> all;
  all.push_back(std::move(r1));
  all.push_back(std::move(hc.series.at(0)));
  for (auto& s : out) all.push_back(std::move(s));
  hc.series = std::move(all);
}

// The R1 machinery's consistency (ReplayCheck).
ReplayCheck replayCheck(const Options& o, const sim::SceneSpec& base, const HapticPlan& plan,
                        const Prefix& pre, const DeviceMotion& m, double h) {
  ReplayCheck rc;
  sim::Simulation sim(referenceSpec(o, base, plan.mesh, h));
  sim::Simulation replay(referenceSpec(o, base, plan.mesh, h));
  restore(sim, pre.state);
  SavedState before;
  double max_diff = 0.0;
  for (int k = 0; k < plan.replay_steps; ++k) {
    const sim::DeviceTarget d = deviceAt(pre.anchor, m, static_cast<double>(k) * h);
    save(sim, before);
    double pen = 0.0, step_s = 0.0;
    const Eigen::Vector3d f = stepForce(sim, d, pen, step_s);
    restore(replay, before);
    const Eigen::Vector3d f_replay = stepForce(replay, d, pen, step_s);
    max_diff = std::max(max_diff, (f - f_replay).norm());
    rc.max_force_n = std::max(rc.max_force_n, f.norm());
    ++rc.steps;
  }
  rc.max_rel_diff = rc.max_force_n > 0.0 ? max_diff / rc.max_force_n : 0.0;
  return rc;
}

}  // namespace

std::vector<HapticCase> runHaptic(const Options& o, const HapticPlan& plan, ReplayCheck& replay) {
  const sim::SceneSpec base = meshScene(o, plan.mesh);
  spdlog::info("haptic: prefix 0 .. {} s", plan.t0_s);
  const Prefix pre = runPrefix(o, base, plan);
  // presses go into the tissue: against the contact force at t0 (else along -x, the approach)
  const Eigen::Vector3d into = pre.force.norm() > 0.05 ? Eigen::Vector3d(-pre.force.normalized())
                                                       : Eigen::Vector3d(-Eigen::Vector3d::UnitX());
  std::vector<DeviceMotion> motions = plan.motions;
  for (DeviceMotion& m : motions) {
    if (m.name != "tremor") m.dir = into;
  }
  replay = replayCheck(o, base, plan, pre, motions.front(), base.time_step_s);
  fmt::print("  R1 replay check: {} steps, max force difference {:.2e} of {:.3f} N\n",
             replay.steps, replay.max_rel_diff, replay.max_force_n);
  std::vector<HapticCase> cases;
  for (const DeviceMotion& m : motions) {
    std::map<double, MethodSeries> r2;
    for (std::size_t pair = 0; pair < plan.rates.size(); ++pair) {
      const auto [rate, h] = plan.rates[pair];
      if (r2.find(rate) == r2.end()) {
        const std::int64_t t0 = shared::monotonicNs();
        r2.emplace(rate, runR2(o, base, plan, pre, m, rate));
        fmt::print("  {:<10} R2 at {:>4.0f} Hz: {:.1f} s\n", m.name, rate,
                   shared::secondsSinceNs(t0));
      }
      for (const char* w : {"scene", "exact"}) {
        if (std::string(w) == "exact" && static_cast<int>(pair) >= plan.exact_snapshot_pairs) {
          continue;
        }
        const std::int64_t t0 = shared::monotonicNs();
        HapticCase hc;
        hc.motion = m.name;
        hc.rate_hz = rate;
        hc.sim_h_s = h;
        hc.snapshot_w = w;
        hc.settle_s = 0.5 * m.lead_in_s;
        hc.series.push_back(r2.at(rate));
        runCase(o, base, plan, pre, m, hc);
        fmt::print("  {:<10} {:>4.0f} Hz, simulation at {:>3.0f} Hz ({} W): R1 and methods "
                   "{:.1f} s\n",
                   m.name, rate, 1.0 / h, w, shared::secondsSinceNs(t0));
        std::fflush(stdout);
        cases.push_back(std::move(hc));
      }
    }
  }
  return cases;
}

}  // namespace tactus::study

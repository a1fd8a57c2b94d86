// The hard-case stability suite, haptic side: the HapticLoop on a real shared segment, fed by an
// in-process Simulation (scenes/haptic_cube.yaml) whose contact problem is written into the
// segment with writeSnapshot every simulation step, driven by a scripted device. Time is
// simulated (1 ms ticks, one simulation step every h), so the runs are deterministic.
//
// Each case asserts: no NaN/Inf in any rendered force or in the simulation, |F| never above the
// clamp, the simulation's contact laws (penetration bound, NSGS residual or budget), and, for
// closed device paths, passivity: the energy the hand puts in, -sum F_k . (x_{k+1} - x_k), is
// at least the energy it gets back (within a margin).
#include <gtest/gtest.h>
#include <unistd.h>

#include <cmath>
#include <functional>
#include <limits>
#include <optional>

#include "../support/scripted_device.h"
#include "hard_case_support.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/segment.h"
#include "tactus/sim/haptic_link.h"

namespace tactus::hard_cases {
namespace {

using test::ScriptedDevice;

constexpr std::int64_t kTickNs = 1'000'000;

/// Simulation + segment + haptic loop, stepped together on a simulated clock.
class Rig {
 public:
  explicit Rig(const std::string& tag, const std::string& scene = "haptic_cube.yaml",
               std::optional<double> max_force_n = std::nullopt)
      : spec_(loadCase(scene)),
        sim_(spec_),
        name_("tactus_hard_" + tag + "_" + std::to_string(::getpid())),
        watch_(spec_) {
    shared::Segment::remove(name_);
    segment_.emplace(shared::Segment::create(
        name_, shared::SegmentCapacity::forContacts(spec_.solver.max_contacts,
                                                    spec_.instrument.friction_mu > 0.0)));
    publisher_ = segment_->snapshotPublisher();
    samples_ = segment_->deviceReader();
    settings_.max_force_n = max_force_n.value_or(spec_.haptics.max_force_n);
    settings_.watchdog_ms = spec_.haptics.watchdog_ms;
    settings_.max_sweeps = spec_.haptics.max_sweeps_per_tick;
    settings_.tolerance = spec_.haptics.nsgs_tolerance;
    settings_.solve_budget_ns = 0;   // simulated time: bound the solve by sweeps only
    loop_.emplace(device_, settings_);
    link_ = std::make_unique<haptic::AttachedSegment>(shared::Segment::open(name_));
    loop_->offerLink(link_.get());
    target_ = sim_.scriptedTarget(0.0);
    ticks_per_step_ = static_cast<int>(std::lround(spec_.time_step_s * 1e9 / kTickNs));
  }
  ~Rig() {
    loop_->offerLink(nullptr);
    t_ns_ += kTickNs;
    loop_->tick(t_ns_, t_ns_);
    link_.reset();
    segment_.reset();
    shared::Segment::remove(name_);
  }

  /// Sets the device's true position for the next tick (velocity from the last position).
  void moveDevice(const Eigen::Vector3d& pos_m) {
    device_vel_ = (pos_m - device_pos_) / (1e-9 * kTickNs);
    device_pos_ = pos_m;
  }
  /// Corrupts what the device reports (NaN/Inf episodes); the true position is unchanged.
  /// Empty: the device reports the truth.
  std::function<void(device::DeviceState&)> corrupt;

  /// One haptic tick, then (every h) one simulation step fed by the newest device sample and
  /// its snapshot. `simulate` false: the simulation is stalled. Accumulates the energy balance
  /// with the device's true position moving to `next_pos` after this tick's force.
  haptic::TickOutput tick(bool simulate = true) {
    t_ns_ += kTickNs;
    device_.state = device::DeviceState{};
    device_.state.t_ns = t_ns_;
    for (int i = 0; i < 3; ++i) {
      device_.state.pos_m[i] = device_pos_[i];
      device_.state.vel_mps[i] = device_vel_[i];
    }
    if (corrupt) corrupt(device_.state);
    const haptic::TickOutput out = loop_->tick(t_ns_, t_ns_);
    ++ticks_;
    const Eigen::Vector3d F(out.force_n[0], out.force_n[1], out.force_n[2]);
    if (!F.allFinite() || !std::isfinite(out.torque_nm[0]) || !std::isfinite(out.torque_nm[1]) ||
        !std::isfinite(out.torque_nm[2])) {
      ++nonfinite_forces_;
    }
    max_force_ = std::max(max_force_, F.allFinite() ? F.norm() : 1e300);
    last_force_ = F;
    if (simulate && ticks_ % ticks_per_step_ == 0) stepSimulation();
    return out;
  }

  /// The hand moves from its current position to `next`: the force of the last tick acts over
  /// the move (zero-order hold). Accumulates the energy in and out of the hand.
  void moveHand(const Eigen::Vector3d& next) {
    const double work_on_hand = last_force_.dot(next - device_pos_);
    if (work_on_hand > 0.0) energy_out_j_ += work_on_hand;
    else energy_in_j_ -= work_on_hand;
    moveDevice(next);
  }

  void stepSimulation() {
    // the device target: the newest sample when finite and not faulted (as sim_server does)
    const shared::DeviceSample& s = samples_.latest();
    bool finite = true;
    for (double x : s.pos_m) finite = finite && std::isfinite(x);
    for (double x : s.quat_wxyz) finite = finite && std::isfinite(x);
    for (double x : s.vel_mps) finite = finite && std::isfinite(x);
    if (!finite) ++nonfinite_samples_;
    // the production path: sim_server's freshness and target rules
    if (sim::deviceSampleFresh(s, t_ns_,
                               static_cast<std::int64_t>(spec_.haptics.watchdog_ms * 1e6))) {
      sim::deviceTargetFromSample(s, spec_.instrument.max_opening_rad, target_);
    }
    sim_.setDeviceTarget(target_);
    const sim::StepReport r = sim_.step();
    watch_.add(sim_, r, /*geometric=*/r.contacts > 0);
    auto slot = publisher_.slot();
    sim::writeSnapshot(sim_, spec_.instrument.max_opening_rad, ++seq_, t_ns_, s.seq, slot);
    publisher_.publish();
  }

  const sim::SceneSpec& spec() const { return spec_; }
  sim::Simulation& sim() { return sim_; }
  haptic::HapticLoop& loop() { return *loop_; }
  const haptic::HapticSettings& settings() const { return settings_; }
  const StepWatch& watch() const { return watch_; }
  const Eigen::Vector3d& devicePos() const { return device_pos_; }
  const Eigen::Vector3d& lastForce() const { return last_force_; }
  double maxForce() const { return max_force_; }
  long nonfiniteForces() const { return nonfinite_forces_; }
  long nonfiniteSamples() const { return nonfinite_samples_; }
  double energyIn() const { return energy_in_j_; }
  double energyOut() const { return energy_out_j_; }

 private:
  sim::SceneSpec spec_;
  sim::Simulation sim_;
  std::string name_;
  std::optional<shared::Segment> segment_;
  shared::SnapshotPublisher publisher_;
  shared::TripleReader<shared::DeviceSample> samples_;
  ScriptedDevice device_;
  haptic::HapticSettings settings_;
  std::optional<haptic::HapticLoop> loop_;
  std::unique_ptr<haptic::AttachedSegment> link_;
  sim::DeviceTarget target_;
  StepWatch watch_;
  int ticks_per_step_ = 10;
  long ticks_ = 0;
  std::uint64_t seq_ = 0;
  std::int64_t t_ns_ = 1'000'000'000;
  Eigen::Vector3d device_pos_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d device_vel_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d last_force_ = Eigen::Vector3d::Zero();
  double max_force_ = 0.0;
  long nonfinite_forces_ = 0;
  long nonfinite_samples_ = 0;
  double energy_in_j_ = 0.0;
  double energy_out_j_ = 0.0;
};

// The device path pieces (1 ms per tick). The cube's top is at z = 0.035; the probe's 6 mm tip
// touches it when the device is at z = 0.041.
const Eigen::Vector3d kStart(0.004, 0.003, 0.046);
const Eigen::Vector3d kPressed(0.004, 0.003, 0.038);   // 3 mm into the cube

void glide(Rig& rig, const Eigen::Vector3d& to, int ticks,
           const std::function<void(const haptic::TickOutput&)>& each = {}) {
  const Eigen::Vector3d from = rig.devicePos();
  for (int k = 1; k <= ticks; ++k) {
    const haptic::TickOutput out = rig.tick();
    if (each) each(out);
    rig.moveHand(from + (to - from) * (static_cast<double>(k) / ticks));
  }
}

void hold(Rig& rig, int ticks, const std::function<void(const haptic::TickOutput&)>& each = {},
          bool simulate = true) {
  for (int k = 0; k < ticks; ++k) {
    const haptic::TickOutput out = rig.tick(simulate);
    if (each) each(out);
    rig.moveHand(rig.devicePos());
  }
}

void jump(Rig& rig, const Eigen::Vector3d& to) {
  rig.tick();
  rig.moveHand(to);
}

std::string figures(const Rig& rig) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), " |F|max=%.3g N (clamp %.3g) E_in=%.4g J E_back=%.4g J",
                rig.maxForce(), rig.settings().max_force_n, rig.energyIn(), rig.energyOut());
  return rig.watch().summary() + buf;
}

// `max_budget_stops`: the simulation's NSGS solves stopped at the sweep budget, measured per case
// plus a margin (the other cases 0). Press through stalls near the tolerance in many steps, so
// its count follows rounding: 47, 54 and 77 (residual <= 7.96e-6) on 2026-11-25 with the same
// arithmetic summed in three orders (W f by rows or by contacts, two or four partial sums).
void expectSafe(const Rig& rig, const std::string& name, long max_budget_stops) {
  EXPECT_EQ(rig.nonfiniteForces(), 0) << name;
  EXPECT_LE(rig.maxForce(), rig.settings().max_force_n + 1e-12) << name;
  rig.watch().expectHealthy(name, 1e-5, max_budget_stops, 1.2e-5);
  EXPECT_GT(rig.watch().min_geometric_gap_m, -1e-3) << name;
}

// Passivity over a closed path: E_in >= E_back - margin (5% of what went in, +0.1 mJ).
void expectPassive(const Rig& rig, const std::string& name) {
  EXPECT_GE(rig.energyIn() - rig.energyOut(), -(0.05 * rig.energyIn() + 1e-4))
      << name << ": the haptic loop returned more energy than the hand put in";
}

void start(Rig& rig, const Eigen::Vector3d& at = kStart) {
  rig.moveDevice(at);
  rig.moveDevice(at);       // zero velocity
  hold(rig, 100);           // engaged at zero force, first snapshots published
}

// --- the device teleports 10 cm in one tick ---------------------------------------------------

TEST(HapticHardCases, DeviceTeleportsTenCentimetresSideways) {
  Rig rig("teleport_x");
  start(rig);
  glide(rig, kPressed, 300);
  hold(rig, 200);
  const double f_pressed = rig.lastForce().norm();
  jump(rig, kPressed + Eigen::Vector3d(0.10, 0.0, 0.0));   // 10 cm in one tick
  hold(rig, 300);
  jump(rig, kPressed);                                      // and back
  hold(rig, 300);
  glide(rig, kStart, 300);                                  // closed path
  hold(rig, 200);
  printCase("teleport_10cm_sideways",
            figures(rig) + " F_pressed=" + std::to_string(f_pressed) + " N");
  expectSafe(rig, "teleport sideways", 2);
  EXPECT_GT(f_pressed, 0.5);
  expectPassive(rig, "teleport sideways");
  EXPECT_LT(rig.lastForce().norm(), 1e-9) << "force left after returning to free space";
}

TEST(HapticHardCases, DeviceTeleportsTenCentimetresIntoTheTissue) {
  // A discontinuous path into the tissue is not a motion a hand can make: the zero-order-hold
  // energy balance is not meaningful across the jumps, so this case checks the clamp, the
  // finite state and the recovery, not passivity (the sideways case covers it).
  Rig rig("teleport_z");
  start(rig);
  glide(rig, kPressed, 300);
  hold(rig, 200);
  const double f_pressed = rig.lastForce().norm();
  jump(rig, kPressed - Eigen::Vector3d(0.0, 0.0, 0.10));
  double f_deep = 0.0;
  hold(rig, 200, [&](const haptic::TickOutput& o) { f_deep = std::max(f_deep, o.unlimited_force_norm_n); });
  const auto clamped = rig.loop().counters().clamped.load();
  jump(rig, kPressed);
  hold(rig, 500);
  const double f_back = rig.lastForce().norm();
  glide(rig, kStart, 300);
  hold(rig, 200);
  printCase("teleport_10cm_down", figures(rig) + " F_pressed=" + std::to_string(f_pressed) +
                                      " F_deep_unclamped=" + std::to_string(f_deep) +
                                      " F_back=" + std::to_string(f_back));
  expectSafe(rig, "teleport down", 2);
  EXPECT_GT(f_deep, rig.settings().max_force_n) << "the jump should ask for more than the clamp";
  EXPECT_GT(clamped, 0u);
  EXPECT_NEAR(f_back, f_pressed, 0.05 * f_pressed) << "the contact did not recover";
  EXPECT_LT(rig.lastForce().norm(), 1e-9);
}

// --- NaN and infinity from the device ----------------------------------------------------------

TEST(HapticHardCases, NonFiniteDeviceDataFadesAndRecovers) {
  Rig rig("nan");
  start(rig);
  glide(rig, kPressed, 300);
  hold(rig, 200);
  const double f_pressed = rig.lastForce().norm();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const double inf = std::numeric_limits<double>::infinity();
  long nonzero_during_fault = 0;
  // the hand stays put; the device reports garbage: NaN position, Inf orientation, NaN velocity
  std::vector<std::function<void(device::DeviceState&)>> faults = {
      [&](device::DeviceState& s) { s.pos_m[0] = nan; },
      [&](device::DeviceState& s) { s.quat_wxyz[1] = inf; },
      [&](device::DeviceState& s) { s.pos_m[2] = -inf; s.vel_mps[1] = nan; },
  };
  for (const auto& fault : faults) {
    rig.corrupt = fault;
    hold(rig, 150);
    if (rig.lastForce().norm() > 0.0) ++nonzero_during_fault;
    rig.corrupt = nullptr;   // healthy again
    hold(rig, 200);
  }
  // a non-finite velocity alone (position fine): the sample sanitises it, forces continue
  rig.corrupt = [&](device::DeviceState& s) { s.vel_mps = {nan, inf, nan}; };
  hold(rig, 50);
  rig.corrupt = nullptr;
  hold(rig, 100);
  // healthy again with the hand still pressing: the engage gate keeps the force off
  const double f_healthy_pressed = rig.lastForce().norm();
  // the hand leaves the tissue and presses again: the force is back
  glide(rig, kStart, 300);
  hold(rig, 100);
  glide(rig, kPressed, 300);
  hold(rig, 200);
  const double f_after = rig.lastForce().norm();
  glide(rig, kStart, 300);
  hold(rig, 100);
  printCase("nan_device_haptic", figures(rig) + " F_pressed=" + std::to_string(f_pressed) +
                                     " F_after=" + std::to_string(f_after) + " non_finite_input=" +
                                     std::to_string(rig.loop().counters().non_finite_input.load()));
  expectSafe(rig, "nan device", 2);
  EXPECT_EQ(rig.nonfiniteSamples(), 0) << "a non-finite device sample reached the segment";
  EXPECT_GT(rig.loop().counters().non_finite_input.load(), 0u);
  EXPECT_EQ(nonzero_during_fault, 0) << "force not faded out during a device fault";
  EXPECT_EQ(f_healthy_pressed, 0.0) << "the force came back with the hand in the tissue";
  EXPECT_NEAR(f_after, f_pressed, 0.05 * f_pressed);
  expectPassive(rig, "nan device");
}

// --- the simulation stalls for 200 ms ----------------------------------------------------------

TEST(HapticHardCases, SimulationStallFadesTheForceAndItComesBackAfterTheHandLeftTheTissue) {
  Rig rig("stall");
  start(rig);
  glide(rig, kPressed, 300);
  hold(rig, 200);
  const double f_pressed = rig.lastForce().norm();
  // 200 ms without a simulation step: the loop keeps ticking on the last snapshot
  double f_end_of_stall = -1.0;
  bool stale_seen = false;
  int tick = 0;
  double f_during_grace = 0.0;
  hold(
      rig, 200,
      [&](const haptic::TickOutput& o) {
        ++tick;
        stale_seen = stale_seen || o.stale;
        if (tick < static_cast<int>(rig.settings().watchdog_ms)) {
          f_during_grace = std::min(f_during_grace == 0.0 ? 1e9 : f_during_grace,
                                    std::sqrt(o.force_n[0] * o.force_n[0] +
                                              o.force_n[1] * o.force_n[1] +
                                              o.force_n[2] * o.force_n[2]));
        }
        f_end_of_stall = std::sqrt(o.force_n[0] * o.force_n[0] + o.force_n[1] * o.force_n[1] +
                                   o.force_n[2] * o.force_n[2]);
      },
      /*simulate=*/false);
  // resume: fresh snapshots; with the hand still pressing the engage gate keeps the force off
  hold(rig, static_cast<int>(rig.settings().fade_ms) + 50);
  const double f_resumed_pressed = rig.lastForce().norm();
  // the hand leaves the tissue and presses again: the force is back
  glide(rig, kStart, 300);
  hold(rig, 100);
  glide(rig, kPressed, 300);
  hold(rig, 200);
  const double f_after = rig.lastForce().norm();
  glide(rig, kStart, 300);
  hold(rig, 100);
  printCase("sim_stall_200ms", figures(rig) + " F_pressed=" + std::to_string(f_pressed) +
                                   " F_end_of_stall=" + std::to_string(f_end_of_stall) +
                                   " F_after=" + std::to_string(f_after));
  expectSafe(rig, "stall", 2);
  EXPECT_TRUE(stale_seen);
  EXPECT_NEAR(f_during_grace, f_pressed, 0.05 * f_pressed) << "faded before the watchdog";
  EXPECT_EQ(f_end_of_stall, 0.0) << "not faded out after watchdog + fade";
  EXPECT_EQ(f_resumed_pressed, 0.0) << "the force came back with the hand in the tissue";
  EXPECT_NEAR(f_after, f_pressed, 0.05 * f_pressed) << "force did not come back";
  expectPassive(rig, "stall");
}

// --- the device pressed through the organ ------------------------------------------------------

// The hand pushes the device through the thin disc of press_through.yaml (4 mm below its bottom
// face, as in the simulation-side case), holds, and comes back out: a closed path. The clamp is
// set below the force the hold asks for, so the rendered force saturates while the disc holds
// the god object.
TEST(HapticHardCases, DevicePressedThroughTheOrganStaysClampedAndPassive) {
  Rig rig("press_through", "press_through.yaml", /*max_force_n=*/0.3);
  const Eigen::Vector3d above = rig.spec().instrument.initial_pose.position_m;
  const Eigen::Vector3d through = rig.spec().instrument.trajectory.back().pose.position_m;
  const double disc_bottom_z = restZRange(rig.sim().tissue(0)).first;
  start(rig, above);
  glide(rig, through, 800);
  hold(rig, 400);
  const double f_held = rig.lastForce().norm();
  const double tool_z = rig.sim().instrument()->pose().pos_m.z();
  const double tip_r = rig.spec().instrument.tip_radius_m;
  const auto clamped = rig.loop().counters().clamped.load();
  glide(rig, above, 800);
  hold(rig, 300);
  printCase("press_through_haptic",
            figures(rig) + " F_held=" + std::to_string(f_held) + " N tool_z=" +
                std::to_string(tool_z) + " m clamped_ticks=" + std::to_string(clamped));
  expectSafe(rig, "press through", 90);
  EXPECT_GT(rig.watch().min_geometric_gap_m, -5e-4);
  EXPECT_LT(tool_z - tip_r, disc_bottom_z) << "the tip was not pressed through the rest thickness";
  EXPECT_GT(tool_z - through.z(), 0.005) << "the god object followed the device through";
  EXPECT_NEAR(f_held, rig.settings().max_force_n, 1e-9) << "the hold should saturate the clamp";
  EXPECT_GT(clamped, 0u);
  expectPassive(rig, "press through");
  EXPECT_LT(rig.lastForce().norm(), 1e-9) << "force left after returning above the disc";
}

}  // namespace
}  // namespace tactus::hard_cases

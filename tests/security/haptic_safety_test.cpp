// Haptic safety limits against nonsense: settings, options and device limits are validated with clear messages, and
// whatever the settings, the snapshots or the device input, the loop writes only finite commands
// within the clamp (property tests over random values including NaN, Inf, negative, huge and
// denormal). Also: the simulation publishes an exactly symmetric W for a real scene and says so.
#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "support/haptic_loop_access.h"
#include "support/scripted_device.h"
#include "tactus/device/device.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/shared/error.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/scene.h"

namespace tactus {
namespace {

using haptic::HapticSettings;
using haptic::HapticSettingsLimits;
using ::testing::HasSubstr;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kDenormal = 4.9e-324;

// |v| in long double (an independent check of the guard's own norm).
long double exactNorm(const std::array<double, 3>& v) {
  long double s = 0.0L;
  for (double x : v) s += static_cast<long double>(x) * static_cast<long double>(x);
  return std::sqrt(s);
}

bool allFinite(const std::array<double, 3>& v) {
  return std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]);
}

// The clamp the guard must respect for a limit: finite and >= kMinLimit, capped by the ceiling;
// anything else means no output at all.
double usableLimit(double limit, double ceiling) {
  return std::isfinite(limit) && limit >= HapticSettingsLimits::kMinLimit ? std::min(limit, ceiling)
                                                                          : 0.0;
}

// A value drawn from the nasty set or from a wide log-uniform range of either sign.
class Nasty {
 public:
  explicit Nasty(std::uint32_t seed) : rng_(seed) {}
  double any() {
    static constexpr double kSpecial[] = {kNaN, kInf,     -kInf,   0.0,    -0.0,  kDenormal,
                                          -kDenormal, 1e308, -1e308, 1e-300, 1e300, -1.0};
    const int pick = std::uniform_int_distribution<int>(0, 3)(rng_);
    if (pick == 0) {
      return kSpecial[std::uniform_int_distribution<int>(0, std::size(kSpecial) - 1)(rng_)];
    }
    const double magnitude = std::pow(10.0, std::uniform_real_distribution<double>(-12, 12)(rng_));
    return pick == 1 ? -magnitude : magnitude;
  }
  // Mostly ordinary values in [lo, hi], sometimes nasty.
  double mostly(double lo, double hi) {
    if (std::uniform_int_distribution<int>(0, 4)(rng_) == 0) return any();
    return std::uniform_real_distribution<double>(lo, hi)(rng_);
  }
  int integer(int lo, int hi) { return std::uniform_int_distribution<int>(lo, hi)(rng_); }
  bool coin() { return integer(0, 1) == 1; }

 private:
  std::mt19937 rng_;
};

// ScriptedDevice with a configurable reported force limit.
class LimitedDevice : public test::ScriptedDevice {
 public:
  device::DeviceInfo info() const override {
    device::DeviceInfo i = ScriptedDevice::info();
    i.max_force_n = max_force_n;
    return i;
  }
  double max_force_n = 20.0;
};

TEST(HapticGuard, WritesOnlyFiniteWrenchesWithinTheClampForAnyInputAndLimit) {
  Nasty r(12345);
  long interventions = 0;
  for (int trial = 0; trial < 200'000; ++trial) {
    std::array<double, 3> force{r.any(), r.any(), r.any()};
    std::array<double, 3> torque{r.any(), r.any(), r.any()};
    const double max_force = r.any();
    const double max_torque = r.any();
    const std::array<double, 3> force_in = force;
    const bool changed = haptic::guardWrench(force, torque, max_force, max_torque);
    interventions += changed ? 1 : 0;
    ASSERT_TRUE(allFinite(force) && allFinite(torque)) << "trial " << trial;
    ASSERT_LE(exactNorm(force), usableLimit(max_force, HapticSettingsLimits::kMaxForceN))
        << "trial " << trial << " limit " << max_force;
    ASSERT_LE(exactNorm(torque), usableLimit(max_torque, HapticSettingsLimits::kMaxTorqueNm))
        << "trial " << trial << " limit " << max_torque;
    if (!changed) {
      ASSERT_EQ(force, force_in) << "trial " << trial;
    }
  }
  EXPECT_GT(interventions, 0);
  // an in-range command passes untouched
  std::array<double, 3> f{1.0, -2.0, 0.5};
  std::array<double, 3> t{0.01, 0.0, 0.0};
  EXPECT_FALSE(haptic::guardWrench(f, t, 8.0, 0.5));
  EXPECT_EQ(f, (std::array<double, 3>{1.0, -2.0, 0.5}));
}

// The whole tick with random (unvalidated) settings, random device limits, random snapshots
// (values, sizes, row offsets and flags) and random device input: every command the loop
// writes to the device is finite and within min(settings clamp, device limit, ceiling).
TEST(HapticLoopProperty, EveryCommandIsFiniteAndWithinTheClampWhateverTheSettings) {
  const std::string name = "tactus_sec_haptic_" + std::to_string(::getpid());
  shared::Segment::remove(name);
  shared::Segment sim = shared::Segment::create(name, shared::SegmentCapacity::forContacts(4, true));
  shared::SnapshotPublisher publisher = sim.snapshotPublisher();
  auto link = std::make_unique<haptic::AttachedSegment>(shared::Segment::open(name));
  Nasty r(2024);
  std::uint64_t seq = 0;
  std::int64_t t = 1'000'000'000;
  long commands = 0;
  long nonzero = 0;
  std::uint64_t interventions = 0;
  for (int trial = 0; trial < 2000; ++trial) {
    HapticSettings s;
    s.force_scale = r.mostly(0.0, 3.0);
    s.max_force_n = r.mostly(0.0, 20.0);
    s.max_torque_nm = r.mostly(0.0, 1.0);
    s.slew_n_per_s = r.mostly(0.0, 1e5);
    s.engage_threshold_n = r.mostly(0.0, 100.0);
    s.watchdog_ms = r.mostly(0.0, 100.0);
    s.fade_ms = r.mostly(0.0, 50.0);
    s.tolerance = r.mostly(0.0, 1e-3);
    s.max_sweeps = r.integer(-2, 30);
    s.solve_budget_ns = r.coin() ? 1'000'000'000 : r.integer(-5, 100'000);
    s.period_ns = r.coin() ? 1'000'000 : r.integer(-5, 2'000'000);
    s.render_torque = r.coin();
    LimitedDevice device;
    device.max_force_n = r.coin() ? r.mostly(0.0, 30.0) : 20.0;
    const auto unchecked = haptic::HapticLoopTestAccess::unchecked(device, s);
    haptic::HapticLoop& loop = *unchecked;
    double clamp = usableLimit(s.max_force_n, HapticSettingsLimits::kMaxForceN);
    if (std::isfinite(device.max_force_n) && device.max_force_n > 0.0) {
      clamp = std::min(clamp, device.max_force_n);
    }
    const double torque_clamp = usableLimit(s.max_torque_nm, HapticSettingsLimits::kMaxTorqueNm);
    ASSERT_LE(clamp, HapticSettingsLimits::kMaxForceN);
    loop.offerLink(link.get());
    for (int tick = 0; tick < 25; ++tick) {
      if (tick % 5 == 0) {
        // a random snapshot: mostly plausible, sometimes nonsense everywhere
        auto slot = publisher.slot();
        const int contacts = r.integer(0, 4);
        const bool friction = r.coin();
        const int rows = friction ? 3 * contacts : contacts;
        ASSERT_TRUE(slot.setSize(rows, contacts));
        auto& h = slot.header();
        h.seq = ++seq;
        h.t_ns = r.integer(0, 9) == 0 ? static_cast<std::int64_t>(r.integer(0, 1000)) : t;
        h.flags = shared::kSnapshotValid |
                  (r.coin() ? shared::kSnapshotHasJacobian : 0u) |
                  (r.coin() ? shared::kSnapshotSymmetricW : 0u) |
                  (r.integer(0, 9) == 0 ? shared::kSnapshotShuttingDown : 0u);
        for (int k = 0; k < 3; ++k) {
          h.device_pose.pos_m[k] = r.mostly(-0.01, 0.01);
          h.tool_pose.pos_m[k] = r.mostly(-0.01, 0.01);
        }
        h.device_pose.quat_wxyz = {r.mostly(0.5, 1.0), r.mostly(-0.1, 0.1), 0.0, 0.0};
        for (int c = 0; c <= contacts; ++c) {
          slot.rowOffset()[c] = r.integer(0, 19) == 0 ? r.integer(-3, 20) : (friction ? 3 : 1) * c;
        }
        for (int c = 0; c < contacts; ++c) {
          slot.mu()[c] = r.mostly(0.0, 1.0);
          for (int k = 0; k < 3; ++k) {
            slot.contactPoint()[3 * c + k] = r.mostly(-0.01, 0.01);
            slot.contactNormal()[3 * c + k] = r.mostly(-1.0, 1.0);
            slot.contactTangent()[6 * c + k] = r.mostly(-1.0, 1.0);
            slot.contactTangent()[6 * c + 3 + k] = r.mostly(-1.0, 1.0);
          }
        }
        for (int i = 0; i < rows; ++i) {
          for (int j = 0; j < rows; ++j) {
            slot.W()[i * slot.ld() + j] = i == j ? r.mostly(1e-4, 1e-2) : r.mostly(-1e-4, 1e-4);
          }
          slot.deltaFree()[i] = r.mostly(-0.01, 0.01);
          slot.f()[i] = r.mostly(0.0, 10.0);
          for (int k = 0; k < 6; ++k) slot.J()[6 * i + k] = r.mostly(-1.0, 1.0);
        }
        publisher.publish();
      }
      device.fault = r.integer(0, 19) == 0;
      device.state = device::DeviceState{};
      for (int k = 0; k < 3; ++k) {
        device.state.pos_m[k] = r.mostly(-0.01, 0.01);
        device.state.vel_mps[k] = r.mostly(-1.0, 1.0);
      }
      device.state.quat_wxyz = {r.mostly(0.5, 1.0), r.mostly(-0.1, 0.1), 0.0, 0.0};
      t += 1'000'000;
      const haptic::TickOutput out = loop.tick(t, t);
      ++commands;
      ASSERT_TRUE(allFinite(device.last.force_n) && allFinite(device.last.torque_nm))
          << "trial " << trial << " tick " << tick;
      ASSERT_LE(exactNorm(device.last.force_n), clamp) << "trial " << trial << " tick " << tick;
      ASSERT_LE(exactNorm(device.last.torque_nm), torque_clamp)
          << "trial " << trial << " tick " << tick;
      ASSERT_EQ(out.force_n, device.last.force_n);
      if (exactNorm(device.last.force_n) > 0.0L) ++nonzero;
    }
    interventions += loop.counters().guard_interventions.load();
    loop.offerLink(nullptr);
    t += 1'000'000;
    (void)loop.tick(t, t);
  }
  // the runs did render forces (the property is not met by rendering nothing); about 1.6 % of
  // the commands are non-zero: most random settings engage late or fade, snapshots with an
  // unusable W diagonal render nothing by design, and the gate closes at every device fault
  // (one tick in 20) and reopens only after the fade-out, below the engage threshold
  EXPECT_GT(nonzero, commands / 100);
  ::testing::Test::RecordProperty("guard_interventions", static_cast<int>(interventions));
  link.reset();
  shared::Segment::remove(name);
}

// With valid settings the chain itself respects the clamp: the guard never has to step in.
TEST(HapticLoopProperty, WithValidSettingsTheGuardNeverIntervenes) {
  const std::string name = "tactus_sec_haptic_ok_" + std::to_string(::getpid());
  shared::Segment::remove(name);
  shared::Segment sim = shared::Segment::create(name, shared::SegmentCapacity::forContacts(2, false));
  shared::SnapshotPublisher publisher = sim.snapshotPublisher();
  auto link = std::make_unique<haptic::AttachedSegment>(shared::Segment::open(name));
  test::ScriptedDevice device;
  HapticSettings s;
  s.max_force_n = 3.0;
  s.slew_n_per_s = 1e6;
  s.fade_ms = 1.0;
  haptic::HapticLoop loop(device, s);
  loop.offerLink(link.get());
  std::int64_t t = 1'000'000'000;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> depth(-0.02, 0.002);
  for (int tick = 0; tick < 3000; ++tick) {
    if (tick % 3 == 0) {
      auto slot = publisher.slot();
      ASSERT_TRUE(slot.setSize(1, 1));
      auto& h = slot.header();
      h.seq = static_cast<std::uint64_t>(tick + 1);
      h.t_ns = t;
      h.flags = shared::kSnapshotValid | shared::kSnapshotSymmetricW;
      slot.rowOffset()[0] = 0;
      slot.rowOffset()[1] = 1;
      slot.mu()[0] = 0.0;
      slot.W()[0] = 1e-3;
      slot.deltaFree()[0] = tick < 30 ? 0.001 : depth(rng);
      slot.f()[0] = 0.0;
      slot.contactNormal()[0] = 0.6;
      slot.contactNormal()[1] = 0.0;
      slot.contactNormal()[2] = 0.8;
      publisher.publish();
    }
    t += 1'000'000;
    (void)loop.tick(t, t);
    ASSERT_LE(exactNorm(device.last.force_n), 3.0L);
  }
  EXPECT_GT(loop.counters().clamped.load(), 0u);   // the clamp was exercised
  EXPECT_EQ(loop.counters().guard_interventions.load(), 0u);
  loop.offerLink(nullptr);
  t += 1'000'000;
  (void)loop.tick(t, t);
  link.reset();
  shared::Segment::remove(name);
}

TEST(HapticSettingsValidate, RejectsEveryNonFiniteOrOutOfRangeValueNamingIt) {
  EXPECT_NO_THROW(HapticSettings{}.validate());
  struct Case {
    const char* name;
    void (*set)(HapticSettings&, double);
    std::vector<double> bad;
  };
  const std::vector<Case> cases = {
      {"force_scale", [](HapticSettings& s, double v) { s.force_scale = v; },
       {-1.0, kNaN, kInf, 1e9}},
      {"max_force_n", [](HapticSettings& s, double v) { s.max_force_n = v; },
       {-1.0, 0.0, kNaN, kInf, 1e6}},
      {"max_torque_nm", [](HapticSettings& s, double v) { s.max_torque_nm = v; },
       {-1.0, 0.0, kNaN, 100.0}},
      {"slew_n_per_s", [](HapticSettings& s, double v) { s.slew_n_per_s = v; },
       {-5.0, 0.0, kNaN, kInf}},
      {"engage_threshold_n", [](HapticSettings& s, double v) { s.engage_threshold_n = v; },
       {-1.0, kNaN, kInf}},
      {"watchdog_ms", [](HapticSettings& s, double v) { s.watchdog_ms = v; },
       {-1.0, 0.0, kNaN, kInf, 1e30}},
      {"fade_ms", [](HapticSettings& s, double v) { s.fade_ms = v; }, {-1.0, kNaN, kInf}},
      {"snapshot_blend_ms", [](HapticSettings& s, double v) { s.snapshot_blend_ms = v; },
       {-1.0, kNaN, kInf, 101.0}},
      {"tolerance", [](HapticSettings& s, double v) { s.tolerance = v; }, {0.0, -1.0, kNaN}},
      {"max_sweeps", [](HapticSettings& s, double v) { s.max_sweeps = static_cast<int>(v); },
       {0.0, -3.0, 1e6}},
      {"period_ns",
       [](HapticSettings& s, double v) { s.period_ns = static_cast<std::int64_t>(v); },
       {0.0, -1.0, 1e12}},
      // (the default period is 1 ms: a budget past 90 % of it leaves no room)
      {"solve_budget_ns",
       [](HapticSettings& s, double v) { s.solve_budget_ns = static_cast<std::int64_t>(v); },
       {-1.0, 1e12, 950'000.0, 1'000'000.0}},
  };
  for (const Case& c : cases) {
    for (double v : c.bad) {
      HapticSettings s;
      c.set(s, v);
      try {
        s.validate();
        ADD_FAILURE() << c.name << " = " << v << " accepted";
      } catch (const Error& e) {
        EXPECT_THAT(e.what(), HasSubstr(c.name)) << v;
        EXPECT_THAT(e.what(), HasSubstr("finite number in")) << v;
      }
      // the loop refuses them too (the library is used by tools and tests)
      test::ScriptedDevice device;
      EXPECT_THROW(haptic::HapticLoop(device, s), Error) << c.name << " = " << v;
    }
  }
}

// No deadline at all (budget 0) only with a bounded sweep count; the default budget is valid.
TEST(HapticSettingsValidation, ABudgetOfZeroNeedsFewSweeps) {
  HapticSettings s;
  EXPECT_NO_THROW(s.validate());
  s.solve_budget_ns = 0;
  s.max_sweeps = HapticSettingsLimits::kMaxSweepsWithoutBudget;
  EXPECT_NO_THROW(s.validate());
  s.max_sweeps = 100'000;
  try {
    s.validate();
    ADD_FAILURE() << "budget 0 with 100000 sweeps accepted";
  } catch (const Error& e) {
    EXPECT_THAT(e.what(), HasSubstr("no deadline"));
  }
  test::ScriptedDevice device;
  EXPECT_THROW(haptic::HapticLoop(device, s), Error);
}

TEST(HapticDeviceLimit, APluginsNonsenseMaxForceIsIgnoredAndASaneOneLowersTheClamp) {
  HapticSettings s;
  s.max_force_n = 8.0;
  for (double reported : {kNaN, kInf, -kInf, -1.0, 0.0}) {
    LimitedDevice device;
    device.max_force_n = reported;
    haptic::HapticLoop loop(device, s);
    EXPECT_EQ(loop.forceLimitN(), 8.0) << reported;
  }
  LimitedDevice device;
  device.max_force_n = 3.0;
  haptic::HapticLoop loop(device, s);
  EXPECT_EQ(loop.forceLimitN(), 3.0);
  device.max_force_n = 30.0;
  haptic::HapticLoop loop2(device, s);
  EXPECT_EQ(loop2.forceLimitN(), 8.0);
}

TEST(HapticDeviceOptions, BackendsRejectNonsenseWithAClearMessage) {
  struct Case {
    const char* backend;
    const char* option;
    const char* expect;
  };
  const std::vector<Case> cases = {
      {"simulated", "mass=-1", "option mass=-1 must be in"},
      {"simulated", "mass=1e-300", "option mass=1e-300 must be in"},
      {"simulated", "mass=nan", "not a finite number"},
      {"simulated", "max_force=-1", "option max_force=-1 must be in"},
      {"simulated", "max_force=1e308", "option max_force=1e308 must be in"},
      {"simulated", "stiffness=-3", "option stiffness=-3 must be in"},
      {"simulated", "damping=1e300", "option damping=1e300 must be in"},
      {"simulated", "period=0", "option period=0 must be in"},
      {"simulated", "amplitude=1e300", "option amplitude=1e300 must be in"},
      {"simulated", "origin=0,0,1e300", "option origin component"},
      {"replay", "speed=1e308", "option speed=1e308 must be in"},
      {"replay", "speed=-1", "option speed=-1 must be in"},
      {"null", "pose=0,1e300,0", "option pose component"},
      {"bridge", "port=70000", "option port=70000 must be in"},
      {"bridge", "timeout_ms=0", "option timeout_ms=0 must be in"},
      {"bridge", "max_force=1e308", "option max_force=1e308 must be in"},
      {"bridge", "bind=10.1.2.3", "allow_remote=1"},
  };
  for (const Case& c : cases) {
    device::DeviceConfig config;
    device::addDeviceOption(config, c.option);
    try {
      (void)device::loadDevice(c.backend, config);
      ADD_FAILURE() << c.backend << " accepted " << c.option;
    } catch (const DeviceError& e) {
      EXPECT_THAT(e.what(), HasSubstr(c.expect)) << c.backend << " " << c.option;
    }
  }
  // a stiff spring on a light hand would make the integration blow up
  device::DeviceConfig stiff;
  device::addDeviceOption(stiff, "mass=0.001");
  device::addDeviceOption(stiff, "stiffness=1e6");
  EXPECT_THROW((void)device::loadDevice("simulated", stiff), DeviceError);
  // defaults and ordinary values still load
  EXPECT_NO_THROW((void)device::loadDevice("simulated", {}));
  device::DeviceConfig ok;
  device::addDeviceOption(ok, "mass=0.5");
  device::addDeviceOption(ok, "max_force=4");
  EXPECT_EQ(device::loadDevice("simulated", ok)->info().max_force_n, 4.0);
}

// Runs haptic_server with `args`; returns its exit status and output (bounded: timeout 20 s,
// and --duration in case it starts).
int runHapticServer(const std::string& args, std::string* output) {
  const std::string cmd = "timeout 20 " + std::string(TACTUS_BINARY_DIR) +
                          "/haptic_server/haptic_server --segment tactus_sec_cli_" +
                          std::to_string(::getpid()) + " --duration 0.3 " + args +
                          " 2>&1";
  FILE* p = ::popen(cmd.c_str(), "r");
  if (p == nullptr) return -1;
  char buf[512];
  while (std::fgets(buf, sizeof buf, p) != nullptr) *output += buf;
  const int status = ::pclose(p);
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

TEST(HapticServerCli, ForceRateAndWatchdogOptionsRejectNonsense) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"--slew -5", "--slew"},          {"--slew nan", "--slew"},
      {"--max-force nan", "--max-force"}, {"--max-force -1", "--max-force"},
      {"--max-force inf", "--max-force"}, {"--force-scale -1", "--force-scale"},
      {"--force-scale nan", "--force-scale"}, {"--watchdog-ms nan", "--watchdog-ms"},
      {"--watchdog-ms 0", "--watchdog-ms"}, {"--fade-ms -1", "--fade-ms"},
      {"--snapshot-blend-ms nan", "--snapshot-blend-ms"},
      {"--snapshot-blend-ms 1e3", "--snapshot-blend-ms"},
      {"--rate nan", "--rate"},         {"--rate 1e9", "--rate"},
      {"--tolerance nan", "--tolerance"}, {"--max-sweeps 0", "--max-sweeps"},
      {"--device-option mass=-1 --device simulated", "mass=-1"},
      {"--workspace-scale 0", "--workspace-scale"}, {"--workspace-scale nan", "--workspace-scale"},
      {"--workspace-rotation 1,0,0,0.5", "unit quaternion"},
      {"--workspace-offset 0,nan,0", "offset[1]"}, {"--workspace-offset 0,1e9,0", "offset[1]"},
      {"--clutch-button 40", "--clutch-button"},
      {"--device bridge --device-option bind=0.0.0.0", "allow_remote=1"},
  };
  for (const auto& [args, expect] : cases) {
    std::string out;
    const int rc = runHapticServer(args + (args.find("--device ") == std::string::npos
                                               ? " --device null"
                                               : ""),
                                   &out);
    EXPECT_NE(rc, 0) << args << "\n" << out;
    EXPECT_NE(rc, 124) << args << " ran until the timeout";
    EXPECT_THAT(out, HasSubstr(expect)) << args;
  }
  std::string out;
  EXPECT_EQ(runHapticServer("--device null --max-force 4 --slew 500 --force-scale 0.5", &out), 0)
      << out;
  EXPECT_EQ(runHapticServer("--device null --workspace-scale 2 --workspace-offset 0,0,0.1 "
                            "--workspace-rotation 0.7071067811865476,0,0,0.7071067811865476 "
                            "--clutch-button 0",
                            &out),
            0)
      << out;
  EXPECT_THAT(out, HasSubstr("workspace: scale 2"));
}

// The simulation publishes W exactly symmetric for a real frictional scene, says so with
// kSnapshotSymmetricW, and fills the solver fields (sweeps, error, converged) of its own solve.
TEST(HapticSnapshot, ARealSceneIsPublishedWithAnExactlySymmetricWAndItsSolverFields) {
  const sim::SceneSpec spec =
      sim::loadScene(std::string(TACTUS_SOURCE_DIR) + "/tests/hard_cases/scenes/drag_mu2.yaml");
  sim::Simulation simulation(spec);
  const std::string name = "tactus_sec_snapshot_" + std::to_string(::getpid());
  shared::Segment::remove(name);
  shared::Segment segment = shared::Segment::create(
      name, shared::SegmentCapacity::forContacts(spec.solver.max_contacts, true));
  shared::SnapshotPublisher publisher = segment.snapshotPublisher();
  int with_contacts = 0;
  int max_rows = 0;
  for (int step = 0; step < 60; ++step) {
    simulation.setDeviceTarget(simulation.scriptedTarget(simulation.time()));
    const sim::StepReport report = simulation.step();
    auto slot = publisher.slot();
    ASSERT_TRUE(sim::writeSnapshot(simulation, 1.0, static_cast<std::uint64_t>(step + 1), 1, 0,
                                   slot));
    const shared::SnapshotView view = slot.view();
    const auto& h = view.header();
    if (h.rows == 0) continue;
    ++with_contacts;
    max_rows = std::max(max_rows, h.rows);
    for (int i = 0; i < h.rows; ++i) {
      for (int j = 0; j < h.rows; ++j) {
        ASSERT_EQ(view.W()[i * view.ld() + j], view.W()[j * view.ld() + i])
            << "step " << step << " W(" << i << ", " << j << ")";
      }
    }
    EXPECT_NE(h.flags & shared::kSnapshotSymmetricW, 0u) << "step " << step;
    EXPECT_EQ(h.solver_sweeps, report.nsgs.sweeps);
    EXPECT_GT(h.solver_sweeps, 0);
    EXPECT_EQ(h.solver_error, report.nsgs.error);
    EXPECT_EQ((h.flags & shared::kSnapshotConverged) != 0,
              report.nsgs.status == shared::NsgsStatus::kConverged);
  }
  EXPECT_GT(with_contacts, 10);
  EXPECT_GT(max_rows, 3);   // several frictional contacts: off-diagonal blocks were compared
  shared::Segment::remove(name);
}

// A problem larger than the segment's capacity is not published as an empty problem still
// flagged valid (the haptic side would render "no contact" from it): it is flagged not valid,
// which the haptic loop treats as stale (it fades the held force out).
TEST(HapticSnapshot, AProblemBeyondTheCapacityIsPublishedNotValid) {
  const sim::SceneSpec spec =
      sim::loadScene(std::string(TACTUS_SOURCE_DIR) + "/tests/hard_cases/scenes/drag_mu2.yaml");
  sim::Simulation simulation(spec);
  const std::string name = "tactus_sec_overflow_" + std::to_string(::getpid());
  shared::Segment::remove(name);
  shared::Segment segment =
      shared::Segment::create(name, shared::SegmentCapacity::forContacts(1, true));
  shared::SnapshotPublisher publisher = segment.snapshotPublisher();
  int overflowed = 0;
  for (int step = 0; step < 60; ++step) {
    simulation.setDeviceTarget(simulation.scriptedTarget(simulation.time()));
    simulation.step();
    auto slot = publisher.slot();
    const bool fits = sim::writeSnapshot(simulation, 1.0, static_cast<std::uint64_t>(step + 1), 1,
                                         0, slot);
    const auto& h = slot.view().header();
    if (fits) {
      EXPECT_NE(h.flags & shared::kSnapshotValid, 0u) << "step " << step;
      continue;
    }
    ++overflowed;
    EXPECT_EQ(h.rows, 0);
    EXPECT_EQ(h.contacts, 0);
    EXPECT_EQ(h.flags & shared::kSnapshotValid, 0u) << "step " << step;
  }
  EXPECT_GT(overflowed, 10) << "the scene should need more than one contact";
  shared::Segment::remove(name);
}

}  // namespace
}  // namespace tactus

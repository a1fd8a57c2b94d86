// Bundled backends: the simulated hand's dynamics (the commanded force changes its motion), the
// scripted press-and-release, trajectory CSV parsing and interpolation, replay, the
// record -> replay round trip, and zero allocations in read()/write() of every built-in.

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <thread>

#include "../../support/alloc_counter.h"
#include "tactus/device/backends.h"
#include "tactus/device/device.h"
#include "tactus/shared/clock.h"

namespace tactus::device {
namespace {

using ::testing::HasSubstr;
constexpr std::int64_t kMs = 1'000'000;

std::string tempPath(const char* tag) {
  return ::testing::TempDir() + "tactus_" + std::to_string(::getpid()) + "_" + tag + ".csv";
}

// Runs a simulated device on a 1 ms virtual clock for `ms` ms with a constant command force.
DeviceState runSimulated(const DeviceConfig& cfg, std::array<double, 3> force, bool enable,
                         int ms) {
  SimulatedDevice dev(cfg);
  dev.openAt(0);
  dev.enableForces(enable);
  DeviceCommand cmd;
  cmd.force_n = force;
  DeviceState s;
  for (int i = 1; i <= ms; ++i) {
    EXPECT_EQ(dev.write(cmd), IoStatus::kOk);
    EXPECT_EQ(dev.readAt(i * kMs, &s), IoStatus::kOk);
  }
  return s;
}

TEST(SimulatedDevice, CommandedForceChangesTheMotion) {
  // a still set point (amplitude 0) isolates the force's effect
  const DeviceConfig cfg = {{"amplitude", "0"}, {"stiffness", "300"}, {"mass", "0.3"}};
  const DeviceState free_hand = runSimulated(cfg, {0.0, 0.0, 0.0}, true, 800);
  const DeviceState pushed = runSimulated(cfg, {0.0, 0.0, 3.0}, true, 800);
  const DeviceState disabled = runSimulated(cfg, {0.0, 0.0, 3.0}, false, 800);
  EXPECT_NEAR(free_hand.pos_m[2], 0.0, 1e-12);
  // static equilibrium of the spring against the force: F / k = 10 mm
  EXPECT_NEAR(pushed.pos_m[2], 3.0 / 300.0, 0.05 * 3.0 / 300.0);
  EXPECT_NEAR(pushed.vel_mps[2], 0.0, 1e-3);
  EXPECT_NEAR(disabled.pos_m[2], 0.0, 1e-12);  // forces off: the command is not rendered
  // a stiffer hand yields less
  DeviceConfig stiff = cfg;
  stiff["stiffness"] = "600";
  EXPECT_NEAR(runSimulated(stiff, {0.0, 0.0, 3.0}, true, 800).pos_m[2], 3.0 / 600.0, 5e-4);
}

TEST(SimulatedDevice, ForceMidMotionDeflectsTheTrajectory) {
  SimulatedDevice a({{"amplitude", "0.02"}, {"period", "2"}});
  SimulatedDevice b({{"amplitude", "0.02"}, {"period", "2"}});
  a.openAt(0);
  b.openAt(0);
  b.enableForces(true);
  DeviceCommand up;
  up.force_n = {0.0, 0.0, 2.0};
  DeviceState sa, sb;
  double min_a = 0.0;
  for (int i = 1; i <= 1000; ++i) {
    // the "tissue" pushes back only while the hand is below z = -5 mm
    DeviceCommand cmd = up;
    if (i > 1 && sb.pos_m[2] > -0.005) cmd.force_n[2] = 0.0;
    EXPECT_EQ(b.write(cmd), IoStatus::kOk);
    ASSERT_EQ(a.readAt(i * kMs, &sa), IoStatus::kOk);
    ASSERT_EQ(b.readAt(i * kMs, &sb), IoStatus::kOk);
    min_a = std::min(min_a, sa.pos_m[2]);
  }
  // unopposed the hand presses nearly the whole amplitude at half period; opposed it stops short
  EXPECT_LT(min_a, -0.017);
  // at half period the opposed hand is short of the free one by about F / k = 6.7 mm
  EXPECT_GT(sb.pos_m[2], sa.pos_m[2] + 0.004);
  EXPECT_LT(sb.pos_m[2], -0.005);  // but still pressed in
}

TEST(SimulatedDevice, RealClockReadFollowsTheSetPoint) {
  auto dev = loadDevice("simulated", {{"amplitude", "0.01"}, {"period", "0.2"}});
  DeviceState s;
  EXPECT_EQ(dev->read(&s), IoStatus::kNoData);  // not open
  dev->open();
  std::int64_t last = 0;
  double min_z = 0.0;
  for (int i = 0; i < 50; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(2));
    ASSERT_EQ(dev->read(&s), IoStatus::kOk);
    EXPECT_GT(s.t_ns, last);
    last = s.t_ns;
    min_z = std::min(min_z, s.pos_m[2]);
  }
  EXPECT_LT(min_z, -0.001);  // it moved down along the default axis
  DeviceCommand bad;
  bad.force_n[1] = INFINITY;
  EXPECT_EQ(dev->write(bad), IoStatus::kFault);
}

TEST(Trajectory, ParsesInterpolatesAndReportsErrorsWithLineAndColumn) {
  const Trajectory t = Trajectory::parseCsv(
      "# a comment\n"
      "t_s, x, y, z, qw, qx, qy, qz, gripper\n"
      "0.0,0,0,0,1,0,0,0,0\n"
      "\n"
      "1.0,0.1,0,-0.02,0,0,0,2,0.5\n",
      "inline");
  ASSERT_EQ(t.points().size(), 2u);
  EXPECT_DOUBLE_EQ(t.points()[1].quat_wxyz[3], 1.0);  // normalised
  DeviceState s;
  t.sample(0.25, &s);
  EXPECT_NEAR(s.pos_m[0], 0.025, 1e-12);
  EXPECT_NEAR(s.pos_m[2], -0.005, 1e-12);
  EXPECT_NEAR(s.vel_mps[0], 0.1, 1e-12);
  EXPECT_NEAR(s.gripper_rad, 0.125, 1e-12);
  const double qn = std::sqrt(s.quat_wxyz[0] * s.quat_wxyz[0] + s.quat_wxyz[3] * s.quat_wxyz[3]);
  EXPECT_NEAR(qn, 1.0, 1e-12);
  EXPECT_GT(s.angvel_radps[2], 0.0);  // rotating about +z
  t.sample(5.0, &s);                   // clamped to the end
  EXPECT_NEAR(s.pos_m[0], 0.1, 1e-12);
  EXPECT_EQ(s.vel_mps[0], 0.0);

  auto error = [](const std::string& text) {
    try {
      Trajectory::parseCsv(text, "traj.csv");
    } catch (const DeviceError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_THAT(error("t,x,y,z\n"), HasSubstr("traj.csv:1: expected the header line"));
  EXPECT_THAT(error(std::string(Trajectory::kCsvHeader) + "\n0,0,0,abc,1,0,0,0,0\n"),
              HasSubstr("traj.csv:2:7: column z: 'abc' is not a finite number"));
  EXPECT_THAT(error(std::string(Trajectory::kCsvHeader) + "\n0,0,0,0,1,0,0,0\n"),
              HasSubstr("traj.csv:2: expected 9 comma-separated values"));
  EXPECT_THAT(error(std::string(Trajectory::kCsvHeader) + "\n1,0,0,0,1,0,0,0,0\n"
                    "0.5,0,0,0,1,0,0,0,0\n"),
              HasSubstr("traj.csv:3:1: t_s"));
  EXPECT_THAT(error(std::string(Trajectory::kCsvHeader) + "\n0,0,0,0,0,0,0,0,0\n"),
              HasSubstr("quaternion qw,qx,qy,qz is zero"));
  EXPECT_THAT(error(std::string(Trajectory::kCsvHeader) + "\n"), HasSubstr("no rows"));
}

TEST(ReplayDevice, PlaysHoldsAndLoops) {
  const std::string path = tempPath("replay");
  {
    std::ofstream f(path);
    f << Trajectory::kCsvHeader << "\n0,0,0,0,1,0,0,0,0\n0.5,0.05,0,0,1,0,0,0,0.2\n";
  }
  ReplayDevice once({{"file", path}});
  once.openAt(1000);
  DeviceState s;
  ASSERT_EQ(once.readAt(1000 + 250 * kMs, &s), IoStatus::kOk);
  EXPECT_NEAR(s.pos_m[0], 0.025, 1e-12);
  EXPECT_NEAR(s.vel_mps[0], 0.1, 1e-12);
  EXPECT_EQ(s.t_ns, 1000 + 250 * kMs);
  ASSERT_EQ(once.readAt(1000 + 900 * kMs, &s), IoStatus::kOk);
  EXPECT_NEAR(s.pos_m[0], 0.05, 1e-12);  // held at the end
  EXPECT_EQ(s.vel_mps[0], 0.0);
  ReplayDevice looped({{"file", path}, {"loop", "true"}, {"speed", "2"}});
  looped.openAt(0);
  ASSERT_EQ(looped.readAt(300 * kMs, &s), IoStatus::kOk);  // 0.6 s of trajectory -> 0.1 s
  EXPECT_NEAR(s.pos_m[0], 0.01, 1e-9);
  std::remove(path.c_str());
}

TEST(RecordReplay, RoundTripReproducesThePoses) {
  const std::string path = tempPath("record");
  std::vector<DeviceState> seen;
  {
    auto dev = loadDevice("simulated", {{"record", path}, {"amplitude", "0.03"},
                                        {"period", "0.1"}});
    ASSERT_NE(dynamic_cast<RecordingDevice*>(dev.get()), nullptr);
    dev->open();
    DeviceState s;
    for (int i = 0; i < 60; ++i) {
      std::this_thread::sleep_for(std::chrono::microseconds(700));
      ASSERT_EQ(dev->read(&s), IoStatus::kOk);
      seen.push_back(s);
    }
    dev->close();
    auto* rec = dynamic_cast<RecordingDevice*>(dev.get());
    EXPECT_EQ(rec->recorded(), seen.size());
    EXPECT_EQ(rec->dropped(), 0u);
  }
  ReplayDevice replay({{"file", path}});
  ASSERT_EQ(replay.trajectory().points().size(), seen.size());
  replay.openAt(seen.front().t_ns);
  double worst = 0.0;
  for (const DeviceState& s : seen) {
    DeviceState r;
    ASSERT_EQ(replay.readAt(s.t_ns, &r), IoStatus::kOk);
    for (std::size_t i = 0; i < 3; ++i) worst = std::max(worst, std::abs(r.pos_m[i] - s.pos_m[i]));
    EXPECT_NEAR(r.quat_wxyz[0], s.quat_wxyz[0], 1e-9);
  }
  EXPECT_LT(worst, 1e-9);
  // the motion was real (not a constant pose)
  double span = 0.0;
  for (const DeviceState& s : seen) span = std::max(span, std::abs(s.pos_m[2]));
  EXPECT_GT(span, 1e-3);
  std::remove(path.c_str());
}

TEST(RecordingDevice, UnwritableFileIsAnError) {
  auto dev = loadDevice("null", {{"record", "/nonexistent/dir/out.csv"}});
  try {
    dev->open();
    FAIL() << "no error";
  } catch (const DeviceError& e) {
    EXPECT_THAT(e.what(), HasSubstr("cannot record to '/nonexistent/dir/out.csv'"));
  }
}

TEST(Backends, ReadAndWriteNeverAllocate) {
  const std::string traj = tempPath("alloc_traj");
  {
    std::ofstream f(traj);
    f << Trajectory::kCsvHeader << "\n0,0,0,0,1,0,0,0,0\n0.01,0.01,0,0,1,0,0,0,0\n"
      << "0.02,0.0,0.01,0,1,0,0,0,0\n";
  }
  const std::string rec = tempPath("alloc_rec");
  const std::string plugin =
      std::string(TACTUS_BINARY_DIR) + "/device/examples/spring_plugin/libtactus_spring_device.so";
  struct Case {
    const char* name;
    std::string backend;
    DeviceConfig cfg;
  };
  const std::vector<Case> cases = {
      {"null", "null", {}},
      {"null pose", "null", {{"pose", "0,0,1"}}},
      {"simulated", "simulated", {}},
      {"simulated trajectory", "simulated", {{"trajectory", traj}}},
      {"replay", "replay", {{"file", traj}, {"loop", "true"}}},
      {"recorder", "simulated", {{"record", rec}}},
      {"plugin", plugin, {}},
  };
  for (const Case& c : cases) {
    auto dev = loadDevice(c.backend, c.cfg);
    dev->open();
    dev->enableForces(true);
    DeviceState s;
    DeviceCommand cmd;
    cmd.force_n = {0.1, 0.2, 0.3};
    test::AllocScope scope;
    for (int i = 0; i < 2000; ++i) {
      (void)dev->read(&s);
      (void)dev->write(cmd);
    }
    EXPECT_EQ(scope.allocations(), 0) << c.name;
    dev->close();
  }
  std::remove(traj.c_str());
  std::remove(rec.c_str());
}

}  // namespace
}  // namespace tactus::device

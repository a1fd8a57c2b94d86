// Both daemons as real processes on a small scene: the simulated hand presses a soft cube through
// a probe. Asserts that the haptic side renders forces that rise with penetration, that the
// simulation follows the device, that killing the simulation fades the force to zero while the
// haptic loop keeps ticking, that a restarted simulation brings forces back, and that killing
// the haptic side leaves the simulation running.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tactus/shared/clock.h"
#include "tactus/shared/segment.h"

namespace {

using namespace std::chrono_literals;
using tactus::shared::Segment;
using tactus::shared::StatsRecord;
using tactus::shared::StatsRingReader;

const std::string kBin = TACTUS_BINARY_DIR;
const std::string kData = TACTUS_TEST_DATA_DIR;

pid_t spawn(const std::vector<std::string>& args, const std::string& log) {
  const pid_t pid = fork();
  if (pid == 0) {
    std::FILE* f = std::freopen(log.c_str(), "a", stdout);
    (void)f;
    dup2(fileno(stdout), fileno(stderr));
    std::vector<char*> argv;
    for (const auto& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    execv(argv[0], argv.data());
    _exit(127);
  }
  return pid;
}

bool alive(pid_t pid) { return waitpid(pid, nullptr, WNOHANG) == 0; }

void stop(pid_t pid, int sig = SIGTERM) {
  if (pid <= 0) return;
  kill(pid, sig);
  for (int i = 0; i < 100 && alive(pid); ++i) std::this_thread::sleep_for(50ms);
  if (alive(pid)) kill(pid, SIGKILL);
  waitpid(pid, nullptr, 0);
}

std::string slurp(const std::string& path) {
  std::ifstream in(path);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

// Tool z positions from the simulation's status lines.
std::vector<double> toolHeights(const std::string& log) {
  std::vector<double> z;
  std::istringstream in(log);
  for (std::string line; std::getline(in, line);) {
    const auto at = line.find("tool=(");
    if (at == std::string::npos) continue;
    double x, y, zz;
    if (std::sscanf(line.c_str() + at, "tool=(%lf, %lf, %lf)", &x, &y, &zz) == 3) z.push_back(zz);
  }
  return z;
}

class TwoProcessTest : public ::testing::Test {
 protected:
  void SetUp() override {
    name_ = "tactus_two_process_" + std::to_string(::getpid());
    dir_ = std::string(::testing::TempDir()) + "/" + name_;
    std::system(("mkdir -p " + dir_).c_str());
    // the hand hovers 2 mm above the cube for 1 s, then presses 12 mm deep over 3 s, holds
    // until 7 s, then lifts off and presses again every 3 s (after an interruption the force
    // re-engages only once the hand has left the tissue)
    std::ofstream csv(dir_ + "/press.csv");
    csv << "t_s,x,y,z,qw,qx,qy,qz,gripper\n";
    csv << "0,0.004,0.003,0.043,1,0,0,0,0\n1.0,0.004,0.003,0.043,1,0,0,0,0\n";
    csv << "4.0,0.004,0.003,0.031,1,0,0,0,0\n7.0,0.004,0.003,0.031,1,0,0,0,0\n";
    for (int k = 0; k < 17; ++k) {
      const double t = 7.0 + 3.0 * k;
      csv << t + 0.5 << ",0.004,0.003,0.043,1,0,0,0,0\n"
          << t + 1.0 << ",0.004,0.003,0.043,1,0,0,0,0\n"
          << t + 2.0 << ",0.004,0.003,0.031,1,0,0,0,0\n"
          << t + 3.0 << ",0.004,0.003,0.031,1,0,0,0,0\n";
    }
  }
  void TearDown() override {
    stop(haptic_);
    stop(sim_);
    Segment::remove(name_);
  }
  pid_t startSim() {
    return spawn({kBin + "/sim_server/sim_server", kData + "/scenes/press_cube.yaml", "--segment",
                  name_, "--status"},
                 dir_ + "/sim.log");
  }
  pid_t startHaptic() {
    return spawn({kBin + "/haptic_server/haptic_server", "--segment", name_, "--device",
                  "simulated", "--device-option", "trajectory=" + dir_ + "/press.csv",
                  "--device-option", "stiffness=2000", "--priority", "0", "--status"},
                 dir_ + "/haptic.log");
  }
  // Opens the current segment read-only (waits up to timeout).
  std::optional<Segment> attach(std::chrono::milliseconds timeout = 15000ms) {
    const auto end = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < end) {
      auto r = Segment::tryOpen(name_, tactus::shared::Access::kReadOnly);
      if (r.ok()) return std::move(*r.segment);
      std::this_thread::sleep_for(50ms);
    }
    return std::nullopt;
  }
  // Newest records over `window` (polls the ring).
  std::vector<StatsRecord> collect(StatsRingReader& reader, std::chrono::milliseconds window) {
    std::vector<StatsRecord> all;
    std::vector<StatsRecord> buf(4096);
    const auto end = std::chrono::steady_clock::now() + window;
    while (std::chrono::steady_clock::now() < end) {
      const std::size_t n = reader.poll(buf.data(), buf.size());
      all.insert(all.end(), buf.begin(), buf.begin() + static_cast<std::ptrdiff_t>(n));
      std::this_thread::sleep_for(20ms);
    }
    return all;
  }
  static double meanForce(const std::vector<StatsRecord>& r) {
    double s = 0.0;
    for (const auto& x : r) s += x.force_norm_n;
    return r.empty() ? 0.0 : s / static_cast<double>(r.size());
  }

  std::string name_, dir_;
  pid_t sim_ = -1, haptic_ = -1;
};

TEST_F(TwoProcessTest, ForcesFollowPenetrationAndSurviveSimulationRestarts) {
  haptic_ = startHaptic();   // the haptic side may start first
  std::this_thread::sleep_for(300ms);
  sim_ = startSim();
  std::optional<Segment> seg = attach();
  ASSERT_TRUE(seg) << slurp(dir_ + "/sim.log");
  StatsRingReader reader = seg->statsReader(StatsRingReader::Start::kNewest);

  // pressing phase: the force rises with penetration
  std::vector<double> force_windows;
  for (int w = 0; w < 8; ++w) {
    const auto recs = collect(reader, 500ms);
    ASSERT_FALSE(recs.empty()) << "no haptic ticks\n" << slurp(dir_ + "/haptic.log");
    force_windows.push_back(meanForce(recs));
    for (const auto& r : recs) {
      EXPECT_TRUE(std::isfinite(r.force_norm_n));
      EXPECT_LE(r.force_norm_n, 8.0 + 1e-9);
    }
  }
  double peak = 0.0;
  for (double f : force_windows) peak = std::max(peak, f);
  EXPECT_GT(peak, 0.2) << "no contact force rendered\n" << slurp(dir_ + "/haptic.log");
  // while the hand goes deeper (about 1.2 s .. 4 s after it started) the force keeps growing
  int rises = 0;
  for (std::size_t i = 1; i < force_windows.size(); ++i) {
    if (force_windows[i] > force_windows[i - 1] + 1e-3) ++rises;
  }
  EXPECT_GE(rises, 3) << "force windows did not rise with penetration";

  // the simulation follows the device: its instrument moved down
  const std::vector<double> z = toolHeights(slurp(dir_ + "/sim.log"));
  ASSERT_GE(z.size(), 2u);
  EXPECT_LT(z.back(), 0.045 - 0.003);   // the scene starts the instrument at z = 45 mm
  EXPECT_NE(slurp(dir_ + "/sim.log").find("device samples arriving"), std::string::npos);

  // kill the simulation: the haptic loop keeps ticking and the force fades to zero
  const double before = meanForce(collect(reader, 200ms));
  EXPECT_GT(before, 0.2);
  kill(sim_, SIGKILL);
  waitpid(sim_, nullptr, 0);
  sim_ = -1;
  const std::int64_t killed_ns = tactus::shared::monotonicNs();
  std::this_thread::sleep_for(400ms);
  std::vector<StatsRecord> after;
  for (const auto& r : collect(reader, 500ms)) {
    // ticks later than watchdog (50 ms) + fade (100 ms) + margin after the kill
    if (r.woken_ns > killed_ns + 250'000'000) after.push_back(r);
  }
  ASSERT_GT(after.size(), 300u) << "the haptic loop stopped ticking";
  for (const auto& r : after) {
    EXPECT_DOUBLE_EQ(r.force_norm_n, 0.0);
    EXPECT_TRUE(r.flags & tactus::shared::kStatsSnapshotStale);
  }
  EXPECT_TRUE(alive(haptic_));

  // restart it: the haptic side re-attaches to the new segment and forces come back once the
  // hand has left the tissue and pressed again
  sim_ = startSim();
  std::this_thread::sleep_for(500ms);
  seg.reset();
  std::optional<Segment> seg2;
  for (int i = 0; i < 100 && !seg2; ++i) {
    auto s = attach(2000ms);
    if (s && s->generation() > 0 && s->creatorAlive()) seg2 = std::move(s);
  }
  ASSERT_TRUE(seg2);
  StatsRingReader reader2 = seg2->statsReader(StatsRingReader::Start::kNewest);
  double resumed = 0.0;
  for (int i = 0; i < 16 && resumed < 0.2; ++i) resumed = meanForce(collect(reader2, 500ms));
  EXPECT_GT(resumed, 0.2) << slurp(dir_ + "/haptic.log");

  // kill the haptic side: the simulation keeps running on its own
  kill(haptic_, SIGKILL);
  waitpid(haptic_, nullptr, 0);
  haptic_ = -1;
  std::this_thread::sleep_for(1500ms);
  EXPECT_TRUE(alive(sim_));
  const std::string log = slurp(dir_ + "/sim.log");
  EXPECT_NE(log.find("no fresh device sample"), std::string::npos);
  const auto z2 = toolHeights(log);
  EXPECT_GT(z2.size(), z.size());
}

}  // namespace

namespace {

TEST_F(TwoProcessTest, SignalsStopCleanlyAndASecondSimulationIsRefused) {
  sim_ = startSim();
  std::optional<Segment> seg = attach();
  ASSERT_TRUE(seg);
  // a second simulation on the same segment name is refused with a clear message
  const pid_t second = spawn({kBin + "/sim_server/sim_server", kData + "/scenes/press_cube.yaml",
                              "--segment", name_},
                             dir_ + "/second.log");
  int status = 0;
  waitpid(second, &status, 0);
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) != 0);
  EXPECT_NE(slurp(dir_ + "/second.log").find("in use by a live simulation"), std::string::npos)
      << slurp(dir_ + "/second.log");
  EXPECT_TRUE(alive(sim_));
  // SIGTERM: the owner removes its segment and exits 0
  seg.reset();
  kill(sim_, SIGTERM);
  waitpid(sim_, &status, 0);
  sim_ = -1;
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << slurp(dir_ + "/sim.log");
  EXPECT_FALSE(Segment::exists(name_));
  // the haptic side stops on SIGINT with exit code 0 too
  haptic_ = startHaptic();
  std::this_thread::sleep_for(500ms);
  kill(haptic_, SIGINT);
  waitpid(haptic_, &status, 0);
  haptic_ = -1;
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0) << slurp(dir_ + "/haptic.log");
}

}  // namespace

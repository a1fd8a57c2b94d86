// The fault suite for the hand (docs/reliability.md): every fault path driven through the real
// haptic_server process, whose device records every command it receives (the recorder wrapper,
// device option record_commands=FILE), and the recorded force series checked against the written
// rules of tests/support/force_rules.h (finite; within the clamp; no change beyond the slew bound
// per nominal period; a lost model fades the held force over the fade, checked at 25/50/75 %;
// zero after it; re-engaged only below the engage threshold).
//
// The hand is the fault plugin (device/test_plugins/fault_plugin.cpp) or, over the network
// bridge, tactus-bridge-client: it hovers, presses into the tissue, holds, lifts off and presses
// again, so each case also shows the force coming back once the hand has left the tissue. The
// simulation is sim_server on tests/data/scenes/press_cube.yaml, or this test itself publishing
// a one-contact problem (a plane) when the snapshot must be corrupt, future-stamped or larger
// than the segment. No timing thresholds: the rules count commands, and the faults are placed
// in the hold with wide margins. No fixed times either: the plugin's hand waits at two gates,
// just before the fault and after the second press, until the test has seen the press rendered
// (haptic_server's tick records in the segment), so a loaded machine only makes the run longer.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "daemon_process.h"
#include "tactus/device/bridge_protocol.h"
#include "support/bridge_sender.h"
#include "support/force_rules.h"
#include "support/one_contact_problem.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/segment.h"

namespace tactus {
namespace {

using namespace std::chrono_literals;
using test::ChildProcess;
using test::checkForceRules;
using test::describe;
using test::ForceRules;
using test::ModelLoss;
using test::RecordedCommand;

const std::string kBin = TACTUS_BINARY_DIR;
const std::string kData = TACTUS_TEST_DATA_DIR;
const std::string kFaultPlugin = kBin + "/device/test_plugins/libfault_plugin.so";

// The hand's path (ms after the device opened: z in m, x = 4 mm, y = 3 mm): hover above the
// cube, press 5 mm beyond the touch (the probe touches at z = 41 mm), hold, lift well clear,
// press again and hold. Faults go into the first hold (kFaultAtMs), the lift shows recovery.
constexpr double kPressEndMs = 600.0;
constexpr double kFaultAtMs = 1000.0;
constexpr double kLiftMs = 1500.0;
constexpr double kRepressEndMs = 2200.0;
constexpr double kRunMs = 2700.0;
// The plugin hand's gates (path times): it waits there, holding its pose, until the test has
// seen the press rendered (before the fault) and, where the force must come back, the second
// press (before the recovery is checked).
constexpr double kPressedGateMs = kFaultAtMs - 200.0;
constexpr double kRepressedGateMs = kRepressEndMs + 200.0;
const char* const kPath =
    "0:0.004,0.003,0.046;300:0.004,0.003,0.046;600:0.004,0.003,0.036;1500:0.004,0.003,0.036;"
    "1700:0.004,0.003,0.055;1900:0.004,0.003,0.055;2200:0.004,0.003,0.036";

// The same path as a replay CSV (the bridge client's hand follows it).
std::string pathCsv() {
  return "t_s,x,y,z,qw,qx,qy,qz,gripper\n"
         "0,0.004,0.003,0.046,1,0,0,0,0\n0.3,0.004,0.003,0.046,1,0,0,0,0\n"
         "0.6,0.004,0.003,0.036,1,0,0,0,0\n1.5,0.004,0.003,0.036,1,0,0,0,0\n"
         "1.7,0.004,0.003,0.055,1,0,0,0,0\n1.9,0.004,0.003,0.055,1,0,0,0,0\n"
         "2.2,0.004,0.003,0.036,1,0,0,0,0\n60,0.004,0.003,0.036,1,0,0,0,0\n";
}

// A plane at z = 40 mm below the hand for the test's own snapshots: W = 1 mm/N, so the hand
// 1.5 mm into it feels 1.5 N (the path's 36 mm is 4 mm in: 4 N).
constexpr double kPlaneZ = 0.040;

enum class Corruption { kNone, kIllPosed, kFuture, kOverflow };

// The simulation's side played by the test: every 10 ms the one-contact problem at the device's
// newest pose (x_h* = that pose, J moves the gap with z), possibly corrupt.
class PlaneSimulation {
 public:
  explicit PlaneSimulation(const std::string& name)
      : segment_(shared::Segment::create(name, shared::SegmentCapacity::forContacts(8, true))),
        publisher_(segment_.snapshotPublisher()),
        samples_(segment_.deviceReader()) {
    thread_ = std::thread([this] { run(); });
  }
  ~PlaneSimulation() {
    stop_.store(true);
    thread_.join();
  }
  void corrupt(Corruption c) { corruption_.store(c); }

 private:
  void run() {
    std::uint64_t seq = 0;
    while (!stop_.load()) {
      const shared::DeviceSample& s = samples_.latest();
      const bool pose = (s.status & shared::kDevicePoseValid) != 0;
      const double z = pose ? s.pos_m[2] : 0.046;
      auto slot = publisher_.slot();
      test::writeOneContactProblem(slot, ++seq, shared::monotonicNs(), z - kPlaneZ, 1e-3,
                                   {0.004, 0.003, z}, std::max(0.0, (kPlaneZ - z) / 1e-3),
                                   {0.0, 0.0, kPlaneZ});
      auto& h = slot.header();
      switch (corruption_.load()) {
        case Corruption::kIllPosed: slot.W()[0] = -1e-3; break;   // a negative compliance
        case Corruption::kFuture: h.t_ns += 3'600'000'000'000; break;   // an hour ahead
        case Corruption::kOverflow:   // rows and contacts beyond the segment's capacity
          h.rows = 25;
          h.contacts = 9;
          break;
        case Corruption::kNone: break;
      }
      publisher_.publish();
      segment_.beat(shared::Side::kSim);
      std::this_thread::sleep_for(10ms);
    }
  }
  shared::Segment segment_;
  shared::SnapshotPublisher publisher_;
  shared::TripleReader<shared::DeviceSample> samples_;
  std::atomic<Corruption> corruption_{Corruption::kNone};
  std::atomic<bool> stop_{false};
  std::thread thread_;
};

class HandFaultTest : public ::testing::Test {
 protected:
  void SetUp() override {
    name_ = "tactus_hand_fault_" + std::to_string(::getpid());
    dir_ = std::filesystem::path(::testing::TempDir()) / name_;
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
    commands_ = (dir_ / "commands.csv").string();
    shared::Segment::remove(name_);
  }
  void TearDown() override {
    haptic_.reset();
    client_.reset();
    sim_.reset();
    shared::Segment::remove(name_);
    std::filesystem::remove_all(dir_);
  }

  void startSim(const std::string& scene) {
    sim_.reset();
    sim_.emplace(std::vector<std::string>{kBin + "/sim_server/sim_server", scene, "--segment",
                                          name_},
                 dir_ / ("sim" + std::to_string(++sims_) + ".out"), dir_ / "sim.err");
    ASSERT_TRUE(waitForSegment(sims_)) << sim_->err();
  }
  // Waits until the segment of the sims-th simulation (generation) is up.
  bool waitForSegment(int generation) {
    return test::waitFor(
        [&] {
          auto r = shared::Segment::tryOpen(name_, shared::Access::kReadOnly);
          return r.ok() && r.segment->creatorAlive() &&
                 r.segment->generation() >= static_cast<std::uint64_t>(generation);
        },
        30s);
  }
  // haptic_server on the fault plugin with `fault` (plugin options) and the command recorder.
  // A 150 ms watchdog instead of the scene's 50 ms: a simulation that a loaded machine leaves
  // waiting for the CPU for tens of ms is no loss of the model the case did not make (each
  // case's own loss, made by its fault, is still one: the rules below do not depend on it).
  void startHaptic(const std::vector<std::string>& device_args) {
    std::vector<std::string> argv = {kBin + "/haptic_server/haptic_server", "--segment", name_,
                                     "--priority", "0", "--watchdog-ms", "150"};
    argv.insert(argv.end(), device_args.begin(), device_args.end());
    argv.insert(argv.end(), {"--device-option", "record_commands=" + commands_});
    haptic_.emplace(argv, dir_ / "haptic.out", dir_ / "haptic.err");
    started_ns_ = shared::monotonicNs();
  }
  void startPluginHand(const std::string& fault = "none",
                       const std::vector<std::string>& more = {}) {
    gates_ = {kPressedGateMs, kRepressedGateMs};
    std::vector<std::string> args = {"--device", kFaultPlugin, "--device-option",
                                     std::string("path=") + kPath, "--device-option",
                                     "fault=" + fault, "--device-option",
                                     "fault_at_ms=" + std::to_string(kFaultAtMs),
                                     "--device-option", "report=" + (dir_ / "t0").string(),
                                     "--device-option",
                                     "gates=" + std::to_string(gates_[0]) + "," +
                                         std::to_string(gates_[1]),
                                     "--device-option",
                                     "gate_file=" + (dir_ / "gates").string()};
    for (const auto& m : more) args.insert(args.end(), {"--device-option", m});
    startHaptic(args);
  }
  // The path's origins the plugin reported (dir_/t0): its open(), then one per gate passed.
  std::vector<std::int64_t> pathOrigins() const {
    std::vector<std::int64_t> origins;
    const std::string text = test::readText(dir_ / "t0");
    std::size_t begin = 0;
    for (std::size_t end = text.find('\n'); end != std::string::npos;
         begin = end + 1, end = text.find('\n', begin)) {
      origins.push_back(std::stoll(text.substr(begin, end - begin)));
    }
    return origins;
  }
  // The origin of the path's time `ms`: the bridge client's start, else the plugin's origin
  // after the last gate at or before `ms` (the newest reported while that gate is not passed).
  std::int64_t originFor(double ms) const {
    if (path_origin_ns_ != 0) return path_origin_ns_;
    const std::vector<std::int64_t> origins = pathOrigins();
    if (origins.empty()) return started_ns_;
    std::size_t passed = 0;
    while (passed < gates_.size() && gates_[passed] <= ms) ++passed;
    return origins[std::min(passed, origins.size() - 1)];
  }
  // Waits until haptic_server renders the hand's press: 150 ticks in a row from now on with a
  // force above 0.5 N in its tick records (the newest segment's, as a restarted simulation
  // creates another), so the last 50 at least at the full gain (the engage ramp is 100 ticks).
  bool waitForPress() {
    std::optional<shared::Segment> segment;
    std::optional<shared::StatsRingReader> ticks;
    std::vector<shared::StatsRecord> got(512);
    int in_a_row = 0;
    return test::waitFor(
        [&] {
          if (!segment || !segment->stillCurrent()) {
            ticks.reset();
            segment.reset();
            auto r = shared::Segment::tryOpen(name_, shared::Access::kReadOnly);
            if (!r.ok()) return false;
            segment.emplace(std::move(*r.segment));
            ticks.emplace(segment->statsReader(shared::StatsRingReader::Start::kNewest));
            in_a_row = 0;
          }
          for (std::size_t n = ticks->poll(got.data(), got.size()); n > 0;
               n = ticks->poll(got.data(), got.size())) {
            for (std::size_t i = 0; i < n; ++i) in_a_row = got[i].force_norm_n > 0.5 ? in_a_row + 1 : 0;
          }
          return in_a_row >= 150 || !haptic_->running();
        },
        120s) && haptic_->running();
  }
  // Sleeps until `ms` into the hand's path (from the plugin's open() once it wrote it, else
  // from when haptic_server or the bridge client started). On the way it opens the plugin's
  // gates up to `ms`, each once the hand waits there and the press is rendered (the second only
  // where the force must come back: recovering_).
  void at(double ms) {
    if (path_origin_ns_ == 0) {
      test::waitFor(
          [&] {
            const std::string t = test::readText(dir_ / "t0");
            return (!t.empty() && t.back() == '\n') || !haptic_->running();
          },
          30s);
    }
    while (gates_opened_ < gates_.size() && gates_[gates_opened_] <= ms) {
      const double gate = gates_[gates_opened_];
      sleepUntil(originFor(gate - 1.0) + static_cast<std::int64_t>(gate * 1e6));
      if (gates_opened_ == 0 || recovering_) {
        EXPECT_TRUE(waitForPress())
            << "the hand's press was not rendered (gate at " << gate << " ms)\n" << log();
      }
      std::ofstream(dir_ / "gates", std::ios::app) << gate << "\n";
      ++gates_opened_;
      test::waitFor([&] { return pathOrigins().size() > gates_opened_ || !haptic_->running(); },
                    30s);
    }
    sleepUntil(originFor(ms) + static_cast<std::int64_t>(ms * 1e6));
  }
  static void sleepUntil(std::int64_t due_ns) {
    while (shared::monotonicNs() < due_ns) std::this_thread::sleep_for(1ms);
  }
  // SIGTERM, then the recording (haptic_server writes it on a clean exit).
  std::vector<RecordedCommand> stopAndRead() {
    haptic_->signal(SIGTERM);
    const std::optional<int> status = haptic_->waitExit(30s);
    EXPECT_TRUE(status && WIFEXITED(*status) && WEXITSTATUS(*status) == 0)
        << "haptic_server did not stop cleanly\n" << log();
    stopped_ns_ = shared::monotonicNs();
    return test::readCommandRecording(commands_);
  }
  std::string log() const { return haptic_ ? haptic_->err() + haptic_->out() : ""; }

  // The path's time: from the plugin's open() (it writes that moment to dir_/t0), or from the
  // bridge client's start (path_origin_ns_).
  std::int64_t pathNs(const std::vector<RecordedCommand>& c, double ms) const {
    std::int64_t origin = path_origin_ns_;
    if (origin == 0) origin = pathOrigins().empty() ? c.front().t_ns : originFor(ms);
    return origin + static_cast<std::int64_t>(ms * 1e6);
  }
  static double forceAt(const std::vector<RecordedCommand>& c, std::int64_t t_ns) {
    const std::size_t i = test::commandAt(c, t_ns);
    return i < c.size() ? test::norm3(c[i].force_n) : -1.0;
  }
  // No zero command between two moments (a fault that must not be a loss of the model).
  static bool neverZero(const std::vector<RecordedCommand>& c, std::int64_t from, std::int64_t to) {
    for (std::size_t i = test::commandAt(c, from); i < c.size() && c[i].t_ns < to; ++i) {
      if (test::norm3(c[i].force_n) == 0.0) return false;
    }
    return true;
  }

  // The checks every case shares: the rules over the whole series, with a loss of the model at
  // `losses` (times), and whether the force came back after the hand left the tissue.
  // `losses`: moments just before a loss of the model (the hand still presses then and until it
  // lifts off at kLiftMs, or for ever when the force does not come back).
  void expectRules(const std::vector<RecordedCommand>& c, const std::vector<std::int64_t>& at,
                   bool recovers) {
    ASSERT_GT(c.size(), 1000u) << "too few commands recorded\n" << log();
    EXPECT_GT(forceAt(c, pathNs(c, kFaultAtMs - 150.0)), 0.5)
        << "the hand did not press before the fault\n" << log();
    std::vector<ModelLoss> losses;
    for (const std::int64_t t : at) {
      losses.push_back({t, recovers ? pathNs(c, kLiftMs) : std::numeric_limits<std::int64_t>::max()});
    }
    if (recovers) {
      EXPECT_GT(forceAt(c, pathNs(c, kRepressEndMs + 300.0)), 0.5)
          << "the force did not come back after the hand left the tissue\n" << log();
      losses.push_back({sigterm_ns_, 0});   // the shutdown fades the force out too
    }
    const std::vector<std::string> bad = checkForceRules(c, ForceRules{}, losses);
    EXPECT_TRUE(bad.empty()) << describe(bad) << "\n" << log();
  }

  // Runs the hand to the end of the path and stops haptic_server; `recovers`: the force must
  // come back after the hand left the tissue (the second gate waits for it).
  std::vector<RecordedCommand> finish(bool recovers) {
    recovering_ = recovers;
    at(kRunMs);
    sigterm_ns_ = shared::monotonicNs();
    return stopAndRead();
  }
  // Just before the fault in the plugin's time (the force is steady there).
  std::int64_t beforeFault(const std::vector<RecordedCommand>& c) const {
    return pathNs(c, kFaultAtMs - 150.0);
  }

  std::string name_;
  std::filesystem::path dir_;
  std::string commands_;
  std::optional<ChildProcess> sim_, haptic_, client_;
  int sims_ = 0;
  std::int64_t started_ns_ = 0, stopped_ns_ = 0, sigterm_ns_ = 0, path_origin_ns_ = 0;
  std::vector<double> gates_;     ///< the plugin hand's gates (path ms), none for the bridge
  std::size_t gates_opened_ = 0;
  bool recovering_ = false;
};

const std::string kCube = kData + "/scenes/press_cube.yaml";

// --- the simulation --------------------------------------------------------------------------

TEST_F(HandFaultTest, SimulationKilled) {
  startSim(kCube);
  startPluginHand();
  at(kFaultAtMs);
  const std::int64_t killed = shared::monotonicNs();
  sim_->signal(SIGKILL);
  const auto c = finish(/*recovers=*/false);
  expectRules(c, {killed}, /*recovers=*/false);
}

TEST_F(HandFaultTest, SimulationStoppedAndResumed) {
  startSim(kCube);
  startPluginHand();
  at(kFaultAtMs);
  const std::int64_t stopped = shared::monotonicNs();
  sim_->signal(SIGSTOP);
  at(kFaultAtMs + 250.0);
  sim_->signal(SIGCONT);   // the hand still presses: the force stays off until it lifts
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {stopped}, /*recovers=*/true);
}

TEST_F(HandFaultTest, SimulationRestartedWithAnotherScene) {
  // another scene: a larger cube, the pressing hand 12 mm inside its tissue
  const std::string mesh = kData + "/meshes/cube_low_res.msh";
  std::string scene = test::readText(kCube);
  scene.replace(scene.find("../meshes/cube_low_res.msh"), 26, mesh);
  scene.replace(scene.find("scale: 0.01"), 11, "scale: 0.012");
  scene.replace(scene.find("-0.034]"), 7, "-0.040]");
  scene.replace(scene.find("0.003, 0.045]"), 13, "0.003, 0.050]");
  const std::string other = (dir_ / "larger_cube.yaml").string();
  std::ofstream(other) << scene;
  startSim(kCube);
  startPluginHand();
  at(kFaultAtMs);
  const std::int64_t killed = shared::monotonicNs();
  sim_->signal(SIGKILL);
  ASSERT_TRUE(sim_->waitExit(10s));
  startSim(other);
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {killed}, /*recovers=*/true);
}

// --- the device ------------------------------------------------------------------------------

TEST_F(HandFaultTest, DeviceSilent) {
  startSim(kCube);
  startPluginHand("silent", {"fault_ms=300"});
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {beforeFault(c)}, /*recovers=*/true);
}

TEST_F(HandFaultTest, DeviceFaulting) {
  startSim(kCube);
  startPluginHand("fault", {"fault_ms=200"});
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {beforeFault(c)}, /*recovers=*/true);
}

// A read that stalls 45 ms once is not a loss: the next command differs from the last by no
// more than one period's slew, and the force never drops out.
TEST_F(HandFaultTest, DeviceStalling45Ms) {
  startSim(kCube);
  startPluginHand("stall", {"stall_ms=45"});
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {}, /*recovers=*/true);
  // (on a machine so loaded that the stall lasted past the stuck-tick bound, the device was
  // halted as a blocked one: that fades, by the rules above)
  if (log().find("stuck") == std::string::npos) {
    EXPECT_TRUE(neverZero(c, beforeFault(c), pathNs(c, kLiftMs)))
        << "the stall faded the force out\n" << log();
  }
  bool gap = false;
  for (std::size_t i = 1; i < c.size(); ++i) gap = gap || c[i].t_ns - c[i - 1].t_ns > 40'000'000;
  EXPECT_TRUE(gap) << "the plugin did not stall";
}

// A read that blocks: the supervisor's watchdog halts the device, the read returns a fault, and
// the force fades from where it was.
TEST_F(HandFaultTest, DeviceBlockingIsHalted) {
  startSim(kCube);
  startPluginHand("block", {"fault_ms=200"});
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {beforeFault(c)}, /*recovers=*/true);
  EXPECT_NE(log().find("asked the device to halt"), std::string::npos) << log();
}

// A read that blocks for ever on a device that cannot be halted: the stuck tick is reported,
// and SIGTERM still ends haptic_server, after a bounded grace period (exit code 4).
TEST_F(HandFaultTest, DeviceBlockingForEverStillStopsOnSigterm) {
  startSim(kCube);
  startPluginHand("block", {"halt=0"});
  at(kFaultAtMs + 500.0);
  haptic_->signal(SIGTERM);
  const std::optional<int> status = haptic_->waitExit(60s);
  ASSERT_TRUE(status) << "SIGTERM did not end haptic_server\n" << log();
  EXPECT_TRUE(WIFEXITED(*status) && WEXITSTATUS(*status) == 4) << log();
  EXPECT_NE(log().find("does not honour halt"), std::string::npos) << log();
  EXPECT_NE(log().find("exiting without it"), std::string::npos) << log();
}

TEST_F(HandFaultTest, DeviceThrowing) {
  startSim(kCube);
  startPluginHand("throw", {"fault_ms=200"});
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {beforeFault(c)}, /*recovers=*/true);
  EXPECT_NE(log().find("exceptions escaped read()"), std::string::npos) << log();
}

TEST_F(HandFaultTest, DeviceZeroQuaternion) {
  startSim(kCube);
  startPluginHand("zero_quat", {"fault_ms=200"});
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {beforeFault(c)}, /*recovers=*/true);
  EXPECT_NE(log().find("not a unit quaternion"), std::string::npos) << log();
}

// --- the network bridge ----------------------------------------------------------------------

class HandBridgeFaultTest : public HandFaultTest {
 protected:
  // haptic_server with the bridge on a free port, then the reference client playing the path.
  void startBridge() {
    std::ofstream(dir_ / "path.csv") << pathCsv();
    // a free UDP port: bind port 0, read it, release it
    const int probe = ::socket(AF_INET, SOCK_DGRAM, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ::bind(probe, reinterpret_cast<sockaddr*>(&a), sizeof a);
    socklen_t len = sizeof a;
    ::getsockname(probe, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    ::close(probe);
    startHaptic({"--device", "bridge", "--device-option", "port=" + std::to_string(port_)});
    std::this_thread::sleep_for(200ms);   // (it binds before the client sends)
    client_.emplace(std::vector<std::string>{kBin + "/tools/bridge_client/tactus-bridge-client",
                                             "--port", std::to_string(port_), "--device-option",
                                             "trajectory=" + (dir_ / "path.csv").string(),
                                             "--device-option", "stiffness=2000"},
                    dir_ / "client.out", dir_ / "client.err");
    started_ns_ = shared::monotonicNs();   // the path starts with the client
    path_origin_ns_ = started_ns_;
  }
  // The bridge's count of datagrams from another sender, from its last counter line.
  std::uint64_t foreignDatagrams() const {
    const std::string l = log();
    const auto at = l.rfind(" from another sender");
    if (at == std::string::npos) return 0;
    auto begin = l.rfind(' ', at - 1);
    return std::stoull(l.substr(begin + 1, at - begin - 1));
  }
  std::uint16_t port_ = 0;
};

// Another sender spoofs the device while the real client is live: one datagram with seq 2^64-1
// and t = INT64_MAX, then states interleaved with the client's from deep inside the tissue. The
// session stays the client's: no dip, no loss, every rule holds.
TEST_F(HandBridgeFaultTest, SpoofedStatesNeverReachTheHand) {
  startSim(kCube);
  startBridge();
  at(kFaultAtMs);
  test::BridgeSender spoofer(port_);
  spoofer.sendState(~std::uint64_t{0}, std::numeric_limits<std::int64_t>::max(),
                    {0.004, 0.003, 0.020});
  for (std::uint64_t seq = 1; seq <= 300; ++seq) {
    spoofer.sendState(seq, shared::monotonicNs(), {0.004, 0.003, 0.020});
    std::this_thread::sleep_for(1ms);
  }
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {}, /*recovers=*/true);
  EXPECT_TRUE(neverZero(c, pathNs(c, kPressEndMs + 200.0), pathNs(c, kLiftMs)))
      << "the spoofed states changed the force\n" << log();
  EXPECT_GE(foreignDatagrams(), 300u)
      << "the spoofed datagrams were not refused as another sender's\n" << log();
}

TEST_F(HandBridgeFaultTest, BridgeClientLost) {
  startSim(kCube);
  startBridge();
  at(kFaultAtMs);
  const std::int64_t lost = shared::monotonicNs();
  client_->signal(SIGKILL);
  const auto c = finish(/*recovers=*/false);
  expectRules(c, {lost}, /*recovers=*/false);
}

// --- the snapshot ----------------------------------------------------------------------------

class HandSnapshotFaultTest : public HandFaultTest,
                              public ::testing::WithParamInterface<Corruption> {};

TEST_P(HandSnapshotFaultTest, CorruptFutureOrOverflowingSnapshotFadesAndRecovers) {
  PlaneSimulation plane(name_);
  startPluginHand();
  at(kFaultAtMs);
  const std::int64_t corrupted = shared::monotonicNs();
  plane.corrupt(GetParam());
  at(kFaultAtMs + 200.0);
  plane.corrupt(Corruption::kNone);
  const auto c = finish(/*recovers=*/true);
  expectRules(c, {corrupted}, /*recovers=*/true);
}

INSTANTIATE_TEST_SUITE_P(Snapshots, HandSnapshotFaultTest,
                         ::testing::Values(Corruption::kIllPosed, Corruption::kFuture,
                                           Corruption::kOverflow),
                         [](const ::testing::TestParamInfo<Corruption>& info) {
                           switch (info.param) {
                             case Corruption::kIllPosed: return std::string("Corrupt");
                             case Corruption::kFuture: return std::string("FutureStamped");
                             case Corruption::kOverflow: return std::string("Overflowing");
                             default: return std::string("None");
                           }
                         });

// --- the bridge client when haptic_server is gone --------------------------------------------

// A fake haptic_server: a UDP socket on a free loopback port that answers the client's states
// with a 1.5 N command until the test has the state it waits for, then falls silent.
class FakeBridgeServer {
 public:
  FakeBridgeServer() {
    fd_ = ::socket(AF_INET, SOCK_DGRAM | SOCK_CLOEXEC, 0);
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    ::bind(fd_, reinterpret_cast<sockaddr*>(&a), sizeof a);
    socklen_t len = sizeof a;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&a), &len);
    port_ = ntohs(a.sin_port);
    timeval tv{0, 100'000};
    ::setsockopt(fd_, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  ~FakeBridgeServer() { ::close(fd_); }
  std::uint16_t port() const { return port_; }
  // Answers every state with a command while `go_on(sent)` holds (asked after each datagram and
  // at least every 100 ms), for at most `limit`; returns the commands sent.
  template <typename GoOn>
  int answerWhile(GoOn go_on, std::chrono::seconds limit = 60s) {
    int sent = 0;
    std::uint64_t seq = 0;
    const std::int64_t until_ns =
        shared::monotonicNs() + std::chrono::duration_cast<std::chrono::nanoseconds>(limit).count();
    while (go_on(sent) && shared::monotonicNs() < until_ns) {
      unsigned char buf[512];
      sockaddr_in from{};
      socklen_t len = sizeof from;
      const ssize_t n =
          ::recvfrom(fd_, buf, sizeof buf, 0, reinterpret_cast<sockaddr*>(&from), &len);
      if (n <= 0) continue;
      device::DeviceCommand cmd;
      cmd.force_n = {0.0, 0.0, 1.5};
      unsigned char out[device::bridge::kCommandBytes];
      const std::size_t size =
          device::bridge::encodeCommand(++seq, shared::monotonicNs(), cmd, 1, out);
      if (::sendto(fd_, out, size, 0, reinterpret_cast<sockaddr*>(&from), len) > 0) ++sent;
    }
    return sent;
  }

 private:
  int fd_ = -1;
  std::uint16_t port_ = 0;
};

// The last "force X Y Z N" a client printed.
std::array<double, 3> lastPrintedForce(const std::string& out) {
  std::array<double, 3> f{-1.0, -1.0, -1.0};
  const auto at = out.rfind("force ");
  if (at != std::string::npos) std::sscanf(out.c_str() + at, "force %lf %lf %lf", &f[0], &f[1], &f[2]);
  return f;
}

// haptic_server dies: the reference client stops rendering its last command (it used to keep
// pushing the hand with it for ever). No fixed times: the server answers until the client's
// status line (once a second) shows the command rendered, however late a loaded machine gets
// there, then falls silent; the client's later status lines (a run of 4 s: at 2 and 3 s) must
// show zero.
TEST(BridgeClientTimeout, TheReferenceClientRendersZeroOnceTheServerIsGone) {
  FakeBridgeServer server;
  const auto dir = std::filesystem::path(::testing::TempDir());
  // an earlier run's output must not open the gate before this client has written its own
  std::filesystem::remove(dir / "bridge_client.out");
  ChildProcess client({kBin + "/tools/bridge_client/tactus-bridge-client", "--port",
                       std::to_string(server.port()), "--status", "--duration", "4"},
                      dir / "bridge_client.out", dir / "bridge_client.err");
  const std::string rendered = "force 0.000 0.000 1.500";
  EXPECT_GT(server.answerWhile([&](int) {
              return client.out().find(rendered) == std::string::npos && client.running();
            }),
            100);
  ASSERT_NE(client.out().find(rendered), std::string::npos)
      << "the client never rendered the server's command\n" << client.out() << client.err();
  ASSERT_TRUE(client.waitExit(30s)) << "the client did not end";
  const std::string out = client.out();
  EXPECT_NE(out.find("force 0.000 0.000 1.500"), std::string::npos) << out;
  EXPECT_NE(out.find("no command for 100 ms: rendering zero force"), std::string::npos) << out;
  EXPECT_EQ(lastPrintedForce(out), (std::array<double, 3>{0.0, 0.0, 0.0})) << out;
}

// The same for the Python client of device/README.md (run as documented, from the README).
TEST(BridgeClientTimeout, TheReadmesPythonClientRendersZeroOnceTheServerIsGone) {
  if (!std::filesystem::exists("/usr/bin/python3")) GTEST_SKIP() << "no /usr/bin/python3";
  const std::string readme = test::readText(std::string(TACTUS_SOURCE_DIR) + "/device/README.md");
  const auto begin = readme.find("```python\n");
  ASSERT_NE(begin, std::string::npos);
  const auto end = readme.find("```", begin + 10);
  const auto dir = std::filesystem::path(::testing::TempDir());
  const auto script = dir / "readme_bridge_client.py";
  std::ofstream(script) << readme.substr(begin + 10, end - begin - 10);
  FakeBridgeServer server;
  // a run long enough for any machine: the test ends it once the client has printed
  ChildProcess client({"/usr/bin/python3", script.string(), "120", std::to_string(server.port())},
                      dir / "py_client.out", dir / "py_client.err");
  // commands for the client's first 500 states, then silence. The client prints its force every
  // 1000 states, so its first line (state 1000) comes at least 500 states (> 0.5 s, five times
  // its 100 ms timeout) after the last command, however slowly a loaded machine runs it.
  EXPECT_EQ(server.answerWhile([&](int sent) { return sent < 500 && client.running(); }), 500)
      << client.out() << client.err();
  ASSERT_TRUE(test::waitFor(
      [&] { return client.out().find("force") != std::string::npos || !client.running(); },
      std::chrono::seconds(60)))
      << "the client printed no force line\n" << client.out() << client.err();
  ASSERT_TRUE(client.running()) << "the client ended early\n" << client.out() << client.err();
  client.signal(SIGTERM);
  ASSERT_TRUE(client.waitExit(30s)) << "the client did not end";
  const std::string out = client.out();
  EXPECT_NE(out.find("1000 states sent, force"), std::string::npos) << out << client.err();
  EXPECT_EQ(lastPrintedForce(out), (std::array<double, 3>{0.0, 0.0, 0.0})) << out;
}

}  // namespace
}  // namespace tactus

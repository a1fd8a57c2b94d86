// The daemons' command lines and signals: every rejected value exits non-zero with a message
// naming the option before any segment exists; SIGHUP (the terminal closed) stops
// sim_server/haptic_server/tactus-monitor cleanly and leaves no segment behind.
#include <gtest/gtest.h>

#include <memory>

#include "daemon_process.h"

namespace fs = std::filesystem;
using namespace std::chrono_literals;
using tactus::test::ChildProcess;
using tactus::test::runProgram;

namespace {

const std::string kSim = TACTUS_BINARY_DIR "/sim_server/sim_server";
const std::string kHaptic = TACTUS_BINARY_DIR "/haptic_server/haptic_server";
const std::string kMonitor = TACTUS_BINARY_DIR "/tools/monitor/tactus-monitor";
const std::string kScene = TACTUS_TEST_DATA_DIR "/scenes/press_cube.yaml";

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string id =
        std::to_string(::getpid()) + "_" +
        ::testing::UnitTest::GetInstance()->current_test_info()->name();
    dir_ = fs::temp_directory_path() / ("tactus_sec_cli_" + id);
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    segment_ = "tactus_sec_cli_" + std::to_string(::getpid());
  }
  void TearDown() override {
    fs::remove(shm());
    fs::remove_all(dir_);
  }
  fs::path shm() const { return fs::path("/dev/shm") / segment_; }

  // Runs argv and expects a refusal that names `option`, with no segment created.
  void expectRejected(std::vector<std::string> argv, const std::string& option) {
    std::string line;
    for (const auto& a : argv) line += a + " ";
    const tactus::test::RunResult r = runProgram(argv, dir_, 20s);
    EXPECT_FALSE(r.timed_out) << line << ": still running after 20 s";
    EXPECT_GT(r.exit_code, 0) << line;
    EXPECT_NE((r.err + r.out).find(option), std::string::npos)
        << line << ": the message does not name " << option << ":\n" << r.err << r.out;
    EXPECT_FALSE(fs::exists(shm())) << line << ": a segment was created";
  }

  fs::path dir_;
  std::string segment_;
};

TEST_F(CliTest, SimServerRejectsEndlessOrInvalidRunLengths) {
  for (const std::string& steps : std::vector<std::string>{"0", "-1", "nan", "1.5"}) {
    expectRejected({kSim, kScene, "--segment", segment_, "--steps", steps}, "--steps");
  }
  for (const std::string& duration :
       std::vector<std::string>{"-1", "nan", "inf", "-inf", "1e400", "3s"}) {
    expectRejected({kSim, kScene, "--segment", segment_, "--duration", duration}, "--duration");
  }
}

TEST_F(CliTest, SimServerHelpStatesWhatZeroDurationMeans) {
  const tactus::test::RunResult r = runProgram({kSim, "--help"}, dir_, 20s);
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("0 (the default): run until SIGINT, SIGTERM"), std::string::npos) << r.out;
}

// --workspace-option I:key=value (device I's own mapping): every bad value is a usage error
// (exit 2) naming the option or the range, before any device or segment exists; a good one is
// logged per device.
TEST_F(CliTest, HapticServerRejectsBadPerDeviceWorkspaceOptions) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {"1:scale=0", "workspace scale = 0"},       {"1:scale=nan", "'nan' is not a finite"},
      {"1:scale=inf", "'inf' is not a finite"},   {"1:scale=1e999", "not a finite number"},
      {"1:scale=1e3", "must be a finite number in [0.01, 100]"},
      {"1:scale=2x", "'2x' is not a finite"},     {"1:scale=", "'' is not a finite"},
      {"1:offset=0,nan,0", "'nan' is not a finite"}, {"1:offset=0,1e9,0", "offset[1]"},
      {"1:offset=0,0", "expects 3 comma-separated"}, {"0:rotation=1,0,0,0.5", "unit quaternion"},
      {"1:rotation=0,0,0,0", "unit quaternion"},  {"1:rotation=1,0,0", "expects 4"},
      {"1:clutch_button=40", "clutch button = 40"}, {"1:clutch_button=1.5", "an integer"},
      {"1:clutch_button=-2", "clutch button = -2"}, {"2:scale=2", "no such device"},
      {"99999999999999999999:scale=2", "no such device"}, {"scale=2", "expected I:key=value"},
      {"1:scale", "expected I:key=value"},        {"-1:scale=2", "expected I:key=value"},
      {"1:gain=2", "unknown key 'gain'"},
  };
  for (const auto& [option, message] : cases) {
    const std::vector<std::string> argv = {kHaptic, "--device", "null", "--device", "null",
                                           "--segment", segment_, "--duration", "0.1",
                                           "--workspace-option", option};
    const tactus::test::RunResult r = runProgram(argv, dir_, 20s);
    EXPECT_FALSE(r.timed_out) << option;
    EXPECT_EQ(r.exit_code, 2) << option << "\n" << r.err << r.out;
    EXPECT_NE((r.err + r.out).find(message), std::string::npos)
        << option << ": the message does not say " << message << ":\n" << r.err << r.out;
    EXPECT_NE((r.err + r.out).find("--workspace-option"), std::string::npos) << option;
    EXPECT_FALSE(fs::exists(shm())) << option << ": a segment was created";
  }
  // the plain options are usage errors too (exit 2)
  const tactus::test::RunResult plain = runProgram(
      {kHaptic, "--device", "null", "--segment", segment_, "--workspace-rotation", "1,0,0,0.5"},
      dir_, 20s);
  EXPECT_EQ(plain.exit_code, 2) << plain.err << plain.out;
  // good: device 1 gets its own scale and rotation over the common scale, device 0 the common one
  const tactus::test::RunResult good = runProgram(
      {kHaptic, "--device", "null", "--device", "null", "--segment", segment_, "--duration",
       "0.1", "--workspace-scale", "0.5", "--workspace-option", "1:scale=2",
       "--workspace-option", "1:rotation=0.7071067811865476,0,0,0.7071067811865476",
       "--workspace-option", "1:clutch_button=3"},
      dir_, 20s);
  EXPECT_EQ(good.exit_code, 0) << good.err << good.out;
  const std::string log = good.err + good.out;
  EXPECT_NE(log.find("device 0 workspace: scale 0.5, offset (0, 0, 0) m, rotation (1, 0, 0, 0), "
                     "clutch button -1"),
            std::string::npos) << log;
  EXPECT_NE(log.find("device 1 workspace: scale 2, offset (0, 0, 0) m, rotation "
                     "(0.7071067811865476, 0, 0, 0.7071067811865476), clutch button 3"),
            std::string::npos) << log;
}

// Two bridge devices on one UDP port: said as such before anything opens (the second used to fail
// to bind with "another haptic_server or program may hold it").
TEST_F(CliTest, HapticServerRefusesTwoBridgesOnOnePort) {
  for (const std::vector<std::string>& ports :
       {std::vector<std::string>{}, std::vector<std::string>{"--device-option", "0:port=47123",
                                                             "--device-option", "1:port=47123"}}) {
    std::vector<std::string> argv = {kHaptic, "--device", "bridge", "--device", "bridge",
                                     "--segment", segment_, "--duration", "0.1"};
    argv.insert(argv.end(), ports.begin(), ports.end());
    const tactus::test::RunResult r = runProgram(argv, dir_, 20s);
    EXPECT_EQ(r.exit_code, 2) << r.err << r.out;
    EXPECT_NE((r.err + r.out).find("devices 0 and 1 are both network bridges on UDP port"),
              std::string::npos)
        << r.err << r.out;
  }
}

TEST_F(CliTest, HapticServerRejectsInvalidDurations) {
  for (const std::string& duration : std::vector<std::string>{"-1", "nan", "inf", "1e400"}) {
    expectRejected(
        {kHaptic, "--device", "simulated", "--segment", segment_, "--duration", duration},
        "--duration");
  }
  const tactus::test::RunResult r = runProgram({kHaptic, "--help"}, dir_, 20s);
  EXPECT_NE(r.out.find("0 (the default): run until SIGINT, SIGTERM or SIGHUP"), std::string::npos)
      << r.out;
}

TEST_F(CliTest, MonitorRejectsFloodingIntervalsAndBadSegmentNames) {
  for (const std::string& interval : std::vector<std::string>{"0", "-1", "0.001", "nan", "inf"}) {
    expectRejected({kMonitor, "--segment", segment_, "--interval", interval}, "--interval");
  }
  for (const std::string& name :
       std::vector<std::string>{"a/b", "../x", "", std::string(100, 'n')}) {
    expectRejected({kMonitor, "--segment", name}, "--segment");
  }
  expectRejected({kMonitor, "--segment", segment_, "--duration", "nan"}, "--duration");
  expectRejected({kMonitor, "--segment", segment_, "--wait", "inf"}, "--wait");
}

TEST_F(CliTest, MonitorGivesUpWaitingForAMissingSegment) {
  const tactus::test::RunResult r = runProgram(
      {kMonitor, "--segment", segment_, "--interval", "0.05", "--wait", "0.3"}, dir_, 20s);
  EXPECT_FALSE(r.timed_out) << "the monitor waited without bound";
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("giving up"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(segment_), std::string::npos) << r.err;
}

// SIGHUP to a running pair: both stop cleanly (exit 0) and the segment is removed.
TEST_F(CliTest, SighupStopsTheDaemonsAndRemovesTheSegment) {
  ChildProcess sim({kSim, kScene, "--segment", segment_}, dir_ / "sim.out", dir_ / "sim.err");
  ChildProcess haptic({kHaptic, "--device", "simulated", "--segment", segment_, "--priority", "0"},
                      dir_ / "haptic.out", dir_ / "haptic.err");
  ChildProcess monitor({kMonitor, "--segment", segment_, "--interval", "0.1"},
                       dir_ / "monitor.out", dir_ / "monitor.err");
  ASSERT_TRUE(tactus::test::waitFor([&] { return fs::exists(shm()) || !sim.running(); }, 60s));
  ASSERT_TRUE(fs::exists(shm())) << sim.out() << sim.err();
  // the haptic side attached (its log says so) before the hang-up
  ASSERT_TRUE(tactus::test::waitFor(
      [&] {
        return (haptic.out() + haptic.err()).find("attached to segment") != std::string::npos ||
               !haptic.running();
      },
      30s));
  ASSERT_TRUE(haptic.running()) << haptic.out() << haptic.err();

  haptic.signal(SIGHUP);
  sim.signal(SIGHUP);
  monitor.signal(SIGHUP);
  for (ChildProcess* p : {&haptic, &sim, &monitor}) {
    const std::optional<int> st = p->waitExit(30s);
    ASSERT_TRUE(st.has_value()) << "still running 30 s after SIGHUP: " << p->out() << p->err();
    EXPECT_TRUE(WIFEXITED(*st) && WEXITSTATUS(*st) == 0)
        << "wait status " << *st << " (killed by the signal?)\n" << p->out() << p->err();
  }
  EXPECT_FALSE(fs::exists(shm())) << "the segment was left behind";
}

}  // namespace

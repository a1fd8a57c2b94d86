// Device loader: built-in names, the example out-of-tree plugin loaded by path and by name, and
// the error paths (unknown backend, missing file, missing symbol, wrong ABI, bad options) with
// the messages a user sees.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <string>
#include <thread>

#include "tactus/device/backends.h"
#include "tactus/device/device.h"

namespace tactus::device {
namespace {

using ::testing::HasSubstr;

const std::string kSpringDir = std::string(TACTUS_BINARY_DIR) + "/device/examples/spring_plugin";
const std::string kSpringPlugin = kSpringDir + "/libtactus_spring_device.so";
const std::string kFixtures = std::string(TACTUS_BINARY_DIR) + "/device/test_plugins";
const std::string kFaultPlugin = kFixtures + "/libfault_plugin.so";

std::string loadError(const std::string& name, const DeviceConfig& config = {}) {
  try {
    loadDevice(name, config);
  } catch (const DeviceError& e) {
    return e.what();
  }
  return "";
}

TEST(DeviceLoader, BuiltinsByName) {
  EXPECT_EQ(builtinDeviceNames(),
            (std::vector<std::string>{"bridge", "null", "replay", "simulated"}));
  auto sim = loadDevice("");  // the default
  EXPECT_EQ(sim->info().model, "tactus simulated hand");
  EXPECT_NE(dynamic_cast<SimulatedDevice*>(sim.get()), nullptr);
  auto null = loadDevice("null");
  DeviceState s;
  EXPECT_EQ(null->read(&s), IoStatus::kNoData);
  auto fixed = loadDevice("null", {{"pose", "0.1,0.2,0.3"}});
  ASSERT_EQ(fixed->read(&s), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(s.pos_m[1], 0.2);
}

TEST(DeviceLoader, BadOptionsAreExplained) {
  EXPECT_THAT(loadError("simulated", {{"mas", "1"}}),
              HasSubstr("device 'simulated': unknown option 'mas' (known: "));
  EXPECT_THAT(loadError("simulated", {{"mas", "1"}}), HasSubstr("mass"));
  EXPECT_THAT(loadError("simulated", {{"mass", "heavy"}}),
              HasSubstr("option mass=heavy is not a finite number"));
  EXPECT_THAT(loadError("simulated", {{"origin", "1,2"}}), HasSubstr("three comma-separated"));
  EXPECT_THAT(loadError("replay"), HasSubstr("needs a trajectory: --device-option file="));
  EXPECT_THAT(loadError("replay", {{"file", "/nonexistent/t.csv"}}),
              HasSubstr("cannot read trajectory '/nonexistent/t.csv'"));
  DeviceConfig c;
  addDeviceOption(c, "mass=0.5");
  addDeviceOption(c, "origin=0,0,0.1");
  EXPECT_EQ(c.at("mass"), "0.5");
  EXPECT_EQ(c.at("origin"), "0,0,0.1");
  // a recorder ring is allocated at once: its capacity is bounded (1e15 ended in bad_alloc)
  EXPECT_THAT(loadError("null", {{"record", "/nonexistent/r.csv"}, {"record_capacity", "1e15"}}),
              HasSubstr("record_capacity=1e15 must be in [2, 16777216]"));
  EXPECT_THROW(addDeviceOption(c, "novalue"), DeviceError);
  EXPECT_THROW(addDeviceOption(c, "=3"), DeviceError);
}

TEST(DeviceLoader, UnknownNameSaysWhatIsAvailable) {
  const std::string msg = loadError("phantom_omni");
  EXPECT_THAT(msg, HasSubstr("device backend 'phantom_omni' is not built in (bridge, null, "
                             "replay, simulated)"));
  EXPECT_THAT(msg, HasSubstr("libphantom_omni.so"));
  EXPECT_THAT(msg, HasSubstr("TACTUS_DEVICE_PATH"));
}

TEST(DeviceLoader, MissingFileSaysWhatToDo) {
  const std::string msg = loadError("/nonexistent/libfoo.so");
  EXPECT_THAT(msg, HasSubstr("cannot load the plugin library"));
  EXPECT_THAT(msg, HasSubstr("/nonexistent/libfoo.so: no such file"));
  EXPECT_THAT(msg, HasSubstr("built-in backend"));
}

TEST(DeviceLoader, MissingSymbolIsRefused) {
  const std::string msg = loadError(kFixtures + "/libno_symbol_plugin.so");
  EXPECT_THAT(msg, HasSubstr("does not export 'tactus_device_plugin'"));
  EXPECT_THAT(msg, HasSubstr("extern \"C\" const TactusDevicePlugin* tactus_device_plugin(void)"));
}

TEST(DeviceLoader, WrongAbiIsRefused) {
  const std::string msg = loadError(kFixtures + "/libwrong_abi_plugin.so");
  EXPECT_THAT(msg, HasSubstr("was built for device plugin ABI version 7, this program loads "
                             "versions 1 to 2"));
  EXPECT_THAT(msg, HasSubstr("rebuild the plugin against"));
}

TEST(DeviceLoader, ExamplePluginByPathRendersForce) {
  auto dev = loadDevice(kSpringPlugin, {{"stiffness", "400"}, {"rest", "0,0,0.05"}});
  EXPECT_EQ(dev->info().model, "example spring (k=400 N/m)");
  EXPECT_DOUBLE_EQ(dev->info().max_force_n, 5.0);
  DeviceState s;
  EXPECT_EQ(dev->read(&s), IoStatus::kNoData);  // not open yet
  dev->open();
  dev->calibrate();
  dev->enableForces(true);
  DeviceCommand cmd;
  cmd.force_n = {0.0, 2.0, -4.0};
  ASSERT_EQ(dev->write(cmd), IoStatus::kOk);
  ASSERT_EQ(dev->read(&s), IoStatus::kOk);
  EXPECT_NEAR(s.pos_m[1], 2.0 / 400.0, 1e-12);
  EXPECT_NEAR(s.pos_m[2], 0.05 - 4.0 / 400.0, 1e-12);
  EXPECT_GT(s.t_ns, 0);
  cmd.force_n[0] = std::nan("");
  EXPECT_EQ(dev->write(cmd), IoStatus::kFault);
  dev->close();
}

TEST(DeviceLoader, ExamplePluginByNameOnSearchPath) {
  ::setenv("TACTUS_DEVICE_PATH", ("/nonexistent:" + kSpringDir).c_str(), 1);
  auto dev = loadDevice("tactus_spring_device");
  EXPECT_THAT(dev->info().model, HasSubstr("example spring"));
  ::unsetenv("TACTUS_DEVICE_PATH");
}

TEST(DeviceLoader, PluginOptionErrorsComeThrough) {
  const std::string msg = loadError(kSpringPlugin, {{"stifness", "1"}});
  EXPECT_THAT(msg, HasSubstr("device plugin 'spring'"));
  EXPECT_THAT(msg, HasSubstr("create failed: unknown option 'stifness' (known: stiffness, rest)"));
}

// A plugin built for version 1 of the ABI (no halt entry) keeps loading and working; it cannot
// be halted.
TEST(DeviceLoader, AVersionOnePluginStillLoads) {
  auto dev = loadDevice(kFixtures + "/libabi_v1_plugin.so");
  EXPECT_EQ(dev->info().model, "abi v1 plugin");
  dev->open();
  DeviceState s;
  ASSERT_EQ(dev->read(&s), IoStatus::kOk);
  EXPECT_DOUBLE_EQ(s.pos_m[2], 0.25);
  EXPECT_FALSE(dev->halt());
  dev->close();
}

// create() may leave its error buffer unterminated: the message holds what fits in the buffer
// and nothing read beyond it (the loader used to read on into its stack until a zero byte).
TEST(DeviceLoader, AnUnterminatedCreateErrorIsCutAtTheBuffer) {
  const std::string msg = loadError(kFaultPlugin, {{"create_error", "unterminated"}});
  const std::string::size_type at = msg.find("create failed: ");
  ASSERT_NE(at, std::string::npos) << msg;
  const std::string text = msg.substr(at + 15);
  EXPECT_EQ(text, std::string(511, 'E')) << "the message must end with the buffer";
}

// An exception escaping a plugin's read or write (against the ABI) is caught at the C boundary:
// the call reports a fault, the diagnostics say what happened, nothing reaches the caller.
TEST(DeviceLoader, APluginsExceptionsNeverCrossTheCBoundary) {
  for (const char* kind : {"throw", "throw_write"}) {
    SCOPED_TRACE(kind);
    auto dev = loadDevice(kFaultPlugin, {{"fault", kind}, {"fault_at_ms", "0"},
                                         {"fault_ms", "1e9"}});
    dev->open();
    DeviceState s;
    const bool in_read = std::string(kind) == "throw";
    EXPECT_EQ(dev->read(&s), in_read ? IoStatus::kFault : IoStatus::kOk);
    EXPECT_EQ(dev->write(DeviceCommand{}), in_read ? IoStatus::kOk : IoStatus::kFault);
    EXPECT_EQ(dev->write(DeviceCommand{}), in_read ? IoStatus::kOk : IoStatus::kFault);
    const std::string d = dev->takeDiagnostics();
    EXPECT_THAT(d, HasSubstr(in_read ? "read() 1 and write() 0" : "read() 0 and write() 2"));
    EXPECT_THAT(d, HasSubstr("throws on purpose"));
    EXPECT_EQ(dev->takeDiagnostics(), "") << "reported once";
    dev->close();
  }
}

// halt() from another thread unblocks a read that blocks (against the contract); a plugin that
// does not honour it stays blocked (the supervisor then says so; see HapticWatchdog).
TEST(DeviceLoader, HaltUnblocksABlockedReadFromAnotherThread) {
  auto dev = loadDevice(kFaultPlugin, {{"fault", "block"}, {"fault_at_ms", "0"},
                                       {"fault_ms", "1e9"}});
  dev->open();
  std::atomic<bool> returned{false};
  IoStatus io = IoStatus::kOk;
  std::thread rt([&] {
    DeviceState s;
    io = dev->read(&s);
    returned.store(true);
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_FALSE(returned.load()) << "the fixture's read should block";
  EXPECT_TRUE(dev->halt());
  rt.join();
  EXPECT_EQ(io, IoStatus::kFault);
  DeviceState s;
  EXPECT_EQ(dev->read(&s), IoStatus::kFault) << "faulty after a halt";
  dev->close();
}

}  // namespace
}  // namespace tactus::device

// haptic_server: the hard-real-time haptic loop. Pins a core, runs at SCHED_FIFO where allowed,
// polls a device backend and re-solves the simulation's last contact problem every period.
#include "tactus/shared/cli.h"
#include <spdlog/spdlog.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <csignal>
#include <cstdlib>
#include <map>
#include <optional>
#include <thread>

#include "tactus/device/backends.h"
#include "tactus/device/bridge_device.h"
#include "tactus/device/bridge_protocol.h"
#include "tactus/device/device.h"
#include "tactus/haptic/clutch_key.h"
#include "tactus/haptic/device_options.h"
#include "tactus/haptic/haptic_loop.h"
#include "tactus/haptic/supervisor.h"
#include "tactus/haptic/workspace_options.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/file_io.h"
#include "tactus/shared/nsgs_kernels.h"
#include "tactus/shared/rt.h"
#include "tactus/shared/workspace_mapping.h"

namespace {
/// After a stop request, how long the real-time thread may take to end (a device call that
/// blocks against its contract) before the process ends without it, with kExitStuck.
constexpr int kStopGraceMs = 1000;
constexpr int kExitStuck = 4;
std::atomic<bool> g_stop{false};
void onSignal(int) {
  g_stop.store(true);
  tactus::shared::requestStop();  // also interrupts file reads (a long replay CSV)
}
}  // namespace

int main(int argc, char** argv) {
  using namespace tactus;
  namespace cli = tactus::shared::cli;
  cli::App app{"Tactus haptic server: renders contact forces at 1 kHz or more"};
  app.footer(
      "Example:\n"
      "  haptic_server --segment tactus   (after sim_server; scripts/start.sh starts both)");
  std::string segment = "tactus";
  std::vector<std::string> device_names;
  std::vector<std::string> device_options;
  double rate_hz = 1000.0;
  int core = -1;
  int priority = 80;
  bool require_rt = false;
  double duration_s = 0.0;
  bool status = false;
  std::string log_level = "info";
  haptic::HapticSettings settings;
  app.addOption("--segment", segment, "Shared-memory segment name")->captureDefault();
  app.addOption("--device", device_names,
                 "Device backend: simulated, replay, null, bridge (network; device/README.md), "
                 "or a plugin .so path; repeat for several devices (device i drives the scene's "
                 "instrument i; default: one simulated device)");
  app.addOption("--device-option", device_options,
                 "Backend option key=value (repeatable); I:key=value for device I (0-based), "
                 "key=value for device 0");
  app.addOption("--rate", rate_hz, "Loop rate [Hz]")
      ->check(cli::finiteRange(50.0, 4000.0, "Hz"))->captureDefault();
  app.addOption("--core", core, "CPU core to pin the loop to (-1: the last core)");
  app.addOption("--priority", priority, "SCHED_FIFO priority (0: do not ask)")
      ->check(cli::range(0, 99))->captureDefault();
  app.addFlag("--require-rt", require_rt, "Fail if pinning, SCHED_FIFO or mlockall is refused");
  using Limits = haptic::HapticSettingsLimits;
  app.addOption("--max-force", settings.max_force_n, "Force clamp [N]")
      ->check(cli::finiteAbove(0.0, Limits::kMaxForceN, "N"))->captureDefault();
  app.addOption("--force-scale", settings.force_scale, "Rendered force per contact force")
      ->check(cli::finiteRange(0.0, Limits::kMaxForceScale))->captureDefault();
  app.addOption("--watchdog-ms", settings.watchdog_ms, "Fade out when the snapshot is older")
      ->check(cli::finiteAbove(0.0, Limits::kMaxWatchdogMs, "ms"))->captureDefault();
  app.addOption("--fade-ms", settings.fade_ms, "Fade ramp [ms]")
      ->check(cli::finiteRange(0.0, Limits::kMaxFadeMs, "ms"))->captureDefault();
  app.addOption("--snapshot-blend-ms", settings.snapshot_blend_ms,
                 "Blend each new snapshot's force in over this time [ms] (0: off)")
      ->check(cli::finiteRange(0.0, Limits::kMaxSnapshotBlendMs, "ms"))->captureDefault();
  app.addOption("--slew", settings.slew_n_per_s, "Force slew-rate limit [N/s]")
      ->check(cli::finiteAbove(0.0, Limits::kMaxSlewNPerS, "N/s"))->captureDefault();
  app.addOption("--max-sweeps", settings.max_sweeps, "NSGS sweeps per tick")
      ->check(cli::range(1, Limits::kMaxSweeps))->captureDefault();
  app.addOption("--tolerance", settings.tolerance, "NSGS tolerance")
      ->check(cli::finiteAbove(0.0, Limits::kMaxTolerance))->captureDefault();
  app.addOption("--nsgs-anderson-depth", settings.anderson_depth,
                 "NSGS Anderson acceleration over this many past sweeps (0: off)")
      ->check(cli::range(0, shared::kMaxAndersonDepth))->captureDefault();
  std::string local_model = "automatic";
  app.addOption("--local-model", local_model,
                 "Local model the tick solves: full (re-solve every tick), linearized (the "
                 "snapshot's solution linearised in the device pose, re-solve where it does not "
                 "hold) or automatic (linearized from the size where a re-solve costs more)")
      ->check(cli::isMember({"full", "linearized", "automatic"}))->captureDefault();
  app.addFlag("--render-torque", settings.render_torque, "Render torques too");
  // the device -> scene workspace mapping (docs/design.md, "Workspace mapping")
  shared::WorkspaceMappingParams workspace;
  std::vector<double> workspace_offset, workspace_rotation;
  bool clutch_key = false;
  app.addOption("--workspace-scale", workspace.scale, "Scene metres per device metre")
      ->check(cli::finiteRange(shared::WorkspaceMappingLimits::kMinScale,
                                  shared::WorkspaceMappingLimits::kMaxScale))
      ->captureDefault();
  app.addOption("--workspace-offset", workspace_offset,
                 "Scene position of the device origin x,y,z [m]")
      ->delimiter(',')->expected(3);
  app.addOption("--workspace-rotation", workspace_rotation,
                 "Device -> scene rotation, unit quaternion w,x,y,z")
      ->delimiter(',')->expected(4);
  app.addOption("--clutch-button", workspace.clutch_button,
                 "Device button (bit) that clutches; -1: none")
      ->check(cli::range(-1, shared::WorkspaceMappingLimits::kMaxButton))->captureDefault();
  std::vector<std::string> workspace_options;
  app.addOption("--workspace-option", workspace_options,
                 "Device I's own mapping field, I:key=value (repeatable; keys scale, "
                 "offset=x,y,z, rotation=w,x,y,z, clutch_button; overrides --workspace-* for "
                 "device I only)");
  app.addFlag("--clutch-key", clutch_key,
               "On a terminal, the space bar toggles the clutch (devices without a button)");
  app.addOption("--duration", duration_s,
                 "Stop after S seconds; 0 (the default): run until SIGINT, SIGTERM or SIGHUP")
      ->check(cli::finiteRange(0.0, 1e7, "s"));
  app.addFlag("--status", status, "Log a status line every second");
  app.addOption("--log-level", log_level, "trace, debug, info, warn, error")
      ->check(cli::isMember({"trace", "debug", "info", "warn", "error"}));
  TACTUS_CLI_PARSE(app, argc, argv);
  spdlog::set_level(spdlog::level::from_str(log_level));
  spdlog::set_pattern("[%H:%M:%S.%e] [haptic] [%^%l%$] %v");
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);
  std::signal(SIGHUP, onSignal);  // the terminal closed: stop cleanly, zero force

  if (device_names.empty()) device_names.emplace_back(device::kDefaultDevice);
  // the workspace mappings are usage: a bad one exits 2 before any device or segment exists
  std::vector<shared::WorkspaceMappingParams> workspaces;
  try {
    if (!workspace_offset.empty()) {
      workspace.offset_m = {workspace_offset[0], workspace_offset[1], workspace_offset[2]};
    }
    if (!workspace_rotation.empty()) {
      workspace.rotation_wxyz = {workspace_rotation[0], workspace_rotation[1],
                                 workspace_rotation[2], workspace_rotation[3]};
    }
    workspace.validate();
    workspaces = haptic::deviceWorkspaces(workspace, workspace_options, device_names.size());
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 2;
  }

  // two network bridges on one UDP port: the second could not bind it; say which before any
  // device opens (usage, like the mappings)
  try {
    const std::vector<device::DeviceConfig> configs =
        haptic::splitDeviceOptions(device_options, device_names.size());
    std::map<std::string, std::size_t> bridge_port;
    for (std::size_t i = 0; i < device_names.size(); ++i) {
      if (device_names[i] != "bridge") continue;
      const auto it = configs[i].find("port");
      const std::string port =
          it != configs[i].end() ? it->second : std::to_string(device::bridge::kDefaultPort);
      if (port == "0") continue;   // any free port
      if (const auto [at, fresh] = bridge_port.emplace(port, i); !fresh) {
        spdlog::error("devices {} and {} are both network bridges on UDP port {}: give each its "
                      "own, --device-option {}:port=N", at->second, i, port, i);
        return 2;
      }
    }
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 2;
  }

  try {
    shared::Segment::validateName(segment);
    const std::vector<device::DeviceConfig> configs =
        haptic::splitDeviceOptions(device_options, device_names.size());
    std::vector<std::unique_ptr<device::Device>> devs;
    std::vector<device::Device*> dev_ptrs;
    bool all_rotation = true;
    for (std::size_t i = 0; i < device_names.size(); ++i) {
      devs.push_back(device::loadDevice(device_names[i], configs[i]));
      devs.back()->open();
      devs.back()->calibrate();
      all_rotation = all_rotation && devs.back()->info().has_rotation;
      dev_ptrs.push_back(devs.back().get());
    }
    device::Device* dev = devs.front().get();
    settings.render_torque = settings.render_torque && all_rotation;
    settings.period_ns = static_cast<std::int64_t>(std::llround(1e9 / rate_hz));
    settings.solve_budget_ns = settings.period_ns * 4 / 10;
    settings.local_model = *haptic::parseLocalModelKind(local_model);   // CLI checked the name

    // validates the settings and combines each clamp with its device's own limit (one loop for
    // every device: docs/design.md, "Several instruments and devices")
    haptic::HapticLoop loop(dev_ptrs, settings);
    for (int i = 0; i < loop.deviceCount(); ++i) {
      const shared::WorkspaceMappingParams& w = workspaces[static_cast<std::size_t>(i)];
      loop.workspaceMapping(i).configure(w);
      spdlog::info("device {} workspace: {}", i, haptic::describeWorkspace(w));
    }
    std::optional<haptic::ClutchKey> key;
    if (clutch_key) key.emplace(loop.workspaceMapping());
    if (key && key->active()) spdlog::info("the space bar clutches device 0");
    if (loop.forceLimitN() < settings.max_force_n) {
      spdlog::info("clamping to the device's maximum force {} N", loop.forceLimitN());
    }
    for (int i = 0; i < loop.deviceCount(); ++i) {
      spdlog::info("device {} '{}' ({}), max force {} N, loop {} Hz", i,
                   device_names[static_cast<std::size_t>(i)],
                   devs[static_cast<std::size_t>(i)]->info().model, loop.forceLimitN(i), rate_hz);
    }
    spdlog::info("NSGS kernel: {} (TACTUS_NSGS_KERNEL=generic|avx2|avx512 picks one)",
                 shared::nsgsKernelName(shared::nsgsKernel()));

    haptic::Supervisor supervisor(loop, segment);
    if (core < 0) core = shared::availableCpuCount() - 1;

    std::atomic<bool> loop_stop{false};
    std::atomic<bool> rt_done{false};
    std::string rt_summary;
    std::atomic<bool> rt_ready{false};
    std::exception_ptr rt_error;
    for (auto& d : devs) d->enableForces(true);
    std::thread rt([&] {
      try {
        rt_summary = shared::setupRealtimeThread(
            core, priority,
            require_rt ? shared::RealtimeConfig::kEnforce : shared::RealtimeConfig::kIgnore);
      } catch (...) {
        rt_error = std::current_exception();
        rt_ready.store(true);
        return;
      }
      rt_ready.store(true);
      shared::PeriodicTimer timer(settings.period_ns);
      while (!loop_stop.load(std::memory_order_relaxed)) {
        const shared::TimerTick t = timer.wait();
        loop.tick(t.scheduled_ns, t.woken_ns);
      }
      // leave every device with zero force (the forces faded out before the stop)
      for (auto& d : devs) (void)d->write(device::DeviceCommand{});
      rt_done.store(true);
    });
    while (!rt_ready.load()) std::this_thread::sleep_for(std::chrono::milliseconds(1));
    if (rt_error) {
      rt.join();
      std::rethrow_exception(rt_error);
    }
    if (rt_summary.empty()) {
      spdlog::info("real-time: core {} pinned, SCHED_FIFO {}, memory locked", core, priority);
    } else {
      spdlog::warn("real-time set-up incomplete (running anyway; --require-rt to refuse): {}",
                   rt_summary);
    }

    // the network bridge's packet counters go into the status line
    device::Device* inner = dev;
    if (auto* rec = dynamic_cast<device::RecordingDevice*>(inner)) inner = &rec->inner();
    const auto* bridge = dynamic_cast<const device::BridgeDevice*>(inner);
    const std::int64_t t0 = shared::monotonicNs();
    std::int64_t last_status = t0;
    std::uint64_t last_ticks = 0;
    std::exception_ptr fatal;
    while (!g_stop.load()) {
      try {
        supervisor.poll();
      } catch (...) {
        fatal = std::current_exception();
        break;
      }
      supervisor.drainEvents();
      const std::int64_t now = shared::monotonicNs();
      if (duration_s > 0.0 && now - t0 > static_cast<std::int64_t>(duration_s * 1e9)) break;
      if (status && now - last_status >= 1'000'000'000) {
        const std::uint64_t ticks = loop.counters().ticks.load();
        spdlog::info("{:.0f} Hz, {} snapshots, {} stale ticks, {} clamped, segment {}",
                     1e9 * static_cast<double>(ticks - last_ticks) /
                         static_cast<double>(now - last_status),
                     loop.counters().snapshots_taken.load(), loop.counters().stale_ticks.load(),
                     loop.counters().clamped.load(), supervisor.attached() ? "attached" : "absent");
        if (bridge != nullptr) spdlog::info("{}", bridge->describeCounters());
        last_ticks = ticks;
        last_status = now;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    spdlog::info("stopping: {} ticks", loop.counters().ticks.load());
    if (bridge != nullptr) spdlog::info("{}", bridge->describeCounters());
    // withdrawing the link fades every force out (over --fade-ms): wait for it, then stop ticking
    supervisor.detach();
    const auto fade_wait = std::chrono::milliseconds(static_cast<int>(settings.fade_ms) + 500);
    const auto fade_end = std::chrono::steady_clock::now() + fade_wait;
    while (!loop.allForcesZero() && std::chrono::steady_clock::now() < fade_end &&
           !rt_done.load()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
    loop_stop.store(true);
    // a device call that blocks (against its contract) would hold the real-time thread for
    // ever: wait a bounded grace period, then end the process without it
    const auto join_end = std::chrono::steady_clock::now() + std::chrono::milliseconds(kStopGraceMs);
    while (!rt_done.load() && std::chrono::steady_clock::now() < join_end) {
      supervisor.watchTick(shared::monotonicNs());
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    if (!rt_done.load()) {
      spdlog::error("the real-time thread is still stuck in a device call {} ms after the stop "
                    "request: exiting without it (the device keeps its last command unless its "
                    "driver stops it)", kStopGraceMs);
      spdlog::shutdown();
      std::_Exit(kExitStuck);
    }
    rt.join();
    loop.stopped();
    supervisor.drainEvents();
    for (auto& d : devs) {
      d->enableForces(false);
      d->close();
    }
    if (fatal) std::rethrow_exception(fatal);
    int code = 0;
    for (const auto& d : devs) {
      if (const auto* rec = dynamic_cast<const device::RecordingDevice*>(d.get());
          rec != nullptr && !rec->writeError().empty()) {
        spdlog::error("recording not saved: {}", rec->writeError());
        code = 1;
      }
    }
    return code;
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 1;
  }
}

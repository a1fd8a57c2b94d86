// tactus-bridge-client: the reference device side of the network bridge (device/README.md,
// "Network device bridge"). It plays the simulated hand (the `simulated` backend: its scripted
// set point or trajectory, and the mass-spring-damper the rendered force pushes) and speaks the
// bridge protocol to haptic_server's `bridge` backend: every period it sends the hand's state
// and applies the newest force command received. A vendor-SDK bridge has the same shape with
// the SDK's read/write in place of the simulated hand. When no valid command has arrived for
// --command-timeout-ms (haptic_server gone), it renders zero force until commands return.
#include "tactus/shared/cli.h"
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <string>
#include <vector>

#include "tactus/device/backends.h"
#include "tactus/device/bridge_protocol.h"
#include "tactus/shared/clock.h"
#include "tactus/shared/rt.h"

namespace {

std::atomic<bool> g_stop{false};
void onSignal(int) { g_stop.store(true); }

}  // namespace

int main(int argc, char** argv) {
  using namespace tactus;
  namespace bridge = device::bridge;
  namespace cli = tactus::shared::cli;
  cli::App app{"Tactus bridge client: plays the simulated hand over the network device bridge"};
  app.footer(
      "Example (beside scripts/start.sh --device bridge):\n"
      "  tactus-bridge-client --duration 20 --device-option trajectory=traj.csv");
  std::string server = "127.0.0.1";
  int port = bridge::kDefaultPort;
  double rate_hz = 1000.0;
  double duration_s = 0.0;
  std::vector<std::string> hand_options;
  bool status = false;
  double command_timeout_ms = 100.0;
  app.addOption("--server", server, "haptic_server's bridge address (IPv4)")
      ->captureDefault();
  app.addOption("--port", port, "its UDP port")->check(cli::range(1, 65535))
      ->captureDefault();
  app.addOption("--rate", rate_hz, "States sent per second")->check(cli::range(10.0, 10000.0))
      ->captureDefault();
  app.addOption("--duration", duration_s, "Stop after S seconds (0: until SIGINT/SIGTERM)")
      ->check(cli::range(0.0, 1e7));
  app.addOption("--device-option", hand_options,
                 "Option of the simulated hand key=value (device/README.md), repeatable");
  app.addFlag("--status", status, "Print the commands received once a second");
  app.addOption("--command-timeout-ms", command_timeout_ms,
                 "No valid command for this long (haptic_server gone, the network down): "
                 "render zero force until commands return")
      ->check(cli::range(1.0, 10'000.0))->captureDefault();
  TACTUS_CLI_PARSE(app, argc, argv);
  std::signal(SIGINT, onSignal);
  std::signal(SIGTERM, onSignal);

  try {
    device::DeviceConfig config;
    for (const auto& kv : hand_options) device::addDeviceOption(config, kv);
    device::SimulatedDevice hand(config);
    hand.open();
    hand.enableForces(true);

    sockaddr_in to{};
    to.sin_family = AF_INET;
    to.sin_port = htons(static_cast<std::uint16_t>(port));
    if (::inet_pton(AF_INET, server.c_str(), &to.sin_addr) != 1) {
      std::fprintf(stderr, "tactus-bridge-client: --server %s is not an IPv4 address\n",
                   server.c_str());
      return 2;
    }
    const int fd = ::socket(AF_INET, SOCK_DGRAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
    if (fd < 0 || ::connect(fd, reinterpret_cast<const sockaddr*>(&to), sizeof to) != 0) {
      std::perror("tactus-bridge-client: socket");
      return 1;
    }

    // no spinning before the deadline: the client shares the machine with haptic_server
    shared::PeriodicTimer timer(static_cast<std::int64_t>(1e9 / rate_hz), 0);
    const std::int64_t t0 = shared::monotonicNs();
    std::int64_t last_status = t0;
    std::uint64_t seq = 0, commands = 0, bad = 0, timeouts = 0;
    device::DeviceCommand command;
    std::int64_t last_command_ns = 0;   // 0: none yet
    bool timed_out = false;
    const auto timeout_ns = static_cast<std::int64_t>(command_timeout_ms * 1e6);
    unsigned char out[bridge::kStateBytes];
    unsigned char in[512];
    while (!g_stop.load()) {
      const shared::TimerTick tick = timer.wait();
      // the newest force command (the server sends one per tick)
      for (;;) {
        const ssize_t n = ::recv(fd, in, sizeof in, MSG_DONTWAIT | MSG_TRUNC);
        if (n < 0) break;
        bridge::Header h;
        std::uint64_t state_seq = 0;
        device::DeviceCommand c;
        if (static_cast<std::size_t>(n) <= sizeof in &&
            bridge::decodeCommand(in, static_cast<std::size_t>(n), &h, &c, &state_seq) ==
                bridge::DecodeStatus::kOk) {
          command = c;
          ++commands;
          last_command_ns = tick.woken_ns;
          timed_out = false;
        } else {
          ++bad;
        }
      }
      // the server went quiet: never keep rendering its last command
      if (last_command_ns != 0 && !timed_out && tick.woken_ns - last_command_ns > timeout_ns) {
        command = device::DeviceCommand{};
        timed_out = true;
        ++timeouts;
        std::printf("no command for %.0f ms: rendering zero force until commands return\n",
                    command_timeout_ms);
        std::fflush(stdout);
      }
      (void)hand.write(command);
      device::DeviceState state;
      if (hand.read(&state) == device::IoStatus::kOk) {
        const std::size_t size = bridge::encodeState(++seq, state.t_ns, state, out);
        (void)::send(fd, out, size, MSG_DONTWAIT | MSG_NOSIGNAL);   // a lost state is harmless
      }
      if (status && tick.woken_ns - last_status >= 1'000'000'000) {
        std::printf("%llu states sent, %llu commands (%llu bad), force %.3f %.3f %.3f N, "
                    "hand at %.4f %.4f %.4f m\n",
                    static_cast<unsigned long long>(seq),
                    static_cast<unsigned long long>(commands),
                    static_cast<unsigned long long>(bad),
                    command.force_n[0], command.force_n[1], command.force_n[2], state.pos_m[0],
                    state.pos_m[1], state.pos_m[2]);
        std::fflush(stdout);
        last_status = tick.woken_ns;
      }
      if (duration_s > 0.0 && tick.woken_ns - t0 > static_cast<std::int64_t>(duration_s * 1e9)) {
        break;
      }
    }
    ::close(fd);
    std::printf("tactus-bridge-client: %llu states sent, %llu commands received, %llu bad, "
                "%llu command timeouts\n",
                static_cast<unsigned long long>(seq), static_cast<unsigned long long>(commands),
                static_cast<unsigned long long>(bad), static_cast<unsigned long long>(timeouts));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tactus-bridge-client: %s\n", e.what());
    return 1;
  }
}

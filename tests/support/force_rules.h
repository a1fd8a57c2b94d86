#pragma once
// The written rules of the force at the hand (docs/reliability.md), checked on the commands a
// device really received: the CSV a RecordingDevice writes with record_commands=FILE (one row per
// write, in order). One checker for every fault case of tests/security/hand_fault_test.cpp:
//
//  1. every command is finite;
//  2. |F| never exceeds the clamp;
//  3. two consecutive commands never differ by more than the slew bound of one nominal period
//     (slew_n_per_s * period), however long the time between them;
//  4. a loss of the model fades the last rendered force over the fade: counted back from the
//     first zero command after the loss, the n commands before it (n = fade / period) are the
//     last rendered force H scaled by (1 - j / n), checked at 25, 50 and 75 % of the ramp;
//  5. zero after the fade;
//  6. re-engaged only below the engage threshold: with the hand still in the tissue (asking for
//     more than the threshold) after the loss, the force stays zero until the hand has left it,
//     whatever the model says meanwhile (a loss's `zero_until_ns`).

#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace tactus::test {

/// One command a device received.
struct RecordedCommand {
  std::int64_t t_ns = 0;
  std::array<double, 3> force_n{};
  std::array<double, 3> torque_nm{};
};

/// Reads a command recording (RecordingDevice, record_commands=FILE); empty when unreadable.
inline std::vector<RecordedCommand> readCommandRecording(const std::string& path) {
  std::vector<RecordedCommand> out;
  std::ifstream in(path);
  std::string line;
  if (!std::getline(in, line)) return out;   // header
  while (std::getline(in, line)) {
    RecordedCommand c;
    long long t = 0;
    if (std::sscanf(line.c_str(), "%lld,%lf,%lf,%lf,%lf,%lf,%lf", &t, &c.force_n[0],
                    &c.force_n[1], &c.force_n[2], &c.torque_nm[0], &c.torque_nm[1],
                    &c.torque_nm[2]) == 7) {
      c.t_ns = t;
      out.push_back(c);
    }
  }
  return out;
}

inline double norm3(const std::array<double, 3>& v) {
  return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
}

/// The settings the rules follow (haptic_server's: --max-force, --slew, --fade-ms, the rate).
struct ForceRules {
  double clamp_n = 8.0;
  double slew_n_per_s = 2000.0;
  double period_s = 1e-3;
  double fade_s = 0.1;
  double engage_threshold_n = 0.5;
  int fadeTicks() const { return static_cast<int>(std::lround(fade_s / period_s)); }
  double slewStepN() const { return slew_n_per_s * period_s; }
};

/// Index of the first command at or after t_ns (size() when none).
inline std::size_t commandAt(const std::vector<RecordedCommand>& c, std::int64_t t_ns) {
  std::size_t i = 0;
  while (i < c.size() && c[i].t_ns < t_ns) ++i;
  return i;
}

/// A loss of the model: `after_ns` a moment at which the force was steady and non-zero and
/// after which the model is lost (the loss itself may come later, e.g. once a watchdog expires);
/// the hand stays in the tissue until `zero_until_ns` (0: nothing is checked after the fade).
struct ModelLoss {
  std::int64_t after_ns = 0;
  std::int64_t zero_until_ns = 0;
};

/// Checks rules 1-3 on every command and rules 4-6 for each loss. Returns the violations, one
/// line each (empty: every rule holds).
inline std::vector<std::string> checkForceRules(const std::vector<RecordedCommand>& c,
                                                const ForceRules& rules,
                                                const std::vector<ModelLoss>& losses) {
  std::vector<std::string> bad;
  auto say = [&bad](std::size_t i, const std::string& what) {
    if (bad.size() < 20) bad.push_back("command " + std::to_string(i) + ": " + what);
  };
  std::array<double, 3> previous{};
  const double slew = rules.slewStepN();
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto& f = c[i].force_n;
    const auto& t = c[i].torque_nm;
    bool finite = true;
    for (int k = 0; k < 3; ++k) finite = finite && std::isfinite(f[k]) && std::isfinite(t[k]);
    if (!finite) {
      say(i, "not finite");
      continue;
    }
    if (norm3(f) > rules.clamp_n * (1.0 + 1e-12)) {
      say(i, "|F| = " + std::to_string(norm3(f)) + " N above the clamp");
    }
    const std::array<double, 3> d{f[0] - previous[0], f[1] - previous[1], f[2] - previous[2]};
    if (norm3(d) > slew * (1.0 + 1e-9) + 1e-12) {
      say(i, "a change of " + std::to_string(norm3(d)) + " N in one command (slew bound " +
                 std::to_string(slew) + " N per period)");
    }
    previous = f;
  }
  const int n = rules.fadeTicks();
  for (const ModelLoss& loss : losses) {
    const std::int64_t loss_ns = loss.after_ns;
    const std::size_t i0 = commandAt(c, loss_ns);
    if (i0 == 0 || i0 >= c.size()) {
      bad.push_back("loss at " + std::to_string(loss_ns) + ": outside the recording");
      continue;
    }
    if (norm3(c[i0 - 1].force_n) == 0.0) {
      bad.push_back("loss at command " + std::to_string(i0) +
                    ": no force was rendered before it (the case did not press)");
      continue;
    }
    std::size_t z = i0;
    while (z < c.size() && norm3(c[z].force_n) != 0.0) ++z;
    if (z == c.size()) {
      bad.push_back("loss at command " + std::to_string(i0) + ": the force never reached zero");
      continue;
    }
    if (z < static_cast<std::size_t>(n)) {
      bad.push_back("loss at command " + std::to_string(i0) + ": zero too early");
      continue;
    }
    const std::array<double, 3> held = c[z - static_cast<std::size_t>(n)].force_n;
    const double h = norm3(held);
    for (int percent : {25, 50, 75}) {
      const int j = n * percent / 100;
      const std::size_t at = z - static_cast<std::size_t>(n) + static_cast<std::size_t>(j);
      const double scale = 1.0 - static_cast<double>(j) / n;
      std::array<double, 3> off{};
      for (int k = 0; k < 3; ++k) off[k] = c[at].force_n[k] - held[k] * scale;
      if (!(h > 0.0) || norm3(off) > 1e-9 * h + 1e-12) {
        say(at, "at " + std::to_string(percent) + " % of the fade |F| = " +
                    std::to_string(norm3(c[at].force_n)) + " N, expected " +
                    std::to_string(h * scale) + " N (the held " + std::to_string(h) +
                    " N scaled down)");
      }
    }
    for (std::size_t k = z; k < c.size() && c[k].t_ns < loss.zero_until_ns; ++k) {
      if (norm3(c[k].force_n) != 0.0) {
        say(k, "|F| = " + std::to_string(norm3(c[k].force_n)) +
                   " N after the fade with the hand still in the tissue: re-engaged above the "
                   "engage threshold");
        break;
      }
    }
  }
  return bad;
}

/// The violations as one message for a test's failure output.
inline std::string describe(const std::vector<std::string>& violations) {
  std::ostringstream s;
  for (const auto& v : violations) s << "\n  " << v;
  return s.str();
}

}  // namespace tactus::test

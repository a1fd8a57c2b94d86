// Workspace mapping per device from the command line (workspace_options.h).
#include "tactus/haptic/workspace_options.h"

#include <fmt/format.h>

#include <cctype>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <string_view>

#include "tactus/shared/error.h"

namespace tactus::haptic {
namespace {

[[noreturn]] void refuse(const std::string& option, const std::string& why) {
  throw Error("--workspace-option '" + option + "': " + why);
}

// Comma-separated finite numbers, exactly `count` of them.
std::vector<double> numbers(const std::string& option, std::string_view text, std::size_t count) {
  std::vector<double> out;
  std::size_t start = 0;
  while (true) {
    const std::size_t comma = text.find(',', start);
    const std::string item(text.substr(start, comma == std::string_view::npos
                                                  ? std::string_view::npos
                                                  : comma - start));
    char* end = nullptr;
    errno = 0;
    const double v = item.empty() ? 0.0 : std::strtod(item.c_str(), &end);
    if (item.empty() || end != item.c_str() + item.size() || errno == ERANGE || !std::isfinite(v)) {
      refuse(option, "'" + item + "' is not a finite number");
    }
    out.push_back(v);
    if (comma == std::string_view::npos) break;
    start = comma + 1;
  }
  if (out.size() != count) {
    refuse(option, fmt::format("expects {} comma-separated number(s), got {}", count, out.size()));
  }
  return out;
}

}  // namespace

std::vector<shared::WorkspaceMappingParams> deviceWorkspaces(
    const shared::WorkspaceMappingParams& common, const std::vector<std::string>& options,
    std::size_t devices) {
  std::vector<shared::WorkspaceMappingParams> out(devices, common);
  for (const std::string& option : options) {
    std::size_t digits = 0;
    while (digits < option.size() && std::isdigit(static_cast<unsigned char>(option[digits]))) {
      ++digits;
    }
    const std::size_t eq = option.find('=');
    if (digits == 0 || digits >= option.size() || option[digits] != ':' ||
        eq == std::string::npos) {
      refuse(option, "expected I:key=value (I: the device, 0-based)");
    }
    if (digits > 3 || std::stoul(option.substr(0, digits)) >= devices) {
      refuse(option, fmt::format("no such device: {} device(s) are given (--device per device)",
                                 devices));
    }
    shared::WorkspaceMappingParams& w = out[std::stoul(option.substr(0, digits))];
    const std::string key = option.substr(digits + 1, eq - digits - 1);
    const std::string_view value = std::string_view(option).substr(eq + 1);
    if (key == "scale") {
      w.scale = numbers(option, value, 1)[0];
    } else if (key == "offset") {
      const std::vector<double> v = numbers(option, value, 3);
      w.offset_m = {v[0], v[1], v[2]};
    } else if (key == "rotation") {
      const std::vector<double> v = numbers(option, value, 4);
      w.rotation_wxyz = {v[0], v[1], v[2], v[3]};
    } else if (key == "clutch_button") {
      const double b = numbers(option, value, 1)[0];
      if (b != std::floor(b) || std::abs(b) > 1e3) refuse(option, "must be an integer");
      w.clutch_button = static_cast<int>(b);
    } else {
      refuse(option, "unknown key '" + key + "' (scale, offset, rotation, clutch_button)");
    }
  }
  for (std::size_t i = 0; i < out.size(); ++i) {
    const std::string problem = out[i].problem();
    if (!problem.empty()) {
      throw Error(fmt::format("device {}: {} (--workspace-* and --workspace-option)", i, problem));
    }
  }
  return out;
}

std::string describeWorkspace(const shared::WorkspaceMappingParams& w) {
  return fmt::format("scale {}, offset ({}, {}, {}) m, rotation ({}, {}, {}, {}), clutch button {}",
                     w.scale, w.offset_m[0], w.offset_m[1], w.offset_m[2], w.rotation_wxyz[0],
                     w.rotation_wxyz[1], w.rotation_wxyz[2], w.rotation_wxyz[3],
                     w.clutch_button);
}

}  // namespace tactus::haptic

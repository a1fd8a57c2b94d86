#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <iomanip>
#include <sstream>

#include "tactus/device/backends.h"

namespace tactus::device {

namespace {
std::string show(double v) {
  std::ostringstream os;
  os << std::setprecision(17) << v;
  return os.str();
}

// Parses a full-string double or throws naming the option.
double parseNumber(const std::string& backend, const std::string& key, const std::string& text) {
  const char* begin = text.c_str();
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(begin, &end);
  if (text.empty() || end == begin || *end != '\0' || errno == ERANGE || !std::isfinite(v)) {
    throw DeviceError("device '" + backend + "': option " + key + "=" + text +
                      " is not a finite number");
  }
  return v;
}
}  // namespace

void addDeviceOption(DeviceConfig& config, std::string_view key_equals_value) {
  const auto eq = key_equals_value.find('=');
  if (eq == std::string_view::npos || eq == 0) {
    throw DeviceError("device option '" + std::string(key_equals_value) +
                      "' must look like key=value (e.g. --device-option mass=0.5)");
  }
  const std::string key(key_equals_value.substr(0, eq));
  config[key] = std::string(key_equals_value.substr(eq + 1));
}

OptionReader::OptionReader(std::string backend, const DeviceConfig& config)
    : backend_(std::move(backend)), config_(config) {}

bool OptionReader::has(const std::string& key) const { return config_.count(key) != 0; }

double OptionReader::number(const std::string& key, double fallback) {
  known_.insert(key);
  const auto it = config_.find(key);
  return it == config_.end() ? fallback : parseNumber(backend_, key, it->second);
}

double OptionReader::number(const std::string& key, double fallback, double lo, double hi) {
  const double v = number(key, fallback);
  if (!(v >= lo && v <= hi)) {
    const auto it = config_.find(key);
    throw DeviceError("device '" + backend_ + "': option " + key + "=" +
                      (it != config_.end() ? it->second : show(v)) +
                      " must be in [" + show(lo) + ", " + show(hi) + "]");
  }
  return v;
}

std::array<double, 3> OptionReader::vec3(const std::string& key,
                                         const std::array<double, 3>& fallback, double max_abs) {
  const std::array<double, 3> v = vec3(key, fallback);
  for (double x : v) {
    if (!(std::abs(x) <= max_abs)) {
      throw DeviceError("device '" + backend_ + "': option " + key + " component " + show(x) +
                        " must be in [" + show(-max_abs) + ", " + show(max_abs) + "]");
    }
  }
  return v;
}

std::array<double, 3> OptionReader::vec3(const std::string& key,
                                         const std::array<double, 3>& fallback) {
  known_.insert(key);
  const auto it = config_.find(key);
  if (it == config_.end()) return fallback;
  std::array<double, 3> v{};
  std::string rest = it->second;
  for (int i = 0; i < 3; ++i) {
    const auto comma = rest.find(',');
    if ((i < 2) != (comma != std::string::npos)) {
      throw DeviceError("device '" + backend_ + "': option " + key + "=" + it->second +
                        " must be three comma-separated numbers x,y,z");
    }
    v[static_cast<std::size_t>(i)] = parseNumber(backend_, key, rest.substr(0, comma));
    rest = comma == std::string::npos ? "" : rest.substr(comma + 1);
  }
  return v;
}

std::string OptionReader::text(const std::string& key, const std::string& fallback) {
  known_.insert(key);
  const auto it = config_.find(key);
  return it == config_.end() ? fallback : it->second;
}

bool OptionReader::flag(const std::string& key, bool fallback) {
  known_.insert(key);
  const auto it = config_.find(key);
  if (it == config_.end()) return fallback;
  const std::string& v = it->second;
  if (v == "1" || v == "true" || v == "yes" || v == "on") return true;
  if (v == "0" || v == "false" || v == "no" || v == "off") return false;
  throw DeviceError("device '" + backend_ + "': option " + key + "=" + v +
                    " must be true or false");
}

void OptionReader::rejectUnknown() const {
  for (const auto& [key, value] : config_) {
    if (known_.count(key) != 0) continue;
    std::string list;
    for (const auto& k : known_) list += (list.empty() ? "" : ", ") + k;
    throw DeviceError("device '" + backend_ + "': unknown option '" + key + "' (known: " +
                      (list.empty() ? std::string("none") : list) + ", and record)");
  }
}

}  // namespace tactus::device

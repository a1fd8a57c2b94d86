// Command-line validators that reject what CLI11's own range checks let through.
//
// CLI::Range(lo, hi) compares with < and >, so "nan" passes every range check, and "inf" passes an
// open upper bound. Every numeric option that can reach a device, a timer or a loop bound goes
// through one of these instead: the text must parse completely as a finite number inside the range.
// Header-only; include it only from programs that already link CLI11 (the daemons and tools).
#pragma once

#include "tactus/shared/cli.h"

#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <string>

namespace tactus::shared {

/// Parses `text` as a finite double; false when it is empty, has trailing characters, overflows
/// or is NaN/Inf.
inline bool parseFiniteDouble(const std::string& text, double& value) {
  if (text.empty()) return false;
  errno = 0;
  char* end = nullptr;
  value = std::strtod(text.c_str(), &end);
  return errno == 0 && end == text.c_str() + text.size() && std::isfinite(value);
}

/// Shortest readable text of a bound (1e+06, 0.05, 4000), for messages.
inline std::string boundText(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%g", v);
  return buf;
}

/// Finite and within the interval from lo to hi; `open_low` excludes lo itself.
inline CLI::Validator finiteInterval(double lo, double hi, const std::string& unit, bool open_low) {
  const std::string range = (open_low ? "(" : "[") + boundText(lo) + ", " + boundText(hi) + "]" +
                            (unit.empty() ? "" : " " + unit);
  return CLI::Validator(
      [lo, hi, open_low, range](std::string& text) -> std::string {
        double value = 0.0;
        if (!parseFiniteDouble(text, value)) return "must be a finite number (got '" + text + "')";
        const bool below = open_low ? !(value > lo) : value < lo;
        if (below || value > hi) return "must be in " + range + " (got " + text + ")";
        return {};
      },
      "FINITE in " + range);
}

/// Finite and within [lo, hi]. `unit` names the unit in the help text (for example "N").
inline CLI::Validator finiteRange(double lo, double hi, const std::string& unit = "") {
  return finiteInterval(lo, hi, unit, false);
}

/// Finite, strictly greater than lo and at most hi.
inline CLI::Validator finiteAbove(double lo, double hi, const std::string& unit = "") {
  return finiteInterval(lo, hi, unit, true);
}

}  // namespace tactus::shared

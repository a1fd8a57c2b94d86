#pragma once
// Fuzz target for the replay CSV trajectory reader, shared by the libFuzzer harness
// (trajectory_fuzz.cpp) and the regression test (tests/unit/device).
//
// Contract checked: Trajectory::parseCsv returns a trajectory or throws tactus::Error
// (DeviceError). An accepted trajectory has strictly increasing times and unit quaternions, and
// sample() gives a finite unit quaternion anywhere; a violation escapes as std::logic_error.

#include <cmath>
#include <stdexcept>
#include <string>

#include "tactus/device/backends.h"
#include "tactus/shared/error.h"

namespace tactus::fuzz {

/// Feeds `bytes` to Trajectory::parseCsv, then samples the result before, inside and after it.
/// Returns true when accepted, false on a tactus::Error; throws std::logic_error on a bug.
inline bool feedTrajectory(const std::string& bytes) {
  device::Trajectory traj;
  try {
    traj = device::Trajectory::parseCsv(bytes, "fuzz.csv");
  } catch (const tactus::Error&) {
    return false;
  }
  const auto& pts = traj.points();
  if (pts.empty()) throw std::logic_error("trajectory accepted without rows");
  auto unit = [](const std::array<double, 4>& q) {
    const double n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    return std::isfinite(n) && std::abs(n - 1.0) < 1e-6;
  };
  for (std::size_t i = 0; i < pts.size(); ++i) {
    if (i > 0 && !(pts[i].t_s > pts[i - 1].t_s)) throw std::logic_error("times not increasing");
    if (!unit(pts[i].quat_wxyz)) throw std::logic_error("row quaternion not unit");
  }
  const double t0 = pts.front().t_s;
  const double d = traj.durationS();
  for (double f : {-0.5, 0.0, 0.25, 0.5, 0.999, 1.0, 1.5}) {
    device::DeviceState s{};
    traj.sample(t0 + f * d, &s);
    if (!unit(s.quat_wxyz)) throw std::logic_error("sampled quaternion not unit");
  }
  return true;
}

}  // namespace tactus::fuzz

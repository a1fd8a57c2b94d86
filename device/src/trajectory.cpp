#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <sstream>

#include "tactus/device/backends.h"
#include "tactus/shared/file_io.h"

namespace tactus::device {

namespace {
std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r");
  return s.substr(b, e - b + 1);
}
}  // namespace

Trajectory::Trajectory(std::vector<TrajectoryPoint> points) : points_(std::move(points)) {}

Trajectory Trajectory::loadCsv(const std::string& path) {
  std::string text;
  try {
    text = shared::readTextFileChecked(path, "trajectory CSV", shared::kMaxTrajectoryCsvBytes);
  } catch (const FileError& e) {
    throw DeviceError("cannot read trajectory '" + shared::printable(path, 256) + "': " + e.what());
  }
  return parseCsv(text, shared::printable(path, 256));
}

Trajectory Trajectory::parseCsv(const std::string& text, const std::string& origin) {
  static const char* kColumns[9] = {"t_s", "x", "y", "z", "qw", "qx", "qy", "qz", "gripper"};
  std::vector<TrajectoryPoint> pts;
  std::istringstream in(text);
  std::string line;
  int line_no = 0;
  bool header_seen = false;
  while (std::getline(in, line)) {
    ++line_no;
    if ((line_no & 0xFFFF) == 0) shared::throwIfStopRequested("reading a trajectory");
    const std::string t = trim(line);
    if (t.empty() || t[0] == '#') continue;
    auto where = [&](int col) {
      std::string w = origin;
      w += ':';
      w += std::to_string(line_no);
      if (col > 0) {
        w += ':';
        w += std::to_string(col);
      }
      return w;
    };
    // header: exactly the nine column names
    if (!header_seen) {
      std::string compact;
      for (char c : t) {
        if (c != ' ' && c != '\t') compact += c;
      }
      if (compact != kCsvHeader) {
        throw DeviceError(where(0) + ": expected the header line '" + std::string(kCsvHeader) +
                          "', found '" + shared::printable(t) + "'");
      }
      header_seen = true;
      continue;
    }
    double v[9];
    std::size_t pos = 0;
    for (int i = 0; i < 9; ++i) {
      const std::size_t comma = t.find(',', pos);
      if ((i < 8) != (comma != std::string::npos)) {
        throw DeviceError(where(0) + ": expected 9 comma-separated values (" +
                          std::string(kCsvHeader) + ")");
      }
      const std::string field = trim(t.substr(pos, comma == std::string::npos ? std::string::npos
                                                                                : comma - pos));
      char* end = nullptr;
      v[i] = std::strtod(field.c_str(), &end);
      if (field.empty() || *end != '\0' || !std::isfinite(v[i])) {
        throw DeviceError(where(static_cast<int>(pos) + 1) + ": column " + kColumns[i] + ": '" +
                          shared::printable(field) + "' is not a finite number");
      }
      pos = comma + 1;
    }
    TrajectoryPoint p;
    p.t_s = v[0];
    p.pos_m = {v[1], v[2], v[3]};
    // norm scaled by the largest component, so that huge finite values do not overflow to inf
    const double big = std::max({std::abs(v[4]), std::abs(v[5]), std::abs(v[6]), std::abs(v[7])});
    double q[4] = {0.0, 0.0, 0.0, 0.0};
    for (int k = 0; k < 4 && big > 0.0; ++k) q[k] = v[4 + k] / big;
    const double n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (big * n < 1e-9) throw DeviceError(where(0) + ": quaternion qw,qx,qy,qz is zero");
    p.quat_wxyz = {q[0] / n, q[1] / n, q[2] / n, q[3] / n};
    p.gripper_rad = v[8];
    if (!pts.empty() && p.t_s <= pts.back().t_s) {
      throw DeviceError(where(1) + ": t_s " + std::to_string(p.t_s) +
                        " is not after the previous row's " + std::to_string(pts.back().t_s) +
                        " (times must increase)");
    }
    pts.push_back(p);
  }
  if (!header_seen) {
    throw DeviceError(origin + ": empty trajectory (expected the header '" +
                      std::string(kCsvHeader) + "' and at least one row)");
  }
  if (pts.empty()) throw DeviceError(origin + ": trajectory has a header but no rows");
  return Trajectory(std::move(pts));
}

double Trajectory::durationS() const noexcept {
  return points_.empty() ? 0.0 : points_.back().t_s - points_.front().t_s;
}

void Trajectory::sample(double t_s, DeviceState* out) const noexcept {
  if (points_.empty()) return;
  const TrajectoryPoint& first = points_.front();
  const TrajectoryPoint& last = points_.back();
  out->vel_mps = {0.0, 0.0, 0.0};
  out->angvel_radps = {0.0, 0.0, 0.0};
  if (points_.size() == 1 || t_s <= first.t_s || t_s >= last.t_s) {
    const TrajectoryPoint& p = (t_s <= first.t_s) ? first : last;
    out->pos_m = p.pos_m;
    out->quat_wxyz = p.quat_wxyz;
    out->gripper_rad = p.gripper_rad;
    return;
  }
  // segment [a, b] with a.t <= t < b.t
  const auto it = std::upper_bound(points_.begin(), points_.end(), t_s,
                                   [](double t, const TrajectoryPoint& p) { return t < p.t_s; });
  const TrajectoryPoint& b = *it;
  const TrajectoryPoint& a = *(it - 1);
  const double dt = b.t_s - a.t_s;
  const double s = (t_s - a.t_s) / dt;
  for (std::size_t i = 0; i < 3; ++i) {
    out->pos_m[i] = a.pos_m[i] + s * (b.pos_m[i] - a.pos_m[i]);
    out->vel_mps[i] = (b.pos_m[i] - a.pos_m[i]) / dt;
  }
  // nlerp along the shorter arc
  double dot = 0.0;
  for (std::size_t i = 0; i < 4; ++i) dot += a.quat_wxyz[i] * b.quat_wxyz[i];
  const double sign = dot < 0.0 ? -1.0 : 1.0;
  double norm = 0.0;
  std::array<double, 4> q{};
  for (std::size_t i = 0; i < 4; ++i) {
    q[i] = (1.0 - s) * a.quat_wxyz[i] + s * sign * b.quat_wxyz[i];
    norm += q[i] * q[i];
  }
  norm = std::sqrt(norm);
  for (std::size_t i = 0; i < 4; ++i) out->quat_wxyz[i] = q[i] / norm;
  // world angular velocity of the segment: w = 2 vec(qb * conj(qa)) / dt (small rotation)
  const auto& qa = a.quat_wxyz;
  std::array<double, 4> qb = b.quat_wxyz;
  for (auto& c : qb) c *= sign;
  const double cw = qa[0], cx = -qa[1], cy = -qa[2], cz = -qa[3];
  const double rx = qb[0] * cx + qb[1] * cw + qb[2] * cz - qb[3] * cy;
  const double ry = qb[0] * cy - qb[1] * cz + qb[2] * cw + qb[3] * cx;
  const double rz = qb[0] * cz + qb[1] * cy - qb[2] * cx + qb[3] * cw;
  out->angvel_radps = {2.0 * rx / dt, 2.0 * ry / dt, 2.0 * rz / dt};
  out->gripper_rad = a.gripper_rad + s * (b.gripper_rad - a.gripper_rad);
}

int Trajectory::formatRow(char* buf, std::size_t size, const TrajectoryPoint& p) noexcept {
  return std::snprintf(buf, size, "%.9f,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g,%.9g\n", p.t_s,
                       p.pos_m[0], p.pos_m[1], p.pos_m[2], p.quat_wxyz[0], p.quat_wxyz[1],
                       p.quat_wxyz[2], p.quat_wxyz[3], p.gripper_rad);
}

}  // namespace tactus::device

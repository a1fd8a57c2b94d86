// Range checks of the workspace mapping parameters.
#include "tactus/shared/workspace_mapping.h"

#include <Eigen/Geometry>
#include <cmath>
#include <iomanip>
#include <sstream>

#include "tactus/shared/error.h"

namespace tactus::shared {

std::string WorkspaceMappingParams::problem() const {
  using L = WorkspaceMappingLimits;
  std::ostringstream os;
  os.precision(17);
  if (!(std::isfinite(scale) && scale >= L::kMinScale && scale <= L::kMaxScale)) {
    os << "workspace scale = " << scale << " must be a finite number in [" << L::kMinScale << ", "
       << L::kMaxScale << "]";
    return os.str();
  }
  for (int i = 0; i < 3; ++i) {
    if (!(std::isfinite(offset_m[i]) && std::abs(offset_m[i]) <= L::kMaxOffsetM)) {
      os << "workspace offset[" << i << "] = " << offset_m[i] << " m must be finite and within +-"
         << L::kMaxOffsetM << " m";
      return os.str();
    }
  }
  double n2 = 0.0;
  for (double c : rotation_wxyz) {
    if (!std::isfinite(c)) {
      os << "workspace rotation must be 4 finite numbers (w, x, y, z)";
      return os.str();
    }
    n2 += c * c;
  }
  if (!(std::abs(std::sqrt(n2) - 1.0) <= L::kUnitTolerance)) {
    os << "workspace rotation must be a unit quaternion (w, x, y, z): its norm is "
       << std::sqrt(n2) << std::setprecision(3) << " (tolerance " << L::kUnitTolerance << ")";
    return os.str();
  }
  if (clutch_button < -1 || clutch_button > L::kMaxButton) {
    os << "clutch button = " << clutch_button << " must be -1 (none) or a button in [0, "
       << L::kMaxButton << "]";
    return os.str();
  }
  return {};
}

void WorkspaceMappingParams::validate() const {
  const std::string p = problem();
  if (!p.empty()) throw Error(p);
}

bool WorkspaceMappingParams::isIdentity() const noexcept {
  return scale == 1.0 && offset_m == std::array<double, 3>{} &&
         rotation_wxyz == std::array<double, 4>{1.0, 0.0, 0.0, 0.0} && clutch_button < 0;
}

void WorkspaceMappingParams::sceneToDevice(std::array<double, 3>& pos_m,
                                           std::array<double, 4>& quat_wxyz) const noexcept {
  const auto& r = rotation_wxyz;
  const Eigen::Quaterniond to_device =
      Eigen::Quaterniond(r[0], r[1], r[2], r[3]).normalized().conjugate();
  const Eigen::Vector3d p = to_device * (Eigen::Vector3d(pos_m[0], pos_m[1], pos_m[2]) -
                                         Eigen::Vector3d(offset_m[0], offset_m[1], offset_m[2])) /
                            scale;
  const Eigen::Quaterniond q =
      (to_device * Eigen::Quaterniond(quat_wxyz[0], quat_wxyz[1], quat_wxyz[2], quat_wxyz[3]))
          .normalized();
  pos_m = {p.x(), p.y(), p.z()};
  quat_wxyz = {q.w(), q.x(), q.y(), q.z()};
}

}  // namespace tactus::shared

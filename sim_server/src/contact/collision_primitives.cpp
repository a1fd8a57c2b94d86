// Collision geometry primitives: closest points on a triangle and a segment, and the slab test
// of a segment against a grown box (the capsule queries' broad phase).

#include <algorithm>
#include <cmath>
#include <utility>

#include "collision_impl.h"

namespace tactus::sim::collision_detail {

// Closest point of p on triangle (a, b, c) by Voronoi regions (Ericson, Real-Time Collision
// Detection 5.1.5); vertex/edge regions carry exact zero weights.
ClosestPoint closestOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                               const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return {a, {1, 0, 0}, kVertex0};
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return {b, {0, 1, 0}, kVertex0 + 1};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);
    return {a + v * ab, {1.0 - v, v, 0.0}, kEdge0};
  }
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return {c, {0, 0, 1}, kVertex0 + 2};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return {a + w * ac, {1.0 - w, 0.0, w}, kEdge0 + 2};
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {b + w * (c - b), {0.0, 1.0 - w, w}, kEdge0 + 1};
  }
  const double sum = va + vb + vc;
  if (!(sum > 0.0)) return {a, {1, 0, 0}, kVertex0};   // degenerate triangle
  const double v = vb / sum, w = vc / sum;
  return {a + v * ab + w * ac, {1.0 - v - w, v, w}, kFace};
}

// Parameter in [0, 1] of the closest point of p on segment a..b.
double closestOnSegment(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                        const Eigen::Vector3d& b) {
  const Eigen::Vector3d ab = b - a;
  const double len2 = ab.squaredNorm();
  if (len2 <= 0.0) return 0.0;
  return std::clamp((p - a).dot(ab) / len2, 0.0, 1.0);
}

// Segment a..b against a box grown by `radius` on every side (slab test): conservative for the
// capsule of that radius.
bool segmentHitsGrownBox(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double radius,
                         const Box& box) {
  double t0 = 0.0, t1 = 1.0;
  const Eigen::Vector3d d = b - a;
  for (int i = 0; i < 3; ++i) {
    const double lo = box.min()[i] - radius, hi = box.max()[i] + radius;
    if (std::abs(d[i]) < 1e-300) {
      if (a[i] < lo || a[i] > hi) return false;
      continue;
    }
    double ta = (lo - a[i]) / d[i], tb = (hi - a[i]) / d[i];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

}  // namespace tactus::sim::collision_detail

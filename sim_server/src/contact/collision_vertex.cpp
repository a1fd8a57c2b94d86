// Collision, narrow phase: the tissue's surface vertices against capsule and pad features.

#include <algorithm>
#include <cmath>

#include "collision_impl.h"

namespace tactus::sim {

using namespace collision_detail;

void Collision::Impl::vertexCapsule(const ToolFeature& f, const shared::Pose& tool_pose) {
  const double cd = options.contact_distance_m;
  const double reach = f.radius_m + cd + options.alarm_distance_m;
  auto visit = [&](int prim) {
    ++stats.candidates;
    const int node = surface.nodes[prim];
    const Eigen::Vector3d v = pos(node);
    const double t = closestOnSegment(v, f.a_m, f.b_m);
    if (f.skip_cap_a && t <= 0.0) return;
    const Eigen::Vector3d axis_point = f.a_m + t * (f.b_m - f.a_m);
    const Eigen::Vector3d diff = axis_point - v;
    const double d = diff.norm();
    if (d > reach) return;
    const Eigen::Vector3d nv = vertexNormal(node);
    const Eigen::Vector3d n = d > kTinyDistance_m ? Eigen::Vector3d(diff / d) : nv;
    if (!(n.dot(nv) > 0.0)) return;   // vertex does not face the tool
    const double gap = d - f.radius_m - cd;
    if (gap > options.alarm_distance_m) return;
    emit(ContactKind::kVertexCapsule, f, node, {node, -1, -1}, {1.0, 0.0, 0.0}, v,
         axis_point - f.radius_m * n, n, gap, tool_pose);
  };
  if (options.brute_force) {
    for (int i = 0; i < static_cast<int>(surface.nodes.size()); ++i) visit(i);
  } else {
    vertex_tree.query(
        [&](const Box& box) { return segmentHitsGrownBox(f.a_m, f.b_m, reach, box); }, visit);
  }
}

// Tissue vertices against a pad (collision.h (c)): over the rectangle the normal is the pad's
// face normal on the side the vertex touched at the previous detect() (so a vertex pushed past
// the pad's mid-plane is pushed back, not through); at the rim the radial normal of the
// rounded edge, as for a capsule.
void Collision::Impl::vertexPad(const ToolFeature& f, const shared::Pose& tool_pose) {
  const double cd = options.contact_distance_m;
  const double reach = f.radius_m + cd + options.alarm_distance_m;
  const Eigen::Vector3d len = f.b_m - f.a_m;
  const double len2 = len.squaredNorm(), hw2 = f.half_width_m.squaredNorm();
  if (!(len2 > 0.0) || !(hw2 > 0.0)) return;
  const Eigen::Vector3d face_n = len.cross(f.half_width_m).normalized();
  const std::size_t slot_base = static_cast<std::size_t>(f.part & 1) * static_cast<std::size_t>(node_count);
  auto visit = [&](int prim) {
    ++stats.candidates;
    const int node = surface.nodes[prim];
    const Eigen::Vector3d v = pos(node);
    const Eigen::Vector3d rel = v - f.a_m;
    const double t = rel.dot(len) / len2, x = rel.dot(f.half_width_m) / hw2;
    const double height = rel.dot(face_n);   // signed, from the mid-plane
    const std::size_t slot = slot_base + static_cast<std::size_t>(node);
    const bool remembered = pad_side_detect[slot] == detect_count - 1;
    Eigen::Vector3d n;
    double gap;
    Eigen::Vector3d tool_point;
    if (t >= 0.0 && t <= 1.0 && std::abs(x) <= 1.0) {
      const double side = remembered ? pad_side[slot] : (height >= 0.0 ? 1.0 : -1.0);
      gap = side * height - f.radius_m - cd;
      if (gap > options.alarm_distance_m) return;
      n = -side * face_n;
      if (!remembered && !(n.dot(vertexNormal(node)) > 0.0)) return;   // not facing the pad
      tool_point = v - height * face_n - f.radius_m * n;
    } else {
      const Eigen::Vector3d c = f.a_m + std::clamp(t, 0.0, 1.0) * len +
                                std::clamp(x, -1.0, 1.0) * f.half_width_m;
      const Eigen::Vector3d diff = c - v;
      const double d = diff.norm();
      if (d > reach) return;
      const Eigen::Vector3d nv = vertexNormal(node);
      n = d > kTinyDistance_m ? Eigen::Vector3d(diff / d) : nv;
      if (!(n.dot(nv) > 0.0)) return;
      gap = d - f.radius_m - cd;
      if (gap > options.alarm_distance_m) return;
      tool_point = c - f.radius_m * n;
    }
    pad_side[slot] = static_cast<std::int8_t>(n.dot(face_n) < 0.0 ? 1 : -1);
    pad_side_detect[slot] = detect_count;
    emit(ContactKind::kVertexCapsule, f, node, {node, -1, -1}, {1.0, 0.0, 0.0}, v, tool_point,
         n, gap, tool_pose);
  };
  const double grown = reach + std::sqrt(hw2);
  if (options.brute_force) {
    for (int i = 0; i < static_cast<int>(surface.nodes.size()); ++i) visit(i);
  } else {
    vertex_tree.query(
        [&](const Box& box) { return segmentHitsGrownBox(f.a_m, f.b_m, grown, box); }, visit);
  }
}

}  // namespace tactus::sim

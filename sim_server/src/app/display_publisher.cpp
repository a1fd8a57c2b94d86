// Display frames for the live viewer.
#include "display_publisher.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "tactus/shared/clock.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {
namespace {

// Appends a tool's drawable primitives to the frame from index n (up to the frame's limit). A
// pad is drawn as three capsules along its length (both long edges and the middle); its sample
// spheres lie inside it and are not drawn.
void appendToolPrimitives(const Instrument& tool, shared::DisplayFrameHeader& h, int& n) {
  for (const ToolFeature& feat : tool.features()) {
    if (feat.face_only) continue;
    const int copies = feat.shape == FeatureShape::kPad ? 3 : 1;
    for (int c = 0; c < copies && n < shared::kMaxDisplayToolPrimitives; ++c) {
      const Eigen::Vector3d shift = static_cast<double>(c - copies / 2) * feat.half_width_m;
      shared::DisplayToolPrimitive& prim = h.tool_primitives[static_cast<std::size_t>(n++)];
      for (int k = 0; k < 3; ++k) {
        prim.a_m[k] = static_cast<float>(feat.a_m[k] + shift[k]);
        prim.b_m[k] = static_cast<float>(
            (feat.shape == FeatureShape::kSphere ? feat.a_m[k] : feat.b_m[k]) + shift[k]);
      }
      prim.radius_m = static_cast<float>(feat.radius_m);
      prim.part = static_cast<std::uint32_t>(feat.part);
    }
  }
}

}  // namespace

DisplayLink::DisplayLink(const std::string& segment_name, const Simulation& sim,
                         const DisplayOptions& options)
    : options_(options) {
  segment_.emplace(shared::Segment::open(segment_name, shared::Access::kReadWrite));
  publisher_ = segment_->displayPublisher();
  if (!publisher_.attached()) {
    spdlog::warn("segment '{}' has no display part: the live view is off", segment_name);
    return;
  }
  // surface of every tissue, concatenated: vertex ranges per tissue, triangles re-indexed
  std::vector<std::uint32_t> triangles;
  std::vector<std::int32_t> tissue_begin;
  for (int t = 0; t < sim.tissueCount(); ++t) {
    const FemBody& body = sim.tissue(t);
    const SurfaceMesh surface = extractSurface(body.mesh());
    TissueMap map;
    map.nodes = surface.nodes;
    std::vector<int> local(static_cast<std::size_t>(body.nodeCount()), -1);
    for (std::size_t i = 0; i < map.nodes.size(); ++i) local[map.nodes[i]] = static_cast<int>(i);
    tissue_begin.push_back(vertex_count_);
    for (const auto& tri : surface.triangles) {
      for (int k = 0; k < 3; ++k) {
        triangles.push_back(static_cast<std::uint32_t>(vertex_count_ + local[tri[k]]));
      }
    }
    // tets incident to each surface vertex (for the vertex stress average)
    const auto& tets = body.mesh().tets;
    std::vector<int> count(map.nodes.size() + 1, 0);
    for (const auto& tet : tets) {
      for (int node : tet) {
        if (local[node] >= 0) ++count[local[node] + 1];
      }
    }
    for (std::size_t i = 1; i < count.size(); ++i) count[i] += count[i - 1];
    map.tet_begin = count;
    map.tets.assign(static_cast<std::size_t>(count.back()), 0);
    std::vector<int> fill(count.begin(), count.end() - 1);
    for (std::size_t e = 0; e < tets.size(); ++e) {
      for (int node : tets[e]) {
        if (local[node] >= 0) map.tets[fill[local[node]]++] = static_cast<int>(e);
      }
    }
    // rest edge matrices and the shear modulus for the vertex stress
    const Eigen::VectorXd& x0 = body.restPositions();
    map.dm_inv.resize(tets.size());
    for (std::size_t e = 0; e < tets.size(); ++e) {
      Eigen::Matrix3d dm;
      for (int k = 0; k < 3; ++k) {
        dm.col(k) = x0.segment<3>(3 * tets[e][k + 1]) - x0.segment<3>(3 * tets[e][0]);
      }
      map.dm_inv[e] = dm.inverse();
    }
    const auto& material = sim.spec().tissues[static_cast<std::size_t>(t)];
    map.mu = material.young_pa / (2.0 * (1.0 + material.poisson));
    map.corotational = material.law != MaterialLaw::kLinear;  // any law with rotations
    vertex_count_ += static_cast<int>(map.nodes.size());
    tissues_.push_back(std::move(map));
  }
  triangle_count_ = static_cast<int>(triangles.size() / 3);
  const shared::DisplayCapacity cap = publisher_.layout().capacity;
  if (vertex_count_ > cap.max_vertices || triangle_count_ > cap.max_triangles) {
    spdlog::warn("the tissue surfaces have {} vertices and {} triangles, the segment's display "
                 "part holds {} and {}: the live view is off (raise the display capacity where "
                 "the segment is created)",
                 vertex_count_, triangle_count_, cap.max_vertices, cap.max_triangles);
    return;
  }
  topology_generation_ =
      publisher_.writeTopology(vertex_count_, triangles.data(), triangle_count_,
                               tissue_begin.data(), static_cast<std::int32_t>(tissue_begin.size()));
  staging_.assign(publisher_.layout().frame_bytes / 8 + 1, 0);
  frame_ = shared::DisplayFrameRef(staging_.data(), publisher_.layout());
  stress_cache_.assign(static_cast<std::size_t>(vertex_count_), 0.0f);
  period_ns_ = options_.max_rate_hz > 0.0
                   ? static_cast<std::int64_t>(1e9 / options_.max_rate_hz) - 500'000
                   : 0;
  enabled_ = topology_generation_ != 0;
  spdlog::info("live view: {} surface vertices, {} triangles, up to {:.0f} frames/s into "
               "segment '{}'",
               vertex_count_, triangle_count_, options_.max_rate_hz, segment_name);
}

DisplayLink::~DisplayLink() {
  if (!enabled_) return;
  // a last frame telling viewers that this simulation is stopping
  frame_.header().seq = ++seq_;
  frame_.header().flags |= shared::kDisplayShuttingDown;
  publisher_.publish(frame_);
}

bool DisplayLink::publish(const Simulation& sim, const StepReport* report) {
  if (!enabled_) return false;
  const std::int64_t now = shared::monotonicNs();
  if (seq_ > 0 && now - last_ns_ < period_ns_) return false;
  return publishNow(sim, report);
}

void DisplayLink::fillStress(const Simulation& sim) {
  // von Mises per element, averaged over the tets around each surface vertex
  float* out = stress_cache_.data();
  double max_s = 0.0;
  for (int t = 0; t < sim.tissueCount(); ++t) {
    const FemBody& body = sim.tissue(t);
    const TissueMap& map = tissues_[static_cast<std::size_t>(t)];
    const auto& tets = body.mesh().tets;
    const Eigen::VectorXd& q = body.positions();
    const std::vector<Eigen::Matrix3d>& rot = body.elementRotations();
    const bool use_rot = map.corotational && rot.size() == tets.size();
    von_mises_.resize(tets.size());
    for (std::size_t e = 0; e < tets.size(); ++e) {
      Eigen::Matrix3d ds;
      for (int k = 0; k < 3; ++k) {
        ds.col(k) = q.segment<3>(3 * tets[e][k + 1]) - q.segment<3>(3 * tets[e][0]);
      }
      const Eigen::Matrix3d f = ds * map.dm_inv[e];
      const Eigen::Matrix3d fl = use_rot ? Eigen::Matrix3d(rot[e].transpose() * f) : f;
      const Eigen::Matrix3d eps = 0.5 * (fl + fl.transpose()) - Eigen::Matrix3d::Identity();
      const Eigen::Matrix3d dev = eps - eps.trace() / 3.0 * Eigen::Matrix3d::Identity();
      von_mises_[e] = 2.0 * map.mu * std::sqrt(1.5 * dev.squaredNorm());
    }
    for (std::size_t i = 0; i < map.nodes.size(); ++i) {
      const int b = map.tet_begin[i], e = map.tet_begin[i + 1];
      double sum = 0.0;
      for (int k = b; k < e; ++k) sum += von_mises_[map.tets[k]];
      const double s = e > b ? sum / (e - b) : 0.0;
      *out++ = static_cast<float>(s);
      max_s = std::max(max_s, s);
    }
  }
  max_stress_pa_ = max_s;
}

bool DisplayLink::publishNow(const Simulation& sim, const StepReport* report) {
  if (!enabled_) return false;
  const std::int64_t now = shared::monotonicNs();
  last_ns_ = now;
  shared::DisplayFrameHeader& h = frame_.header();
  h.seq = ++seq_;
  h.t_ns = now;
  h.step = static_cast<std::uint64_t>(sim.stepIndex());
  h.sim_time_s = sim.time();
  h.topology_generation = topology_generation_;
  h.vertex_count = vertex_count_;
  h.flags = 0;
  if (report != nullptr) {
    h.step_time_s = report->times.total_s;
    h.solver_sweeps = report->nsgs.sweeps;
    h.solver_error = report->nsgs.error;
  }

  // surface positions and displacement magnitudes
  float* pos = frame_.positions();
  float* disp = frame_.displacement();
  double max_d = 0.0;
  for (int t = 0; t < sim.tissueCount(); ++t) {
    const FemBody& body = sim.tissue(t);
    const Eigen::VectorXd& q = body.positions();
    const Eigen::VectorXd& q0 = body.restPositions();
    for (int node : tissues_[static_cast<std::size_t>(t)].nodes) {
      const Eigen::Vector3d x = q.segment<3>(3 * node);
      const double d = (x - q0.segment<3>(3 * node)).norm();
      *pos++ = static_cast<float>(x.x());
      *pos++ = static_cast<float>(x.y());
      *pos++ = static_cast<float>(x.z());
      *disp++ = static_cast<float>(d);
      max_d = std::max(max_d, d);
    }
  }
  h.max_displacement_m = max_d;
  if (options_.stress_every > 0 && (seq_ - 1) % static_cast<std::uint64_t>(options_.stress_every) == 0) {
    fillStress(sim);
  }
  if (options_.stress_every > 0) {
    std::copy(stress_cache_.begin(), stress_cache_.end(), frame_.stress());
    h.flags |= shared::kDisplayHasStress;
    h.max_stress_pa = max_stress_pa_;
  }

  // contacts: point on the tissue and the force the tool applies to it
  const ContactProblemData& p = sim.lastProblem();
  const int cap_c = publisher_.layout().capacity.max_contacts;
  const int nc = std::min(p.contacts, cap_c);
  if (p.contacts > cap_c) {
    h.flags |= shared::kDisplayTruncated;
    if (!warned_contacts_) {
      spdlog::warn("live view: {} contacts, only {} shown", p.contacts, cap_c);
      warned_contacts_ = true;
    }
  }
  float* cp = frame_.contactPoint();
  float* cf = frame_.contactForce();
  for (int i = 0; i < nc; ++i) {
    const int r = p.row_offset[static_cast<std::size_t>(i)];
    const int rows = p.row_offset[static_cast<std::size_t>(i) + 1] - r;
    Eigen::Vector3d f = p.f[r] * p.normal[static_cast<std::size_t>(i)];
    if (rows == 3) {
      f += p.f[r + 1] * p.tangent1[static_cast<std::size_t>(i)] +
           p.f[r + 2] * p.tangent2[static_cast<std::size_t>(i)];
    }
    // the normal points tissue -> tool: f acts on the tool, the tissue receives -f
    const Eigen::Vector3d& x = p.point_m[static_cast<std::size_t>(i)];
    for (int k = 0; k < 3; ++k) {
      *cp++ = static_cast<float>(x[k]);
      *cf++ = static_cast<float>(-f[k]);
    }
  }
  h.contact_count = nc;

  // the instrument: pose, jaw opening, primitives for drawing, rendered wrench
  h.tool_primitive_count = 0;
  h.tool_type = static_cast<std::uint32_t>(shared::DisplayTool::kNone);
  if (sim.hasInstrument()) {
    const Instrument* tool = const_cast<Simulation&>(sim).instrument();
    const shared::Pose& pose = tool->pose();
    h.flags |= shared::kDisplayHasTool;
    h.tool_type = static_cast<std::uint32_t>(tool->spec().kind == InstrumentKind::kGrasper
                                                 ? shared::DisplayTool::kGrasper
                                                 : shared::DisplayTool::kProbe);
    h.tool_pos_m = {pose.pos_m.x(), pose.pos_m.y(), pose.pos_m.z()};
    h.tool_quat_wxyz = {pose.rot.w(), pose.rot.x(), pose.rot.y(), pose.rot.z()};
    h.gripper_opening = tool->gripperOpening();
    h.gripper_angle_rad = tool->gripperOpening() * tool->spec().max_opening_rad;
    // every instrument's primitives (world coordinates) go into the one list, so the view draws
    // them all; the pose, type, opening and force are instrument 0's
    int n = 0;
    for (int t = 0; t < sim.instrumentCount(); ++t) appendToolPrimitives(sim.instrument(t), h, n);
    h.tool_primitive_count = n;
    const Eigen::Matrix<double, 6, 1> w = sim.renderedWrench();
    h.tool_force_n = {w[0], w[1], w[2]};
    h.tool_torque_nm = {w[3], w[4], w[5]};
  }
  return publisher_.publish(frame_);
}

}  // namespace tactus::sim

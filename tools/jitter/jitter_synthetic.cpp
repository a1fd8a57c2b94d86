// Synthetic snapshots, the scripted device and the in-process haptic loop of the jitter tool.
#include "jitter_synthetic.h"

#include <fmt/format.h>
#include <unistd.h>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>
#include <random>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"
#include "tactus/shared/nsgs.h"
#include "tactus/shared/rt.h"

namespace tactus::haptic::jitter {
namespace {

// god-object compliance seen through the contacts: (m/h^2 + b/h + k)^-1 for the liver scene's
// grasper (0.05 kg, 8 N s/m, 800 N/m, h = 10 ms) and its rotational counterpart
constexpr double kToolCompliance = 4.8e-4;   // m/N
constexpr double kToolRotCompliance = 0.24;  // rad/(N m)
// share of a device displacement the god object follows within one step: k / (m/h^2 + b/h + k)
constexpr double kTransmission = 0.38;

std::atomic<int> g_rig_counter{0};

}  // namespace

SyntheticProblem makeSyntheticProblem(const SyntheticProblemOptions& o) {
  const int nc = o.rows / 3;
  if (nc < 1) throw Error(fmt::format("synthetic problem: rows = {} (need at least 3)", o.rows));
  const int m = 3 * nc;
  SyntheticProblem p;
  p.contacts = nc;
  p.rows = m;
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);

  // contact points on a sphere cap (radius 6 cm, top at the origin), frames n (outward), t1, t2
  const double sphere_r = 0.06;
  const Eigen::Vector3d centre(0.0, 0.0, -sphere_r);
  const Eigen::Vector3d tool_origin(0.0, 0.0, 0.01);
  std::vector<Eigen::Vector3d> pts(nc);
  std::vector<Eigen::Matrix3d> frames(nc);  // columns n, t1, t2
  p.point_m.resize(3 * nc);
  p.normal.resize(3 * nc);
  p.tangent.resize(6 * nc);
  p.drift_phase.resize(nc);
  for (int c = 0; c < nc; ++c) {
    const double rad = o.patch_radius_m * std::sqrt(uni(rng));
    const double th = 2.0 * std::numbers::pi * uni(rng);
    const double x = rad * std::cos(th);
    const double y = rad * std::sin(th);
    const double z = std::sqrt(sphere_r * sphere_r - x * x - y * y) - sphere_r;
    pts[c] = Eigen::Vector3d(x, y, z);
    const Eigen::Vector3d n = (pts[c] - centre).normalized();
    const Eigen::Vector3d a =
        std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    const Eigen::Vector3d t1 = n.cross(a).normalized();
    const Eigen::Vector3d t2 = n.cross(t1);
    frames[c].col(0) = n;
    frames[c].col(1) = t1;
    frames[c].col(2) = t2;
    for (int k = 0; k < 3; ++k) {
      p.point_m[3 * c + k] = pts[c][k];
      p.normal[3 * c + k] = n[k];
      p.tangent[6 * c + k] = t1[k];
      p.tangent[6 * c + 3 + k] = t2[k];
    }
    p.drift_phase[c] = 2.0 * std::numbers::pi * uni(rng);
  }

  // per row: direction e and the tool twist sensitivity g = [e; r x e]
  std::vector<Eigen::Matrix<double, 6, 1>> g(m);
  for (int c = 0; c < nc; ++c) {
    const Eigen::Vector3d r = pts[c] - tool_origin;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d e = frames[c].col(k);
      g[3 * c + k].head<3>() = e;
      g[3 * c + k].tail<3>() = r.cross(e);
    }
  }
  Eigen::Matrix<double, 6, 1> tool_c;
  tool_c << kToolCompliance, kToolCompliance, kToolCompliance, kToolRotCompliance,
      kToolRotCompliance, kToolRotCompliance;

  // W = F^T (c_t K (x) I3) F + c_l I + G C_tool G^T
  // (the upper triangle is computed and mirrored: W is exactly symmetric, as the simulation's)
  p.W.assign(static_cast<std::size_t>(m) * m, 0.0);
  for (int i = 0; i < nc; ++i) {
    for (int j = i; j < nc; ++j) {
      const double kij =
          o.compliance_m_per_n * std::exp(-(pts[i] - pts[j]).norm() / o.kernel_length_m);
      const Eigen::Matrix3d block = kij * frames[i].transpose() * frames[j];
      for (int a = 0; a < 3; ++a) {
        for (int b = 0; b < 3; ++b) {
          const int r = 3 * i + a;
          const int s = 3 * j + b;
          if (s < r) continue;
          double w = block(a, b) + g[r].cwiseProduct(tool_c).dot(g[s]);
          if (r == s) w += o.local_compliance_m_per_n;
          p.W[static_cast<std::size_t>(r) * m + s] = w;
          p.W[static_cast<std::size_t>(s) * m + r] = w;
        }
      }
    }
  }

  // friction, identities, gaps: ~65 % penetrating (to -1 mm), the rest open (to +0.5 mm)
  p.row_offset.resize(nc + 1);
  p.contact_id.resize(nc);
  p.mu.resize(nc);
  p.delta_free.resize(m);
  p.J.resize(static_cast<std::size_t>(m) * 6);
  for (int c = 0; c < nc; ++c) {
    p.row_offset[c] = 3 * c;
    p.contact_id[c] = 1000 + static_cast<std::uint64_t>(c);
    p.mu[c] = o.mu + 0.2 * (uni(rng) - 0.5);
    p.delta_free[3 * c] = uni(rng) < 0.65 ? -1e-3 * uni(rng) : 5e-4 * uni(rng);
    p.delta_free[3 * c + 1] = 2e-4 * (uni(rng) - 0.5);
    p.delta_free[3 * c + 2] = 2e-4 * (uni(rng) - 0.5);
  }
  p.row_offset[nc] = m;
  for (int r = 0; r < m; ++r) {
    for (int k = 0; k < 6; ++k) p.J[6 * r + k] = kTransmission * g[r][k];
  }
  p.device_pose.pos_m = {tool_origin.x(), tool_origin.y(), tool_origin.z()};
  p.tool_pose = p.device_pose;

  // the simulation's solution: cold NSGS to 1e-8
  const shared::ContactProblemView view = shared::denseProblemView(
      nc, m, p.row_offset.data(), p.W.data(), m, p.delta_free.data(), p.mu.data());
  shared::NsgsWorkspace ws(m, nc);
  shared::NsgsSettings ns;
  ns.tolerance = 1e-8;
  ns.max_sweeps = 2000;
  ns.time_budget_ns = 5 * shared::kNsPerS;
  p.f.assign(m, 0.0);
  const shared::NsgsResult res = shared::solveNsgs(view, ns, ws, p.f.data());
  p.solve_sweeps = res.sweeps;
  p.solve_error = res.error;
  return p;
}

void writeSnapshot(const SyntheticProblem& p, shared::SnapshotWriter slot, std::uint64_t seq,
                   double t_s, double drift_m) {
  auto& h = slot.header();
  slot.setSize(p.rows, p.contacts);
  h.seq = seq;
  h.t_ns = shared::monotonicNs();
  h.step = seq;
  h.h_s = 0.01;
  h.flags = shared::kSnapshotValid | shared::kSnapshotConverged | shared::kSnapshotHasJacobian;
  h.solver_sweeps = p.solve_sweeps;
  h.solver_error = p.solve_error;
  h.device_seq = 0;
  h.device_pose = p.device_pose;
  h.tool_pose = p.tool_pose;
  const int m = p.rows;
  const int ld = slot.ld();
  std::copy(p.row_offset.begin(), p.row_offset.end(), slot.rowOffset());
  std::copy(p.contact_id.begin(), p.contact_id.end(), slot.contactId());
  std::copy(p.mu.begin(), p.mu.end(), slot.mu());
  std::copy(p.point_m.begin(), p.point_m.end(), slot.contactPoint());
  std::copy(p.normal.begin(), p.normal.end(), slot.contactNormal());
  std::copy(p.tangent.begin(), p.tangent.end(), slot.contactTangent());
  double* W = slot.W();
  for (int r = 0; r < m; ++r) {
    std::copy_n(p.W.data() + static_cast<std::ptrdiff_t>(r) * m, m,
                W + static_cast<std::ptrdiff_t>(r) * ld);
  }
  // the gaps drift slowly between publications (0.5 Hz), as a moving organ's would
  double* df = slot.deltaFree();
  std::copy(p.delta_free.begin(), p.delta_free.end(), df);
  for (int c = 0; c < p.contacts; ++c) {
    df[3 * c] += drift_m * std::sin(p.drift_phase[c] + 2.0 * std::numbers::pi * 0.5 * t_s);
  }
  std::copy(p.f.begin(), p.f.end(), slot.f());
  std::copy(p.J.begin(), p.J.end(), slot.J());
}

SyntheticRig::SyntheticRig(const SyntheticOptions& options)
    : options_(options),
      problem_(makeSyntheticProblem(options.problem)),
      t0_ns_(shared::monotonicNs()),
      rig_(fmt::format("tactus-jitter-{}-{}", static_cast<long>(::getpid()), g_rig_counter++),
           shared::SegmentCapacity{problem_.rows, problem_.contacts},
           std::make_unique<CircleDevice>(std::vector<shared::PoseSample>{problem_.device_pose},
                                          "jitter scripted device"),
           RigLoopOptions{options, std::max(50.0, 3e3 / options.sim_rate_hz)}) {
  publish(0.0);
}

void SyntheticRig::publish(double t_s) {
  rig_.publish([&](shared::SnapshotWriter slot, std::uint64_t seq) {
    writeSnapshot(problem_, slot, seq, t_s, options_.drift_m);
  });
}

void SyntheticRig::start() {
  rig_.start([this] {
    const auto period = static_cast<std::int64_t>(std::llround(1e9 / options_.sim_rate_hz));
    std::int64_t next = shared::monotonicNs() + period;
    while (!rig_.stopRequested()) {
      shared::sleepUntilNs(next);
      next += period;
      publish(1e-9 * static_cast<double>(shared::monotonicNs() - t0_ns_));
    }
  });
}

}  // namespace tactus::haptic::jitter

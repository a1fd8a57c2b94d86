// Strain limiting on volume (strain_limit.h).
#include "strain_limit.h"

#include <algorithm>
#include <cmath>

#include "tactus/shared/grow_only_matrix.h"

namespace tactus::sim {

namespace {

// the limiter aims this far above the bound, so that a tet it has lifted is not pulled back
// below by its neighbours' projections in the same sweep
constexpr double kStrainLimitSlack = 0.02;
// a sweep measures only the tets around the nodes it moved, so that the sweeps a crushed bite
// needs cost its few tets, not a scan of the mesh: median 17 sweeps on liver_grasp_23k's worst
// corner, one pass in 1059 took 400 (docs/design.md, "Strain limiting")
constexpr int kStrainLimitMaxSweeps = 400;
// the longest move of a node in one projection, in units of the tet's size (cbrt of 6 V_rest)
constexpr double kStrainLimitMaxStep = 0.25;
// after this many sweeps the contact nodes move too: the tets left below the bound are held
// between contact nodes (a bite squeezed across its whole thickness), and only the contact
// nodes can give them their volume back (the next contact pass or step sees the gaps)
constexpr int kStrainLimitFreeNodeSweeps = 10;

double volume6At(const Eigen::VectorXd& q, const std::array<int, 4>& t) {
  const Eigen::Vector3d a = q.segment<3>(3 * t[0]);
  return (q.segment<3>(3 * t[1]) - a).dot((q.segment<3>(3 * t[2]) - a).cross(q.segment<3>(3 * t[3]) - a));
}

// the tets below min_ratio at q, into active
void collectBelow(const FemBody& body, const std::vector<double>& rest6, double min_ratio,
                  std::vector<int>& active) {
  active.clear();
  const Eigen::VectorXd& q = body.positions();
  const auto& tets = body.mesh().tets;
  for (std::size_t i = 0; i < tets.size(); ++i) {
    if (volume6At(q, tets[i]) < min_ratio * rest6[i]) active.push_back(static_cast<int>(i));
  }
}

// The tets around `nodes` not yet measured at `stamp` (scratch.checked), measured at q: each
// below min_ratio goes into scratch.below and to on_below. Uses scratch.node_tet*.
template <class OnBelow>
void measureAround(const std::vector<int>& nodes, int stamp, const Eigen::VectorXd& q,
                   const std::vector<std::array<int, 4>>& tets, const std::vector<double>& rest6,
                   double min_ratio, StrainLimitScratch& scratch, OnBelow&& on_below) {
  for (int node : nodes) {
    const auto k = static_cast<std::size_t>(node);
    for (int i = scratch.node_tet_offset[k]; i < scratch.node_tet_offset[k + 1]; ++i) {
      const int e = scratch.node_tet[static_cast<std::size_t>(i)];
      const auto te = static_cast<std::size_t>(e);
      if (scratch.checked[te] == stamp) continue;
      scratch.checked[te] = stamp;
      if (volume6At(q, tets[te]) < min_ratio * rest6[te]) {
        scratch.below.push_back(e);
        on_below(e);
      }
    }
  }
}

// Per node of a contact with friction rows, the unit mean of its contacts' normals (each turned
// to agree with the sum so far, so that a node between both pads keeps their common axis), into
// scratch.slide_normal; zero for the other contact nodes (scratch.contact_nodes, whose entries
// alone are written and read: the cost is the rows', not the mesh's).
void contactNormals(std::span<const TissueRow> rows, std::span<const int> row_offset,
                    StrainLimitScratch& scratch) {
  if (scratch.slide_normal.size() < scratch.pinned.size()) {
    scratch.slide_normal.resize(scratch.pinned.size(), Eigen::Vector3d::Zero());
  }
  for (int node : scratch.contact_nodes) {
    scratch.slide_normal[static_cast<std::size_t>(node)].setZero();
  }
  for (std::size_t c = 0; c + 1 < row_offset.size(); ++c) {
    if (row_offset[c + 1] - row_offset[c] < 3) continue;   // frictionless: free to slide
    const TissueRow& normal = rows[static_cast<std::size_t>(row_offset[c])];
    for (std::size_t k = 0; k < 3; ++k) {
      const int node = normal.node[k];
      // fixed nodes never move
      if (node < 0 || normal.weight[k] == 0.0 || scratch.pinned[static_cast<std::size_t>(node)] != 1) {
        continue;
      }
      Eigen::Vector3d& sum = scratch.slide_normal[static_cast<std::size_t>(node)];
      sum += (sum.dot(normal.dir) < 0.0 ? -1.0 : 1.0) * std::abs(normal.weight[k]) * normal.dir;
    }
  }
  for (int node : scratch.contact_nodes) {
    Eigen::Vector3d& n = scratch.slide_normal[static_cast<std::size_t>(node)];
    const double length = n.norm();
    if (length > 0.0) n /= length;
  }
}

// node -> its tets (CSR), once per body
void buildNodeTets(const FemBody& body, StrainLimitScratch& scratch) {
  const int n = body.nodeCount();
  if (scratch.node_tet_offset.size() == static_cast<std::size_t>(n) + 1) return;
  const auto& tets = body.mesh().tets;
  scratch.node_tet_offset.assign(static_cast<std::size_t>(n) + 1, 0);
  for (const auto& t : tets) {
    for (int k : t) ++scratch.node_tet_offset[static_cast<std::size_t>(k) + 1];
  }
  for (std::size_t i = 1; i < scratch.node_tet_offset.size(); ++i) {
    scratch.node_tet_offset[i] += scratch.node_tet_offset[i - 1];
  }
  scratch.node_tet.assign(static_cast<std::size_t>(scratch.node_tet_offset.back()), 0);
  std::vector<int> fill(scratch.node_tet_offset.begin(), scratch.node_tet_offset.end() - 1);
  for (std::size_t e = 0; e < tets.size(); ++e) {
    for (int k : tets[e]) scratch.node_tet[static_cast<std::size_t>(fill[static_cast<std::size_t>(k)]++)] = static_cast<int>(e);
  }
}

// The tets the sweeps left below the bound: their nodes go back to q_valid (the step's start,
// where every tet kept its bound), then the nodes of every tet that this leaves below (a tet
// with some nodes back and some not), ring after ring, until no tet around a node moved back is
// below the bound or every free node is back; velocities take the change over the step. The
// tets left below then are those below in q_valid itself. Uses scratch.node_tet* (built by the
// sweeps) and leaves the tets still below in scratch.below.
void rollBack(FemBody& body, const std::vector<double>& rest6, double min_ratio, double h,
              const Eigen::VectorXd& q_valid, StrainLimitScratch& scratch, StrainLimitResult& out) {
  Eigen::VectorXd& q = body.positions();
  Eigen::VectorXd& v = body.velocities();
  const auto& tets = body.mesh().tets;
  const std::vector<bool>& fixed = body.fixedMask();
  // per node: 1 queued or back (fixed nodes never move: they are where q_valid has them)
  scratch.rolled.assign(static_cast<std::size_t>(body.nodeCount()), 0);
  std::vector<int>& ring = scratch.moved_nodes;
  std::vector<int>& next = scratch.active;   // the sweeps are done with it
  ring.clear();
  auto queueTet = [&](int e) {
    for (int k : tets[static_cast<std::size_t>(e)]) {
      const auto node = static_cast<std::size_t>(k);
      if (scratch.rolled[node] == 0 && !fixed[node]) {
        scratch.rolled[node] = 1;
        next.push_back(k);
      }
    }
  };
  next.clear();
  for (int e : scratch.below) queueTet(e);
  int stamp = kStrainLimitMaxSweeps + 1;
  while (!next.empty()) {
    ring.swap(next);
    next.clear();
    for (int k : ring) {
      const Eigen::Vector3d dx = q_valid.segment<3>(3 * k) - q.segment<3>(3 * k);
      q.segment<3>(3 * k) = q_valid.segment<3>(3 * k);
      v.segment<3>(3 * k) += dx / h;
    }
    out.rolled_back += static_cast<int>(ring.size());
    ++stamp;
    scratch.below.clear();
    measureAround(ring, stamp, q, tets, rest6, min_ratio, scratch, queueTet);
  }
}

}  // namespace

std::vector<double> restVolumes6(const TetMesh& mesh) {
  std::vector<double> out(mesh.tets.size());
  for (std::size_t i = 0; i < mesh.tets.size(); ++i) {
    const auto& t = mesh.tets[i];
    const Eigen::Vector3d a = mesh.nodes.col(t[0]);
    out[i] = (mesh.nodes.col(t[1]) - a).dot((mesh.nodes.col(t[2]) - a).cross(mesh.nodes.col(t[3]) - a));
  }
  return out;
}

StrainLimitResult limitVolumes(FemBody& body, const std::vector<double>& rest6, double min_ratio,
                               double h, std::span<const TissueRow> rows,
                               std::span<const int> row_offset, StrainLimitScratch& scratch,
                               const Eigen::VectorXd* q_valid) {
  StrainLimitResult out;
  collectBelow(body, rest6, min_ratio, scratch.active);
  out.limited = static_cast<int>(scratch.active.size());
  if (scratch.active.empty()) return out;
  // every tet found below in any sweep is projected in every later one (skipped while above the
  // target): a tet its neighbour's projection pushed back below is lifted in the same sweep,
  // where a list of the last scan's tets only lifted the pair by turns
  scratch.below = scratch.active;
  scratch.listed.assign(body.mesh().tets.size(), 0);
  for (int e : scratch.active) scratch.listed[static_cast<std::size_t>(e)] = 1;
  const int n = body.nodeCount();
  scratch.pinned.assign(static_cast<std::size_t>(n), 0);
  const std::vector<bool>& fixed = body.fixedMask();
  // 2: fixed, never moves; 1: in a contact row, moves only with no free node in its tet
  for (int i = 0; i < n; ++i) scratch.pinned[static_cast<std::size_t>(i)] = fixed[static_cast<std::size_t>(i)] ? 2 : 0;
  scratch.contact_nodes.clear();
  for (const TissueRow& r : rows) {
    for (int k = 0; k < 3; ++k) {
      const int node = r.node[static_cast<std::size_t>(k)];
      if (node >= 0 && r.weight[static_cast<std::size_t>(k)] != 0.0 && scratch.pinned[static_cast<std::size_t>(node)] == 0) {
        scratch.pinned[static_cast<std::size_t>(node)] = 1;
        scratch.contact_nodes.push_back(node);
      }
    }
  }
  contactNormals(rows, row_offset, scratch);
  Eigen::VectorXd& q = body.positions();
  Eigen::VectorXd& v = body.velocities();
  const Eigen::VectorXd& mass = body.lumpedMass();
  const auto& tets = body.mesh().tets;
  buildNodeTets(body, scratch);
  scratch.moved.assign(static_cast<std::size_t>(n), 0);
  scratch.checked.assign(tets.size(), 0);
  const double target = min_ratio + kStrainLimitSlack;
  scratch.moved_nodes.clear();
  for (out.sweeps = 1; out.sweeps <= kStrainLimitMaxSweeps; ++out.sweeps) {
    scratch.below.clear();
    for (int e : scratch.active) {
      const std::array<int, 4>& t = tets[static_cast<std::size_t>(e)];
      const double c = volume6At(q, t) - target * rest6[static_cast<std::size_t>(e)];
      if (c >= 0.0) continue;
      const Eigen::Vector3d x0 = q.segment<3>(3 * t[0]);
      const Eigen::Vector3d d1 = q.segment<3>(3 * t[1]) - x0;
      const Eigen::Vector3d d2 = q.segment<3>(3 * t[2]) - x0;
      const Eigen::Vector3d d3 = q.segment<3>(3 * t[3]) - x0;
      std::array<Eigen::Vector3d, 4> g;
      g[1] = d2.cross(d3);
      g[2] = d3.cross(d1);
      g[3] = d1.cross(d2);
      g[0] = -(g[1] + g[2] + g[3]);
      // a node of a frictional contact moves along its normal only: the projection of the
      // volume's gradient onto that line is the constraint's gradient for the node so restricted
      for (std::size_t k = 0; k < 4; ++k) {
        const Eigen::Vector3d& normal = scratch.slide_normal[static_cast<std::size_t>(t[k])];
        if (scratch.pinned[static_cast<std::size_t>(t[k])] == 1 && normal.squaredNorm() > 0.0) {
          g[k] = normal.dot(g[k]) * normal;
        }
      }
      // the free nodes move; a tet whose nodes are all in contact (or fixed) moves its contact
      // nodes, and the next contact pass or step sees what that did to the gaps
      std::array<double, 4> w{};
      double denom = 0.0;
      for (int pass = 0; pass < 2 && !(denom > 0.0); ++pass) {
        for (int k = 0; k < 4; ++k) {
          const auto node = static_cast<std::size_t>(t[static_cast<std::size_t>(k)]);
          const bool contact_moves = out.sweeps > kStrainLimitFreeNodeSweeps;
          const bool moves = pass == 0 ? scratch.pinned[node] == 0 || (contact_moves && scratch.pinned[node] == 1)
                                       : scratch.pinned[node] == 1;
          w[static_cast<std::size_t>(k)] = moves ? 1.0 / mass[static_cast<Eigen::Index>(3 * node)] : 0.0;
          denom += w[static_cast<std::size_t>(k)] * g[static_cast<std::size_t>(k)].squaredNorm();
        }
      }
      // fixed nodes only, or contact nodes whose normal is square to the gradient: it stays below
      if (!(denom > 0.0)) {
        if (volume6At(q, t) < min_ratio * rest6[static_cast<std::size_t>(e)]) {
          scratch.checked[static_cast<std::size_t>(e)] = out.sweeps;
          scratch.below.push_back(e);
        }
        continue;
      }
      double lambda = -c / denom;
      // a flat tet's gradient is small and the linear step long: no node moves more than a
      // quarter of the tet's size in one projection, so that the step does not invert the tets
      // around the node it moves (the sweeps take it the rest of the way)
      double longest = 0.0;
      for (int k = 0; k < 4; ++k) {
        longest = std::max(longest, w[static_cast<std::size_t>(k)] * g[static_cast<std::size_t>(k)].norm());
      }
      const double reach = kStrainLimitMaxStep * std::cbrt(rest6[static_cast<std::size_t>(e)]);
      if (lambda * longest > reach) lambda = reach / longest;
      for (int k = 0; k < 4; ++k) {
        const double wk = w[static_cast<std::size_t>(k)];
        if (wk == 0.0) continue;
        const Eigen::Vector3d dx = lambda * wk * g[static_cast<std::size_t>(k)];
        const int node = t[static_cast<std::size_t>(k)];
        q.segment<3>(3 * node) += dx;
        v.segment<3>(3 * node) += dx / h;
        if (scratch.moved[static_cast<std::size_t>(node)] != out.sweeps) {
          scratch.moved[static_cast<std::size_t>(node)] = out.sweeps;
          scratch.moved_nodes.push_back(node);
        }
      }
    }
    // only the tets around a node that moved can have changed
    measureAround(scratch.moved_nodes, out.sweeps, q, tets, rest6, min_ratio, scratch,
                  [](int) {});
    scratch.moved_nodes.clear();
    if (scratch.below.empty()) break;
    for (int e : scratch.below) {
      if (scratch.listed[static_cast<std::size_t>(e)] == 0) {
        scratch.listed[static_cast<std::size_t>(e)] = 1;
        scratch.active.push_back(e);
      }
    }
  }
  out.sweeps = std::min(out.sweeps, kStrainLimitMaxSweeps);
  if (!scratch.below.empty() && q_valid != nullptr) rollBack(body, rest6, min_ratio, h, *q_valid, scratch, out);
  out.unresolved = static_cast<int>(scratch.below.size());
  return out;
}

void prepareStrainLimit(const FemBody& body, StrainLimitScratch& scratch) {
  using shared::reserveWritten;
  buildNodeTets(body, scratch);
  const auto nodes = static_cast<std::size_t>(body.nodeCount());
  const auto tets = body.mesh().tets.size();
  reserveWritten(scratch.pinned, nodes, char{0});
  reserveWritten(scratch.rolled, nodes, char{0});
  reserveWritten(scratch.moved, nodes, 0);
  reserveWritten(scratch.listed, tets, char{0});
  reserveWritten(scratch.checked, tets, 0);
  reserveWritten(scratch.slide_normal, nodes, Eigen::Vector3d::Zero().eval());
  reserveWritten(scratch.contact_nodes, nodes, 0);
}

}  // namespace tactus::sim

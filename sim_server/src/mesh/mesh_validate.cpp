// The readers' common ground: number parsing, tokens, and the validation every format goes
// through (id resolution, unreferenced nodes, orientation, degeneracy).

#include <spdlog/spdlog.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "mesh_internal.h"
#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/mesh.h"

namespace tactus::sim {
namespace detail {

void fail(const std::string& name, int line, const std::string& message) {
  // the message may quote file content: no control bytes, bounded length
  throw MeshError(fmt::format("{}:{}: {}", name, line, shared::printable(message, 1000)));
}

bool parseDouble(std::string_view token, double* out) {
  if (!token.empty() && token.front() == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const char* end = token.data() + token.size();
  auto [ptr, ec] = std::from_chars(token.data(), end, *out, std::chars_format::general);
  return ec == std::errc() && ptr == end;
}

bool parseInt(std::string_view token, std::int64_t* out) {
  if (!token.empty() && token.front() == '+') token.remove_prefix(1);
  if (token.empty()) return false;
  const char* end = token.data() + token.size();
  auto [ptr, ec] = std::from_chars(token.data(), end, *out);
  return ec == std::errc() && ptr == end;
}

void splitTokens(std::string_view line, std::vector<std::string_view>* tokens) {
  tokens->clear();
  std::size_t i = 0;
  const auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\n' ||
                                            c == '\v' || c == '\f'; };
  while (i < line.size()) {
    while (i < line.size() && is_space(line[i])) ++i;
    const std::size_t start = i;
    while (i < line.size() && !is_space(line[i])) ++i;
    if (i > start) tokens->push_back(line.substr(start, i - start));
  }
}

int lineOf(std::string_view text, std::size_t pos) {
  pos = std::min(pos, text.size());
  const auto end = text.begin() + static_cast<long>(pos);
  return 1 + static_cast<int>(std::count(text.begin(), end, '\n'));
}

std::string excerpt(std::string_view s) { return shared::printable(s, 40); }

bool equalsNoCase(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const auto lower = [](char c) {
      return (c >= 'A' && c <= 'Z') ? static_cast<char>(c + 32) : c;
    };
    if (lower(a[i]) != lower(b[i])) return false;
  }
  return true;
}

std::string_view trim(std::string_view s) {
  const auto is_space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' ||
                                            c == '\f'; };
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

namespace {

// Signed 6 x volume of the tetrahedron (a, b, c, d).
double sixVolume(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                 const Eigen::Vector3d& d) {
  return (b - a).dot((c - a).cross(d - a));
}

// Every problem of a mesh, reported together in one MeshError: one problem reads
// "name:line: message" as before, several "name: N problems in the mesh" and then one
// "name:line: message" line each, the first kListedMeshProblems of them.
class MeshProblems {
 public:
  explicit MeshProblems(const std::string& name) : name_(name) {}
  void add(int line, const std::string& message) {
    ++count_;
    if (listed_.size() < static_cast<std::size_t>(kListedMeshProblems))
      listed_.emplace_back(line, message);
  }
  void raiseIfAny() const {
    if (count_ == 0) return;
    if (count_ == 1) fail(name_, listed_[0].first, listed_[0].second);
    std::string text = fmt::format("{} problems in the mesh{}:", count_,
                                   count_ > kListedMeshProblems
                                       ? fmt::format(" (the first {} listed)", kListedMeshProblems)
                                       : std::string());
    for (const auto& [line, message] : listed_)
      text += fmt::format("\n{}:{}: {}", name_, line, shared::printable(message, 300));
    throw MeshError(fmt::format("{}: {}", name_, text));
  }

 private:
  std::string name_;
  int count_ = 0;
  std::vector<std::pair<int, std::string>> listed_;
};

// Mean ratio of a tetrahedron: 12 (3 |V|)^(2/3) / (sum of its squared edge lengths), 1 for the
// regular tetrahedron, towards 0 as it flattens (a sliver, a needle, a cap).
double meanRatio(const Eigen::Vector3d* x) {
  const double v = std::abs(sixVolume(x[0], x[1], x[2], x[3])) / 6.0;
  double edges = 0.0;
  for (int a = 0; a < 4; ++a)
    for (int b = a + 1; b < 4; ++b) edges += (x[a] - x[b]).squaredNorm();
  return edges > 0.0 ? 12.0 * std::cbrt(3.0 * v) * std::cbrt(3.0 * v) / edges : 0.0;
}

// Interior faces whose two tetrahedra lie on the same side (they overlap: the mesh is tangled,
// e.g. a node pushed through a face) and faces shared by more than two tetrahedra. Only the
// tetrahedra marked `valid` take part.
void findTangles(const TetMesh& mesh, const std::vector<char>& valid, const RawMesh& raw,
                 const std::string& element_word, MeshProblems* problems, int* folded_faces) {
  static constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};
  struct Face {
    std::array<int, 3> key;
    int tet;
    int apex;   // local index of the node opposite the face
    bool operator<(const Face& o) const { return key != o.key ? key < o.key : tet < o.tet; }
  };
  std::vector<Face> faces;
  faces.reserve(mesh.tets.size() * 4);
  for (std::size_t t = 0; t < mesh.tets.size(); ++t) {
    if (!valid[t]) continue;
    for (int f = 0; f < 4; ++f) {
      Face face{{mesh.tets[t][kFaces[f][0]], mesh.tets[t][kFaces[f][1]],
                 mesh.tets[t][kFaces[f][2]]},
                static_cast<int>(t), f};
      std::sort(face.key.begin(), face.key.end());
      faces.push_back(face);
    }
  }
  std::sort(faces.begin(), faces.end());
  for (std::size_t i = 0; i < faces.size();) {
    std::size_t j = i + 1;
    while (j < faces.size() && faces[j].key == faces[i].key) ++j;
    const auto& k = faces[i].key;
    if (j - i > 2) {
      problems->add(raw.tet_lines[static_cast<std::size_t>(faces[i + 2].tet)],
                    fmt::format("{}s {}, {} and {} share one face ({} {}s in all): the mesh is "
                                "not a manifold there",
                                element_word, raw.tet_ids[static_cast<std::size_t>(faces[i].tet)],
                                raw.tet_ids[static_cast<std::size_t>(faces[i + 1].tet)],
                                raw.tet_ids[static_cast<std::size_t>(faces[i + 2].tet)], j - i,
                                element_word));
    } else if (j - i == 2) {
      // both apexes against the face's plane: opposite signs for a valid mesh
      const Eigen::Vector3d a = mesh.nodes.col(k[0]), b = mesh.nodes.col(k[1]),
                            c = mesh.nodes.col(k[2]);
      const int t0 = faces[i].tet, t1 = faces[i + 1].tet;
      const double s0 = sixVolume(a, b, c, mesh.nodes.col(mesh.tets[t0][faces[i].apex]));
      const double s1 = sixVolume(a, b, c, mesh.nodes.col(mesh.tets[t1][faces[i + 1].apex]));
      if (s0 * s1 > 0.0) {
        ++*folded_faces;
        problems->add(raw.tet_lines[static_cast<std::size_t>(t1)],
                      fmt::format("{}s {} and {} overlap: both lie on the same side of their "
                                  "shared face (the mesh is tangled, e.g. a node pushed "
                                  "through a face)",
                                  element_word, raw.tet_ids[static_cast<std::size_t>(t0)],
                                  raw.tet_ids[static_cast<std::size_t>(t1)]));
      }
    }
    i = j;
  }
}

}  // namespace

TetMesh finalizeMesh(RawMesh&& raw, const std::string& name, MeshReport* report) {
  const std::size_t n = raw.node_ids.size();
  const std::string& ew = raw.element_word;
  const std::string& nw = raw.node_word;
  MeshProblems problems(name);
  // file id -> position in file order; a duplicate is ambiguous (the first is kept to go on)
  std::unordered_map<std::int64_t, int> index_of;
  index_of.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    auto [it, inserted] = index_of.emplace(raw.node_ids[i], static_cast<int>(i));
    if (!inserted) {
      problems.add(raw.node_lines[i],
                   fmt::format("{} {} is defined twice (first at line {})", nw, raw.node_ids[i],
                               raw.node_lines[static_cast<std::size_t>(it->second)]));
    }
    for (int k = 0; k < 3; ++k) {
      if (!std::isfinite(raw.coords[3 * i + static_cast<std::size_t>(k)])) {
        problems.add(raw.node_lines[i],
                     fmt::format("{} {} has a non-finite coordinate", nw, raw.node_ids[i]));
        break;
      }
    }
  }
  if (raw.tets.empty()) {
    problems.add(raw.last_line,
                 fmt::format("no tetrahedra (4-node elements) in the file ({} other elements "
                             "ignored)",
                             raw.ignored_elements));
    problems.raiseIfAny();
  }
  // resolve node ids; element ids must be unique too
  std::unordered_map<std::int64_t, int> tet_index_of;
  tet_index_of.reserve(raw.tets.size());
  std::vector<std::array<int, 4>> tets(raw.tets.size());
  std::vector<char> referenced(n, 0);
  std::vector<char> valid(raw.tets.size(), 1);   // resolved and with four distinct nodes
  for (std::size_t t = 0; t < raw.tets.size(); ++t) {
    auto [it, inserted] = tet_index_of.emplace(raw.tet_ids[t], static_cast<int>(t));
    if (!inserted) {
      problems.add(raw.tet_lines[t],
                   fmt::format("{} {} is defined twice (first at line {})", ew, raw.tet_ids[t],
                               raw.tet_lines[static_cast<std::size_t>(it->second)]));
    }
    for (int k = 0; k < 4; ++k) {
      const std::int64_t id = raw.tets[t][static_cast<std::size_t>(k)];
      auto found = index_of.find(id);
      if (found == index_of.end()) {
        problems.add(raw.tet_lines[t], fmt::format("{} {} refers to {} {} which is not defined",
                                                   ew, raw.tet_ids[t], nw, id));
        valid[t] = 0;
        tets[t][static_cast<std::size_t>(k)] = -1;
        continue;
      }
      tets[t][static_cast<std::size_t>(k)] = found->second;
      referenced[static_cast<std::size_t>(found->second)] = 1;
    }
    for (int a = 0; a < 4 && valid[t]; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        if (tets[t][static_cast<std::size_t>(a)] == tets[t][static_cast<std::size_t>(b)]) {
          problems.add(raw.tet_lines[t],
                       fmt::format("{} {} is degenerate: it uses {} {} twice", ew,
                                   raw.tet_ids[t], nw, raw.tets[t][static_cast<std::size_t>(a)]));
          valid[t] = 0;
          break;
        }
      }
    }
  }
  // dense renumbering of the referenced nodes, in file order
  std::vector<int> new_index(n, -1);
  int kept = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (referenced[i]) new_index[i] = kept++;
  }
  TetMesh mesh;
  mesh.source = name;
  mesh.nodes.resize(3, kept);
  for (std::size_t i = 0; i < n; ++i) {
    if (new_index[i] < 0) continue;
    mesh.nodes.col(new_index[i]) =
        Eigen::Vector3d(raw.coords[3 * i], raw.coords[3 * i + 1], raw.coords[3 * i + 2]);
  }
  const Eigen::Vector3d lo = mesh.nodes.rowwise().minCoeff();
  const Eigen::Vector3d hi = mesh.nodes.rowwise().maxCoeff();
  const double size = (hi - lo).norm();
  // |6V| below this is a zero volume at the scale of the mesh
  const double tol = 1e-12 * size * size * size;
  int flipped = 0;
  int first_flipped_line = 0;
  int slivers = 0;
  double worst_quality = 1.0;
  std::size_t worst_tet = 0;
  mesh.tets.resize(tets.size());
  for (std::size_t t = 0; t < tets.size(); ++t) {
    if (!valid[t]) {
      mesh.tets[t] = {0, 0, 0, 0};
      continue;
    }
    std::array<int, 4> tet;
    for (std::size_t k = 0; k < 4; ++k) {
      tet[k] = new_index[static_cast<std::size_t>(tets[t][k])];
    }
    Eigen::Vector3d x[4];
    for (int k = 0; k < 4; ++k) x[k] = mesh.nodes.col(tet[static_cast<std::size_t>(k)]);
    const double v6 = sixVolume(x[0], x[1], x[2], x[3]);
    if (!(std::abs(v6) > tol)) {
      problems.add(raw.tet_lines[t],
                   fmt::format("{} {} is degenerate: volume {:.3g} is zero at the mesh size "
                               "{:.3g} (its nodes are coplanar)",
                               ew, raw.tet_ids[t], v6 / 6.0, size));
      valid[t] = 0;
    } else {
      const double quality = meanRatio(x);
      if (quality < kSliverMeanRatio) ++slivers;
      if (quality < worst_quality) {
        worst_quality = quality;
        worst_tet = t;
      }
    }
    if (v6 < 0) {
      std::swap(tet[2], tet[3]);
      if (flipped == 0) first_flipped_line = raw.tet_lines[t];
      ++flipped;
    }
    mesh.tets[t] = tet;
  }
  int folded_faces = 0;
  findTangles(mesh, valid, raw, ew, &problems, &folded_faces);
  problems.raiseIfAny();
  const int dropped = static_cast<int>(n) - kept;
  int dropped_group_nodes = 0;
  mesh.groups = resolveGroups(raw, mesh, index_of, new_index, name, &dropped_group_nodes);
  if (dropped_group_nodes > 0) {
    spdlog::warn("{}: {} nodes of physical groups are used by no tetrahedron and left out of their "
                 "groups", name, dropped_group_nodes);
  }
  if (raw.ignored_elements > 0) {
    spdlog::warn("{}: {} non-tetrahedral elements ignored", name, raw.ignored_elements);
  }
  if (flipped > 0) {
    spdlog::warn("{}: {} negatively oriented tetrahedra re-oriented (first at line {}); the "
                 "mesh is not tangled (every shared face has its two tetrahedra on either side)",
                 name, flipped, first_flipped_line);
  }
  if (dropped > 0) {
    spdlog::warn("{}: {} nodes referenced by no tetrahedron dropped", name, dropped);
  }
  if (slivers > 0) {
    spdlog::warn("{}: {} near-degenerate tetrahedra (mean ratio below {}; 1 is the regular "
                 "tetrahedron), the worst {:.3g} at line {} ({} {}): their stiffness and "
                 "rotation are ill-conditioned",
                 name, slivers, kSliverMeanRatio, worst_quality, raw.tet_lines[worst_tet], ew,
                 raw.tet_ids[worst_tet]);
  }
  if (report != nullptr) {
    report->format = raw.format;
    report->ignored_elements = raw.ignored_elements;
    report->flipped_tets = flipped;
    report->dropped_nodes = dropped;
    report->sliver_tets = slivers;
    report->worst_mean_ratio = worst_quality;
    report->worst_mean_ratio_line = raw.tet_lines[worst_tet];
  }
  return mesh;
}

}  // namespace detail
}  // namespace tactus::sim

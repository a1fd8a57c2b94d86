// The readers' common ground: number parsing, tokens, and the validation every format goes
// through (id resolution, unreferenced nodes, orientation, degeneracy).

#include <spdlog/fmt/fmt.h>
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

}  // namespace

TetMesh finalizeMesh(RawMesh&& raw, const std::string& name, MeshReport* report) {
  const std::size_t n = raw.node_ids.size();
  const std::string& ew = raw.element_word;
  const std::string& nw = raw.node_word;
  // file id -> position in file order; duplicates are ambiguous
  std::unordered_map<std::int64_t, int> index_of;
  index_of.reserve(n);
  for (std::size_t i = 0; i < n; ++i) {
    auto [it, inserted] = index_of.emplace(raw.node_ids[i], static_cast<int>(i));
    if (!inserted) {
      fail(name, raw.node_lines[i],
           fmt::format("{} {} is defined twice (first at line {})", nw, raw.node_ids[i],
                       raw.node_lines[static_cast<std::size_t>(it->second)]));
    }
    for (int k = 0; k < 3; ++k) {
      if (!std::isfinite(raw.coords[3 * i + static_cast<std::size_t>(k)])) {
        fail(name, raw.node_lines[i],
             fmt::format("{} {} has a non-finite coordinate", nw, raw.node_ids[i]));
      }
    }
  }
  if (raw.tets.empty()) {
    fail(name, raw.last_line,
         fmt::format("no tetrahedra (4-node elements) in the file ({} other elements ignored)",
                     raw.ignored_elements));
  }
  // resolve node ids; element ids must be unique too
  std::unordered_map<std::int64_t, int> tet_index_of;
  tet_index_of.reserve(raw.tets.size());
  std::vector<std::array<int, 4>> tets(raw.tets.size());
  std::vector<char> referenced(n, 0);
  for (std::size_t t = 0; t < raw.tets.size(); ++t) {
    auto [it, inserted] = tet_index_of.emplace(raw.tet_ids[t], static_cast<int>(t));
    if (!inserted) {
      fail(name, raw.tet_lines[t],
           fmt::format("{} {} is defined twice (first at line {})", ew, raw.tet_ids[t],
                       raw.tet_lines[static_cast<std::size_t>(it->second)]));
    }
    for (int k = 0; k < 4; ++k) {
      const std::int64_t id = raw.tets[t][static_cast<std::size_t>(k)];
      auto found = index_of.find(id);
      if (found == index_of.end()) {
        fail(name, raw.tet_lines[t],
             fmt::format("{} {} refers to {} {} which is not defined", ew, raw.tet_ids[t], nw, id));
      }
      tets[t][static_cast<std::size_t>(k)] = found->second;
      referenced[static_cast<std::size_t>(found->second)] = 1;
    }
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        if (tets[t][static_cast<std::size_t>(a)] == tets[t][static_cast<std::size_t>(b)]) {
          fail(name, raw.tet_lines[t],
               fmt::format("{} {} is degenerate: it uses {} {} twice", ew, raw.tet_ids[t], nw,
                           raw.tets[t][static_cast<std::size_t>(a)]));
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
  mesh.tets.resize(tets.size());
  for (std::size_t t = 0; t < tets.size(); ++t) {
    std::array<int, 4> tet;
    for (std::size_t k = 0; k < 4; ++k) {
      tet[k] = new_index[static_cast<std::size_t>(tets[t][k])];
    }
    const double v6 = sixVolume(mesh.nodes.col(tet[0]), mesh.nodes.col(tet[1]),
                                mesh.nodes.col(tet[2]), mesh.nodes.col(tet[3]));
    if (!(std::abs(v6) > tol)) {
      fail(name, raw.tet_lines[t],
           fmt::format("{} {} is degenerate: volume {:.3g} is zero at the mesh size {:.3g} "
                       "(its nodes are coplanar)",
                       ew, raw.tet_ids[t], v6 / 6.0, size));
    }
    if (v6 < 0) {
      std::swap(tet[2], tet[3]);
      if (flipped == 0) first_flipped_line = raw.tet_lines[t];
      ++flipped;
    }
    mesh.tets[t] = tet;
  }
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
    spdlog::warn("{}: {} negatively oriented tetrahedra re-oriented (first at line {})", name,
                 flipped, first_flipped_line);
  }
  if (dropped > 0) {
    spdlog::warn("{}: {} nodes referenced by no tetrahedron dropped", name, dropped);
  }
  if (report != nullptr) {
    report->format = raw.format;
    report->ignored_elements = raw.ignored_elements;
    report->flipped_tets = flipped;
    report->dropped_nodes = dropped;
  }
  return mesh;
}

}  // namespace detail
}  // namespace tactus::sim

// OBJ and STL triangle surfaces (surface_io.h).
#include <fmt/format.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <sstream>

#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/surface_io.h"

namespace tactus::sim {
namespace {

[[noreturn]] void fail(const std::string& name, int line, const std::string& what) {
  if (line > 0) throw MeshError(fmt::format("{}:{}: {}", name, line, what));
  throw MeshError(fmt::format("{}: {}", name, what));
}

double parseCoordinate(const std::string& token, const std::string& name, int line) {
  double v = 0.0;
  const char* end = token.data() + token.size();
  const auto [ptr, ec] = std::from_chars(token.data(), end, v);
  if (ec != std::errc() || ptr != end) {
    fail(name, line, fmt::format("'{}' is not a number", shared::printable(token)));
  }
  if (!std::isfinite(v)) fail(name, line, "a coordinate is not finite");
  return v;
}

// Vertices deduplicated by their exact bits (STL repeats every vertex per facet).
struct VertexMerger {
  std::map<std::array<double, 3>, int> index;
  std::vector<Eigen::Vector3d> points;
  int add(const Eigen::Vector3d& p) {
    const auto [it, inserted] = index.try_emplace({p.x(), p.y(), p.z()},
                                                  static_cast<int>(points.size()));
    if (inserted) points.push_back(p);
    return it->second;
  }
};

void finish(TriangleSurface& s, const std::vector<Eigen::Vector3d>& points,
            const std::vector<std::array<int, 3>>& triangles, const std::string& name) {
  s.source = name;
  s.vertices.resize(3, static_cast<Eigen::Index>(points.size()));
  for (std::size_t i = 0; i < points.size(); ++i) s.vertices.col(static_cast<Eigen::Index>(i)) = points[i];
  int overflowed = 0;   // triangles whose area is not finite: coordinates too large
  for (const auto& t : triangles) {
    const Eigen::Vector3d a = points[static_cast<std::size_t>(t[0])];
    const double area = (points[static_cast<std::size_t>(t[1])] - a)
                            .cross(points[static_cast<std::size_t>(t[2])] - a)
                            .norm();
    if (area > 0.0 && std::isfinite(area)) s.triangles.push_back(t);
    if (!std::isfinite(area)) ++overflowed;
  }
  if (overflowed > 0) {
    double largest = 0.0;
    for (const Eigen::Vector3d& p : points) largest = std::max(largest, p.cwiseAbs().maxCoeff());
    fail(name, 0, fmt::format("{} of {} triangles have no finite area: the coordinates are too "
                              "large (the largest is {:g}); use smaller units in the file",
                              overflowed, triangles.size(), largest));
  }
  if (s.triangles.empty()) {
    fail(name, 0, triangles.empty() ? std::string("no triangle in the surface")
                                    : fmt::format("all {} triangles are degenerate (zero area)",
                                                  triangles.size()));
  }
}

TriangleSurface parseObj(const std::string& content, const std::string& name) {
  std::istringstream in(content);
  std::string line_text;
  std::vector<Eigen::Vector3d> points;
  std::vector<std::array<int, 3>> triangles;
  int line = 0;
  while (std::getline(in, line_text)) {
    ++line;
    std::istringstream ls(line_text);
    std::string tag;
    if (!(ls >> tag)) continue;
    if (tag == "v") {
      std::string x, y, z;
      if (!(ls >> x >> y >> z)) fail(name, line, "a vertex needs three coordinates");
      points.emplace_back(parseCoordinate(x, name, line), parseCoordinate(y, name, line),
                          parseCoordinate(z, name, line));
    } else if (tag == "f") {
      std::vector<int> poly;
      std::string item;
      while (ls >> item) {
        const std::string first = item.substr(0, item.find('/'));
        long long idx = 0;
        const auto [ptr, ec] = std::from_chars(first.data(), first.data() + first.size(), idx);
        if (ec != std::errc() || ptr != first.data() + first.size() || idx == 0) {
          fail(name, line, fmt::format("'{}' is not a vertex index", shared::printable(item)));
        }
        const long long n = static_cast<long long>(points.size());
        const long long zero_based = idx > 0 ? idx - 1 : n + idx;
        if (zero_based < 0 || zero_based >= n) {
          fail(name, line, fmt::format("vertex index {} is out of range ({} vertices so far)",
                                       idx, n));
        }
        poly.push_back(static_cast<int>(zero_based));
      }
      if (poly.size() < 3) fail(name, line, "a face needs at least three vertices");
      for (std::size_t k = 1; k + 1 < poly.size(); ++k) {
        triangles.push_back({poly[0], poly[k], poly[k + 1]});
      }
    }
  }
  TriangleSurface s;
  finish(s, points, triangles, name);
  return s;
}

TriangleSurface parseAsciiStl(const std::string& content, const std::string& name) {
  std::istringstream in(content);
  std::string line_text;
  VertexMerger merger;
  std::vector<std::array<int, 3>> triangles;
  std::array<int, 3> facet{};
  int corners = 0;
  int line = 0;
  while (std::getline(in, line_text)) {
    ++line;
    std::istringstream ls(line_text);
    std::string tag;
    if (!(ls >> tag)) continue;
    if (tag == "facet") {
      corners = 0;
    } else if (tag == "vertex") {
      std::string x, y, z;
      if (!(ls >> x >> y >> z)) fail(name, line, "a vertex needs three coordinates");
      if (corners >= 3) fail(name, line, "a facet with more than three vertices");
      facet[static_cast<std::size_t>(corners++)] = merger.add(Eigen::Vector3d(
          parseCoordinate(x, name, line), parseCoordinate(y, name, line),
          parseCoordinate(z, name, line)));
    } else if (tag == "endfacet") {
      if (corners != 3) fail(name, line, "a facet without three vertices");
      triangles.push_back(facet);
      corners = 0;
    }
  }
  TriangleSurface s;
  finish(s, merger.points, triangles, name);
  return s;
}

bool isBinaryStl(const std::string& content) {
  if (content.size() < 84) return false;
  std::uint32_t count = 0;
  std::memcpy(&count, content.data() + 80, 4);
  return content.size() == 84 + 50 * static_cast<std::uint64_t>(count);
}

TriangleSurface parseBinaryStl(const std::string& content, const std::string& name) {
  std::uint32_t count = 0;
  std::memcpy(&count, content.data() + 80, 4);
  VertexMerger merger;
  std::vector<std::array<int, 3>> triangles;
  for (std::uint32_t t = 0; t < count; ++t) {
    const char* facet = content.data() + 84 + 50 * static_cast<std::size_t>(t);
    std::array<int, 3> tri{};
    for (int k = 0; k < 3; ++k) {
      float xyz[3];
      std::memcpy(xyz, facet + 12 + 12 * k, 12);
      const Eigen::Vector3d p(xyz[0], xyz[1], xyz[2]);
      if (!p.allFinite()) fail(name, 0, fmt::format("facet {} has a non-finite vertex", t));
      tri[static_cast<std::size_t>(k)] = merger.add(p);
    }
    triangles.push_back(tri);
  }
  TriangleSurface s;
  finish(s, merger.points, triangles, name);
  return s;
}

}  // namespace

TriangleSurface parseTriangleSurface(const std::string& content, const std::string& name) {
  if (isBinaryStl(content)) return parseBinaryStl(content, name);
  const std::size_t start = content.find_first_not_of(" \t\r\n");
  if (start != std::string::npos && content.compare(start, 5, "solid") == 0 &&
      content.find("facet") != std::string::npos) {
    return parseAsciiStl(content, name);
  }
  if (content.find('\0') != std::string::npos) {
    fail(name, 0, "binary content that is not a binary STL (size does not match its count)");
  }
  return parseObj(content, name);
}

TriangleSurface loadTriangleSurface(const std::filesystem::path& path) {
  std::string content;
  try {
    content = shared::readFileChecked(path, "surface file", shared::kMaxMeshBytes);
  } catch (const FileError& e) {
    throw MeshError(e.what());
  }
  return parseTriangleSurface(content, path.string());
}

}  // namespace tactus::sim

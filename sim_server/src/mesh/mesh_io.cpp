// Mesh input: format detection and the entry points; one reader per format (gmsh_reader.cpp,
// vtk_legacy_reader.cpp, vtu_reader.cpp), the common validation in mesh_validate.cpp.

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

namespace {

enum class MeshFormat { kUnknown, kGmsh, kVtkLegacy, kVtu };

// The format from the first bytes; `start` is where the content begins (after a UTF-8 byte order
// mark and white space). kUnknown also when `head` holds only white space.
MeshFormat sniffMeshFormat(std::string_view head, std::size_t* start) {
  std::size_t i = 0;
  if (head.substr(0, 3) == "\xEF\xBB\xBF") i = 3;  // UTF-8 byte order mark
  while (i < head.size() && std::isspace(static_cast<unsigned char>(head[i]))) ++i;
  *start = i;
  const std::string_view h = head.substr(i);
  if (!h.empty() && h.front() == '$') return MeshFormat::kGmsh;
  if (h.rfind("# vtk DataFile", 0) == 0) return MeshFormat::kVtkLegacy;
  if (h.rfind("<?xml", 0) == 0 || h.rfind("<VTKFile", 0) == 0) return MeshFormat::kVtu;
  return MeshFormat::kUnknown;
}

[[noreturn]] void failUnrecognised(std::string_view content, std::size_t start,
                                   const std::string& name) {
  detail::fail(name, detail::lineOf(content, start),
               "unrecognised mesh format (expected Gmsh .msh, legacy VTK .vtk or VTK XML .vtu)");
}

}  // namespace

TetMesh parseTetMesh(const std::string& content, const std::string& name, MeshReport* report) {
  std::size_t start = 0;
  const MeshFormat format = sniffMeshFormat(content, &start);
  detail::RawMesh raw;
  switch (format) {
    case MeshFormat::kGmsh: detail::readGmsh(content, name, &raw); break;
    case MeshFormat::kVtkLegacy: detail::readVtkLegacy(content.substr(start), name, &raw); break;
    case MeshFormat::kVtu: detail::readVtu(content, name, &raw); break;
    case MeshFormat::kUnknown: failUnrecognised(content, start, name);
  }
  return detail::finalizeMesh(std::move(raw), name, report);
}

TetMesh loadTetMesh(const std::filesystem::path& path, MeshReport* report) {
  try {
    shared::InputFile file(path, "mesh file", shared::kMaxMeshBytes);
    // sniff the format from the first bytes before reading the whole file
    std::string content(static_cast<std::size_t>(std::min<std::uint64_t>(file.size(), 4096)), '\0');
    content.resize(file.read(content.data(), content.size()));
    std::size_t start = 0;
    const bool all_blank = content.find_first_not_of(" \t\r\n\v\f") == std::string::npos;
    if (!all_blank && sniffMeshFormat(content, &start) == MeshFormat::kUnknown) {
      failUnrecognised(content, start, file.name());
    }
    content += file.readRest();
    return parseTetMesh(content, file.name(), report);
  } catch (const FileError& e) {
    throw MeshError(e.what());
  }
}

}  // namespace tactus::sim

// VTK output: ASCII .vtu files and ParaView .pvd collections.

#include <fmt/format.h>

#include <charconv>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/shared/file_io.h"
#include "tactus/sim/vtk_writer.h"

namespace tactus::sim {
namespace {

// Shortest text that reads back to the same double.
void appendDouble(std::string* out, double v) {
  char buf[32];
  auto [ptr, ec] = std::to_chars(buf, buf + sizeof(buf), v);
  (void)ec;
  out->append(buf, ptr);
}

// One cell scalar per line, as an ascii Float64 DataArray named `name`.
void appendScalarArray(std::string* out, const char* name, const Eigen::VectorXd& values) {
  *out += "<DataArray type=\"Float64\" Name=\"";
  *out += name;
  *out += "\" format=\"ascii\">\n";
  for (Eigen::Index c = 0; c < values.size(); ++c) {
    appendDouble(out, values(c));
    *out += '\n';
  }
  *out += "</DataArray>\n";
}

// The series' own files: replaced on a re-run into the same folder, always through a checked,
// fsync'ed temporary file (a full disk is an error, never a silently truncated file).
void writeFile(const std::filesystem::path& path, const std::string& text) {
  try {
    shared::writeFileChecked(path, text, "VTK output file", {.overwrite = true});
  } catch (const FileError& e) {
    throw Error(fmt::format("{} (does the folder exist and have space?)", e.what()));
  }
}

std::string xmlEscape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      default: out += c;
    }
  }
  return out;
}

}  // namespace

void writeVtu(const std::filesystem::path& path, const TetMesh& mesh,
              const Eigen::Matrix3Xd& positions, const Eigen::Matrix3Xd& displacement,
              const Eigen::VectorXd& von_mises, const Eigen::VectorXd& volume_ratio,
              const std::vector<NamedPointVectors>& point_vectors) {
  const Eigen::Index n = mesh.nodes.cols();
  const auto m = static_cast<Eigen::Index>(mesh.tets.size());
  if (positions.cols() != n) {
    throw Error(fmt::format("{}: writeVtu got {} positions for {} nodes", path.string(),
                            positions.cols(), n));
  }
  if (displacement.cols() != 0 && displacement.cols() != n) {
    throw Error(fmt::format("{}: writeVtu got {} displacements for {} nodes", path.string(),
                            displacement.cols(), n));
  }
  if (von_mises.size() != 0 && von_mises.size() != m) {
    throw Error(fmt::format("{}: writeVtu got {} von Mises values for {} tets", path.string(),
                            von_mises.size(), m));
  }
  if (volume_ratio.size() != 0 && volume_ratio.size() != m) {
    throw Error(fmt::format("{}: writeVtu got {} volume ratios for {} tets", path.string(),
                            volume_ratio.size(), m));
  }
  std::string s;
  s.reserve(static_cast<std::size_t>(n * 80 + m * 40 + 1024));
  s += "<?xml version=\"1.0\"?>\n";
  s += "<VTKFile type=\"UnstructuredGrid\" version=\"1.0\" byte_order=\"LittleEndian\" "
       "header_type=\"UInt32\">\n";
  s += "<UnstructuredGrid>\n";
  s += fmt::format("<Piece NumberOfPoints=\"{}\" NumberOfCells=\"{}\">\n", n, m);
  // points
  s += "<Points>\n<DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">\n";
  for (Eigen::Index i = 0; i < n; ++i) {
    for (int k = 0; k < 3; ++k) {
      appendDouble(&s, positions(k, i));
      s += k < 2 ? ' ' : '\n';
    }
  }
  s += "</DataArray>\n</Points>\n";
  // cells
  s += "<Cells>\n<DataArray type=\"Int32\" Name=\"connectivity\" format=\"ascii\">\n";
  for (const auto& t : mesh.tets) s += fmt::format("{} {} {} {}\n", t[0], t[1], t[2], t[3]);
  s += "</DataArray>\n<DataArray type=\"Int32\" Name=\"offsets\" format=\"ascii\">\n";
  for (Eigen::Index c = 0; c < m; ++c) s += fmt::format("{}\n", 4 * (c + 1));
  s += "</DataArray>\n<DataArray type=\"UInt8\" Name=\"types\" format=\"ascii\">\n";
  for (Eigen::Index c = 0; c < m; ++c) s += "10\n";
  s += "</DataArray>\n</Cells>\n";
  const bool with_displacement = displacement.cols() == n && n > 0;
  for (const auto& [name, values] : point_vectors) {
    if (values.cols() != n) {
      throw Error(fmt::format("{}: writeVtu got {} values of '{}' for {} nodes", path.string(),
                              values.cols(), name, n));
    }
  }
  if (n > 0 && (with_displacement || !point_vectors.empty())) {
    s += fmt::format("<PointData Vectors=\"{}\">\n",
                     with_displacement ? std::string("displacement") : point_vectors[0].first);
    const auto array = [&](const std::string& name, const Eigen::Matrix3Xd& values) {
      s += "<DataArray type=\"Float64\" Name=\"" + name +
           "\" NumberOfComponents=\"3\" format=\"ascii\">\n";
      for (Eigen::Index i = 0; i < n; ++i) {
        for (int k = 0; k < 3; ++k) {
          appendDouble(&s, values(k, i));
          s += k < 2 ? ' ' : '\n';
        }
      }
      s += "</DataArray>\n";
    };
    if (with_displacement) array("displacement", displacement);
    for (const auto& [name, values] : point_vectors) array(name, values);
    s += "</PointData>\n";
  }
  const bool with_vm = von_mises.size() == m && m > 0;
  const bool with_ratio = volume_ratio.size() == m && m > 0;
  if (with_vm || with_ratio) {
    s += with_vm ? "<CellData Scalars=\"von_mises\">\n" : "<CellData Scalars=\"volume_ratio\">\n";
    if (with_vm) appendScalarArray(&s, "von_mises", von_mises);
    if (with_ratio) {
      // det F: current / rest signed volume; inverted: 1 where det F <= 0
      appendScalarArray(&s, "volume_ratio", volume_ratio);
      s += "<DataArray type=\"UInt8\" Name=\"inverted\" format=\"ascii\">\n";
      for (Eigen::Index c = 0; c < m; ++c) s += volume_ratio(c) > 0.0 ? "0\n" : "1\n";
      s += "</DataArray>\n";
    }
    s += "</CellData>\n";
  }
  s += "</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
  writeFile(path, s);
}

void writePvd(const std::filesystem::path& path, const std::vector<std::string>& files,
              const std::vector<double>& times_s) {
  if (files.size() != times_s.size()) {
    throw Error(fmt::format("{}: writePvd got {} files for {} times", path.string(), files.size(),
                            times_s.size()));
  }
  std::string s = "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\">\n"
                  "<Collection>\n";
  for (std::size_t i = 0; i < files.size(); ++i) {
    s += "<DataSet timestep=\"";
    appendDouble(&s, times_s[i]);
    s += fmt::format("\" group=\"\" part=\"0\" file=\"{}\"/>\n", xmlEscape(files[i]));
  }
  s += "</Collection>\n</VTKFile>\n";
  writeFile(path, s);
}

}  // namespace tactus::sim

// VTK output: writeVtu reads back identically through the .vtu reader; writePvd lists its files.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>

#include <unistd.h>

#include "tactus/shared/error.h"
#include "tactus/sim/mesh.h"
#include "tactus/sim/vtk_writer.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kVtkMeshes = std::filesystem::path(TACTUS_TEST_DATA_DIR) / "meshes";

std::filesystem::path tempDir() {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("tactus_vtk_writer_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  return dir;
}

std::string readFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

TEST(VtkWriter, VtuRoundTripIsExact) {
  const TetMesh mesh = loadTetMesh(kVtkMeshes / "liver2.msh");
  Eigen::Matrix3Xd displacement = Eigen::Matrix3Xd::Random(3, mesh.nodeCount()) * 1e-3;
  const Eigen::Matrix3Xd positions = mesh.nodes + displacement;
  const Eigen::VectorXd von_mises = Eigen::VectorXd::LinSpaced(mesh.tetCount(), 0.0, 1234.5);
  const auto path = tempDir() / "liver2_000.vtu";
  writeVtu(path, mesh, positions, displacement, von_mises);

  MeshReport report;
  const TetMesh back = loadTetMesh(path, &report);
  EXPECT_EQ(report.format, "vtu");
  EXPECT_EQ(back.nodes, positions);  // shortest round-trip text: bit-exact
  EXPECT_EQ(back.tets, mesh.tets);
  const std::string text = readFile(path);
  EXPECT_THAT(text, ::testing::HasSubstr("Name=\"displacement\" NumberOfComponents=\"3\""));
  EXPECT_THAT(text, ::testing::HasSubstr("Name=\"von_mises\""));
  EXPECT_THAT(text, ::testing::HasSubstr("1234.5\n"));
  std::filesystem::remove_all(path.parent_path());
}

TEST(VtkWriter, OptionalFieldsMayBeEmpty) {
  const TetMesh mesh = loadTetMesh(kVtkMeshes / "single_tetra.msh");
  const auto path = tempDir() / "single.vtu";
  writeVtu(path, mesh, mesh.nodes, Eigen::Matrix3Xd(3, 0), Eigen::VectorXd());
  const std::string text = readFile(path);
  EXPECT_THAT(text, ::testing::Not(::testing::HasSubstr("displacement")));
  EXPECT_THAT(text, ::testing::Not(::testing::HasSubstr("von_mises")));
  EXPECT_EQ(loadTetMesh(path).nodes, mesh.nodes);
  std::filesystem::remove_all(path.parent_path());
}

TEST(VtkWriter, SizeMismatchAndUnwritablePathThrow) {
  const TetMesh mesh = loadTetMesh(kVtkMeshes / "single_tetra.msh");
  const auto dir = tempDir();
  EXPECT_THROW(writeVtu(dir / "a.vtu", mesh, Eigen::Matrix3Xd(3, 3), Eigen::Matrix3Xd(3, 0),
                        Eigen::VectorXd()),
               Error);
  EXPECT_THROW(writeVtu(dir / "a.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(3, 0),
                        Eigen::VectorXd(2)),
               Error);
  EXPECT_THROW(writeVtu(dir / "no" / "such" / "a.vtu", mesh, mesh.nodes, Eigen::Matrix3Xd(3, 0),
                        Eigen::VectorXd()),
               Error);
  std::filesystem::remove_all(dir);
}

TEST(VtkWriter, PvdListsFilesAndTimes) {
  const auto path = tempDir() / "run.pvd";
  writePvd(path, {"run_000.vtu", "run_001.vtu"}, {0.0, 0.25});
  const std::string text = readFile(path);
  EXPECT_THAT(text, ::testing::HasSubstr("type=\"Collection\""));
  EXPECT_THAT(text, ::testing::HasSubstr("<DataSet timestep=\"0\" group=\"\" part=\"0\" "
                                         "file=\"run_000.vtu\"/>"));
  EXPECT_THAT(text, ::testing::HasSubstr("<DataSet timestep=\"0.25\" group=\"\" part=\"0\" "
                                         "file=\"run_001.vtu\"/>"));
  EXPECT_THROW(writePvd(path, {"a.vtu"}, {}), Error);
  std::filesystem::remove_all(path.parent_path());
}

}  // namespace
}  // namespace tactus::sim

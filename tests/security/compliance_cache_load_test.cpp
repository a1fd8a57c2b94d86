// Compliance cache loading (sim_server/src/fem/compliance_cache.cpp, readCache): the chunked load
// (the file mapped, checksum and finiteness check per chunk) gives a C0 bit-identical
// to the precomputed one, and a truncated, padded, corrupt or old-format file is rejected and
// rebuilt, never trusted. The box mesh is large enough (386 surface nodes: a 10.7 MB double and
// a 5.4 MB float C0) for the payload to span several load chunks with a partial last one.

#include <gtest/gtest.h>
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <vector>

#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/mesh_gen.h"
#include "tactus/shared/error.h"
#include "tactus/sim/scene.h"

namespace fs = std::filesystem;
using namespace tactus::sim;

namespace {

constexpr std::size_t kHeaderBytes = 40;  // sizeof(CacheHeader)

class CacheDir {
 public:
  CacheDir() {
    std::string templ = (fs::temp_directory_path() / "tactus_cache_load_XXXXXX").string();
    if (::mkdtemp(templ.data()) == nullptr) throw std::runtime_error("mkdtemp failed");
    path = templ;
  }
  ~CacheDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
  fs::path path;
};

std::string readCacheFile(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeAll(const fs::path& file, const std::string& bytes) {
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(out.good()) << file;
}

class CacheLoad : public ::testing::TestWithParam<bool> {
 protected:
  void SetUp() override {
    spdlog::set_level(spdlog::level::err);
    mesh_ = makeBoxTetMesh(8, 8, 8, Eigen::Vector3d(0.08, 0.08, 0.08));
    FemMaterial material;
    material.young_pa = 5000.0;
    material.poisson = 0.4;
    body_ = std::make_unique<FemBody>(mesh_, material, std::vector<int>{0, 1, 2, 3}, nullptr);
    opt_.h_s = 0.01;
    opt_.cache_dir = dir_.path;
    opt_.show_progress = false;
    opt_.cache_name = "box";
    opt_.c0_single_precision = GetParam();
    // three rows (x, y, z) on every surface node: W = C0 exactly at rest
    for (int node : body_->surfaceNodes())
      for (int k = 0; k < 3; ++k) {
        TissueRow row;
        row.node = {node, -1, -1};
        row.weight = {1.0, 0.0, 0.0};
        row.dir = Eigen::Vector3d::Unit(k);
        rows_.push_back(row);
      }
  }
  void TearDown() override { spdlog::set_level(spdlog::level::info); }

  Eigen::MatrixXd w(TissueCompliance& model) {
    model.update(*body_);
    const auto m = static_cast<Eigen::Index>(rows_.size());
    Eigen::MatrixXd out = Eigen::MatrixXd::Zero(m, m);
    model.addW(rows_, out);
    return out;
  }
  static bool bitIdentical(const Eigen::MatrixXd& a, const Eigen::MatrixXd& b) {
    return a.rows() == b.rows() && a.cols() == b.cols() &&
           std::memcmp(a.data(), b.data(), sizeof(double) * static_cast<std::size_t>(a.size())) ==
               0;
  }
  fs::path file() const { return complianceCachePath(*body_, opt_); }

  CacheDir dir_;
  TetMesh mesh_;
  std::unique_ptr<FemBody> body_;
  ComplianceOptions opt_;
  std::vector<TissueRow> rows_;
};

TEST_P(CacheLoad, LoadedCacheGivesBitIdenticalW) {
  auto built = makeCompliance(ComplianceKind::kWarped, *body_, opt_);
  ASSERT_FALSE(built->buildInfo().loaded_from_cache);
  ASSERT_TRUE(fs::exists(file()));
  const std::size_t scalar = GetParam() ? sizeof(float) : sizeof(double);
  const std::size_t d = 3 * body_->surfaceNodes().size();
  ASSERT_GT(d * d * scalar, std::size_t{4} << 20) << "C0 must span several load chunks";
  const Eigen::MatrixXd w_built = w(*built);
  ASSERT_TRUE(w_built.allFinite());
  ASSERT_GT(w_built.diagonal().maxCoeff(), 0.0);
  ASSERT_GE(w_built.diagonal().minCoeff(), 0.0);

  auto loaded = makeCompliance(ComplianceKind::kWarped, *body_, opt_);
  EXPECT_TRUE(loaded->buildInfo().loaded_from_cache) << loaded->buildInfo().cache_message;
  EXPECT_FALSE(loaded->buildInfo().cache_rejected);
  EXPECT_TRUE(bitIdentical(w(*loaded), w_built));
  // the uncoupled model reads the same cache and keeps only the diagonal
  auto uncoupled = makeCompliance(ComplianceKind::kUncoupled, *body_, opt_);
  EXPECT_TRUE(uncoupled->buildInfo().loaded_from_cache);
}

// Each case rebuilds C0 (about a second): run for the double cache only; the float cache's
// rejections go through the same code (and the fuzz regression test covers both).
class CacheReject : public CacheLoad {};

TEST_P(CacheReject, TruncatedPaddedCorruptOrOldFilesAreRejectedAndRebuilt) {
  Eigen::MatrixXd w_ref;
  {
    auto built = makeCompliance(ComplianceKind::kWarped, *body_, opt_);
    w_ref = w(*built);
  }
  const std::string valid = readCacheFile(file());
  ASSERT_GT(valid.size(), kHeaderBytes + 8);

  struct Case {
    const char* name;
    std::string bytes;
    const char* reason;  // part of the rejection message
  };
  std::vector<Case> cases;
  cases.push_back({"truncated by 8 bytes", valid.substr(0, valid.size() - 8), "size"});
  cases.push_back({"one byte appended", valid + '\0', "more than"});
  // in the node list, a middle chunk and the partial last chunk
  for (std::size_t at : {kHeaderBytes + 1, valid.size() / 2, valid.size() - 13}) {
    std::string bytes = valid;
    bytes[at] = static_cast<char>(bytes[at] ^ 0x10);
    cases.push_back({"one payload bit flipped", bytes, "checksum"});
  }
  {
    // two words of one lane swapped (same bytes, other order)
    std::string bytes = valid;
    const std::size_t a = kHeaderBytes + 64, b = a + 32;
    std::string word_a = bytes.substr(a, 8);
    bytes.replace(a, 8, bytes.substr(b, 8));
    bytes.replace(b, 8, word_a);
    ASSERT_NE(bytes, valid);
    cases.push_back({"two words swapped", bytes, "checksum"});
  }
  {
    std::string bytes = valid;
    const std::uint32_t old_version = 1;
    std::memcpy(bytes.data() + 8, &old_version, sizeof(old_version));
    cases.push_back({"format version 1", bytes, "version"});
  }
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    writeAll(file(), c.bytes);
    auto model = makeCompliance(ComplianceKind::kWarped, *body_, opt_);
    const ComplianceBuildInfo info = model->buildInfo();
    EXPECT_TRUE(info.cache_rejected);
    EXPECT_FALSE(info.loaded_from_cache);
    EXPECT_NE(info.cache_message.find(c.reason), std::string::npos) << info.cache_message;
    EXPECT_TRUE(bitIdentical(w(*model), w_ref));  // rebuilt, not the damaged values
    EXPECT_EQ(readCacheFile(file()), valid);      // and the file rewritten
    auto again = makeCompliance(ComplianceKind::kWarped, *body_, opt_);
    EXPECT_TRUE(again->buildInfo().loaded_from_cache) << again->buildInfo().cache_message;
  }
}

// The scene asks for a float C0 with compliance.c0_precision; anything else is refused.
TEST(CacheScene, C0PrecisionKeySelectsFloat) {
  const fs::path scenes = fs::path(TACTUS_TEST_DATA_DIR) / "scenes";
  const auto parse = [&](const std::string& compliance) {
    return parseScene("time_step: 0.005\ntissues:\n  - mesh: ../meshes/liver.msh\n"
                      "    compliance: " +
                          compliance + "\n",
                      "s.yaml", scenes);
  };
  EXPECT_FALSE(parse("{model: warped}").tissues.at(0).c0_single_precision);
  EXPECT_FALSE(parse("{model: warped, c0_precision: double}").tissues.at(0).c0_single_precision);
  EXPECT_TRUE(parse("{model: warped, c0_precision: float}").tissues.at(0).c0_single_precision);
  EXPECT_THROW(parse("{model: warped, c0_precision: half}"), tactus::SceneError);
}

INSTANTIATE_TEST_SUITE_P(Precision, CacheLoad, ::testing::Values(false, true),
                         [](const auto& info) { return info.param ? "Float" : "Double"; });
INSTANTIATE_TEST_SUITE_P(Precision, CacheReject, ::testing::Values(false),
                         [](const auto&) { return "Double"; });

}  // namespace

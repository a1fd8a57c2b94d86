// Replays the compliance-cache fuzz corpus and the saved crashing inputs through makeCompliance
// (layout in tests/fuzz/feed_compliance.h: a flag byte, then the cache file): every file is
// loaded or rejected and rebuilt, never a throw, a crash or a non-finite W.
#include <gtest/gtest.h>

#include <spdlog/spdlog.h>

#include "../../fuzz/feed_compliance.h"
#include "../../fuzz/regression_inputs.h"

namespace tactus::fuzz {
namespace {

class ComplianceCacheFuzzRegression : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    spdlog::set_level(spdlog::level::err);  // every rejected cache logs a warning
    target_ = new ComplianceCacheTarget();
  }
  static void TearDownTestSuite() {
    delete target_;
    target_ = nullptr;
    spdlog::set_level(spdlog::level::info);
  }
  static ComplianceCacheTarget* target_;
};
ComplianceCacheTarget* ComplianceCacheFuzzRegression::target_ = nullptr;

TEST_F(ComplianceCacheFuzzRegression, ValidCachesLoadAndDamagedOnesAreRebuilt) {
  using T = ComplianceCacheTarget;
  for (bool single : {false, true}) {
    SCOPED_TRACE(single ? "float" : "double");
    const unsigned char prec = single ? T::kSingle : 0;
    EXPECT_TRUE(target_->feed(target_->validInput(single, prec)));
    EXPECT_TRUE(target_->feed(target_->validInput(single, prec | T::kStampHash | T::kFixChecksum)));
    // one payload byte flipped: the checksum rejects it; with the checksum fixed it still loads
    std::string damaged = target_->validInput(single, prec);
    damaged[damaged.size() / 2] ^= 0x01;
    EXPECT_FALSE(target_->feed(damaged));
    damaged[0] = static_cast<char>(prec | T::kFixChecksum);
    EXPECT_TRUE(target_->feed(damaged));
    // another hash: stale unless the hash is stamped back
    std::string stale = target_->validInput(single, prec);
    stale[1 + T::kHashOffset] ^= 0x40;
    EXPECT_FALSE(target_->feed(stale));
    stale[0] = static_cast<char>(prec | T::kStampHash);
    EXPECT_TRUE(target_->feed(stale));
    // truncated, empty, header only, wrong precision
    const std::string valid = target_->validInput(single, prec);
    EXPECT_FALSE(target_->feed(valid.substr(0, valid.size() - 9)));
    EXPECT_FALSE(target_->feed(std::string(1, static_cast<char>(prec))));
    EXPECT_FALSE(target_->feed(valid.substr(0, 1 + T::kHeaderBytes)));
    EXPECT_FALSE(target_->feed(target_->validInput(!single, prec | T::kStampHash)));
  }
}

TEST_F(ComplianceCacheFuzzRegression, CorpusAndSavedCrashesAreLoadedOrRebuilt) {
  const auto seeds = inputFiles(corpusDir("compliance_cache"));
  EXPECT_GE(seeds.size(), 2u) << corpusDir("compliance_cache");
  auto files = seeds;
  for (const auto& f : inputFiles(regressionDir("compliance_cache"))) files.push_back(f);
  for (const auto& f : files) {
    SCOPED_TRACE(f.string());
    bool loaded = false;
    EXPECT_NO_THROW(loaded = target_->feed(readBytes(f)));
    // seeds with the hash stamped and the checksum fixed (flags 3 / 7) are complete caches
    const std::string name = f.filename().string();
    if (name.find("_flags3.") != std::string::npos || name.find("_flags7.") != std::string::npos) {
      EXPECT_TRUE(loaded);
    }
  }
}

}  // namespace
}  // namespace tactus::fuzz

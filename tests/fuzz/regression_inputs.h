#pragma once
// Inputs the gtest regression tests replay through the fuzz targets (feed_<parser>.h): the seed
// corpus tests/fuzz/corpus/<parser>/ and the crashing inputs scripts/fuzz.sh saved in
// tests/data/fuzz_regressions/<parser>/ (README files skipped).

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace tactus::fuzz {

/// Sorted regular files of `dir` except README*; empty when the folder does not exist.
inline std::vector<std::filesystem::path> inputFiles(const std::filesystem::path& dir) {
  std::vector<std::filesystem::path> files;
  if (!std::filesystem::is_directory(dir)) return files;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (!entry.is_regular_file()) continue;
    if (entry.path().filename().string().rfind("README", 0) == 0) continue;
    files.push_back(entry.path());
  }
  std::sort(files.begin(), files.end());
  return files;
}

inline std::filesystem::path corpusDir(const std::string& parser) {
  return std::filesystem::path(TACTUS_SOURCE_DIR) / "tests" / "fuzz" / "corpus" / parser;
}

inline std::filesystem::path regressionDir(const std::string& parser) {
  return std::filesystem::path(TACTUS_TEST_DATA_DIR) / "fuzz_regressions" / parser;
}

inline std::string readBytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

}  // namespace tactus::fuzz

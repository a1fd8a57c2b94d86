#pragma once
// The FCLIB problems under tests/data/fclib (problems/*.fc3d.txt; the Siconos reference solutions
// in reference/), listed in name order, and the ones several tests single out.

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "tactus/shared/fclib.h"

namespace tactus::test {

/// tests/data/fclib/problems/*, sorted. `data_dir` is tests/data.
inline std::vector<std::filesystem::path> fclibProblemFiles(const std::filesystem::path& data_dir) {
  std::vector<std::filesystem::path> out;
  for (const auto& e : std::filesystem::directory_iterator(data_dir / "fclib" / "problems")) {
    out.push_back(e.path());
  }
  std::sort(out.begin(), out.end());
  return out;
}

/// A problem file's name without ".fc3d.txt".
inline std::string fclibStem(const std::filesystem::path& path) {
  const std::string n = path.filename().string();
  return n.substr(0, n.size() - std::string(".fc3d.txt").size());
}

/// Box_Stacks-i0122-82-5: a steadily converging multi-contact problem.
inline shared::FclibProblem fclibBoxStacks(const std::filesystem::path& data_dir) {
  return shared::readFclibText(data_dir / "fclib" / "problems" /
                               "Box_Stacks-i0122-82-5.local.fc3d.txt");
}

}  // namespace tactus::test

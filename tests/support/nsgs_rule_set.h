#pragma once
// The problem set the NSGS relaxation rule is measured and tested on (tests/bench/
// nsgs_rule_bench.cpp prints the table, nsgs_stagnation_test asserts the criterion): the FCLIB problems, the
// cycling mu = 2 drag problem, and generated sphere piles, capsule piles and redundant tissue
// patches.

#include <algorithm>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "contact_generators.h"
#include "fclib_set.h"
#include "sphere_pile.h"
#include "tactus/shared/fclib.h"

namespace tactus::test {

struct NamedProblem {
  std::string name;
  DenseProblem problem;
};

/// Reads an FCLIB text file into a DenseProblem.
inline DenseProblem fromFclib(const shared::FclibProblem& f) {
  DenseProblem p;
  p.row_offset = f.row_offset;
  p.W = f.W;
  p.q = f.q;
  p.mu = f.mu;
  return p;
}

/// `data_dir` is tests/data.
inline std::vector<NamedProblem> nsgsRuleSet(const std::filesystem::path& data_dir) {
  std::vector<NamedProblem> set;
  std::vector<std::filesystem::path> files = fclibProblemFiles(data_dir);
  files.push_back(data_dir / "nsgs" / "drag_mu2_cycle.fc3d.txt");
  for (const auto& path : files) {
    set.push_back({fclibStem(path), fromFclib(shared::readFclibText(path))});
  }
  for (unsigned seed = 1; seed <= 5; ++seed) {
    set.push_back({"spheres20_mu2_s" + std::to_string(seed), spherePile(20, seed, 2.0)});
    set.push_back({"spheres40_mu0.8_s" + std::to_string(seed), spherePile(40, seed, 0.8)});
  }
  for (unsigned seed = 1; seed <= 3; ++seed) {
    set.push_back({"capsules4x3_mu0.8_s" + std::to_string(seed), capsulePile(4, 3, seed, 0.8)});
    set.push_back({"capsules4x3_mu2_s" + std::to_string(seed), capsulePile(4, 3, seed, 2.0)});
    set.push_back({"patch5x3_mu0.8_s" + std::to_string(seed), redundantPatch(5, 3, seed, 0.8)});
    set.push_back({"patch5x3_mu2_s" + std::to_string(seed), redundantPatch(5, 3, seed, 2.0)});
  }
  return set;
}

}  // namespace tactus::test

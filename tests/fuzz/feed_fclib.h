#pragma once
// Fuzz target for the FCLIB text readers (problem and reference), shared by the libFuzzer harness
// (fclib_fuzz.cpp, which writes each input to a temporary file) and the regression test
// (tests/unit/shared, which reads the files directly).
//
// Contract checked: readFclibText / readFclibReference return or throw tactus::Error; an accepted
// problem has consistent sizes (mu: nc, q: 3 nc, W: m x m) and finite values.

#include <cmath>
#include <filesystem>
#include <stdexcept>

#include "tactus/shared/error.h"
#include "tactus/shared/fclib.h"

namespace tactus::fuzz {

/// Reads `path` as a problem and as a reference. Returns how many of the two readers accepted it
/// (0..2); throws std::logic_error on a broken invariant.
inline int feedFclibFile(const std::filesystem::path& path) {
  int accepted = 0;
  try {
    const shared::FclibProblem p = shared::readFclibText(path);
    const auto nc = static_cast<std::size_t>(p.contacts);
    if (p.contacts < 1 || p.mu.size() != nc || p.q.size() != 3 * nc ||
        p.W.size() != 9 * nc * nc || p.row_offset.size() != nc + 1) {
      throw std::logic_error("fclib problem accepted with inconsistent sizes");
    }
    for (double w : p.W) {
      if (!std::isfinite(w)) throw std::logic_error("fclib problem accepted with non-finite W");
    }
    ++accepted;
  } catch (const tactus::Error&) {
  }
  try {
    const shared::FclibReference r = shared::readFclibReference(path);
    if (r.r.size() != r.u.size()) throw std::logic_error("fclib reference r/u sizes differ");
    ++accepted;
  } catch (const tactus::Error&) {
  }
  return accepted;
}

}  // namespace tactus::fuzz

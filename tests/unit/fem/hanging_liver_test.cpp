// Inverted elements recover: liver2 (1493 tets, E = 3 kPa) fixed at its lowest 10 % hangs under
// gravity for 3 s, then the load is removed for 3 s (tests/support/hanging_liver.h). With the
// invertible neo-Hookean law no tetrahedron is inverted at the end and few while it hangs; the
// larger livers run in hanging_liver_study (minutes each).
#include <gtest/gtest.h>

#include <cstdio>

#include "../../support/hanging_liver.h"

namespace tactus::sim {
namespace {

const std::string kLiver2 = std::string(TACTUS_SOURCE_DIR) + "/scenes/meshes/liver2.msh";

void print(const char* what, const test_support::HangingLiverResult& r) {
  std::printf("[hanging] liver2, %s: hanging: inverted max %d, at release %d, smallest det F "
              "%.3f; released: at the end %d, smallest det F %.3f\n",
              what, r.inverted_max_hanging, r.inverted_end_hanging, r.min_ratio_hanging,
              r.inverted_end, r.min_ratio_end);
}

TEST(HangingLiver, TheInvertibleLawLeavesNoInvertedTetOnceTheLoadIsRemoved) {
  test_support::HangingLiverOptions o;
  o.law = MaterialLaw::kInvertibleNeoHookean;
  const auto r = test_support::hangLiver(kLiver2, o);
  print("invertible neo-Hookean", r);
  EXPECT_TRUE(r.ok);
  EXPECT_EQ(r.inverted_end, 0);
  EXPECT_GT(r.min_ratio_end, 0.5);
  // the bound while it hangs: at most 2 % of the tets at any step start (measured 13 of 1493,
  // against 137 with the corotational law: docs/measurements.md)
  EXPECT_LE(r.inverted_max_hanging, r.tets / 50);
}

}  // namespace
}  // namespace tactus::sim

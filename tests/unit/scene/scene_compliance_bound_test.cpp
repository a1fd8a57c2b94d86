// compliance.exact_below_coherence (ComplianceOptions::exact_below_coherence): read into the
// tissue spec, absent = off, outside [0, 1] or not a number refused with the field's path.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

SceneSpec parseCompliance(const std::string& compliance) {
  const std::filesystem::path scenes = std::filesystem::path(TACTUS_TEST_DATA_DIR) / "scenes";
  return parseScene("time_step: 0.005\ntissues:\n  - mesh: ../meshes/liver.msh\n"
                    "    compliance: " + compliance + "\n",
                    "s.yaml", scenes);
}

TEST(SceneComplianceBound, ReadRangeCheckedAndOffByDefault) {
  EXPECT_EQ(parseCompliance("{model: warped}").tissues.at(0).exact_below_coherence, 0.0);
  EXPECT_EQ(parseCompliance("{model: warped, exact_below_coherence: 0.9995}")
                .tissues.at(0).exact_below_coherence, 0.9995);
  for (const char* bad : {"-0.1", "1.5", "nan", "yes"}) {
    try {
      parseCompliance(std::string("{model: warped, exact_below_coherence: ") + bad + "}");
      ADD_FAILURE() << bad << " accepted";
    } catch (const SceneError& e) {
      EXPECT_NE(std::string(e.what()).find("compliance.exact_below_coherence"), std::string::npos)
          << e.what();
    }
  }
}

}  // namespace
}  // namespace tactus::sim

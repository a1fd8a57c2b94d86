// The scene's `instruments:` list (several god objects): values, the single
// `instrument:` form as a list of one, and the errors with file:line:col.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>

#include "tactus/shared/error.h"
#include "tactus/shared/messages.h"
#include "../../support/scene_snippet.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

using ::testing::HasSubstr;
using ::testing::StartsWith;

const std::filesystem::path& kScenes = test_support::kSceneDir;
const std::string& kHead = test_support::kSceneHead;
std::string error(const std::string& yaml) { return test_support::snippetError(yaml); }

TEST(SceneInstruments, ListGivesEachInstrumentItsOwnValues) {
  const SceneSpec s = parseScene(kHead +
                                     "instruments:\n"
                                     "  - {name: left, type: grasper, friction: 0.4,\n"
                                     "     coupling: {stiffness: 800}}\n"
                                     "  - {name: right, type: probe, friction: 0,\n"
                                     "     probe: {tip_radius: 0.004}, contact_compliance: 1e-4}\n"
                                     "solver: {max_contacts: 120}\n",
                                 "s.yaml", kScenes);
  ASSERT_EQ(instrumentCount(s), 2);
  EXPECT_EQ(s.instrument.name, "left");
  EXPECT_EQ(s.instrument.kind, InstrumentKind::kGrasper);
  EXPECT_DOUBLE_EQ(s.instrument.friction_mu, 0.4);
  EXPECT_DOUBLE_EQ(s.instrument.coupling_k_npm, 800.0);
  const InstrumentSpec& right = instrumentSpec(s, 1);
  EXPECT_TRUE(right.present);
  EXPECT_EQ(right.name, "right");
  EXPECT_EQ(right.kind, InstrumentKind::kProbe);
  EXPECT_DOUBLE_EQ(right.friction_mu, 0.0);
  EXPECT_DOUBLE_EQ(right.tip_radius_m, 0.004);
  EXPECT_DOUBLE_EQ(right.contact_compliance_mpn, 1e-4);
  EXPECT_DOUBLE_EQ(right.coupling_k_npm, InstrumentSpec{}.coupling_k_npm);   // its own default
  EXPECT_TRUE(anyFriction(s));
  EXPECT_EQ(problemContactCapacity(s), 240);   // max_contacts per instrument
}

TEST(SceneInstruments, SingleInstrumentFormIsAListOfOne) {
  const SceneSpec one = parseScene(kHead + "instrument: {type: probe, friction: 0.2}\n", "s.yaml",
                                   kScenes);
  const SceneSpec list = parseScene(kHead + "instruments:\n  - {type: probe, friction: 0.2}\n",
                                    "s.yaml", kScenes);
  EXPECT_EQ(instrumentCount(one), 1);
  EXPECT_EQ(instrumentCount(list), 1);
  EXPECT_DOUBLE_EQ(one.instrument.friction_mu, list.instrument.friction_mu);
  EXPECT_TRUE(one.additional_instruments.empty());
  EXPECT_EQ(problemContactCapacity(one), one.solver.max_contacts);
  const SceneSpec none = parseScene(kHead, "s.yaml", kScenes);
  EXPECT_EQ(instrumentCount(none), 0);
  EXPECT_FALSE(anyFriction(none));
}

TEST(SceneInstruments, ErrorsNameTheInstrumentAndPosition) {
  // a range error inside the second instrument names its index, line and column
  EXPECT_THAT(error("instruments:\n  - {type: probe}\n  - {type: probe, friction: -1}\n"),
              StartsWith("s.yaml:6:29: instruments[1].friction: must be >= 0 (got -1)"));
  EXPECT_THAT(error("instruments:\n  - {type: probe}\n  - {type: probe, mass: .nan}\n"),
              HasSubstr("instruments[1].mass"));
  // both forms
  EXPECT_THAT(error("instrument: {type: probe}\ninstruments:\n  - {type: probe}\n"),
              HasSubstr("give either `instrument:` (one) or `instruments:` (a list), not both"));
  // empty list, too many, not a list, an item not a map
  EXPECT_THAT(error("instruments: []\n"), HasSubstr("must be a list of 1 to 4 instrument maps"));
  std::string five = "instruments:\n";
  for (int i = 0; i <= shared::kMaxInstruments; ++i) five += "  - {type: probe}\n";
  EXPECT_THAT(error(five), HasSubstr("instruments: must be a list of 1 to 4 instrument maps "
                                     "(got 5 items)"));
  EXPECT_THAT(error("instruments: {type: probe}\n"), HasSubstr("(got a map)"));
  EXPECT_THAT(error("instruments:\n  - 3\n"),
              StartsWith("s.yaml:5:5: instruments[0]: must be a map"));
  // unknown keys, names
  EXPECT_THAT(error("instruments:\n  - {type: probe, colour: red}\n"),
              HasSubstr("instruments[0].colour"));
  EXPECT_THAT(error("instruments:\n  - {name: a, type: probe}\n  - {name: a, type: probe}\n"),
              HasSubstr("instruments[1].name: 'a' is already the name of instruments[0]"));
  EXPECT_THAT(error("instruments:\n  - {name: 'a b', type: probe}\n"),
              HasSubstr("instruments[0].name: must be 1 to 32 letters, digits, _ or -"));
  // the problem's size grows with the instruments: max_contacts x instruments must fit
  EXPECT_EQ(error("instruments:\n  - {type: probe}\nsolver: {max_contacts: 3000}\n"),
            "(no error)");
  EXPECT_THAT(error("instruments:\n  - {type: probe}\n  - {type: probe}\n"
                    "solver: {max_contacts: 3000}\n"),
              HasSubstr("solver.max_contacts: 6000 contacts need"));
}

}  // namespace
}  // namespace tactus::sim

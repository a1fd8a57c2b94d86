// hanging_liver_study: a liver mesh fixed at its lowest 10 % hangs under gravity, then springs
// back without it (tests/support/hanging_liver.h); prints the inverted tetrahedra while it hangs
// and at the end, for each law asked. The test command runs liver2 (hanging_liver_test); this
// tool runs the larger meshes (minutes each), e.g.
//   build/tools/hanging_liver_study/hanging_liver_study --mesh scenes/meshes/liver_23k.msh --law invertible_neo_hookean
#include "tactus/shared/cli.h"
#include <cstdio>
#include <string>
#include <vector>

#include "support/hanging_liver.h"
#include "tactus/shared/error.h"

int main(int argc, char** argv) {
  using tactus::sim::MaterialLaw;
  namespace cli = tactus::shared::cli;
  cli::App app{"hanging_liver_study: inverted tetrahedra of a liver hanging from its base"};
  app.footer(
      "Example:\n"
      "  hanging_liver_study --mesh scenes/meshes/liver_23k.msh --law invertible_neo_hookean");
  std::vector<std::string> meshes;
  std::vector<std::string> laws{"corotational", "invertible_neo_hookean"};
  tactus::test_support::HangingLiverOptions o;
  bool smoothed = false;
  app.addOption("--mesh", meshes, "Mesh files (decimetres, z up)")
      ->required()
      ->check(cli::existingFile());
  app.addOption("--law", laws, "corotational, consistent (its full tangent), "
                                "invertible_neo_hookean")
      ->check(cli::isMember({"corotational", "consistent", "invertible_neo_hookean"}));
  app.addOption("--young", o.young_pa, "Young's modulus [Pa]")->check(cli::range(10.0, 1e9));
  app.addOption("--hang-s", o.hang_s, "Time under gravity [s]")->check(cli::range(0.01, 100.0));
  app.addOption("--release-s", o.release_s, "Time after [s]")->check(cli::range(0.0, 100.0));
  app.addOption("--dt", o.h_s, "Time step [s]")->check(cli::range(1e-5, 0.1));
  app.addFlag("--edge-smoothed", smoothed, "Edge-smoothed tetrahedra");
  TACTUS_CLI_PARSE(app, argc, argv);
  if (smoothed) o.element = tactus::sim::ElementKind::kEdgeSmoothedTet;
  try {
    for (const std::string& mesh : meshes)
      for (const std::string& law : laws) {
        o.law = law == "invertible_neo_hookean" ? MaterialLaw::kInvertibleNeoHookean
                                                : MaterialLaw::kCorotational;
        o.tangent = law == "consistent" ? tactus::sim::TangentKind::kConsistent
                                        : tactus::sim::TangentKind::kCorotated;
        const auto r = tactus::test_support::hangLiver(mesh, o);
        std::printf("%s (%d tets), %s%s: hanging: inverted max %d, at release %d, smallest det F "
                    "%.3f; released: inverted max %d, at the end %d, smallest det F %.3f, "
                    "kinetic %.2e J%s\n",
                    mesh.c_str(), r.tets, law.c_str(), smoothed ? ", edge-smoothed" : "",
                    r.inverted_max_hanging, r.inverted_end_hanging, r.min_ratio_hanging,
                    r.inverted_max_released, r.inverted_end, r.min_ratio_end, r.kinetic_end_j,
                    r.ok ? "" : " (a step failed)");
        std::fflush(stdout);
      }
  } catch (const tactus::Error& e) {
    std::fprintf(stderr, "hanging_liver_study: %s\n", e.what());
    return 1;
  }
  return 0;
}

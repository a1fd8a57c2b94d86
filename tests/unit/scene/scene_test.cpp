// Scene loader: full scene values, defaults, absent effects, and exact error messages.

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include <filesystem>
#include <random>
#include <fstream>
#include <sstream>

#include "tactus/shared/error.h"
#include "tactus/sim/scene.h"

namespace tactus::sim {
namespace {

const std::filesystem::path kData = TACTUS_TEST_DATA_DIR;
const std::filesystem::path kSceneFiles = kData / "scenes";

std::filesystem::path normal(const std::filesystem::path& p) {
  return std::filesystem::absolute(p).lexically_normal();
}

// Parses `yaml` as "s.yaml" located in tests/data/scenes; returns the error message.
std::string sceneError(const std::string& yaml) {
  try {
    parseScene(yaml, "s.yaml", kSceneFiles);
  } catch (const SceneError& e) {
    return e.what();
  }
  return "(no error)";
}

// A valid prefix: errors below are in the lines that follow it.
const std::string kFullHead =
    "time_step: 0.01\n"
    "tissues:\n"
    "  - mesh: ../meshes/liver.msh\n";

TEST(Scene, FullSceneParsesToTheExpectedValues) {
  const SceneSpec s = loadScene(kSceneFiles / "full_scene.yaml");
  EXPECT_EQ(s.source, kSceneFiles / "full_scene.yaml");
  EXPECT_DOUBLE_EQ(s.time_step_s, 0.01);
  EXPECT_DOUBLE_EQ(s.duration_s, 10.0);
  ASSERT_TRUE(s.gravity_mps2.has_value());
  EXPECT_EQ(*s.gravity_mps2, Eigen::Vector3d(0, 0, -9.81));

  ASSERT_EQ(s.tissues.size(), 2u);
  const TissueSpec& liver = s.tissues[0];
  EXPECT_EQ(liver.name, "liver");
  EXPECT_EQ(liver.mesh_path, normal(kData / "meshes" / "liver2.msh"));
  EXPECT_TRUE(liver.mesh_path.is_absolute());
  EXPECT_DOUBLE_EQ(liver.scale, 0.1);
  EXPECT_EQ(liver.rotation_deg, Eigen::Vector3d(90, 0, 0));
  EXPECT_EQ(liver.translation_m, Eigen::Vector3d(0.01, 0.02, 0.03));
  EXPECT_EQ(liver.law, MaterialLaw::kCorotational);
  EXPECT_DOUBLE_EQ(liver.young_pa, 3000.0);
  EXPECT_DOUBLE_EQ(liver.poisson, 0.45);
  EXPECT_DOUBLE_EQ(liver.density_kgpm3, 1000.0);
  ASSERT_TRUE(liver.damping.has_value());
  EXPECT_DOUBLE_EQ(liver.damping->mass_alpha_per_s, 0.1);
  EXPECT_DOUBLE_EQ(liver.damping->stiffness_beta_s, 0.01);
  EXPECT_EQ(liver.fixed_nodes, (std::vector<int>{1, 2, 3}));
  ASSERT_EQ(liver.fixed_boxes.size(), 1u);
  EXPECT_EQ(liver.fixed_boxes[0].min_m, Eigen::Vector3d(-1, -1, -1));
  EXPECT_EQ(liver.fixed_boxes[0].max_m, Eigen::Vector3d(1, 1, -0.5));
  EXPECT_EQ(liver.compliance, ComplianceKind::kExact);
  EXPECT_EQ(liver.compliance_cache_dir, normal(kSceneFiles / "cache"));

  const TissueSpec& cube = s.tissues[1];
  EXPECT_EQ(cube.name, "cube");
  EXPECT_EQ(cube.law, MaterialLaw::kLinear);
  EXPECT_DOUBLE_EQ(cube.young_pa, 1e5);
  EXPECT_FALSE(cube.damping.has_value());
  EXPECT_EQ(cube.compliance, ComplianceKind::kWarped);

  const InstrumentSpec& in = s.instrument;
  EXPECT_TRUE(in.present);
  EXPECT_EQ(in.kind, InstrumentKind::kGrasper);
  EXPECT_DOUBLE_EQ(in.mass_kg, 0.05);
  EXPECT_DOUBLE_EQ(in.inertia_kgm2, 1e-5);
  EXPECT_DOUBLE_EQ(in.coupling_k_npm, 500);
  EXPECT_DOUBLE_EQ(in.coupling_b_nspm, 5);
  EXPECT_DOUBLE_EQ(in.coupling_k_rot_nmprad, 0.5);
  EXPECT_DOUBLE_EQ(in.coupling_b_rot_nmsprad, 0.005);
  EXPECT_DOUBLE_EQ(in.friction_mu, 0.8);
  EXPECT_DOUBLE_EQ(in.alarm_distance_m, 0.004);
  EXPECT_DOUBLE_EQ(in.contact_distance_m, 0.001);
  EXPECT_DOUBLE_EQ(in.tip_radius_m, 0.003);
  EXPECT_DOUBLE_EQ(in.shaft_length_m, 0.05);
  EXPECT_DOUBLE_EQ(in.jaw_length_m, 0.02);
  EXPECT_DOUBLE_EQ(in.jaw_radius_m, 0.002);
  EXPECT_NEAR(in.max_opening_rad, 35.0 * M_PI / 180.0, 1e-15);
  EXPECT_EQ(in.jaw_samples, 8);
  EXPECT_EQ(in.initial_pose.position_m, Eigen::Vector3d(0, 0, 0.1));
  // 90 degrees about z takes x to y
  EXPECT_TRUE((in.initial_pose.orientation * Eigen::Vector3d::UnitX())
                  .isApprox(Eigen::Vector3d::UnitY(), 1e-12));
  ASSERT_EQ(in.trajectory.size(), 2u);
  EXPECT_DOUBLE_EQ(in.trajectory[0].t_s, 0.0);
  EXPECT_DOUBLE_EQ(in.trajectory[0].gripper_opening, 1.0);
  EXPECT_TRUE(in.trajectory[0].pose.orientation.isApprox(Eigen::Quaterniond::Identity()));
  EXPECT_DOUBLE_EQ(in.trajectory[1].t_s, 1.5);
  EXPECT_EQ(in.trajectory[1].pose.position_m, Eigen::Vector3d(0, 0, 0.05));
  EXPECT_TRUE(in.trajectory[1].pose.orientation.isApprox(Eigen::Quaterniond(0, 1, 0, 0)));
  EXPECT_DOUBLE_EQ(in.trajectory[1].gripper_opening, 0.25);

  EXPECT_EQ(s.solver.linear, LinearSolverKind::kPcg);
  EXPECT_DOUBLE_EQ(s.solver.cg_tolerance, 1e-9);
  EXPECT_EQ(s.solver.cg_max_iterations, 400);
  EXPECT_DOUBLE_EQ(s.solver.nsgs_tolerance, 1e-7);
  EXPECT_EQ(s.solver.nsgs_max_sweeps, 300);
  EXPECT_DOUBLE_EQ(s.solver.nsgs_sor, 1.2);
  EXPECT_EQ(s.solver.nsgs_anderson_depth, 3);
  EXPECT_EQ(s.solver.max_contacts, 200);

  EXPECT_TRUE(s.haptics.enabled);
  EXPECT_DOUBLE_EQ(s.haptics.rate_hz, 2000);
  EXPECT_DOUBLE_EQ(s.haptics.force_scale, 0.5);
  EXPECT_DOUBLE_EQ(s.haptics.max_force_n, 6.0);
  EXPECT_DOUBLE_EQ(s.haptics.watchdog_ms, 40);
  EXPECT_EQ(s.haptics.max_sweeps_per_tick, 30);
  EXPECT_DOUBLE_EQ(s.haptics.nsgs_tolerance, 1e-5);

  EXPECT_TRUE(s.output.enabled);
  EXPECT_EQ(s.output.directory, std::filesystem::path("out/liver"));
  EXPECT_EQ(s.output.every_n_steps, 10);
}

TEST(Scene, MinimalSceneTakesDefaultsAndLeavesEffectsAbsent) {
  const SceneSpec s = loadScene(kSceneFiles / "minimal_scene.yaml");
  const SceneSpec def;
  const TissueSpec tdef;
  EXPECT_DOUBLE_EQ(s.time_step_s, 0.005);
  EXPECT_DOUBLE_EQ(s.duration_s, 0.0);
  EXPECT_FALSE(s.gravity_mps2.has_value());
  ASSERT_EQ(s.tissues.size(), 1u);
  const TissueSpec& t = s.tissues[0];
  EXPECT_EQ(t.name, "tissue");
  EXPECT_EQ(t.mesh_path, normal(kData / "meshes" / "liver.msh"));
  EXPECT_DOUBLE_EQ(t.scale, 1.0);
  EXPECT_EQ(t.rotation_deg, Eigen::Vector3d::Zero());
  EXPECT_EQ(t.translation_m, Eigen::Vector3d::Zero());
  EXPECT_EQ(t.law, MaterialLaw::kCorotational);
  EXPECT_DOUBLE_EQ(t.young_pa, tdef.young_pa);
  EXPECT_DOUBLE_EQ(t.poisson, tdef.poisson);
  EXPECT_DOUBLE_EQ(t.density_kgpm3, tdef.density_kgpm3);
  EXPECT_FALSE(t.damping.has_value());
  EXPECT_TRUE(t.fixed_nodes.empty());
  EXPECT_TRUE(t.fixed_boxes.empty());
  EXPECT_EQ(t.compliance, ComplianceKind::kWarped);
  EXPECT_TRUE(t.compliance_cache_dir.empty());
  EXPECT_FALSE(s.instrument.present);
  EXPECT_FALSE(s.haptics.enabled);
  EXPECT_FALSE(s.output.enabled);
  EXPECT_EQ(s.solver.linear, def.solver.linear);
  EXPECT_EQ(s.solver.max_contacts, def.solver.max_contacts);
  EXPECT_DOUBLE_EQ(s.solver.nsgs_sor, def.solver.nsgs_sor);
  EXPECT_EQ(s.solver.nsgs_anderson_depth, 0);
}

TEST(Scene, SectionsPresentWithDefaults) {
  const SceneSpec s = parseScene(kFullHead +
                                     "    damping: {}\n"
                                     "instrument: {}\n"
                                     "haptics: {rate: 500}\n",
                                 "s.yaml", kSceneFiles);
  ASSERT_TRUE(s.tissues[0].damping.has_value());
  EXPECT_EQ(s.tissues[0].damping->mass_alpha_per_s, 0.0);
  EXPECT_TRUE(s.instrument.present);
  EXPECT_EQ(s.instrument.kind, InstrumentKind::kProbe);
  EXPECT_EQ(s.instrument.friction_mu, 0.0);
  EXPECT_TRUE(s.haptics.enabled);  // a haptics section turns haptics on
  EXPECT_EQ(s.haptics.rate_hz, 500);
  EXPECT_FALSE(
      parseScene(kFullHead + "haptics: {enabled: false}\n", "s.yaml", kSceneFiles).haptics.enabled);
}

TEST(Scene, ContactDetectionAndFaceContacts) {
  const SceneSpec def = parseScene(kFullHead + "instrument: {}\n", "s.yaml", kSceneFiles);
  EXPECT_EQ(def.solver.contact_detection, ContactDetection::kFreeState);
  EXPECT_TRUE(def.instrument.face_contacts);
  const SceneSpec s = parseScene(kFullHead +
                                     "instrument: {face_contacts: false}\n"
                                     "solver: {contact_detection: step_start}\n",
                                 "s.yaml", kSceneFiles);
  EXPECT_EQ(s.solver.contact_detection, ContactDetection::kStepStart);
  EXPECT_FALSE(s.instrument.face_contacts);
  EXPECT_EQ(
      parseScene(kFullHead + "solver: {contact_detection: free_state}\n", "s.yaml", kSceneFiles)
          .solver.contact_detection,
      ContactDetection::kFreeState);
  EXPECT_EQ(sceneError(kFullHead + "solver: {contact_detection: later}\n"),
            "s.yaml:4:29: solver.contact_detection: must be one of free_state, step_start (got "
            "'later')");
}

TEST(Scene, RotationSmoothing) {
  const auto parse = [](const std::string& compliance) {
    return parseScene(kFullHead + "    compliance: " + compliance + "\n", "s.yaml", kSceneFiles);
  };
  EXPECT_EQ(parse("{model: warped}").tissues.at(0).rotation_smoothing_passes, 0);
  EXPECT_EQ(
      parse("{model: warped, rotation_smoothing: 2}").tissues.at(0).rotation_smoothing_passes, 2);
  EXPECT_THROW(parse("{model: warped, rotation_smoothing: -1}"), SceneError);
  EXPECT_THROW(parse("{model: warped, rotation_smoothing: 11}"), SceneError);
  EXPECT_THROW(parse("{model: warped, rotation_smoothing: 1.5}"), SceneError);
}

TEST(Scene, StrainLimit) {
  const auto parse = [](const std::string& limit) {
    return parseScene(kFullHead + "    strain_limit: " + limit + "\n", "s.yaml", kSceneFiles);
  };
  EXPECT_EQ(parseScene(kFullHead, "s.yaml", kSceneFiles).tissues.at(0).min_volume_ratio, 0.0);
  EXPECT_EQ(parse("{min_volume_ratio: 0.5}").tissues.at(0).min_volume_ratio, 0.5);
  EXPECT_THROW(parse("{min_volume_ratio: -0.1}"), SceneError);
  EXPECT_THROW(parse("{min_volume_ratio: 1.0}"), SceneError);
  EXPECT_THROW(parse("{min_ratio: 0.5}"), SceneError);
}

TEST(Scene, LawTangentAndElement) {
  const auto tissue = [](const std::string& lines) {
    return parseScene(kFullHead + lines, "s.yaml", kSceneFiles).tissues.at(0);
  };
  const TissueSpec def = tissue("");
  EXPECT_EQ(def.law, MaterialLaw::kCorotational);
  EXPECT_EQ(def.tangent, TangentKind::kCorotated);
  EXPECT_EQ(def.element, ElementKind::kLinearTet);
  const TissueSpec s = tissue("    material: {law: corotational, tangent: consistent}\n"
                              "    element: edge_smoothed_tet\n");
  EXPECT_EQ(s.tangent, TangentKind::kConsistent);
  EXPECT_EQ(s.element, ElementKind::kEdgeSmoothedTet);
  EXPECT_EQ(tissue("    material: {law: invertible_neo_hookean}\n").law,
            MaterialLaw::kInvertibleNeoHookean);
  EXPECT_EQ(sceneError(kFullHead + "    material: {law: linear, tangent: consistent}\n"),
            "s.yaml:4:38: tissues[0].material.tangent: 'consistent' is a linearisation of the "
            "corotational law only (the linear law's tangent is exact, invertible_neo_hookean "
            "always uses its full tangent)");
  EXPECT_EQ(sceneError(kFullHead + "    material: {tangent: exact}\n"),
            "s.yaml:4:25: tissues[0].material.tangent: must be one of corotated, consistent (got "
            "'exact')");
  EXPECT_EQ(sceneError(kFullHead + "    element: quadratic_tet\n"),
            "s.yaml:4:14: tissues[0].element: must be one of linear_tet, edge_smoothed_tet (got "
            "'quadratic_tet')");
}

TEST(Scene, SplitContactGroups) {
  EXPECT_TRUE(parseScene(kFullHead, "s.yaml", kSceneFiles).solver.split_contact_groups);
  EXPECT_FALSE(
      parseScene(kFullHead + "solver: {split_contact_groups: false}\n", "s.yaml", kSceneFiles)
          .solver.split_contact_groups);
  EXPECT_NE(sceneError(kFullHead + "solver: {split_contact_groups: 3}\n")
                .find("solver.split_contact_groups"),
            std::string::npos);
}

TEST(Scene, LinearSolverStrategies) {
  const SceneSpec def = parseScene(kFullHead, "s.yaml", kSceneFiles);
  EXPECT_EQ(def.solver.linear, LinearSolverKind::kCholmod);
  EXPECT_EQ(def.solver.refactor_iterations, 8);
  EXPECT_EQ(def.solver.refactor_every_steps, 0);
  EXPECT_EQ(def.solver.background_refactor_lag_steps, 0);
  EXPECT_EQ(def.solver.background_refactor_free_lag_steps, 0);
  EXPECT_FALSE(def.solver.background_refactor_when_ready);
  EXPECT_EQ(def.solver.preconditioner_precision, PreconditionerPrecision::kDouble);
  const SceneSpec s = parseScene(
      kFullHead +
          "solver: {linear: cholmod_reuse, refactor_iterations: 12, refactor_every_steps: 50,\n"
          "         background_refactor_lag_steps: 2, background_refactor_when_ready: true,\n"
          "         background_refactor_free_lag_steps: 4,\n"
          "         preconditioner_precision: half}\n",
      "s.yaml", kSceneFiles);
  EXPECT_EQ(s.solver.background_refactor_lag_steps, 2);
  EXPECT_EQ(s.solver.background_refactor_free_lag_steps, 4);
  EXPECT_TRUE(s.solver.background_refactor_when_ready);
  EXPECT_EQ(s.solver.preconditioner_precision, PreconditionerPrecision::kHalf);
  EXPECT_EQ(parseScene(kFullHead + "solver: {preconditioner_precision: float}\n", "s.yaml",
                       kSceneFiles)
                .solver.preconditioner_precision,
            PreconditionerPrecision::kFloat);
  EXPECT_EQ(sceneError(kFullHead + "solver: {preconditioner_precision: single}\n"),
            "s.yaml:4:36: solver.preconditioner_precision: must be one of double, float, half "
            "(got 'single')");
  // the key it replaced: a clear error, not a silent double
  EXPECT_EQ(sceneError(kFullHead + "solver: {single_precision_preconditioner: true}\n"),
            "s.yaml:4:43: solver.single_precision_preconditioner: replaced by "
            "solver.preconditioner_precision (double, float or half): write "
            "`preconditioner_precision: float` for `true`, or leave both out for `false`");
  EXPECT_EQ(s.solver.linear, LinearSolverKind::kCholmodReuse);
  EXPECT_EQ(s.solver.refactor_iterations, 12);
  EXPECT_EQ(s.solver.refactor_every_steps, 50);
  EXPECT_EQ(sceneError(kFullHead + "solver: {linear: lu}\n"),
            "s.yaml:4:18: solver.linear: must be one of cholmod, pcg, cholmod_reuse (got 'lu')");
  EXPECT_EQ(sceneError(kFullHead + "solver: {refactor_iterations: 0}\n"),
            "s.yaml:4:31: solver.refactor_iterations: must be >= 1 (got 0)");
  EXPECT_EQ(sceneError(kFullHead + "solver: {refactor_every_steps: -1}\n"),
            "s.yaml:4:32: solver.refactor_every_steps: must be >= 0 (got -1)");
  EXPECT_EQ(sceneError(kFullHead + "solver: {refactor_iterations: 20000}\n"),
            "s.yaml:4:31: solver.refactor_iterations: must be in [1, 10000] (got 20000)");
  EXPECT_EQ(sceneError(kFullHead + "solver: {background_refactor_lag_steps: -1}\n"),
            "s.yaml:4:41: solver.background_refactor_lag_steps: must be >= 0 (got -1)");
  EXPECT_EQ(sceneError(kFullHead + "solver: {background_refactor_free_lag_steps: -1}\n"),
            "s.yaml:4:46: solver.background_refactor_free_lag_steps: must be >= 0 (got -1)");
}

TEST(Scene, EulerAnglesApplyXThenYThenZ) {
  const SceneSpec s = parseScene(kFullHead +
                                     "instrument:\n"
                                     "  initial_pose: {rotation_deg: [90, 0, 90]}\n",
                                 "s.yaml", kSceneFiles);
  const Eigen::Quaterniond q = s.instrument.initial_pose.orientation;
  // R = Rz(90) Rx(90): x -> x -> y, y -> z -> z
  EXPECT_TRUE((q * Eigen::Vector3d::UnitX()).isApprox(Eigen::Vector3d::UnitY(), 1e-12));
  EXPECT_TRUE((q * Eigen::Vector3d::UnitY()).isApprox(Eigen::Vector3d::UnitZ(), 1e-12));
}

TEST(Scene, RelativeMeshPathResolvedAgainstTheSceneFolder) {
  const SceneSpec s = parseScene(kFullHead, "s.yaml", kSceneFiles);
  EXPECT_EQ(s.tissues[0].mesh_path, normal(kData / "meshes" / "liver.msh"));
  // the same text seen from another folder does not find the mesh
  EXPECT_EQ(
      [&] {
        try {
          parseScene(kFullHead, "s.yaml", kData);
        } catch (const SceneError& e) {
          return std::string(e.what());
        }
        return std::string();
      }(),
      "s.yaml:3:11: tissues[0].mesh: mesh file not found: " +
          normal(kData / ".." / "meshes" / "liver.msh").string() +
          " (relative paths are resolved against the scene file's folder)");
}

TEST(Scene, EachKindOfErrorHasItsExactMessage) {
  EXPECT_EQ(sceneError("time_step: 0\ntissues:\n  - mesh: ../meshes/liver.msh\n"),
            "s.yaml:1:12: time_step: must be > 0 (got 0)");
  EXPECT_EQ(sceneError("tissues:\n  - mesh: ../meshes/liver.msh\n"),
            "s.yaml:1:1: time_step: is required");
  EXPECT_EQ(sceneError("time_step: 0.01\n"),
            "s.yaml:1:1: tissues: is required (a list with at least one tissue)");
  EXPECT_EQ(sceneError("time_step: 0.01\ntissues: []\n"),
            "s.yaml:2:10: tissues: must be a list with at least one tissue (got an empty list)");
  EXPECT_EQ(
      sceneError(kFullHead + "timestep: 0.01\n"),
      "s.yaml:4:1: timestep: unknown key (expected one of: time_step, duration, gravity, "
      "tissues, instrument, instruments, solver, haptics, output, obstacles, obstacle_contact, "
      "tissue_contact)");
  // a key that was removed says where its setting went, not only that it is unknown
  EXPECT_EQ(sceneError(kFullHead + "haptics: {rate: 1000, device: simulated}\n"),
            "s.yaml:4:23: haptics.device: no longer a scene key: the device backend is chosen "
            "where haptic_server starts (scripts/start.sh --device NAME|PATH.so, haptic_server "
            "--device); delete the line");
  EXPECT_EQ(sceneError(kFullHead + "duration: ten\n"),
            "s.yaml:4:11: duration: must be a number (got 'ten')");
  EXPECT_EQ(sceneError(kFullHead + "gravity: [0, -9.81]\n"),
            "s.yaml:4:10: gravity: must be a list of 3 numbers (got 2 items)");
  EXPECT_EQ(sceneError(kFullHead + "    material: {young_modulus: -3000}\n"),
            "s.yaml:4:31: tissues[0].material.young_modulus: must be > 0 (got -3000)");
  EXPECT_EQ(sceneError(kFullHead + "    material: {poisson_ratio: 0.5}\n"),
            "s.yaml:4:31: tissues[0].material.poisson_ratio: must be in (-1, 0.5) (got 0.5)");
  EXPECT_EQ(sceneError(kFullHead + "    material: {density: 0}\n"),
            "s.yaml:4:25: tissues[0].material.density: must be > 0 (got 0)");
  EXPECT_EQ(sceneError(kFullHead + "    material: {law: neo_hookean}\n"),
            "s.yaml:4:21: tissues[0].material.law: must be one of linear, corotational, "
            "invertible_neo_hookean (got 'neo_hookean')");
  EXPECT_EQ(sceneError(kFullHead + "    damping: {rayleigh_mass: -0.1}\n"),
            "s.yaml:4:30: tissues[0].damping.rayleigh_mass: must be >= 0 (got -0.1)");
  EXPECT_EQ(sceneError(kFullHead + "    fixed: {nodes: [1, x]}\n"),
            "s.yaml:4:24: tissues[0].fixed.nodes[1]: must be an integer node index (got 'x')");
  EXPECT_EQ(sceneError(kFullHead + "    fixed: {boxes: [{min: [0, 0, 1], max: [1, 1, 0]}]}\n"),
            "s.yaml:4:43: tissues[0].fixed.boxes[0].max: must be >= min in every coordinate");
  EXPECT_EQ(sceneError(kFullHead + "    compliance: {model: fast}\n"),
            "s.yaml:4:25: tissues[0].compliance.model: must be one of exact, warped, rest, "
            "uncoupled (got 'fast')");
  EXPECT_EQ(sceneError(kFullHead + "    compliance: {correction: fast}\n"),
            "s.yaml:4:30: tissues[0].compliance.correction: must be one of model, exact (got "
            "'fast')");
  EXPECT_EQ(sceneError(kFullHead + "    transform: 0.1\n"),
            "s.yaml:4:16: tissues[0].transform: must be a map (got '0.1')");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {friction: -0.5}\n"),
            "s.yaml:4:24: instrument.friction: must be >= 0 (got -0.5)");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {type: scalpel}\n"),
            "s.yaml:4:20: instrument.type: must be one of probe, grasper (got 'scalpel')");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {grasper: {samples: 2.5}}\n"),
            "s.yaml:4:33: instrument.grasper.samples: must be an integer (got '2.5')");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {grasper: {width: -0.001}}\n"),
            "s.yaml:4:31: instrument.grasper.width: must be >= 0 (got -0.001)");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {grasper: {grip_stiffness: -1}}\n"),
            "s.yaml:4:40: instrument.grasper.grip_stiffness: must be >= 0 (got -1)");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {grasper: {grip_squeeze: -0.01}}\n"),
            "s.yaml:4:38: instrument.grasper.grip_squeeze: must be >= 0 (got -0.01)");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {grasper: {width_samples: 0}}\n"),
            "s.yaml:4:39: instrument.grasper.width_samples: must be >= 1 (got 0)");
  EXPECT_EQ(sceneError(kFullHead + "instrument: {initial_pose: {quaternion: [2, 0, 0, 0]}}\n"),
            "s.yaml:4:41: instrument.initial_pose.quaternion: must be a unit quaternion "
            "[w, x, y, z] (norm is 2)");
  EXPECT_EQ(sceneError(kFullHead + "instrument:\n  trajectory:\n"
                                   "    - {t: 1.0, position: [0, 0, 0]}\n"
                                   "    - {t: 1.0, position: [0, 0, 0], gripper: 1.5}\n"),
            "s.yaml:7:11: instrument.trajectory[1].t: must be greater than the previous key's t "
            "(1)\n"
            "s.yaml:7:46: instrument.trajectory[1].gripper: must be in [0, 1] (got 1.5)");
  EXPECT_EQ(sceneError(kFullHead + "instrument:\n  trajectory:\n    - {position: [0, 0, 0]}\n"),
            "s.yaml:6:7: instrument.trajectory[0].t: is required");
  EXPECT_EQ(sceneError(kFullHead + "solver: {nsgs_sor: 2}\n"),
            "s.yaml:4:20: solver.nsgs_sor: must be in (0, 2) (got 2)");
  EXPECT_EQ(sceneError(kFullHead + "solver: {pcg_local_correction_threshold: 1.5}\n"),
            "s.yaml:4:42: solver.pcg_local_correction_threshold: must be in [0, 1] (got 1.5)");
  EXPECT_EQ(sceneError(kFullHead + "solver: {nsgs_anderson_depth: 9}\n"),
            "s.yaml:4:31: solver.nsgs_anderson_depth: must be in [0, 8] (got 9)");
  EXPECT_EQ(sceneError(kFullHead + "haptics: {nsgs_anderson_depth: -1}\n"),
            "s.yaml:4:32: haptics.nsgs_anderson_depth: must be >= 0 (got -1)");
  EXPECT_EQ(sceneError(kFullHead + "haptics: {local_model: reduced}\n"),
            "s.yaml:4:24: haptics.local_model: must be one of automatic, full, linearized (got "
            "'reduced')");
  EXPECT_EQ(sceneError(kFullHead + "haptics: {snapshot_blend_ms: 200}\n"),
            "s.yaml:4:30: haptics.snapshot_blend_ms: must be <= 100 (got 200): not a physically "
            "sensible value");
  EXPECT_EQ(sceneError(kFullHead + "solver: {max_contacts: 0}\n"),
            "s.yaml:4:24: solver.max_contacts: must be >= 1 (got 0)");
  EXPECT_EQ(sceneError(kFullHead + "haptics: {enabled: maybe}\n"),
            "s.yaml:4:20: haptics.enabled: must be true or false (got 'maybe')");
  EXPECT_EQ(sceneError(kFullHead + "output: {every: 10}\n"), "s.yaml:4:9: output.vtk: is required");
  EXPECT_EQ(sceneError(kFullHead + "duration: 1\nduration: 2\n"),
            "s.yaml:5:1: duration: duplicate key");
  EXPECT_EQ(sceneError("time_step: 0.01\ntissues:\n  - mesh: ../meshes/nowhere.msh\n"),
            "s.yaml:3:11: tissues[0].mesh: mesh file not found: " +
                normal(kData / "meshes" / "nowhere.msh").string() +
                " (relative paths are resolved against the scene file's folder)");
}

TEST(Scene, AllProblemsAreReportedAtOnceInDocumentOrder) {
  const std::string yaml =
      "time_step: -1\n"
      "tissues:\n"
      "  - mesh: ../meshes/liver.msh\n"
      "    material: {young_modulus: 0, poisson_ratio: 0.7, colour: red}\n"
      "instrument: {friction: -1}\n";
  EXPECT_EQ(sceneError(yaml),
            "s.yaml:1:12: time_step: must be > 0 (got -1)\n"
            "s.yaml:4:31: tissues[0].material.young_modulus: must be > 0 (got 0)\n"
            "s.yaml:4:49: tissues[0].material.poisson_ratio: must be in (-1, 0.5) (got 0.7)\n"
            "s.yaml:4:54: tissues[0].material.colour: unknown key (expected one of: law, "
            "tangent, young_modulus, poisson_ratio, density)\n"
            "s.yaml:5:24: instrument.friction: must be >= 0 (got -1)");
}

TEST(Scene, YamlSyntaxErrorsNameFileLineAndColumn) {
  EXPECT_THAT(sceneError("time_step: 0.01\ntissues: [\n  - a\n"),
              ::testing::MatchesRegex("s\\.yaml:[0-9]+:[0-9]+: YAML syntax error: .+"));
  EXPECT_EQ(sceneError("time_step: 0.01\n  bad: indentation\n"),
            "s.yaml:2:6: YAML syntax error: illegal map value");
  EXPECT_EQ(sceneError("- 1\n- 2\n"), "s.yaml:1:1: scene: must be a map of settings (got a list)");
  EXPECT_EQ(sceneError(""), "s.yaml:1:1: scene: must be a map of settings (got nothing)");
}

TEST(Scene, ReadmeExampleIsValid) {
  const std::filesystem::path readme = std::filesystem::path(TACTUS_SOURCE_DIR) / "scenes";
  std::ifstream in(readme / "README.md");
  std::stringstream text;
  text << in.rdbuf();
  const std::string md = text.str();
  const std::size_t begin = md.find("```yaml\n");
  ASSERT_NE(begin, std::string::npos);
  const std::size_t end = md.find("```", begin + 8);
  ASSERT_NE(end, std::string::npos);
  const SceneSpec s = parseScene(md.substr(begin + 8, end - begin - 8), "README.md", readme);
  EXPECT_EQ(s.tissues.at(0).mesh_path, normal(readme / "meshes" / "liver2.msh"));
  EXPECT_TRUE(s.instrument.present);
  EXPECT_EQ(s.instrument.trajectory.size(), 2u);
  EXPECT_TRUE(s.haptics.enabled);
  EXPECT_TRUE(s.output.enabled);
}

// Random corruption of a valid scene: a SceneSpec or a SceneError, never anything else.
TEST(Scene, CorruptedInputGivesSceneErrorOnly) {
  std::ifstream in(kSceneFiles / "full_scene.yaml");
  std::stringstream text;
  text << in.rdbuf();
  const std::string good = text.str();
  const std::string alphabet = "{}[]:,-#&*!|>'\"%@ \n\t0123456789.eE+abcxyz";
  std::mt19937 rng(7);
  int rejected = 0;
  for (int trial = 0; trial < 400; ++trial) {
    std::string bad = good;
    const int edits = 1 + static_cast<int>(rng() % 3);
    for (int e = 0; e < edits; ++e) {
      bad[rng() % bad.size()] = alphabet[rng() % alphabet.size()];
    }
    try {
      parseScene(bad, "fuzz.yaml", kSceneFiles);
    } catch (const SceneError& e) {
      ++rejected;
      EXPECT_THAT(e.what(), ::testing::StartsWith("fuzz.yaml:"));
    }
  }
  EXPECT_GT(rejected, 100);
}

// Physical sanity: impossible or memory-exhausting values are errors naming file:line:col and the
// field; merely unusual ones are warnings in the same form.
std::vector<std::string> sceneWarnings(const std::string& yaml) {
  return parseScene(yaml, "s.yaml", kSceneFiles).warnings;
}

TEST(Scene, AbsurdValuesAreErrorsWithFileLineColumnAndField) {
  using ::testing::HasSubstr;
  using ::testing::StartsWith;
  EXPECT_THAT(sceneError(kFullHead + "solver: {max_contacts: 2000000000}\n"),
              StartsWith("s.yaml:4:24: solver.max_contacts: 2000000000 contacts need too many MiB "
                         "for the contact problem"));
  EXPECT_THAT(sceneError(kFullHead + "solver: {max_contacts: 5000}\n"),
              StartsWith("s.yaml:4:24: solver.max_contacts: 5000 contacts need "));
  EXPECT_THAT(sceneError(kFullHead + "gravity: [0, 0, -1e300]\n"),
              StartsWith("s.yaml:4:17: gravity[2]: must be in [-1000, 1000] (got -1e+300): not a "
                         "physically sensible value"));
  EXPECT_THAT(sceneError(kFullHead + "instrument: {probe: {tip_radius: 1e6}}\n"),
              StartsWith("s.yaml:4:34: instrument.probe.tip_radius: must be <= 1 (got"));
  EXPECT_THAT(sceneError("time_step: 1e9\ntissues:\n  - mesh: ../meshes/liver.msh\n"),
              StartsWith("s.yaml:1:12: time_step: must be <= 1 (got"));
  EXPECT_THAT(sceneError(kFullHead + "instrument: {initial_pose: {position: [0, 1e300, 0]}}\n"),
              StartsWith("s.yaml:4:43: instrument.initial_pose.position[1]: must be in [-1000, "
                         "1000]"));
  EXPECT_THAT(sceneError(kFullHead + "    material: {young_modulus: 1e20, density: 1e9}\n"),
              HasSubstr("tissues[0].material.young_modulus: must be <= 1000000000000 (got"));
  EXPECT_THAT(sceneError(kFullHead + "    material: {young_modulus: 1e20, density: 1e9}\n"),
              HasSubstr("tissues[0].material.density: must be <= 100000 (got"));
  EXPECT_THAT(sceneError(kFullHead + "instrument: {grasper: {samples: 1000000}}\n"),
              StartsWith("s.yaml:4:33: instrument.grasper.samples: must be in [1, 10000] (got "
                         "1000000)"));
  EXPECT_THAT(sceneError(kFullHead + "instrument: {mass: 1e30}\n"),
              StartsWith("s.yaml:4:20: instrument.mass: must be <= 1000"));
  EXPECT_THAT(sceneError(kFullHead + "haptics: {max_force: 1e9}\n"),
              StartsWith("s.yaml:4:22: haptics.max_force: must be <= 50"));
  EXPECT_THAT(sceneError(kFullHead + "haptics: {rate: 1e12}\n"),
              StartsWith("s.yaml:4:17: haptics.rate: must be in [50, 4000]"));
  EXPECT_THAT(sceneError(kFullHead + "duration: 1e300\n"),
              StartsWith("s.yaml:4:11: duration: must be <= 10000000"));
  EXPECT_THAT(sceneError(kFullHead + "solver: {nsgs_max_sweeps: 2000000000}\n"),
              StartsWith("s.yaml:4:27: solver.nsgs_max_sweeps: must be in [1, 10000000]"));
  EXPECT_THAT(
      sceneError(kFullHead + "instrument: {workspace: {min: [0, 0, 0], max: [1, 1e9, 1]}}\n"),
      StartsWith("s.yaml:4:51: instrument.workspace.max[1]: must be in [-1000, 1000]"));
  EXPECT_THAT(
      sceneError(kFullHead + "instrument: {workspace: {min: [0, 0, 0], max: [1, -1, 1]}}\n"),
      StartsWith("s.yaml:4:47: instrument.workspace.max: must be >= min in every "
                 "coordinate"));
}

TEST(Scene, UnusualValuesAreWarningsWithFileLineColumnAndField) {
  using ::testing::ElementsAre;
  using ::testing::HasSubstr;
  using ::testing::StartsWith;
  EXPECT_THAT(sceneWarnings("time_step: 0.5\ntissues:\n  - mesh: ../meshes/liver.msh\n"),
              ElementsAre(StartsWith("s.yaml:1:12: time_step: unusual value 0.5 (plausible: in "
                                     "[1e-05, 0.05])")));
  EXPECT_THAT(sceneWarnings(kFullHead + "gravity: [0, 0, -98.1]\n"),
              ElementsAre(StartsWith("s.yaml:4:17: gravity[2]: unusual value -98.1")));
  EXPECT_THAT(sceneWarnings(kFullHead + "instrument: {probe: {tip_radius: 0.3}}\n"),
              ElementsAre(StartsWith("s.yaml:4:34: instrument.probe.tip_radius: unusual value "
                                     "0.3")));
  EXPECT_THAT(sceneWarnings(kFullHead + "solver: {max_contacts: 3000}\n"),
              ElementsAre(StartsWith("s.yaml:4:24: solver.max_contacts: unusual value 3000")));
  EXPECT_THAT(sceneWarnings(kFullHead + "haptics: {max_force: 45}\n"),
              ElementsAre(HasSubstr("haptics.max_force: unusual value 45")));
  // warnings come in document order, and a usual scene has none
  EXPECT_THAT(sceneWarnings(kFullHead + "    material: {young_modulus: 2, density: 50000}\n"),
              ElementsAre(StartsWith("s.yaml:4:31: tissues[0].material.young_modulus"),
                          StartsWith("s.yaml:4:43: tissues[0].material.density")));
  EXPECT_TRUE(sceneWarnings(kFullHead).empty());
  EXPECT_TRUE(loadScene(kSceneFiles / "full_scene.yaml").warnings.empty());
}

TEST(Scene, InstrumentWorkspace) {
  const SceneSpec s = parseScene(
      kFullHead + "instrument: {workspace: {min: [-0.1, -0.2, -0.3], max: [0.1, 0.2, 0.3]}}\n",
      "s.yaml", kSceneFiles);
  ASSERT_TRUE(s.instrument.workspace.has_value());
  EXPECT_EQ(s.instrument.workspace->min_m, Eigen::Vector3d(-0.1, -0.2, -0.3));
  EXPECT_EQ(s.instrument.workspace->max_m, Eigen::Vector3d(0.1, 0.2, 0.3));
  EXPECT_FALSE(parseScene(kFullHead + "instrument: {}\n", "s.yaml", kSceneFiles)
                   .instrument.workspace.has_value());
}

TEST(Scene, ShippedScenesLoad) {
  int count = 0;
  for (const auto& entry :
       std::filesystem::directory_iterator(std::filesystem::path(TACTUS_SOURCE_DIR) / "scenes")) {
    if (entry.path().extension() != ".yaml") continue;
    SCOPED_TRACE(entry.path().string());
    const SceneSpec s = loadScene(entry.path());
    EXPECT_FALSE(s.tissues.empty());
    EXPECT_TRUE(s.warnings.empty()) << s.warnings.front();
    ++count;
  }
  EXPECT_GE(count, 1);
}

TEST(Scene, MissingSceneFile) {
  EXPECT_THROW(loadScene(kSceneFiles / "no_such_scene.yaml"), SceneError);
}

}  // namespace
}  // namespace tactus::sim

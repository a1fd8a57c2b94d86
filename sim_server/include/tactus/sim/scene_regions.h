#pragma once
// Scene description, organs touching: node regions (selectors for fixed
// nodes and loads) and static obstacles. Included by scene.h; parsed by scene_regions.cpp and
// scene_obstacles.cpp; documented in scenes/README.md ("Regions", "Obstacles").

#include <Eigen/Core>
#include <filesystem>
#include <string>
#include <vector>

namespace tactus::sim {

/// How a region chooses its nodes (positions after the tissue's transform, at rest).
enum class RegionKind {
  kBox,        ///< nodes inside the axis-aligned box [min_m, max_m]
  kPlaneSide,  ///< nodes with (x - point_m) . normal >= -tolerance_m (the side the normal points to)
  kLowest,     ///< nodes with x[axis] <= min over the mesh of x[axis] + tolerance_m
  kHighest,    ///< nodes with x[axis] >= max over the mesh of x[axis] - tolerance_m
  kGroup,      ///< the nodes of a physical group of the mesh (TetMesh::groups), by name or tag
};

/// A set of nodes of one tissue chosen by a selector. A region that selects no node is an error
/// naming it (`where`), raised when the scene's model is built (selectRegionNodes).
struct RegionSpec {
  RegionKind kind = RegionKind::kBox;
  Eigen::Vector3d min_m = Eigen::Vector3d::Zero();      ///< kBox
  Eigen::Vector3d max_m = Eigen::Vector3d::Zero();      ///< kBox
  Eigen::Vector3d point_m = Eigen::Vector3d::Zero();    ///< kPlaneSide: a point of the plane
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();    ///< kPlaneSide: unit normal
  int axis = 2;                                         ///< kLowest/kHighest: 0 x, 1 y, 2 z
  double tolerance_m = 0.0;                             ///< see RegionKind
  /// kGroup: a group's name; when no group has that name and it is an integer, a physical tag
  std::string group;
  /// Where the scene defines it ("file:line:col: path"), for messages; empty when built in code.
  std::string where;
};

enum class LoadKind {
  kForce,          ///< a total force spread evenly over the region's nodes
  kPressure,       ///< a pressure on the surface triangles whose three nodes are in the region
  kDisplacement,   ///< the region's nodes moved along a path (they become Dirichlet nodes)
};

/// One key of a prescribed displacement path: the offset from the rest position at t_s
/// (linear between keys; the first offset before the first key, the last after the last).
struct DisplacementKey {
  double t_s = 0.0;
  Eigen::Vector3d offset_m = Eigen::Vector3d::Zero();
};

/// A load on one tissue (tissues[i].loads; loads.h has how each acts).
struct LoadSpec {
  LoadKind kind = LoadKind::kForce;
  RegionSpec region;
  Eigen::Vector3d force_n = Eigen::Vector3d::Zero();   ///< kForce: total [N]
  double pressure_pa = 0.0;                            ///< kPressure: > 0 pushes inward [Pa]
  double ramp_s = 0.0;     ///< kForce, kPressure: linear ramp from 0 over this time (0: at once)
  std::vector<DisplacementKey> path;                   ///< kDisplacement: increasing t_s
  std::string where;                                   ///< "file:line:col: tissues[i].loads[j]"
};

enum class ObstacleKind { kPlane, kBox, kMesh };

/// A static, rigid obstacle the tissues' surface vertices collide with (obstacles.h).
struct ObstacleSpec {
  std::string name;
  ObstacleKind kind = ObstacleKind::kPlane;
  Eigen::Vector3d point_m = Eigen::Vector3d::Zero();    ///< kPlane: a point of the plane
  Eigen::Vector3d normal = Eigen::Vector3d::UnitZ();    ///< kPlane: unit, out of the solid side
  Eigen::Vector3d min_m = Eigen::Vector3d::Zero();      ///< kBox: corners (axis-aligned)
  Eigen::Vector3d max_m = Eigen::Vector3d::Zero();
  std::filesystem::path mesh_path;                      ///< kMesh: OBJ or STL surface
  double scale = 1.0;                                   ///< kMesh: applied first
  Eigen::Vector3d rotation_deg = Eigen::Vector3d::Zero();   ///< kMesh: then XYZ Euler
  Eigen::Vector3d translation_m = Eigen::Vector3d::Zero();  ///< kMesh: then translation
  /// kMesh: how far behind a triangle (against its normal) a vertex still counts as touching it
  /// and is pushed back out; deeper vertices are taken to be past a thin surface and ignored
  double thickness_m = 0.005;
  double friction_mu = 0.0;                             ///< Coulomb coefficient with tissue
  std::string where;                                    ///< "file:line:col: obstacles[i]"
};

/// The obstacles' collision settings (obstacle_contact section of the scene).
struct ObstacleContactSpec {
  double alarm_distance_m = 0.002;   ///< vertices within this gap become contacts
  int max_contacts = 300;            ///< per tissue (deepest kept)
  /// The obstacles' corners and sharp edges against the tissues' faces too (obstacles.h,
  /// "Edges"): for boxes and mesh obstacles with features finer than the tissue's surface
  bool edges = false;
  double edge_spacing_m = 0.002;     ///< points along a sharp edge at most this far apart
  /// How far inside a tissue an edge point still counts as touching its face (deeper: past a
  /// thin part, ignored)
  double edge_depth_m = 0.005;
};

/// Pairs of a scene at most (tissue_contact.h: slot = 2 pair + direction fits the id's 6 bits).
inline constexpr int kMaxTissueContactPairs = 32;

/// Contact between two tissues, or of one tissue with itself (`tissue_contact:`, tissue_contact.h).
struct TissueContactSpec {
  int tissue_a = 0;                  ///< index into SceneSpec::tissues
  int tissue_b = 0;                  ///< == tissue_a: self-contact
  double friction_mu = 0.0;          ///< Coulomb coefficient between the two surfaces
  double alarm_distance_m = 0.002;   ///< vertices within this gap of the other surface are contacts
  /// How far behind the other surface a vertex still counts as touching it and is pushed back out
  /// (deeper: taken to be past a thin part, ignored)
  double depth_m = 0.005;
  /// Added to W's diagonal on the pair's rows: a contact carrying f_n penetrates by c f_n
  /// (collision.h "Contact compliance"); 0: rigid contact
  double contact_compliance_mpn = 0.0;
  int max_contacts = 300;            ///< per direction (smallest gaps kept)
  bool two_way = true;               ///< two tissues: B's vertices against A's surface too
  std::string where;                 ///< "file:line:col: tissue_contact[i]"
};

}  // namespace tactus::sim

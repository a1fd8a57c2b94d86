#pragma once
// Reaction forces (docs/design.md, "Reaction forces"): what holds the tissues,
// so equilibrium can be checked (weight = reactions) and a bench-top load read off.
//
// All forces are those applied TO the tissues [N]:
//  * fixed-node reaction R_i = -(f_el,i(q) + m_i g + c_i + l_i) at every fixed node i (l_i the
//    last step's force and pressure loads on it, loads.h): the force the
//    support must apply for the node to stay still, with f_el the elastic (restoring) force at the
//    current positions (FemBody::elasticForce) and c_i the contact force H^T f on the node. It is
//    the static reaction: the inertia and the damping force of the fixed nodes' neighbours are
//    left out, so it is exact at rest (and what a load cell under a slow experiment reads);
//  * contact force per node: H^T f of the last step's contact problem (instrument, obstacles and
//    the other tissues);
//  * per tissue, from the other tissues (tissue_contact.h): the sum of its parts of the rows
//    between tissues; these are internal to the scene and cancel over all tissues;
//  * per obstacle: the sum over its contacts of the force it applies, -(n f_n + t1 f_t1 + t2 f_t2);
//  * on the tissues from the instrument: the same sum over the instrument's contacts.
//  * the applied loads: the sum of the last step's force and pressure loads.
// At rest: weight + loads + sum of fixed reactions + obstacle forces + instrument force = 0.

#include <Eigen/Core>
#include <string>
#include <vector>

namespace tactus::sim {

struct TissueReactions {
  Eigen::Matrix3Xd fixed_reaction_n;   ///< per node: R_i at fixed nodes, 0 elsewhere
  Eigen::Matrix3Xd contact_force_n;    ///< per node: H^T f
  Eigen::Vector3d fixed_total_n = Eigen::Vector3d::Zero();   ///< sum of R_i
  Eigen::Vector3d weight_n = Eigen::Vector3d::Zero();        ///< sum of m_i g (all nodes)
  /// From the other tissues (and itself, self-contact: 0 in sum) through tissue contacts
  Eigen::Vector3d from_tissues_n = Eigen::Vector3d::Zero();
};

struct ReactionForces {
  std::vector<TissueReactions> tissues;
  std::vector<std::string> obstacle_names;
  std::vector<Eigen::Vector3d> obstacle_force_n;            ///< per obstacle, on the tissues
  Eigen::Vector3d instrument_force_n = Eigen::Vector3d::Zero();   ///< on the tissues
  Eigen::Vector3d weight_n = Eigen::Vector3d::Zero();       ///< all tissues
  Eigen::Vector3d applied_load_n = Eigen::Vector3d::Zero(); ///< force and pressure loads
  Eigen::Vector3d fixed_total_n = Eigen::Vector3d::Zero();  ///< all tissues
  /// weight + loads + fixed + obstacles + instrument: 0 at rest
  Eigen::Vector3d imbalance_n() const;
};

}  // namespace tactus::sim

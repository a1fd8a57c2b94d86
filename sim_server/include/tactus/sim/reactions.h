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

#include "tactus/types.h"

namespace tactus::sim {

// The result types are the public API's (tactus/types.h).
using tactus::ReactionForces;
using tactus::TissueReactions;

}  // namespace tactus::sim

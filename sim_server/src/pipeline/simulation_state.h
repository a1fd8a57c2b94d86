#pragma once
// The simulation's state, in the manner of MuJoCo's mjData (simulation_model.h has the overview):
// everything a step changes and the next step starts from. A run continues from what is here;
// StepScratch is rebuilt by the next step before it is read.

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

#include "tactus/sim/collision.h"
#include "tactus/sim/compliance.h"
#include "tactus/sim/fem.h"
#include "tactus/sim/instrument.h"
#include "tactus/sim/obstacles.h"
#include "tactus/sim/pipeline.h"
#include "tactus/sim/tissue_contact.h"

namespace tactus::sim {

/// One tissue's physics objects.
struct TissueState {
  /// Positions q, velocities v and the FEM's factorisation (FemState), with its model (rest
  /// data, element data: FemModel) and step buffers (FemScratch) inside it (fem_body_impl.h).
  std::unique_ptr<FemBody> body;
  /// C0 (its model) and the rotations of the last updateCompliance (its state); only with an
  /// instrument.
  std::unique_ptr<TissueCompliance> compliance;
  /// The surface's AABB trees, refit at every detection, and the contacts they found; the
  /// feature-side memory of the pad and sphere queries carries to the next step (collision.h).
  /// One per instrument (each keeps its features' memory); with several instruments each
  /// refits its own trees.
  std::vector<std::unique_ptr<Collision>> collisions;
  /// Contacts of the last detection, instrument by instrument: the one collision's list with
  /// one instrument, else `merged`.
  const std::vector<Contact>* found = nullptr;
  std::vector<Contact> merged;                   ///< several instruments' contacts, in order
  /// Contacts with the static obstacles of the last detection (obstacle_stage.h)
  std::vector<Contact> obstacle_found;
  int obstacle_overflow = 0;
};

struct SimulationState {
  double t_s = 0.0;                         ///< simulated time
  long step = 0;                            ///< steps taken
  std::vector<TissueState> tissues;         ///< as SimulationModel::tissues
  /// The god objects: pose, twist, jaw opening (their parameters inside); empty without
  /// instrument. Instrument i follows targets[i].
  std::vector<Instrument> instruments;
  std::vector<DeviceTarget> targets;        ///< the device targets the next step follows
  std::vector<char> target_rejected;        ///< the last setDeviceTarget(i) was non-finite
  /// The static obstacles (obstacles.h); null without any.
  std::unique_ptr<Obstacles> obstacles;
  /// Contact between tissues and self-contact (tissue_contact.h); null without any pair.
  std::unique_ptr<TissueContacts> tissue_contacts;
  /// The last solve's force per contact id (n, t1, t2): the next solve's warm start.
  std::unordered_map<std::uint64_t, std::array<double, 3>> warm_start_f;
};

}  // namespace tactus::sim

#pragma once
// The haptic local model on ContactProblem (docs/api.md; docs/design.md, "The haptic local
// model"): a simulation's last contact problem (or one read from a snapshot file) re-solved for
// the devices' current poses, as haptic_server does every tick, without a segment or a device.
// The work is tactus/haptic/local_model.h's (the class the haptic loop runs); this adopts a
// ContactProblem through a snapshot slot, the form the haptic process receives.

#include <cstdint>
#include <span>
#include <vector>

#include "tactus/contact.h"
#include "tactus/haptic/local_model.h"
#include "tactus/types.h"

namespace tactus {

using haptic::FallbackReason;
using haptic::LocalModelKind;
using haptic::LocalModelResult;
using haptic::LocalModelSettings;
using haptic::LocalModelUsed;
using haptic::PrepareStatus;

class HapticModel {
 public:
  /// Throws tactus::Error naming a setting that is not finite or out of range.
  explicit HapticModel(const LocalModelSettings& settings = {});
  ~HapticModel();
  HapticModel(HapticModel&&) noexcept;
  HapticModel& operator=(HapticModel&&) noexcept;

  /// Prepares `problem` (copied: it may change afterwards) and adopts it: checked, solved to a
  /// tight tolerance at `device_poses` and, for the linearised model, linearised there. Device i
  /// drives instrument i; without poses (or fewer than the instruments), at the poses the problem
  /// was made at. Returns the preparation's status (PrepareStatus::kReady: solve() may run).
  PrepareStatus adopt(const ContactProblem& problem, std::span<const Pose> device_poses = {});
  /// The contact wrench on each instrument with the devices at `device_poses` (as adopt), and
  /// what the model did. deadline_ns: absolute CLOCK_MONOTONIC time at which a re-solve stops
  /// (0: none). Allocation-free after adopt.
  LocalModelResult solve(std::span<const Pose> device_poses = {}, std::int64_t deadline_ns = 0);
  /// The contact forces of the last solve (one per row of the adopted problem) [N].
  std::span<const double> forces() const;
  const LocalModelSettings& settings() const;
  /// What the preparation found (rows, linearisation, contact states, timings).
  const haptic::PreparedSnapshot& prepared() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace tactus

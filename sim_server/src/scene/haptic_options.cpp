// haptic_server options from a scene's haptics section (sim_server --print-haptic-options).
#include <fmt/format.h>

#include "tactus/sim/scene.h"

namespace tactus::sim {

std::vector<std::string> hapticServerOptions(const HapticsSpec& haptics) {
  std::vector<std::string> options;
  if (!haptics.enabled) return options;  // no haptics section: haptic_server's own defaults
  // the loop's rate, clamp and solver budget (the scene parser checked them against the same
  // hard ranges haptic_server applies: shared/haptic_limits.h)
  options.push_back(fmt::format("--rate={:.17g}", haptics.rate_hz));
  options.push_back(fmt::format("--max-force={:.17g}", haptics.max_force_n));
  options.push_back(fmt::format("--force-scale={:.17g}", haptics.force_scale));
  options.push_back(fmt::format("--watchdog-ms={:.17g}", haptics.watchdog_ms));
  options.push_back(fmt::format("--max-sweeps={}", haptics.max_sweeps_per_tick));
  options.push_back(fmt::format("--tolerance={:.17g}", haptics.nsgs_tolerance));
  if (haptics.nsgs_anderson_depth > 0) {
    options.push_back(fmt::format("--nsgs-anderson-depth={}", haptics.nsgs_anderson_depth));
  }
  if (haptics.snapshot_blend_ms > 0.0) {
    options.push_back(fmt::format("--snapshot-blend-ms={:.17g}", haptics.snapshot_blend_ms));
  }
  if (haptics.local_model != HapticLocalModel::kAutomatic) {
    options.push_back(fmt::format("--local-model={}", haptics.local_model == HapticLocalModel::kFull
                                                          ? "full"
                                                          : "linearized"));
  }
  // haptics.workspaces: every field of each device's own mapping (haptic_server's
  // --workspace-option I:key=value; the scene parser refuses it together with `workspace`)
  for (std::size_t i = 0; i < haptics.workspaces.size(); ++i) {
    const shared::WorkspaceMappingParams& d = haptics.workspaces[i];
    options.push_back(fmt::format("--workspace-option={}:scale={:.17g}", i, d.scale));
    options.push_back(fmt::format("--workspace-option={}:offset={:.17g},{:.17g},{:.17g}", i,
                                  d.offset_m[0], d.offset_m[1], d.offset_m[2]));
    options.push_back(fmt::format("--workspace-option={}:rotation={:.17g},{:.17g},{:.17g},{:.17g}",
                                  i, d.rotation_wxyz[0], d.rotation_wxyz[1], d.rotation_wxyz[2],
                                  d.rotation_wxyz[3]));
    options.push_back(fmt::format("--workspace-option={}:clutch_button={}", i, d.clutch_button));
  }
  const shared::WorkspaceMappingParams& w = haptics.workspace;
  if (w.isIdentity()) return options;
  options.push_back(fmt::format("--workspace-scale={:.17g}", w.scale));
  options.push_back(fmt::format("--workspace-offset={:.17g},{:.17g},{:.17g}", w.offset_m[0],
                                w.offset_m[1], w.offset_m[2]));
  options.push_back(fmt::format("--workspace-rotation={:.17g},{:.17g},{:.17g},{:.17g}",
                                w.rotation_wxyz[0], w.rotation_wxyz[1], w.rotation_wxyz[2],
                                w.rotation_wxyz[3]));
  if (w.clutch_button >= 0) options.push_back(fmt::format("--clutch-button={}", w.clutch_button));
  return options;
}

}  // namespace tactus::sim

// haptic_server options from a scene's haptics section (sim_server --print-haptic-options).
#include <fmt/format.h>

#include "tactus/sim/scene.h"

namespace tactus::sim {

std::vector<std::string> hapticServerOptions(const HapticsSpec& haptics) {
  const shared::WorkspaceMappingParams& w = haptics.workspace;
  std::vector<std::string> options;
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

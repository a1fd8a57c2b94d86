#pragma once
// haptic_server's workspace mapping per device: the plain --workspace-* options give every
// device one mapping; `--workspace-option I:key=value` (repeatable) overrides one field of it for
// device I only (0-based). Keys: scale, offset (x,y,z metres), rotation (w,x,y,z unit
// quaternion, device -> scene), clutch_button (-1: none). Every device's final mapping is
// validated with shared::WorkspaceMappingLimits (a quaternion off unit norm is refused, as with
// --workspace-rotation). Not real-time (runs once at start).

#include <cstddef>
#include <string>
#include <vector>

#include "tactus/shared/workspace_mapping.h"

namespace tactus::haptic {

/// One mapping per device: `common` with each option applied to its device, in the order given.
/// Throws tactus::Error, naming --workspace-option and the offending option, on a malformed
/// option, an unknown key, a device index outside [0, devices), a value that is not a finite
/// number (or not an integer for clutch_button), or a mapping out of range.
std::vector<shared::WorkspaceMappingParams> deviceWorkspaces(
    const shared::WorkspaceMappingParams& common, const std::vector<std::string>& options,
    std::size_t devices);

/// One line describing a mapping, for the start-up log ("scale 2, offset (...) m, ...").
std::string describeWorkspace(const shared::WorkspaceMappingParams& w);

}  // namespace tactus::haptic

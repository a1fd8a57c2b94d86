#pragma once
// Fuzz target for the scene YAML reader, shared by the libFuzzer harness (scene_fuzz.cpp) and
// the regression test (tests/unit/scene).
//
// Contract checked: parseScene returns a SceneSpec or throws tactus::Error (SceneError); a
// yaml-cpp exception or any other exception escaping is a bug.

#include <filesystem>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/scene.h"

namespace tactus::fuzz {

/// Feeds `bytes` to parseScene with relative paths resolved against `base_dir`. Returns true
/// when the scene was accepted, false on a tactus::Error.
inline bool feedScene(const std::string& bytes, const std::filesystem::path& base_dir) {
  try {
    const sim::SceneSpec spec = sim::parseScene(bytes, "fuzz.yaml", base_dir);
    (void)spec;
    return true;
  } catch (const tactus::Error&) {
    return false;
  }
}

}  // namespace tactus::fuzz

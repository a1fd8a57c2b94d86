#pragma once
// Test support for the scene parser's tests: a scene of one tissue (liver.msh) followed by the
// YAML under test, parsed as "s.yaml" (so its first added line is line 4 in messages).

#include <filesystem>
#include <string>

#include "tactus/shared/error.h"
#include "tactus/sim/scene.h"

namespace tactus::test_support {

inline const std::filesystem::path kSceneDir =
    std::filesystem::path(TACTUS_TEST_DATA_DIR) / "scenes";
inline const std::string kSceneHead = "time_step: 0.01\ntissues:\n  - mesh: ../meshes/liver.msh\n";

/// The scene kSceneHead + yaml, parsed.
inline sim::SceneSpec parseSnippet(const std::string& yaml) {
  return sim::parseScene(kSceneHead + yaml, "s.yaml", kSceneDir);
}

/// The parser's error for kSceneHead + yaml, or "(no error)".
inline std::string snippetError(const std::string& yaml) {
  try {
    parseSnippet(yaml);
  } catch (const SceneError& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace tactus::test_support

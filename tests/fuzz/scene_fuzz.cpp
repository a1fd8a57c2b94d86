// libFuzzer harness: scene YAML reader (parseScene), relative paths against tests/data/scenes.
#include "feed_scene.h"
#include "fuzz_main_common.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  tactus::fuzz::feedScene(tactus::fuzz::bytesOf(data, size), TACTUS_SCENE_BASE_DIR);
  return 0;
}

// libFuzzer harness: tetrahedral mesh readers (parseTetMesh: Gmsh 1/2/4, legacy VTK, VTU).
#include "feed_mesh.h"
#include "fuzz_main_common.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  tactus::fuzz::feedMesh(tactus::fuzz::bytesOf(data, size));
  return 0;
}

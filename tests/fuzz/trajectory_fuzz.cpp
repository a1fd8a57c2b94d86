// libFuzzer harness: replay CSV trajectory reader (device::Trajectory::parseCsv) and sample().
#include "feed_trajectory.h"
#include "fuzz_main_common.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  tactus::fuzz::feedTrajectory(tactus::fuzz::bytesOf(data, size));
  return 0;
}

// libFuzzer harness: the network device bridge decoder (device::bridge::decodeState/Command).
#include "feed_bridge.h"
#include "fuzz_main_common.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  tactus::fuzz::feedBridge(tactus::fuzz::bytesOf(data, size));
  return 0;
}

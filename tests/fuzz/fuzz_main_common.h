#pragma once
// Common part of the libFuzzer harnesses: silence spdlog (the readers log every repair, which
// would dominate the run time) and turn the input into a std::string.

#include <spdlog/spdlog.h>

#include <cstddef>
#include <cstdint>
#include <string>

extern "C" int LLVMFuzzerInitialize(int* /*argc*/, char*** /*argv*/) {
  spdlog::set_level(spdlog::level::off);
  return 0;
}

namespace tactus::fuzz {
inline std::string bytesOf(const std::uint8_t* data, std::size_t size) {
  return std::string(reinterpret_cast<const char*>(data), size);
}
}  // namespace tactus::fuzz

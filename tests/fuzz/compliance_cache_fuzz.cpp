// libFuzzer harness: compliance cache loader, through makeCompliance on a tiny box body with the
// input written as its cache file (layout in feed_compliance.h).
// With TACTUS_FUZZ_WRITE_SEEDS=DIR in the environment, the first input also writes the valid
// cache files of the current build (double and float, with several flag bytes) into DIR as seeds.
#include <cstdlib>
#include <fstream>

#include "feed_compliance.h"
#include "fuzz_main_common.h"

namespace {
tactus::fuzz::ComplianceCacheTarget& target() {
  static tactus::fuzz::ComplianceCacheTarget t;
  static const bool seeded = [] {
    const char* dir = std::getenv("TACTUS_FUZZ_WRITE_SEEDS");
    if (dir == nullptr || *dir == '\0') return false;
    for (int single = 0; single < 2; ++single) {
      for (unsigned char flags : {0, 1, 3}) {
        const unsigned char f = static_cast<unsigned char>(flags | (single ? 4 : 0));
        const std::string name = std::string(single ? "valid_float" : "valid_double") +
                                 "_flags" + std::to_string(f) + ".bin";
        std::ofstream out(std::filesystem::path(dir) / name, std::ios::binary);
        const std::string bytes = t.validInput(single != 0, f);
        out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
      }
    }
    return true;
  }();
  (void)seeded;
  return t;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  target().feed(tactus::fuzz::bytesOf(data, size));
  return 0;
}

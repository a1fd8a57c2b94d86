// libFuzzer harness: FCLIB text readers (readFclibText, readFclibReference). They read files,
// so each input is written to one temporary file per process first.
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>

#include "feed_fclib.h"
#include "fuzz_main_common.h"

namespace {
const std::filesystem::path& inputFile() {
  static const std::filesystem::path path = std::filesystem::temp_directory_path() /
      ("tactus_fclib_fuzz_" + std::to_string(::getpid()) + ".fc3d.txt");
  return path;
}
struct RemoveAtExit {
  ~RemoveAtExit() {
    std::error_code ec;
    std::filesystem::remove(inputFile(), ec);
  }
} remove_at_exit;
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  {
    std::ofstream out(inputFile(), std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    if (!out) throw std::runtime_error("cannot write " + inputFile().string());
  }
  tactus::fuzz::feedFclibFile(inputFile());
  return 0;
}

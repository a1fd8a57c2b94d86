// libFuzzer harness: FCLIB text readers (readFclibText, readFclibReference). They read files, so
// each input goes into an anonymous in-memory file (memfd) read through /proc/self/fd: nothing is
// created in /tmp, so a crash, a timeout or a kill leaves no file behind.
#include <sys/mman.h>
#include <unistd.h>

#include <filesystem>
#include <stdexcept>
#include <string>

#include "feed_fclib.h"
#include "fuzz_main_common.h"

namespace {
int inputFd() {
  static const int fd = [] {
    const int f = ::memfd_create("tactus_fclib_fuzz", MFD_CLOEXEC);
    if (f < 0) throw std::runtime_error("memfd_create failed");
    return f;
  }();
  return fd;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const int fd = inputFd();
  if (::ftruncate(fd, 0) != 0 || ::lseek(fd, 0, SEEK_SET) != 0) {
    throw std::runtime_error("cannot reset the fuzz input file");
  }
  std::size_t done = 0;
  while (done < size) {
    const ssize_t w = ::write(fd, data + done, size - done);
    if (w <= 0) throw std::runtime_error("cannot write the fuzz input file");
    done += static_cast<std::size_t>(w);
  }
  tactus::fuzz::feedFclibFile("/proc/self/fd/" + std::to_string(fd));
  return 0;
}

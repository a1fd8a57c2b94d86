#pragma once
// main() of the command-line tools: one place that turns an escaping exception into a logged
// message and exit status 1.

#include <spdlog/spdlog.h>

#include <exception>

namespace tactus::shared {

/// Returns run(argc, argv), or 1 after logging the message of an exception it throws.
inline int runToolMain(int (*run)(int, char**), int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    spdlog::error("{}", e.what());
    return 1;
  }
}

}  // namespace tactus::shared

// CLI11 for the daemons' and tools' command lines, its own code compiled without optimisation.
//
// CLI11 2.1 is header-only: every program that parses its command line compiles CLI11's parser,
// help formatter and validators again, about 14 s of CPU at -O3, 8 s at -O1 and 7 s at -O0 for a
// small program (docs/measurements.md, "Build and test time"), for code that runs once at
// start-up.
// The standard headers CLI11 includes come first, outside the -O0 region, so that only CLI11's
// own functions (namespace CLI) carry the attribute, never a standard template the program's
// other code instantiates. Include this header, never <CLI/CLI.hpp> directly: a second inclusion
// elsewhere would be compiled at the file's level. Header-only; include it only from programs
// that link CLI11 (the daemons and tools).
#pragma once

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <iostream>
#include <iterator>
#include <limits>
#include <locale>
#include <map>
#include <memory>
#include <numeric>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <sys/stat.h>
#include <sys/types.h>
#include <tuple>
#include <type_traits>
#include <utility>
#include <vector>

#pragma GCC push_options
#pragma GCC optimize("O0")
#include <CLI/CLI.hpp>
#pragma GCC pop_options

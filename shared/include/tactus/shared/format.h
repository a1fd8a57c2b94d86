// fmt's formatting engine taken from libfmt instead of compiled again in every translation unit.
//
// fmt 9's format.h defines the engine behind every spdlog call with arguments and every
// fmt::format_to (detail::vformat_to<char>: the parser, the integer and floating-point writers,
// Dragonbox and Dragon4) without declaring the instantiation that libfmt already holds, so each
// translation unit that logs with arguments compiled it again at its own optimisation level,
// about 3-5 s of CPU per unit at -O3 (docs/measurements.md, "Build and test time"). The explicit
// instantiation declaration below makes those calls use libfmt's copy (fmt's own format.cc
// instantiates it; fmt 10 declares it in format.h itself).
//
// No source includes this header: the build gives it to every project translation unit before
// its first line (-include, through the tactus_warnings interface target that every project
// target links; the tests' precompiled header holds it instead, top-level CMakeLists.txt). It
// declares, before any of fmt's own headers is seen, what fmt's core.h declares, so it includes
// only core.h (about half a second of CPU in a unit that uses no fmt at all). A unit that uses fmt
// needs libfmt at link time, which spdlog::spdlog and fmt::fmt bring. A header-only fmt
// (FMT_HEADER_ONLY) and other fmt versions are left as they are.
#pragma once

#include <fmt/core.h>

#if !defined(FMT_HEADER_ONLY) && FMT_VERSION >= 90000 && FMT_VERSION < 100000
FMT_BEGIN_NAMESPACE
namespace detail {
extern template void vformat_to<char>(buffer<char>&, basic_string_view<char>,
                                      basic_format_args<FMT_BUFFER_CONTEXT(char)>, locale_ref);
}  // namespace detail
FMT_END_NAMESPACE
#endif

// fmt for the project's sources, its formatting engine taken from libfmt instead of compiled again.
//
// fmt 9's format.h defines the engine behind every spdlog call with arguments and every
// fmt::format_to (detail::vformat_to<char>: the parser, the integer and floating-point writers,
// Dragonbox and Dragon4) without declaring the instantiation that libfmt already holds, so each
// translation unit that logs with arguments compiled it again at its own optimisation level,
// about 3-5 s of CPU per unit at -O3 (docs/measurements.md, "Build and test time"). The explicit
// instantiation declaration below makes those calls use libfmt's copy (fmt's own format.cc
// instantiates it; fmt 10 declares it in format.h itself). Include this header wherever a source
// includes <spdlog/spdlog.h> or <fmt/format.h> (after them, or instead of the latter); it needs
// fmt::fmt, which spdlog::spdlog brings. A header-only fmt (FMT_HEADER_ONLY) and other fmt
// versions are left as they are.
#pragma once

#include <fmt/format.h>

#if !defined(FMT_HEADER_ONLY) && FMT_VERSION >= 90000 && FMT_VERSION < 100000
FMT_BEGIN_NAMESPACE
namespace detail {
extern template void vformat_to<char>(buffer<char>&, basic_string_view<char>,
                                      basic_format_args<FMT_BUFFER_CONTEXT(char)>, locale_ref);
}  // namespace detail
FMT_END_NAMESPACE
#endif

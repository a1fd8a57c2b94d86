#pragma once
// The clock solveNsgs reads (shared/nsgs.h: NsgsSettings::deadline_ns and time_budget_ns,
// NsgsResult::elapsed_ns) [ns]: CLOCK_MONOTONIC (shared::monotonicNs()) unless a test has set a
// scripted one, to place a deadline at a chosen point of a solve without timing anything
// (tests/unit/shared/nsgs_test.cpp). Process-wide and read on every look at the clock (one
// relaxed atomic load); never set outside tests.

#include <cstdint>

namespace tactus::shared {

/// A scripted clock: returns the time [ns]; must be noexcept, allocation-free and callable from
/// whichever thread solves.
using NsgsClockFn = std::int64_t (*)(void* context) noexcept;

/// Sets the clock solveNsgs reads (nullptr: CLOCK_MONOTONIC again). Not for concurrent solves
/// that expect the real clock: tests only.
void setNsgsClockForTesting(NsgsClockFn clock, void* context) noexcept;

}  // namespace tactus::shared

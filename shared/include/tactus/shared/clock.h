#pragma once
// Monotonic time in integer nanoseconds (CLOCK_MONOTONIC), the one time base of every message,
// heartbeat and stats record. Both processes on one machine read the same clock, so a t_ns
// written by one side compares directly with the other side's clock.
//
// Real-time: every function here is noexcept and allocation-free; monotonicNs() is a vDSO call
// (no system call on x86-64 Linux).

#include <cerrno>
#include <cstdint>
#include <ctime>

namespace tactus::shared {

inline constexpr std::int64_t kNsPerUs = 1'000;
inline constexpr std::int64_t kNsPerMs = 1'000'000;
inline constexpr std::int64_t kNsPerS = 1'000'000'000;

/// CLOCK_MONOTONIC now, in ns.
inline std::int64_t monotonicNs() noexcept {
  timespec ts{};
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return static_cast<std::int64_t>(ts.tv_sec) * kNsPerS + ts.tv_nsec;
}

/// ns -> timespec (t_ns >= 0).
inline timespec toTimespec(std::int64_t t_ns) noexcept {
  timespec ts{};
  ts.tv_sec = static_cast<time_t>(t_ns / kNsPerS);
  ts.tv_nsec = static_cast<long>(t_ns % kNsPerS);
  return ts;
}

inline double nsToSeconds(std::int64_t t_ns) noexcept { return static_cast<double>(t_ns) * 1e-9; }
/// Seconds elapsed since the monotonicNs() reading t0_ns (the one stopwatch of the tools and the
/// simulation's stage timers).
inline double secondsSinceNs(std::int64_t t0_ns) noexcept {
  return nsToSeconds(monotonicNs() - t0_ns);
}
inline std::int64_t secondsToNs(double t_s) noexcept {
  return static_cast<std::int64_t>(t_s * 1e9 + (t_s >= 0 ? 0.5 : -0.5));
}

/// Sleeps until the absolute CLOCK_MONOTONIC time t_ns (restarts on EINTR). A system call:
/// allowed in the haptic tick only as the period sleep.
inline void sleepUntilNs(std::int64_t t_ns) noexcept {
  const timespec ts = toTimespec(t_ns);
  while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &ts, nullptr) == EINTR) {
  }
}

/// CPU relax hint for spin loops (PAUSE on x86, YIELD on ARM).
inline void cpuRelax() noexcept {
#if defined(__x86_64__) || defined(__i386__)
  __builtin_ia32_pause();
#elif defined(__aarch64__)
  asm volatile("yield" ::: "memory");
#endif
}

}  // namespace tactus::shared

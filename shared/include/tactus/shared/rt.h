#pragma once
// Real-time thread utilities: CPU pinning, SCHED_FIFO, memory locking, stack pre-faulting and the
// periodic timer used by the haptic loop and by the jitter tool's bare-loop baseline.
//
// Set-up functions (pin, FIFO, mlockall, prefault) are called once before the loop. They return
// an RtStatus instead of throwing, so the caller decides whether a failure is fatal
// (RealtimeConfig::kEnforce) or only reported (kIgnore, the default for development and CI, where
// containers usually refuse SCHED_FIFO and mlockall).
//
// PeriodicTimer::wait() is real-time safe: noexcept, allocation-free; its only system call is the
// absolute-deadline clock_nanosleep (plus vDSO clock reads while spinning).
//
// Timer method (../../../../docs/design.md#real-time-rules-and-the-timer): sleep with
// clock_nanosleep(TIMER_ABSTIME) until (deadline - spin_margin), then spin on the clock until
// the deadline. A plain sleep wakes ~70 us late on a virtual machine; sleep-then-spin ~0.1 us.
// Never spin through a whole period under SCHED_FIFO (the kernel throttles a task that takes
// more than 95 % of a core).

#include <cstddef>
#include <cstdint>
#include <string>

namespace tactus::shared {

/// Outcome of a real-time set-up call: errno-style code (0 = success) and the call it came from.
struct RtStatus {
  int error = 0;                 ///< 0 on success, else the errno of the failing call
  const char* what = "";         ///< short name of the operation ("sched_setscheduler", ...)
  bool ok() const noexcept { return error == 0; }
  /// Human-readable explanation with a hint on what to do (allocates: not for the RT thread).
  std::string message() const;
};

/// Whether set-up failures abort (kEnforce) or are only reported (kIgnore), as in libfranka.
enum class RealtimeConfig : std::uint8_t { kEnforce, kIgnore };

/// Pins the calling thread to one CPU (0-based). EINVAL if the CPU does not exist.
RtStatus pinCurrentThread(int cpu) noexcept;

/// SCHED_FIFO at `priority` (1..99) for the calling thread. EPERM without CAP_SYS_NICE / rtprio.
RtStatus setFifoPriority(int priority) noexcept;

/// Back to SCHED_OTHER for the calling thread (used by tests and on shutdown).
RtStatus setNormalPriority() noexcept;

/// mlockall(MCL_CURRENT | MCL_FUTURE): no page faults from swapping or lazy mapping afterwards.
RtStatus lockMemory() noexcept;

/// Touches `kib` KiB of the calling thread's stack so that the pages exist before the loop.
void prefaultStack(std::size_t kib = 256) noexcept;

/// Number of CPUs this process may run on (sched_getaffinity), >= 1.
int availableCpuCount() noexcept;

/// Convenience: pin (cpu >= 0), FIFO (priority > 0), lock memory, prefault the stack. Under
/// kEnforce the first failure throws tactus::RealtimeError; under kIgnore it returns a
/// human-readable summary of what was refused (empty when everything succeeded).
std::string setupRealtimeThread(int cpu, int priority, RealtimeConfig config,
                                std::size_t prefault_kib = 256);

/// One timer wake-up. lateness_ns = woken_ns - scheduled_ns (>= 0 up to clock granularity).
struct TimerTick {
  std::int64_t scheduled_ns = 0;     ///< the absolute deadline of this tick
  std::int64_t woken_ns = 0;         ///< monotonic time at return from wait()
  std::int64_t missed = 0;           ///< deadlines skipped before this one (0 when on time)
};

/// Absolute-deadline periodic timer (sleep to deadline - spin_margin, then spin).
///
/// Overruns: when wait() is entered after its deadline (the previous tick ran too long), it
/// returns at once and counts one overrun. When it is entered more than a whole period late, the
/// missed deadlines are skipped (no burst of catch-up ticks) and counted in TimerTick::missed and
/// missedTicks(). Periods down to 250 us are supported.
class PeriodicTimer {
 public:
  static constexpr std::int64_t kMinPeriodNs = 250'000;
  static constexpr std::int64_t kDefaultSpinMarginNs = 80'000;

  /// period_ns >= kMinPeriodNs (smaller values are raised to it); spin_margin_ns is clamped to
  /// [0, period / 2]. The first deadline is start_ns + period_ns (start_ns = 0: now).
  explicit PeriodicTimer(std::int64_t period_ns, std::int64_t spin_margin_ns = kDefaultSpinMarginNs,
                         std::int64_t start_ns = 0) noexcept;

  /// Blocks until the next deadline and advances it by one period.
  TimerTick wait() noexcept;

  /// Restarts the schedule: next deadline = start_ns + period (start_ns = 0: now).
  void reset(std::int64_t start_ns = 0) noexcept;

  std::int64_t periodNs() const noexcept { return period_ns_; }
  std::int64_t spinMarginNs() const noexcept { return spin_margin_ns_; }
  std::int64_t nextDeadlineNs() const noexcept { return next_deadline_ns_; }
  std::int64_t overruns() const noexcept { return overruns_; }
  std::int64_t missedTicks() const noexcept { return missed_; }
  std::int64_t ticks() const noexcept { return ticks_; }

 private:
  std::int64_t period_ns_;
  std::int64_t spin_margin_ns_;
  std::int64_t next_deadline_ns_ = 0;
  std::int64_t overruns_ = 0;
  std::int64_t missed_ = 0;
  std::int64_t ticks_ = 0;
};

/// Summary of a bare timer loop (no work in the tick): the jitter tool's baseline.
struct BareLoopStats {
  std::int64_t ticks = 0;
  std::int64_t overruns = 0;
  std::int64_t missed = 0;
  std::int64_t min_late_ns = 0;
  std::int64_t max_late_ns = 0;
  double mean_late_ns = 0.0;
};

/// Runs `ticks` iterations of PeriodicTimer with nothing in the tick, the same timer method as
/// the haptic loop. If `late_ns_out` is not null it receives `ticks` lateness values (woken -
/// scheduled). Real-time safe (call it on a prepared thread for a meaningful baseline).
BareLoopStats runBareLoop(std::int64_t period_ns, std::int64_t ticks,
                          std::int64_t spin_margin_ns = PeriodicTimer::kDefaultSpinMarginNs,
                          std::int64_t* late_ns_out = nullptr) noexcept;

}  // namespace tactus::shared

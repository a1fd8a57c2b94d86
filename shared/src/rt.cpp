#include "tactus/shared/rt.h"

#include <pthread.h>
#include <sched.h>
#include <sys/mman.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <limits>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"

namespace tactus::shared {

std::string RtStatus::message() const {
  if (ok()) return std::string(what) + ": ok";
  std::string msg = std::string(what) + " failed: " + std::strerror(error);
  // hints for the usual refusals in containers and unprivileged shells
  if (error == EPERM && std::strcmp(what, "sched_setscheduler") == 0) {
    msg += " (SCHED_FIFO needs CAP_SYS_NICE or an rtprio limit: run as root, `setcap "
           "cap_sys_nice+ep` the binary, or add '<user> - rtprio 95' to "
           "/etc/security/limits.conf)";
  } else if ((error == EPERM || error == ENOMEM || error == EAGAIN) &&
             std::strcmp(what, "mlockall") == 0) {
    msg += " (raise the memlock limit: `ulimit -l unlimited` or '<user> - memlock unlimited' in "
           "/etc/security/limits.conf)";
  } else if (error == EINVAL && std::strcmp(what, "pthread_setaffinity_np") == 0) {
    msg += " (no such CPU, or it is not in this process's cpuset)";
  }
  return msg;
}

RtStatus pinCurrentThread(int cpu) noexcept {
  if (cpu < 0 || cpu >= CPU_SETSIZE) return {EINVAL, "pthread_setaffinity_np"};
  cpu_set_t set;
  CPU_ZERO(&set);
  CPU_SET(cpu, &set);
  const int rc = pthread_setaffinity_np(pthread_self(), sizeof(set), &set);
  return {rc, "pthread_setaffinity_np"};
}

RtStatus setFifoPriority(int priority) noexcept {
  const int lo = sched_get_priority_min(SCHED_FIFO);
  const int hi = sched_get_priority_max(SCHED_FIFO);
  if (priority < lo || priority > hi) return {EINVAL, "sched_setscheduler"};
  sched_param param{};
  param.sched_priority = priority;
  const int rc = pthread_setschedparam(pthread_self(), SCHED_FIFO, &param);
  return {rc, "sched_setscheduler"};
}

RtStatus setNormalPriority() noexcept {
  sched_param param{};
  param.sched_priority = 0;
  const int rc = pthread_setschedparam(pthread_self(), SCHED_OTHER, &param);
  return {rc, "sched_setscheduler"};
}

RtStatus lockMemory() noexcept {
  if (mlockall(MCL_CURRENT | MCL_FUTURE) != 0) return {errno, "mlockall"};
  return {0, "mlockall"};
}

void prefaultStack(std::size_t kib) noexcept {
  // touch one byte per page of a stack array; volatile keeps the writes
  constexpr std::size_t kChunk = 4096;
  const std::size_t bytes = kib * 1024;
  volatile unsigned char* probe = static_cast<volatile unsigned char*>(__builtin_alloca(bytes));
  for (std::size_t i = 0; i < bytes; i += kChunk) probe[i] = 0;
  if (bytes > 0) probe[bytes - 1] = 0;
}

int availableCpuCount() noexcept {
  cpu_set_t set;
  CPU_ZERO(&set);
  if (sched_getaffinity(0, sizeof(set), &set) != 0) return 1;
  return std::max(1, CPU_COUNT(&set));
}

std::string setupRealtimeThread(int cpu, int priority, RealtimeConfig config,
                                std::size_t prefault_kib) {
  std::string refused;
  // each step: report or throw depending on the config
  auto handle = [&](const RtStatus& st) {
    if (st.ok()) return;
    if (config == RealtimeConfig::kEnforce) throw RealtimeError(st.message());
    if (!refused.empty()) refused += "; ";
    refused += st.message();
  };
  if (cpu >= 0) handle(pinCurrentThread(cpu));
  if (priority > 0) handle(setFifoPriority(priority));
  handle(lockMemory());
  prefaultStack(prefault_kib);
  return refused;
}

PeriodicTimer::PeriodicTimer(std::int64_t period_ns, std::int64_t spin_margin_ns,
                             std::int64_t start_ns) noexcept
    : period_ns_(std::max(period_ns, kMinPeriodNs)),
      spin_margin_ns_(std::clamp<std::int64_t>(spin_margin_ns, 0,
                                               std::max(period_ns, kMinPeriodNs) / 2)) {
  reset(start_ns);
}

void PeriodicTimer::reset(std::int64_t start_ns) noexcept {
  if (start_ns == 0) start_ns = monotonicNs();
  next_deadline_ns_ = start_ns + period_ns_;
}

TimerTick PeriodicTimer::wait() noexcept {
  TimerTick tick;
  std::int64_t now = monotonicNs();
  // late entry: the previous tick overran this deadline
  if (now >= next_deadline_ns_) {
    ++overruns_;
    const std::int64_t behind = (now - next_deadline_ns_) / period_ns_;
    if (behind > 0) {
      // skip whole missed periods instead of bursting through them
      next_deadline_ns_ += behind * period_ns_;
      tick.missed = behind;
      missed_ += behind;
    }
  } else {
    // coarse sleep, then spin the last spin_margin_ns
    const std::int64_t wake_at = next_deadline_ns_ - spin_margin_ns_;
    if (now < wake_at) sleepUntilNs(wake_at);
    now = monotonicNs();
    while (now < next_deadline_ns_) {
      cpuRelax();
      now = monotonicNs();
    }
  }
  tick.scheduled_ns = next_deadline_ns_;
  tick.woken_ns = now;
  next_deadline_ns_ += period_ns_;
  ++ticks_;
  return tick;
}

BareLoopStats runBareLoop(std::int64_t period_ns, std::int64_t ticks, std::int64_t spin_margin_ns,
                          std::int64_t* late_ns_out) noexcept {
  BareLoopStats stats;
  if (ticks <= 0) return stats;
  PeriodicTimer timer(period_ns, spin_margin_ns);
  stats.min_late_ns = std::numeric_limits<std::int64_t>::max();
  double sum = 0.0;
  for (std::int64_t i = 0; i < ticks; ++i) {
    const TimerTick t = timer.wait();
    const std::int64_t late = t.woken_ns - t.scheduled_ns;
    if (late_ns_out != nullptr) late_ns_out[i] = late;
    stats.min_late_ns = std::min(stats.min_late_ns, late);
    stats.max_late_ns = std::max(stats.max_late_ns, late);
    sum += static_cast<double>(late);
  }
  stats.ticks = ticks;
  stats.overruns = timer.overruns();
  stats.missed = timer.missedTicks();
  stats.mean_late_ns = sum / static_cast<double>(ticks);
  return stats;
}

}  // namespace tactus::shared

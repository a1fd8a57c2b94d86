// Real-time utilities: clock, set-up calls (succeed or explain the refusal), the periodic
// timer's schedule and overrun accounting, the bare-loop baseline. No wall-clock thresholds:
// only ordering and counting properties that hold on any machine.

#include "tactus/shared/rt.h"

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <sys/mman.h>

#include <sys/resource.h>

#include <cerrno>
#include <cstdlib>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include "tactus/shared/clock.h"
#include "tactus/shared/error.h"

namespace tactus::shared {
namespace {

using ::testing::HasSubstr;

TEST(Clock, MonotonicAndConversions) {
  const std::int64_t a = monotonicNs();
  const std::int64_t b = monotonicNs();
  EXPECT_GT(a, 0);
  EXPECT_GE(b, a);
  const timespec ts = toTimespec(3 * kNsPerS + 17);
  EXPECT_EQ(ts.tv_sec, 3);
  EXPECT_EQ(ts.tv_nsec, 17);
  EXPECT_EQ(secondsToNs(1.5), 1'500'000'000);
  EXPECT_DOUBLE_EQ(nsToSeconds(250'000), 250e-6);
  const std::int64_t target = monotonicNs() + 2 * kNsPerMs;
  sleepUntilNs(target);
  EXPECT_GE(monotonicNs(), target);
}

TEST(Realtime, PinningToAnAllowedCpuWorksAndABadOneIsExplained) {
  EXPECT_GE(availableCpuCount(), 1);
  std::thread t([] {
    cpu_set_t set;
    CPU_ZERO(&set);
    ASSERT_EQ(sched_getaffinity(0, sizeof(set), &set), 0);
    int cpu = 0;
    while (!CPU_ISSET(cpu, &set)) ++cpu;
    EXPECT_TRUE(pinCurrentThread(cpu).ok());
    EXPECT_EQ(sched_getcpu(), cpu);
    const RtStatus bad = pinCurrentThread(CPU_SETSIZE + 1);
    EXPECT_FALSE(bad.ok());
    EXPECT_EQ(bad.error, EINVAL);
    EXPECT_THAT(bad.message(), HasSubstr("pthread_setaffinity_np failed"));
  });
  t.join();
}

// What the kernel will grant this process, read from its capabilities and rlimits, so each
// environment has exactly one expected outcome (privileged: must succeed; unprivileged: must be
// refused with the explanation).
bool hasEffectiveCapability(int cap) {
  std::ifstream status("/proc/self/status");
  std::string line;
  while (std::getline(status, line)) {
    if (line.rfind("CapEff:", 0) == 0) {
      const unsigned long long mask = std::stoull(line.substr(7), nullptr, 16);
      return ((mask >> cap) & 1ULL) != 0;
    }
  }
  return false;
}

long long statusKib(const char* key) {
  std::ifstream status("/proc/self/status");
  std::string line;
  const std::string k = std::string(key) + ":";
  while (std::getline(status, line)) {
    if (line.rfind(k, 0) == 0) return std::stoll(line.substr(k.size()));
  }
  return -1;
}

// cgroup v1 with RT group scheduling: a group with no RT runtime refuses SCHED_FIFO even to root.
bool cgroupDeniesRealtime() {
  std::ifstream cg("/proc/self/cgroup");
  std::string line;
  while (std::getline(cg, line)) {
    const auto colon = line.find(':');
    const auto colon2 = line.find(':', colon + 1);
    if (colon == std::string::npos || colon2 == std::string::npos) continue;
    const std::string controllers = line.substr(colon + 1, colon2 - colon - 1);
    if (controllers.find("cpu") == std::string::npos || controllers == "cpuset" ||
        controllers == "cpuacct") {
      continue;
    }
    std::ifstream rt("/sys/fs/cgroup/" + controllers + line.substr(colon2 + 1) +
                     "/cpu.rt_runtime_us");
    long long us = -1;
    if (rt >> us) return us == 0;
  }
  return false;
}

constexpr int kCapIpcLock = 14;   // linux/capability.h
constexpr int kCapSysNice = 23;

TEST(Realtime, FifoIsGrantedExactlyWhenThePrivilegesAllowIt) {
  rlimit rtprio{};
  ASSERT_EQ(getrlimit(RLIMIT_RTPRIO, &rtprio), 0);
  const bool privileged = hasEffectiveCapability(kCapSysNice) ||
                          rtprio.rlim_cur == RLIM_INFINITY || rtprio.rlim_cur >= 10;
  const bool expect_granted = privileged && !cgroupDeniesRealtime();
  std::thread t([expect_granted] {
    const RtStatus fifo = setFifoPriority(10);
    if (expect_granted) {
      ASSERT_TRUE(fifo.ok()) << "CAP_SYS_NICE or RLIMIT_RTPRIO >= 10, yet refused: "
                             << fifo.message();
      EXPECT_EQ(sched_getscheduler(0), SCHED_FIFO);
      EXPECT_TRUE(setNormalPriority().ok());
      EXPECT_EQ(sched_getscheduler(0), SCHED_OTHER);
    } else {
      ASSERT_FALSE(fifo.ok()) << "no CAP_SYS_NICE and RLIMIT_RTPRIO < 10, yet granted";
      EXPECT_EQ(fifo.error, EPERM);
      EXPECT_THAT(fifo.message(), HasSubstr("sched_setscheduler failed"));
      EXPECT_THAT(fifo.message(), HasSubstr("rtprio"));
      EXPECT_EQ(sched_getscheduler(0), SCHED_OTHER);
    }
    EXPECT_EQ(setFifoPriority(1000).error, EINVAL);  // out of range, never applied
  });
  t.join();
  prefaultStack(128);  // must simply not crash
}

TEST(Realtime, MlockallIsGrantedExactlyWhenTheLimitAllowsIt) {
  // mlockall(MCL_CURRENT) succeeds iff CAP_IPC_LOCK or the mapped size fits RLIMIT_MEMLOCK
  rlimit memlock{};
  ASSERT_EQ(getrlimit(RLIMIT_MEMLOCK, &memlock), 0);
  const long long vm_kib = statusKib("VmSize");
  ASSERT_GT(vm_kib, 0);
  const bool unlimited =
      hasEffectiveCapability(kCapIpcLock) || memlock.rlim_cur == RLIM_INFINITY;
  const long long limit_kib =
      unlimited ? 0 : static_cast<long long>(memlock.rlim_cur / 1024);
  // the mapped size can move by a few pages between the read and the call: no verdict there
  constexpr long long kMarginKib = 4096;
  if (!unlimited && std::llabs(vm_kib - limit_kib) < kMarginKib) {
    GTEST_SKIP() << "VmSize " << vm_kib << " KiB is within " << kMarginKib
                 << " KiB of RLIMIT_MEMLOCK " << limit_kib << " KiB: outcome not determined";
  }
  const bool expect_granted = unlimited || vm_kib < limit_kib;
  const RtStatus lock = lockMemory();
  if (expect_granted) {
    ASSERT_TRUE(lock.ok()) << lock.message();
    EXPECT_GT(statusKib("VmLck"), 0);
    munlockall();
  } else {
    ASSERT_FALSE(lock.ok()) << "VmSize " << vm_kib << " KiB over RLIMIT_MEMLOCK " << limit_kib
                            << " KiB without CAP_IPC_LOCK, yet mlockall succeeded";
    EXPECT_EQ(lock.error, ENOMEM);
    EXPECT_THAT(lock.message(), HasSubstr("mlockall failed"));
  }
}

TEST(Realtime, SetupEnforceThrowsIgnoreReports) {
  std::thread t([] {
    EXPECT_THROW(setupRealtimeThread(CPU_SETSIZE + 5, 0, RealtimeConfig::kEnforce, 16),
                 RealtimeError);
    const std::string refused =
        setupRealtimeThread(CPU_SETSIZE + 5, 0, RealtimeConfig::kIgnore, 16);
    EXPECT_THAT(refused, HasSubstr("pthread_setaffinity_np"));
    munlockall();
  });
  t.join();
}

TEST(PeriodicTimer, DeadlinesAreExactMultiplesOfThePeriod) {
  constexpr std::int64_t kPeriod = 1 * kNsPerMs;
  const std::int64_t start = monotonicNs();
  PeriodicTimer timer(kPeriod, 50'000, start);
  std::int64_t prev = start;
  for (int i = 0; i < 100; ++i) {
    const TimerTick t = timer.wait();
    EXPECT_GE(t.woken_ns, t.scheduled_ns);  // never early: the spin reaches the deadline
    EXPECT_EQ((t.scheduled_ns - start) % kPeriod, 0);
    EXPECT_GT(t.scheduled_ns, prev);
    prev = t.scheduled_ns;
  }
  EXPECT_EQ(timer.ticks(), 100);
  // absolute schedule: the last deadline is start + k * period with k >= 100 (no drift)
  EXPECT_EQ((prev - start) % kPeriod, 0);
  EXPECT_GE(prev - start, 100 * kPeriod);
}

TEST(PeriodicTimer, OverrunIsCountedAndMissedPeriodsSkipped) {
  constexpr std::int64_t kPeriod = 1 * kNsPerMs;
  PeriodicTimer timer(kPeriod, 50'000);
  timer.wait();
  const std::int64_t overruns0 = timer.overruns();
  // simulate a tick whose work took 3.5 periods
  sleepUntilNs(monotonicNs() + 3 * kPeriod + kPeriod / 2);
  const TimerTick late = timer.wait();
  EXPECT_EQ(timer.overruns(), overruns0 + 1);
  EXPECT_GE(late.missed, 2);            // at least the whole periods slept through
  EXPECT_EQ(timer.missedTicks(), late.missed);
  EXPECT_GE(late.woken_ns, late.scheduled_ns);
  // no burst of catch-up ticks: the next deadline is in the future
  EXPECT_GT(timer.nextDeadlineNs(), monotonicNs() - kPeriod);
  const TimerTick next = timer.wait();
  EXPECT_GT(next.scheduled_ns, late.scheduled_ns);
  EXPECT_EQ((next.scheduled_ns - late.scheduled_ns) % kPeriod, 0);
}

TEST(PeriodicTimer, PeriodAndSpinMarginAreClamped) {
  PeriodicTimer fast(10'000, 1'000'000);
  EXPECT_EQ(fast.periodNs(), PeriodicTimer::kMinPeriodNs);
  EXPECT_EQ(fast.spinMarginNs(), PeriodicTimer::kMinPeriodNs / 2);
  for (int i = 0; i < 20; ++i) {
    const TimerTick t = fast.wait();
    EXPECT_GE(t.woken_ns, t.scheduled_ns);
  }
}

TEST(BareLoop, ReportsOneLatenessPerTick) {
  std::vector<std::int64_t> late(200, -1);
  const BareLoopStats s = runBareLoop(250'000, 200, 50'000, late.data());
  EXPECT_EQ(s.ticks, 200);
  EXPECT_GE(s.min_late_ns, 0);
  EXPECT_GE(s.max_late_ns, s.min_late_ns);
  EXPECT_GE(s.mean_late_ns, static_cast<double>(s.min_late_ns));
  EXPECT_LE(s.mean_late_ns, static_cast<double>(s.max_late_ns));
  for (std::int64_t l : late) EXPECT_GE(l, 0);
  EXPECT_EQ(runBareLoop(250'000, 0).ticks, 0);
}

}  // namespace
}  // namespace tactus::shared

#pragma once
// Single-producer single-consumer ring of fixed-size POD events, in-process: the real-time thread
// try-pushes events (never allocates, never blocks; when full the event is dropped and counted),
// a non-real-time thread drains them into spdlog. The RT thread never calls spdlog itself.
//
// Classic Lamport ring with two monotonically increasing indices, each on its own cache line.
// Capacity is a compile-time power of two. Everything is noexcept and allocation-free.

#include <array>
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <type_traits>

namespace tactus::shared {

/// Event codes used by the daemons (others may be added above kUser).
enum EventCode : std::uint32_t {
  kEventNone = 0,
  kEventOverrun = 1,            ///< arg0 = lateness ns, arg1 = missed deadlines
  kEventSnapshotStale = 2,      ///< arg0 = snapshot age ns
  kEventSnapshotFresh = 3,      ///< arg0 = snapshot seq
  kEventDeviceNoData = 4,
  kEventDeviceFault = 5,
  kEventForceClamped = 6,       ///< arg0 = requested |F| N, arg1 = clamped |F| N
  kEventSolverNotConverged = 7, ///< arg0 = sweeps, arg1 = error
  kEventSegmentLost = 8,
  kEventSegmentAttached = 9,    ///< arg0 = generation
  kEventUser = 1000,
};

/// Short name of a code ("overrun", ...) or "event" for unknown codes.
constexpr const char* eventCodeName(std::uint32_t code) noexcept {
  switch (code) {
    case kEventNone: return "none";
    case kEventOverrun: return "overrun";
    case kEventSnapshotStale: return "snapshot_stale";
    case kEventSnapshotFresh: return "snapshot_fresh";
    case kEventDeviceNoData: return "device_no_data";
    case kEventDeviceFault: return "device_fault";
    case kEventForceClamped: return "force_clamped";
    case kEventSolverNotConverged: return "solver_not_converged";
    case kEventSegmentLost: return "segment_lost";
    case kEventSegmentAttached: return "segment_attached";
    default: return "event";
  }
}

/// One event: 32 bytes, trivially copyable.
struct RtEvent {
  std::int64_t t_ns = 0;        ///< monotonic time
  std::uint32_t code = 0;       ///< EventCode
  std::uint32_t reserved = 0;
  double arg0 = 0.0;
  double arg1 = 0.0;
};

/// SPSC ring of T with Capacity (power of two) slots.
template <class T, std::size_t Capacity>
class SpscRing {
  static_assert(Capacity >= 2 && (Capacity & (Capacity - 1)) == 0, "capacity: a power of two");
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  static constexpr std::size_t kCapacity = Capacity;

  /// Producer: copies `item` in; false (and one more drop counted) when full.
  bool tryPush(const T& item) noexcept {
    // relaxed: only the producer writes head_
    const std::uint64_t head = head_.load(std::memory_order_relaxed);
    // acquire: the consumer's copy out of a slot happens before we overwrite it
    const std::uint64_t tail = tail_.load(std::memory_order_acquire);
    if (head - tail >= Capacity) {
      // relaxed: a statistic, no data depends on it
      dropped_.fetch_add(1, std::memory_order_relaxed);
      return false;
    }
    items_[head & (Capacity - 1)] = item;
    // release: the slot contents are visible to the consumer that acquires head_
    head_.store(head + 1, std::memory_order_release);
    return true;
  }

  /// Consumer: copies the oldest item out; false when empty.
  bool tryPop(T* out) noexcept {
    // relaxed: only the consumer writes tail_
    const std::uint64_t tail = tail_.load(std::memory_order_relaxed);
    // acquire: pairs with the producer's release of head_ (slot contents complete)
    const std::uint64_t head = head_.load(std::memory_order_acquire);
    if (tail == head) return false;
    *out = items_[tail & (Capacity - 1)];
    // release: our copy completes before the producer may reuse the slot
    tail_.store(tail + 1, std::memory_order_release);
    return true;
  }

  /// Consumer: pops up to `max` items and calls fn(item) for each; returns how many.
  template <class Fn>
  std::size_t drain(Fn&& fn, std::size_t max = Capacity) {
    std::size_t n = 0;
    T item;
    while (n < max && tryPop(&item)) {
      fn(item);
      ++n;
    }
    return n;
  }

  /// Items pushed and not yet popped (approximate while both sides run).
  std::size_t size() const noexcept {
    // relaxed: approximate by design
    return static_cast<std::size_t>(head_.load(std::memory_order_relaxed) -
                                    tail_.load(std::memory_order_relaxed));
  }
  /// Pushes refused because the ring was full.
  std::uint64_t dropped() const noexcept {
    // relaxed: a statistic
    return dropped_.load(std::memory_order_relaxed);
  }

 private:
  alignas(64) std::atomic<std::uint64_t> head_{0};      ///< next slot to write (producer)
  alignas(64) std::atomic<std::uint64_t> tail_{0};      ///< next slot to read (consumer)
  alignas(64) std::atomic<std::uint64_t> dropped_{0};
  alignas(64) std::array<T, Capacity> items_{};
};

/// The RT thread's log channel: 1024 events (32 KiB).
using EventRing = SpscRing<RtEvent, 1024>;

/// Convenience for the RT thread: pushes {t_ns, code, arg0, arg1}; false when dropped.
template <std::size_t N>
inline bool pushEvent(SpscRing<RtEvent, N>& ring, std::int64_t t_ns, std::uint32_t code,
                      double arg0 = 0.0, double arg1 = 0.0) noexcept {
  RtEvent e;
  e.t_ns = t_ns;
  e.code = code;
  e.arg0 = arg0;
  e.arg1 = arg1;
  return ring.tryPush(e);
}

}  // namespace tactus::shared

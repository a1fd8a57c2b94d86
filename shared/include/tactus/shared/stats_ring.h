#pragma once
// Single-writer, multi-reader ring of fixed-size records with per-record sequence numbers
// (seqlock style), laid out in caller-provided memory (the shared segment). The haptic loop
// writes one StatsRecord per tick; the jitter tool and the viewer follow it live, possibly through
// a read-only mapping.
//
// Layout at `base` (64-byte aligned, offsets only):
//   [ SeqRingControl (128 B) | slot 0 | slot 1 | ... | slot capacity-1 ]
//   slot: { atomic<uint64> seq; atomic<uint64> words[sizeof(T) / 8] }
//
// Protocol. Record i (i = 0, 1, ...) goes to slot i % capacity. The writer stores seq = 2i+1 (odd:
// being written), the words, then seq = 2i+2 (even: complete), then write_index = i+1. A reader
// wanting record i loads seq (must be 2i+2), copies the words, loads seq again: if it changed, the
// writer lapped it mid-copy and the record is counted lost, never returned torn. Readers only
// load, so a read-only mapping works; the writer never waits for readers (it overwrites the
// oldest record); a reader that lags more than `capacity` records detects the gap from the write
// index and counts the skipped records as lost.
//
// All data words are std::atomic<uint64_t> accessed relaxed, ordered by fences and the seq
// acquire/release pairs (Boehm, "Can seqlocks get along with programming language memory
// models?"), so the protocol is free of data races in the C++ model (ThreadSanitizer-clean).
//
// Everything here is noexcept and allocation-free.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <new>
#include <type_traits>

#include "tactus/shared/messages.h"
#include "tactus/shared/triple_buffer.h"

namespace tactus::shared {

static_assert(std::atomic<std::uint64_t>::is_always_lock_free,
              "the stats ring needs lock-free 64-bit atomics in shared memory");

/// Control block of a ring: sizes (written once by the creator) and the write index.
struct alignas(kCacheLineBytes) SeqRingControl {
  std::uint64_t capacity = 0;        ///< records, a power of two
  std::uint64_t record_bytes = 0;    ///< sizeof(T)
  std::uint64_t slot_stride = 0;     ///< 8 + sizeof(T)
  std::uint64_t reserved[5]{};
  /// Records written so far (= index of the next record). Own cache line: readers poll it.
  alignas(kCacheLineBytes) std::atomic<std::uint64_t> write_index{0};
};
static_assert(sizeof(SeqRingControl) == 2 * kCacheLineBytes);

template <class T>
struct SeqRingSlot {
  static_assert(std::is_trivially_copyable_v<T> && sizeof(T) % 8 == 0,
                "ring records are copied as 64-bit words");
  static constexpr std::size_t kWords = sizeof(T) / 8;
  std::atomic<std::uint64_t> seq{0};
  std::atomic<std::uint64_t> words[kWords];
};

/// Bytes a ring of `capacity` records of T occupies.
template <class T>
constexpr std::size_t seqRingBytes(std::size_t capacity) noexcept {
  return sizeof(SeqRingControl) + capacity * sizeof(SeqRingSlot<T>);
}

/// Constructs an empty ring at `base` (capacity must be a power of two >= 2). Call once.
template <class T>
SeqRingControl* initSeqRing(void* base, std::size_t capacity) noexcept {
  auto* control = new (base) SeqRingControl();
  control->capacity = capacity;
  control->record_bytes = sizeof(T);
  control->slot_stride = sizeof(SeqRingSlot<T>);
  auto* slots = reinterpret_cast<unsigned char*>(control) + sizeof(SeqRingControl);
  for (std::size_t i = 0; i < capacity; ++i) {
    auto* s = new (slots + i * sizeof(SeqRingSlot<T>)) SeqRingSlot<T>();
    for (auto& w : s->words) w.store(0, std::memory_order_relaxed);
  }
  // release: a reader acquiring write_index sees initialised slots
  control->write_index.store(0, std::memory_order_release);
  return control;
}

namespace detail {
template <class T>
inline SeqRingSlot<T>* ringSlot(const SeqRingControl* control, std::uint64_t index) noexcept {
  auto* base = reinterpret_cast<unsigned char*>(const_cast<SeqRingControl*>(control));
  return reinterpret_cast<SeqRingSlot<T>*>(base + sizeof(SeqRingControl) +
                                           (index & (control->capacity - 1)) *
                                               sizeof(SeqRingSlot<T>));
}
}  // namespace detail

/// The single writer (process-local handle). Resumes after the last record on attach.
template <class T>
class SeqRingWriter {
 public:
  SeqRingWriter() = default;
  explicit SeqRingWriter(SeqRingControl* control) noexcept : control_(control) {
    // relaxed: we are the only writer; the value is only our own earlier progress
    next_ = control_->write_index.load(std::memory_order_relaxed);
  }
  bool attached() const noexcept { return control_ != nullptr; }

  /// Appends one record, overwriting the oldest when full. Never blocks.
  void push(const T& record) noexcept {
    SeqRingSlot<T>* slot = detail::ringSlot<T>(control_, next_);
    // relaxed + release fence: the odd seq becomes visible no later than any data word below, so
    // a reader that sees a new word also sees the odd (or a later) seq on its second check
    slot->seq.store(2 * next_ + 1, std::memory_order_relaxed);
    std::atomic_thread_fence(std::memory_order_release);
    std::uint64_t words[SeqRingSlot<T>::kWords];
    std::memcpy(words, &record, sizeof(T));
    for (std::size_t w = 0; w < SeqRingSlot<T>::kWords; ++w) {
      // relaxed: ordered by the fence above and the release store below
      slot->words[w].store(words[w], std::memory_order_relaxed);
    }
    // release: the data words happen-before a reader's acquire of the even seq
    slot->seq.store(2 * next_ + 2, std::memory_order_release);
    ++next_;
    // release: a reader that acquires the index finds the record complete
    control_->write_index.store(next_, std::memory_order_release);
  }

  std::uint64_t written() const noexcept { return next_; }

 private:
  SeqRingControl* control_ = nullptr;
  std::uint64_t next_ = 0;
};

/// Outcome of reading one record by index.
enum class RingRead : std::uint8_t { kOk, kNotYet, kOverwritten };

/// A reader (process-local; any number of readers, read-only mappings allowed).
template <class T>
class SeqRingReader {
 public:
  enum class Start : std::uint8_t { kNewest, kOldest };

  SeqRingReader() = default;
  /// kNewest: only records written after attaching; kOldest: everything still in the ring.
  explicit SeqRingReader(const SeqRingControl* control, Start start = Start::kNewest) noexcept
      : control_(control) {
    // acquire: pairs with the writer's release of write_index
    const std::uint64_t w = control_->write_index.load(std::memory_order_acquire);
    if (start == Start::kNewest) {
      next_ = w;
    } else {
      next_ = w > control_->capacity ? w - control_->capacity : 0;
    }
  }
  bool attached() const noexcept { return control_ != nullptr; }

  /// Reads record `index` without moving the cursor.
  RingRead read(std::uint64_t index, T* out) const noexcept {
    const SeqRingSlot<T>* slot = detail::ringSlot<T>(control_, index);
    const std::uint64_t want = 2 * index + 2;
    // acquire: pairs with the writer's release of the even seq (the data words are complete)
    const std::uint64_t s1 = slot->seq.load(std::memory_order_acquire);
    if (s1 != want) return s1 > want ? RingRead::kOverwritten : RingRead::kNotYet;
    std::uint64_t words[SeqRingSlot<T>::kWords];
    for (std::size_t w = 0; w < SeqRingSlot<T>::kWords; ++w) {
      // relaxed: validated by the second seq check below
      words[w] = slot->words[w].load(std::memory_order_relaxed);
    }
    // acquire fence: the word loads above happen before the seq re-load below
    std::atomic_thread_fence(std::memory_order_acquire);
    const std::uint64_t s2 = slot->seq.load(std::memory_order_relaxed);
    if (s2 != s1) return RingRead::kOverwritten;
    std::memcpy(out, words, sizeof(T));
    return RingRead::kOk;
  }

  /// Copies up to `max` new records in order into `out`; returns how many. Records the writer
  /// overwrote before this reader got to them are skipped and added to lost().
  std::size_t poll(T* out, std::size_t max) noexcept {
    // acquire: records below the index are complete
    const std::uint64_t w = control_->write_index.load(std::memory_order_acquire);
    if (w - next_ > control_->capacity) {
      lost_ += w - control_->capacity - next_;
      next_ = w - control_->capacity;
    }
    std::size_t n = 0;
    while (next_ < w && n < max) {
      const RingRead r = read(next_, out + n);
      if (r == RingRead::kOk) {
        ++n;
      } else if (r == RingRead::kOverwritten) {
        ++lost_;
      } else {
        break;
      }
      ++next_;
    }
    return n;
  }

  /// The newest complete record, if any (does not move the cursor).
  bool newest(T* out) const noexcept {
    for (int attempt = 0; attempt < 4; ++attempt) {
      // acquire: pairs with the writer's release of write_index
      const std::uint64_t w = control_->write_index.load(std::memory_order_acquire);
      if (w == 0) return false;
      if (read(w - 1, out) == RingRead::kOk) return true;
    }
    return false;
  }

  std::uint64_t lost() const noexcept { return lost_; }
  std::uint64_t nextIndex() const noexcept { return next_; }
  /// Records written so far by the writer.
  std::uint64_t written() const noexcept {
    // relaxed: informational
    return control_->write_index.load(std::memory_order_relaxed);
  }

 private:
  const SeqRingControl* control_ = nullptr;
  std::uint64_t next_ = 0;
  std::uint64_t lost_ = 0;
};

using StatsRingWriter = SeqRingWriter<StatsRecord>;
using StatsRingReader = SeqRingReader<StatsRecord>;

}  // namespace tactus::shared

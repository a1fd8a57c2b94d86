#pragma once
// Wait-free single-producer single-consumer triple buffer with runtime-sized slots, laid out in
// caller-provided memory (the shared segment, or a heap block in tests).
//
// Memory layout at `base` (64-byte aligned, no pointers: valid at any mapping address):
//
//   [ TripleBufferControl (64 B) | slot 0 | slot 1 | slot 2 ]     each slot: slot_stride bytes,
//                                                                 a multiple of 64 (cache lines)
//
// Protocol (../../../../docs/design.md#the-triple-buffer; HadrienG2/triple-buffer's idea). One
// atomic byte `state` holds the three slot roles and a fresh bit:
//
//   bits 0-1 back (the writer's slot), bits 2-3 middle (the hand-over slot),
//   bits 4-5 front (the reader's slot), bit 6 fresh (middle holds data the reader has not taken).
//
//   writer: fill back;  state <- {back: middle, middle: back, front, fresh: 1}
//   reader: if fresh:   state <- {back, middle: front, front: middle, fresh: 0};  read front
//
// Each side caches its own slot index in its own process (TripleBufferWriter/Reader) and touches
// only its own slot, so neither side ever waits or copies under a lock and the reader always gets
// the newest complete write. Keeping all three roles in the byte (rather than only the back index)
// lets a restarted writer or reader re-attach to a live buffer: its slot is read from `state`.
//
// Both transitions are compare-exchange loops that are bounded: the writer's CAS can only fail
// because the reader took the fresh slot, which clears `fresh`, and the reader cannot change the
// state again until the next publish, so the writer succeeds on its second attempt at the latest.
// The reader's CAS fails only when the writer published in between; after kMaxReaderRetries such
// failures (a writer publishing millions of times per second) the reader keeps its current slot,
// which is still a complete, consistent value. Both sides are therefore wait-free.
//
// The atomic must be lock-free (hence address-free) to work across processes:
// static_assert(std::atomic<std::uint8_t>::is_always_lock_free).
//
// Exactly one writer and one reader at a time (per buffer). Everything here is noexcept and
// allocation-free except TripleBufferStorage (heap, for tests and in-process use).

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <new>
#include <type_traits>

namespace tactus::shared {

static_assert(std::atomic<std::uint8_t>::is_always_lock_free,
              "the triple buffer needs a lock-free (address-free) atomic byte in shared memory");

inline constexpr std::size_t kCacheLineBytes = 64;

constexpr std::size_t roundUpToCacheLine(std::size_t bytes) noexcept {
  return (bytes + kCacheLineBytes - 1) / kCacheLineBytes * kCacheLineBytes;
}

/// Control block at the start of a triple buffer; alone on its cache line.
struct alignas(kCacheLineBytes) TripleBufferControl {
  static constexpr std::uint8_t kIndexMask = 0b11;
  static constexpr int kBackShift = 0;
  static constexpr int kMiddleShift = 2;
  static constexpr int kFrontShift = 4;
  static constexpr std::uint8_t kFresh = 0b100'0000;
  /// back = 0, middle = 1, front = 2, nothing fresh.
  static constexpr std::uint8_t kInitialState = (0 << kBackShift) | (1 << kMiddleShift) |
                                                (2 << kFrontShift);

  std::atomic<std::uint8_t> state{kInitialState};
  std::uint8_t reserved[7]{};
  std::uint64_t slot_bytes = 0;      ///< payload bytes per slot (as requested)
  std::uint64_t slot_stride = 0;     ///< bytes between slots (roundUpToCacheLine(slot_bytes))
  std::uint64_t reserved2 = 0;

  static constexpr std::uint8_t back(std::uint8_t s) noexcept {
    return (s >> kBackShift) & kIndexMask;
  }
  static constexpr std::uint8_t middle(std::uint8_t s) noexcept {
    return (s >> kMiddleShift) & kIndexMask;
  }
  static constexpr std::uint8_t front(std::uint8_t s) noexcept {
    return (s >> kFrontShift) & kIndexMask;
  }
  static constexpr std::uint8_t make(std::uint8_t b, std::uint8_t m, std::uint8_t f,
                                     bool fresh) noexcept {
    return static_cast<std::uint8_t>((b << kBackShift) | (m << kMiddleShift) |
                                     (f << kFrontShift) | (fresh ? kFresh : 0));
  }
  /// True when the byte is a valid permutation of the three slots. Checked when a segment is
  /// attached (Segment::tryOpen), and by both endpoints before each transition: a byte another
  /// process corrupted is never followed to a slot index of 3.
  static constexpr bool valid(std::uint8_t s) noexcept {
    const int b = back(s), m = middle(s), f = front(s);
    return b != m && m != f && b != f && b < 3 && m < 3 && f < 3 && (s & 0x80) == 0;
  }
};
static_assert(sizeof(TripleBufferControl) == kCacheLineBytes);
static_assert(std::is_standard_layout_v<TripleBufferControl>);

/// Bytes a triple buffer of `slot_bytes`-byte slots occupies (control + 3 aligned slots).
constexpr std::size_t tripleBufferBytes(std::size_t slot_bytes) noexcept {
  return sizeof(TripleBufferControl) + 3 * roundUpToCacheLine(slot_bytes);
}

/// Slot `index` (0..2) of the triple buffer at `control` with slots of `slot_bytes`: the stride
/// comes from the size the caller expects, never from the control block (shared memory that
/// another process may change).
inline unsigned char* tripleBufferSlot(TripleBufferControl* control, int index,
                                       std::size_t slot_bytes) noexcept {
  return reinterpret_cast<unsigned char*>(control) + sizeof(TripleBufferControl) +
         static_cast<std::size_t>(index) * roundUpToCacheLine(slot_bytes);
}
inline const unsigned char* tripleBufferSlot(const TripleBufferControl* control, int index,
                                             std::size_t slot_bytes) noexcept {
  return tripleBufferSlot(const_cast<TripleBufferControl*>(control), index, slot_bytes);
}

/// Whether the triple buffer at `control` is one of `slot_bytes`-byte slots in a valid state
/// (for an attacher: a control block that does not match is refused, never used).
inline bool tripleBufferMatches(const TripleBufferControl* control,
                                std::size_t slot_bytes) noexcept {
  // acquire: pairs with initTripleBuffer's release
  const std::uint8_t s = control->state.load(std::memory_order_acquire);
  return TripleBufferControl::valid(s) && control->slot_bytes == slot_bytes &&
         control->slot_stride == roundUpToCacheLine(slot_bytes);
}

/// Constructs a triple buffer at `base` (64-byte aligned, tripleBufferBytes(slot_bytes) bytes):
/// zeroes the slots and sets the initial state. Call once, before any writer or reader attaches.
inline TripleBufferControl* initTripleBuffer(void* base, std::size_t slot_bytes) noexcept {
  auto* control = new (base) TripleBufferControl();
  control->slot_bytes = slot_bytes;
  control->slot_stride = roundUpToCacheLine(slot_bytes);
  std::memset(tripleBufferSlot(control, 0, slot_bytes), 0, 3 * roundUpToCacheLine(slot_bytes));
  // release: a thread that acquires the state sees the zeroed slots and sizes
  control->state.store(TripleBufferControl::kInitialState, std::memory_order_release);
  return control;
}

/// The writer's process-local handle for slots of `slot_bytes` (the size the caller expects: the
/// stride is computed from it, never read from shared memory). Attaching reads the writer's slot
/// from the state, so a restarted writer resumes on the right slot.
class TripleBufferWriter {
 public:
  TripleBufferWriter() = default;
  TripleBufferWriter(TripleBufferControl* control, std::size_t slot_bytes) noexcept
      : control_(control), slot_bytes_(slot_bytes) {
    // acquire: pairs with the reader's release in case the slot we own was its front before
    const std::uint8_t s = control_->state.load(std::memory_order_acquire);
    back_ = TripleBufferControl::valid(s) ? TripleBufferControl::back(s) : 0;
  }

  bool attached() const noexcept { return control_ != nullptr; }
  std::size_t slotBytes() const noexcept { return slot_bytes_; }

  /// The slot to fill; valid until publish().
  void* buffer() noexcept { return tripleBufferSlot(control_, back_, slot_bytes_); }

  /// Hands the filled slot to the reader. Returns true when it replaced a value the reader had
  /// not taken yet (informational: the reader only ever wants the newest). A corrupt state (not
  /// a permutation of the slots) is left alone: nothing is published.
  bool publish() noexcept {
    using C = TripleBufferControl;
    // relaxed: only the value is needed; the CAS below carries the ordering
    std::uint8_t s = control_->state.load(std::memory_order_relaxed);
    std::uint8_t next;
    do {
      if (!C::valid(s)) return false;
      next = C::make(C::middle(s), C::back(s), C::front(s), true);
      // success acq_rel: release makes our slot writes visible to the reader that acquires this
      // state; acquire makes the reader's earlier reads of the slot we get back (possibly its old
      // front) happen before our next writes into it. failure relaxed: we retry with the value.
    } while (!control_->state.compare_exchange_weak(s, next, std::memory_order_acq_rel,
                                                    std::memory_order_relaxed));
    back_ = C::middle(s);
    return (s & C::kFresh) != 0;
  }

 private:
  TripleBufferControl* control_ = nullptr;
  std::size_t slot_bytes_ = 0;
  std::uint8_t back_ = 0;
};

/// The reader's process-local handle. Attaching reads the reader's slot from the state.
class TripleBufferReader {
 public:
  static constexpr int kMaxReaderRetries = 64;

  TripleBufferReader() = default;
  /// For slots of `slot_bytes` (as TripleBufferWriter).
  TripleBufferReader(TripleBufferControl* control, std::size_t slot_bytes) noexcept
      : control_(control), slot_bytes_(slot_bytes) {
    // acquire: the slot we attach to was last handed over by a release CAS
    const std::uint8_t s = control_->state.load(std::memory_order_acquire);
    front_ = TripleBufferControl::valid(s) ? TripleBufferControl::front(s) : 2;
  }

  bool attached() const noexcept { return control_ != nullptr; }
  std::size_t slotBytes() const noexcept { return slot_bytes_; }

  /// True when the writer published since the reader last took a slot.
  bool hasNew() const noexcept {
    // relaxed: a hint only; latest() does the synchronising CAS
    return (control_->state.load(std::memory_order_relaxed) & TripleBufferControl::kFresh) != 0;
  }

  /// Takes the newest published slot if there is one and returns the reader's slot. `fresh`
  /// (optional) tells whether a new slot was taken by this call. The pointer stays valid and
  /// unchanged by the writer until the next latest().
  const void* latest(bool* fresh = nullptr) noexcept {
    using C = TripleBufferControl;
    bool took = false;
    // relaxed: only tests the fresh bit; the CAS acquires
    std::uint8_t s = control_->state.load(std::memory_order_relaxed);
    // (a corrupt state is never followed: the reader keeps its slot)
    for (int attempt = 0;
         attempt < kMaxReaderRetries && (s & C::kFresh) != 0 && C::valid(s); ++attempt) {
      const std::uint8_t next = C::make(C::back(s), C::front(s), C::middle(s), false);
      // success acq_rel: acquire sees the writer's slot contents (its release CAS); release
      // orders our reads of the old front before the writer may reuse it as back.
      // failure relaxed: the writer published again; retry with the new value.
      if (control_->state.compare_exchange_strong(s, next, std::memory_order_acq_rel,
                                                  std::memory_order_relaxed)) {
        front_ = C::middle(s);
        took = true;
        break;
      }
    }
    if (fresh != nullptr) *fresh = took;
    return tripleBufferSlot(control_, front_, slot_bytes_);
  }

  /// The reader's current slot, without looking for a newer one.
  const void* current() const noexcept {
    return tripleBufferSlot(control_, front_, slot_bytes_);
  }

 private:
  TripleBufferControl* control_ = nullptr;
  std::size_t slot_bytes_ = 0;
  std::uint8_t front_ = 2;
};

/// Typed views for a fixed-size trivially copyable T.
template <class T>
class TripleWriter {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  TripleWriter() = default;
  explicit TripleWriter(TripleBufferControl* control) noexcept : raw_(control, sizeof(T)) {}
  bool attached() const noexcept { return raw_.attached(); }
  T& buffer() noexcept { return *static_cast<T*>(raw_.buffer()); }
  bool publish() noexcept { return raw_.publish(); }
  /// buffer() = value; publish().
  bool publish(const T& value) noexcept {
    buffer() = value;
    return raw_.publish();
  }

 private:
  TripleBufferWriter raw_;
};

template <class T>
class TripleReader {
  static_assert(std::is_trivially_copyable_v<T>);

 public:
  TripleReader() = default;
  explicit TripleReader(TripleBufferControl* control) noexcept : raw_(control, sizeof(T)) {}
  bool attached() const noexcept { return raw_.attached(); }
  bool hasNew() const noexcept { return raw_.hasNew(); }
  const T& latest(bool* fresh = nullptr) noexcept {
    return *static_cast<const T*>(raw_.latest(fresh));
  }
  const T& current() const noexcept { return *static_cast<const T*>(raw_.current()); }

 private:
  TripleBufferReader raw_;
};

/// Heap-owned triple buffer for in-process use and tests (allocates; not for the RT thread).
class TripleBufferStorage {
 public:
  explicit TripleBufferStorage(std::size_t slot_bytes)
      : slot_bytes_(slot_bytes),
        bytes_(tripleBufferBytes(slot_bytes)),
        memory_(static_cast<unsigned char*>(std::aligned_alloc(kCacheLineBytes, bytes_))) {
    if (memory_ == nullptr) throw std::bad_alloc();
    control_ = initTripleBuffer(memory_, slot_bytes);
  }
  ~TripleBufferStorage() { std::free(memory_); }
  TripleBufferStorage(const TripleBufferStorage&) = delete;
  TripleBufferStorage& operator=(const TripleBufferStorage&) = delete;

  TripleBufferControl* control() noexcept { return control_; }
  std::size_t bytes() const noexcept { return bytes_; }
  std::size_t slotBytes() const noexcept { return slot_bytes_; }

 private:
  std::size_t slot_bytes_;
  std::size_t bytes_;
  unsigned char* memory_;
  TripleBufferControl* control_ = nullptr;
};

}  // namespace tactus::shared

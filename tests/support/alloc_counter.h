#pragma once
// Counting replacement of the global operator new/delete, and (glibc) of malloc, calloc,
// realloc, aligned_alloc, posix_memalign, memalign and free, for "zero allocations" tests.
//
// The replaceable global allocation functions are defined in alloc_counter.cpp, which a test
// executable that counts allocations links (tests/CMakeLists.txt). Then:
//
//   tactus::test::AllocScope scope;          // counts allocations made by this thread
//   device->read(&state);
//   EXPECT_EQ(scope.allocations(), 0);
//
// Counting is per thread (thread_local), so allocations of unrelated threads (a recorder's
// flusher, gtest internals on other threads) do not pollute the measurement; a process-wide
// total is kept too. Every operator new and every C allocation call (malloc, calloc, realloc,
// aligned_alloc, posix_memalign, memalign) counts once; cAllocations() counts the C calls alone.
// The C functions are interposed by defining them in the executable (glibc resolves the
// program's own definitions first, for libstdc++ and every other library too) and forward to
// glibc's __libc_* entry points; operator new allocates through those directly, so it is not
// counted twice.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <new>

extern "C" {
void* __libc_malloc(std::size_t n);
void* __libc_calloc(std::size_t count, std::size_t n);
void* __libc_realloc(void* p, std::size_t n);
void* __libc_memalign(std::size_t align, std::size_t n);
void __libc_free(void* p);
}

namespace tactus::test {

namespace detail {
// constant-initialised thread-locals of the executable: no allocation on first use
inline thread_local std::int64_t thread_allocations = 0;
inline thread_local std::int64_t thread_c_allocations = 0;
inline std::atomic<std::int64_t> total_allocations{0};

inline void countC() noexcept {
  ++thread_c_allocations;
  ++thread_allocations;
  total_allocations.fetch_add(1, std::memory_order_relaxed);
}

inline void countOne() noexcept {
  ++thread_allocations;
  // relaxed: a statistic only
  total_allocations.fetch_add(1, std::memory_order_relaxed);
}

inline void* allocate(std::size_t n) {
  countOne();
  void* p = __libc_malloc(n == 0 ? 1 : n);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}

inline void* allocateAligned(std::size_t n, std::size_t align) {
  countOne();
  if (align < sizeof(void*)) align = sizeof(void*);
  const std::size_t rounded = (n + align - 1) / align * align;
  void* p = __libc_memalign(align, rounded == 0 ? align : rounded);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}
}  // namespace detail

// The readers are out of line (alloc_counter.cpp): the compiler takes malloc and free for
// builtins that write no memory of the program, so an inline read of a counter could be moved
// across them and miss the counts they made.

/// C allocation calls (malloc family) made by the calling thread so far.
std::int64_t threadCAllocations() noexcept;

/// Allocations (operator new and malloc-family calls) made by the calling thread so far.
std::int64_t threadAllocations() noexcept;
/// Allocations made by all threads so far.
std::int64_t totalAllocations() noexcept;

/// RAII: allocations made by this thread between construction and allocations().
class AllocScope {
 public:
  AllocScope() noexcept : start_(threadAllocations()), c_start_(threadCAllocations()) {}
  /// operator new and malloc-family calls
  std::int64_t allocations() const noexcept { return threadAllocations() - start_; }
  /// malloc-family calls only
  std::int64_t cAllocations() const noexcept { return threadCAllocations() - c_start_; }

 private:
  std::int64_t start_;
  std::int64_t c_start_;
};

}  // namespace tactus::test

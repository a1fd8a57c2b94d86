#pragma once
// Counting replacement of the global operator new/delete for "zero allocations" tests.
//
// Include this header in exactly ONE translation unit of a test executable (it defines the
// replaceable global allocation functions). Then:
//
//   tactus::test::AllocScope scope;          // counts allocations made by this thread
//   device->read(&state);
//   EXPECT_EQ(scope.allocations(), 0);
//
// Counting is per thread (thread_local), so allocations of unrelated threads (a recorder's
// flusher, gtest internals on other threads) do not pollute the measurement; a process-wide
// total is kept too. malloc/calloc called directly are not counted (only operator new).

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <new>

namespace tactus::test {

namespace detail {
inline thread_local std::int64_t thread_allocations = 0;
inline std::atomic<std::int64_t> total_allocations{0};

inline void countOne() noexcept {
  ++thread_allocations;
  // relaxed: a statistic only
  total_allocations.fetch_add(1, std::memory_order_relaxed);
}

inline void* allocate(std::size_t n) {
  countOne();
  void* p = std::malloc(n == 0 ? 1 : n);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}

inline void* allocateAligned(std::size_t n, std::size_t align) {
  countOne();
  if (align < sizeof(void*)) align = sizeof(void*);
  const std::size_t rounded = (n + align - 1) / align * align;
  void* p = std::aligned_alloc(align, rounded == 0 ? align : rounded);
  if (p == nullptr) throw std::bad_alloc();
  return p;
}
}  // namespace detail

/// Allocations (operator new calls) made by the calling thread so far.
inline std::int64_t threadAllocations() noexcept { return detail::thread_allocations; }
/// Allocations made by all threads so far.
inline std::int64_t totalAllocations() noexcept {
  return detail::total_allocations.load(std::memory_order_relaxed);
}

/// RAII: allocations made by this thread between construction and allocations().
class AllocScope {
 public:
  AllocScope() noexcept : start_(threadAllocations()) {}
  std::int64_t allocations() const noexcept { return threadAllocations() - start_; }

 private:
  std::int64_t start_;
};

}  // namespace tactus::test

// Replaceable global allocation functions (must not be inline).
void* operator new(std::size_t n) { return tactus::test::detail::allocate(n); }
void* operator new[](std::size_t n) { return tactus::test::detail::allocate(n); }
void* operator new(std::size_t n, const std::nothrow_t&) noexcept {
  try {
    return tactus::test::detail::allocate(n);
  } catch (...) {
    return nullptr;
  }
}
void* operator new[](std::size_t n, const std::nothrow_t&) noexcept {
  try {
    return tactus::test::detail::allocate(n);
  } catch (...) {
    return nullptr;
  }
}
void* operator new(std::size_t n, std::align_val_t a) {
  return tactus::test::detail::allocateAligned(n, static_cast<std::size_t>(a));
}
void* operator new[](std::size_t n, std::align_val_t a) {
  return tactus::test::detail::allocateAligned(n, static_cast<std::size_t>(a));
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }
void operator delete(void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { std::free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { std::free(p); }

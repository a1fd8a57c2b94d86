// The counting allocation functions of alloc_counter.h: the C allocator interposed and the
// replaceable global operator new/delete (none of them may be inline).

#include "alloc_counter.h"

namespace tactus::test {
std::int64_t threadCAllocations() noexcept { return detail::thread_c_allocations; }
std::int64_t threadAllocations() noexcept { return detail::thread_allocations; }
std::int64_t totalAllocations() noexcept {
  return detail::total_allocations.load(std::memory_order_relaxed);
}
}  // namespace tactus::test

// The C allocator, interposed (glibc only).
extern "C" {
void* malloc(std::size_t n) noexcept {
  tactus::test::detail::countC();
  return __libc_malloc(n);
}
void* calloc(std::size_t count, std::size_t n) noexcept {
  tactus::test::detail::countC();
  return __libc_calloc(count, n);
}
void* realloc(void* p, std::size_t n) noexcept {
  tactus::test::detail::countC();
  return __libc_realloc(p, n);
}
void* aligned_alloc(std::size_t align, std::size_t n) noexcept {
  tactus::test::detail::countC();
  return __libc_memalign(align, n);
}
void* memalign(std::size_t align, std::size_t n) noexcept {
  tactus::test::detail::countC();
  return __libc_memalign(align, n);
}
int posix_memalign(void** out, std::size_t align, std::size_t n) noexcept {
  tactus::test::detail::countC();
  if (align < sizeof(void*) || (align & (align - 1)) != 0) return 22;  // EINVAL
  void* p = __libc_memalign(align, n);
  if (p == nullptr) return 12;  // ENOMEM
  *out = p;
  return 0;
}
void free(void* p) noexcept { __libc_free(p); }
}

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
void operator delete(void* p) noexcept { __libc_free(p); }
void operator delete[](void* p) noexcept { __libc_free(p); }
void operator delete(void* p, std::size_t) noexcept { __libc_free(p); }
void operator delete[](void* p, std::size_t) noexcept { __libc_free(p); }
void operator delete(void* p, std::align_val_t) noexcept { __libc_free(p); }
void operator delete[](void* p, std::align_val_t) noexcept { __libc_free(p); }
void operator delete(void* p, std::size_t, std::align_val_t) noexcept { __libc_free(p); }
void operator delete[](void* p, std::size_t, std::align_val_t) noexcept { __libc_free(p); }

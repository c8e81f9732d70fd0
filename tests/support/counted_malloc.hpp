// Counts this thread's calls to malloc, calloc and realloc, and to free, by
// interposing them for the whole test binary (they forward to glibc's own):
// per thread, so that nothing else in the process interferes with a count.
// Include it in exactly one source file of a test binary, and leave the
// binary out of a sanitized build, where AddressSanitizer owns malloc.
#pragma once

#include <cstddef>

extern "C" {
void* __libc_malloc(std::size_t size);
void* __libc_calloc(std::size_t count, std::size_t size);
void* __libc_realloc(void* p, std::size_t size);
void __libc_free(void* p);
}

namespace riccati::testing {
inline thread_local std::size_t allocations = 0;  // malloc, calloc and realloc calls
inline thread_local std::size_t frees = 0;        // free calls (of a pointer, not of null)
}  // namespace riccati::testing

extern "C" {
void* malloc(std::size_t size) {
  ++riccati::testing::allocations;
  return __libc_malloc(size);
}
void* calloc(std::size_t count, std::size_t size) {
  ++riccati::testing::allocations;
  return __libc_calloc(count, size);
}
void* realloc(void* p, std::size_t size) {
  ++riccati::testing::allocations;
  return __libc_realloc(p, size);
}
void free(void* p) {
  if (p != nullptr) ++riccati::testing::frees;
  __libc_free(p);
}
}

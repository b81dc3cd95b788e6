// A counting malloc for whole-process measurements of nccompd (LD_PRELOAD): every malloc,
// calloc, realloc, memalign, posix_memalign, aligned_alloc, valloc, pvalloc and free of the
// process goes through glibc's own allocator and is counted per thread. nccompd looks up
// nccomp_preload_thread_allocations / nccomp_preload_thread_frees at start-up (dlsym) and, when
// present, reports its loop thread's counts after warm-up (`nccomp status --json`:
// allocations_after_warmup, frees_after_warmup). operator new / delete of libstdc++ call malloc /
// free, so C++ allocations are counted too.
//
//   LD_PRELOAD=build/release/bench/daemon/libnccomp_alloc_preload.so nccompd -c ...
//
// Not linked into anything: production builds never contain it.
#include <cstddef>
#include <cstdint>

extern "C" {
void* __libc_malloc(std::size_t size);
void* __libc_calloc(std::size_t n, std::size_t size);
void* __libc_realloc(void* p, std::size_t size);
void* __libc_memalign(std::size_t alignment, std::size_t size);
void __libc_free(void* p);
}

namespace {
// initial-exec: a preloaded library's TLS is static, so reading it never allocates.
__thread std::uint64_t t_allocations __attribute__((tls_model("initial-exec"))) = 0;
__thread std::uint64_t t_frees __attribute__((tls_model("initial-exec"))) = 0;

bool power_of_two(std::size_t a) { return a != 0 && (a & (a - 1)) == 0; }
}  // namespace

extern "C" {

__attribute__((visibility("default"))) std::uint64_t nccomp_preload_thread_allocations() noexcept {
  return t_allocations;
}
__attribute__((visibility("default"))) std::uint64_t nccomp_preload_thread_frees() noexcept {
  return t_frees;
}

__attribute__((visibility("default"))) void* malloc(std::size_t size) noexcept {
  ++t_allocations;
  return __libc_malloc(size);
}
__attribute__((visibility("default"))) void* calloc(std::size_t n, std::size_t size) noexcept {
  ++t_allocations;
  return __libc_calloc(n, size);
}
__attribute__((visibility("default"))) void* realloc(void* p, std::size_t size) noexcept {
  ++t_allocations;
  return __libc_realloc(p, size);
}
__attribute__((visibility("default"))) void free(void* p) noexcept {
  if (p != nullptr) {
    ++t_frees;
  }
  __libc_free(p);
}
__attribute__((visibility("default"))) void* memalign(std::size_t a, std::size_t size) noexcept {
  ++t_allocations;
  return __libc_memalign(a, size);
}
__attribute__((visibility("default"))) void* aligned_alloc(std::size_t a,
                                                           std::size_t size) noexcept {
  ++t_allocations;
  return __libc_memalign(a, size);
}
__attribute__((visibility("default"))) int posix_memalign(void** out, std::size_t a,
                                                          std::size_t size) noexcept {
  ++t_allocations;
  if (!power_of_two(a) || a % sizeof(void*) != 0) {
    return 22;  // EINVAL
  }
  void* p = __libc_memalign(a, size);
  if (p == nullptr) {
    return 12;  // ENOMEM
  }
  *out = p;
  return 0;
}
__attribute__((visibility("default"))) void* valloc(std::size_t size) noexcept {
  ++t_allocations;
  return __libc_memalign(4096, size);
}
__attribute__((visibility("default"))) void* pvalloc(std::size_t size) noexcept {
  ++t_allocations;
  return __libc_memalign(4096, (size + 4095) / 4096 * 4096);
}

}  // extern "C"

// What the kernel library was compiled for and which vector paths the running machine
// takes, a plain C ABI for ctypes (read by `voxax.show_config`).
//
// The library is compiled for the compiler's baseline (x86-64: SSE2 only), so that one
// build runs on every machine; kernels that gain from wider vectors carry
// `target_clones("avx2", "default")` (csrc/esi/bounds_host.cc), and the dynamic loader
// picks a clone once, when the library is loaded, from what the CPU supports.
//
//   voxax_cpu_features(out (n,) i32, n) -> count
//
// Writes up to n values, in this order, and returns how many there are (call with n = 0
// or out null to ask):
//   0: the AVX2 clones are compiled in (1) or not (0: not x86-64 Linux, or a sanitizer
//      build),
//   1: the clones the loader selects: 1 the AVX2 ones, 0 the default ones (GCC's and
//      Clang's resolvers for target_clones("avx2", "default") take the AVX2 clone exactly
//      when __builtin_cpu_supports("avx2")),
//   2-6: the library was compiled with SSE4.2 / AVX / AVX2 / FMA / AVX-512F enabled
//      everywhere (all 0 for a portable build),
//   7-11: the running CPU supports SSE4.2 / AVX / AVX2 / FMA / AVX-512F (with the
//      operating system's support for the wider registers), -1 where the question does
//      not apply (not x86-64),
//   12: std::thread::hardware_concurrency(), the thread count of the eager host entry
//      points when none is given (0 if unknown).

#include <cstdint>
#include <thread>

// The same condition as VOXAX_CLONES in csrc/esi/bounds_host.cc.
#if defined(__GNUC__) && defined(__x86_64__) && defined(__linux__) && !defined(__SANITIZE_ADDRESS__)
#define VOXAX_HAS_CLONES 1
#else
#define VOXAX_HAS_CLONES 0
#endif

namespace {

#if defined(__SSE4_2__)
constexpr int32_t kBuiltSse42 = 1;
#else
constexpr int32_t kBuiltSse42 = 0;
#endif
#if defined(__AVX__)
constexpr int32_t kBuiltAvx = 1;
#else
constexpr int32_t kBuiltAvx = 0;
#endif
#if defined(__AVX2__)
constexpr int32_t kBuiltAvx2 = 1;
#else
constexpr int32_t kBuiltAvx2 = 0;
#endif
#if defined(__FMA__)
constexpr int32_t kBuiltFma = 1;
#else
constexpr int32_t kBuiltFma = 0;
#endif
#if defined(__AVX512F__)
constexpr int32_t kBuiltAvx512f = 1;
#else
constexpr int32_t kBuiltAvx512f = 0;
#endif

}  // namespace

extern "C" {

__attribute__((visibility("default"))) int voxax_cpu_features(int32_t* out, int n) {
#if defined(__GNUC__) && defined(__x86_64__)
  __builtin_cpu_init();
  const int32_t sse42 = __builtin_cpu_supports("sse4.2") ? 1 : 0;
  const int32_t avx = __builtin_cpu_supports("avx") ? 1 : 0;
  const int32_t avx2 = __builtin_cpu_supports("avx2") ? 1 : 0;
  const int32_t fma = __builtin_cpu_supports("fma") ? 1 : 0;
  const int32_t avx512f = __builtin_cpu_supports("avx512f") ? 1 : 0;
#else
  const int32_t sse42 = -1, avx = -1, avx2 = -1, fma = -1, avx512f = -1;
#endif
  const int32_t selected = VOXAX_HAS_CLONES && avx2 == 1 ? 1 : 0;
  const int32_t values[] = {VOXAX_HAS_CLONES,
                            selected,
                            kBuiltSse42,
                            kBuiltAvx,
                            kBuiltAvx2,
                            kBuiltFma,
                            kBuiltAvx512f,
                            sse42,
                            avx,
                            avx2,
                            fma,
                            avx512f,
                            static_cast<int32_t>(std::thread::hardware_concurrency())};
  const int count = static_cast<int>(sizeof(values) / sizeof(values[0]));
  if (out == nullptr) return count;
  for (int i = 0; i < n && i < count; ++i) out[i] = values[i];
  return count;
}

}  // extern "C"

// The nearest-seed assignment with region moments (csrc/cvt/assign.h) as a host entry point
// for ctypes (the XLA FFI handler is in assign_ffi.cc).
//
//   voxax_cvt_assign_host(S, n, X, W, m, hint, threads, idx, moments, count, energy, err,
//                         errlen) -> 0 or 1 (message in err)

#include <cstdint>
#include <string>

#include "common/host_errors.h"
#include "common/host_pool.h"
#include "cvt/assign.h"
#include "cvt/assign_checks.h"

extern "C" __attribute__((visibility("default"))) int voxax_cvt_assign_host(
    const double* S, int64_t n, const double* X, const double* W, int64_t m, const int32_t* hint,
    int32_t threads, int32_t* idx, double* moments, int32_t* count, double* energy, char* err,
    int64_t errlen) {
  return voxax::host_guarded("the CVT assignment", err, errlen, [&](std::string* msg) {
    return voxax::cvt::assign_moments(
        S, n, X, W, m, hint, idx, moments, count, energy,
        [&](int64_t chunks, auto&& body) {
          voxax::spatial::parallel_chunks(chunks, 1, threads,
                                          [&](int64_t c, int64_t, int64_t) { body(c); });
        },
        msg);
  });
}

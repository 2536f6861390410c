// Nearest-seed assignment with region moments (csrc/cvt/assign.h): an XLA FFI handler and
// a host entry point for ctypes.
//
//   voxax_cvt_assign(seeds (n, 3) f64, points (m, 3) f64, weights (m,) f64, hint (m,) s32)
//       -> idx (m,) s32, moments (n, 4) f64, count (n,) s32, energy (1,) f64
//   voxax_cvt_assign_host(S, n, X, W, m, hint, threads, idx, moments, count, energy, err,
//                         errlen) -> 0 or 1 (message in err)

#include <cmath>
#include <cstdint>
#include <string>

#include "common/errors.h"
#include "common/host_errors.h"
#include "common/host_pool.h"
#include "common/parallel.h"
#include "cvt/assign.h"

namespace voxax {
namespace {

// The checks of both entry points; false with a message on bad input.
bool check_assign(const double* S, int64_t n, const double* X, const double* W, int64_t m,
                  std::string* msg) {
  if (n < 1 || n > INT32_MAX) {
    *msg = "voxax: the assignment needs between 1 and 2^31 - 1 seeds";
    return false;
  }
  if (m < 0) {
    *msg = "voxax: negative sample count";
    return false;
  }
  if (!check_host_coordinates(S, 3 * n, "seeds", msg) ||
      !check_coordinate_scale(S, 3 * n, "seeds", msg) ||
      !check_host_coordinates(X, 3 * m, "samples", msg))
    return false;
  for (int64_t i = 0; i < m; ++i)
    if (!(W[i] >= 0.0) || !std::isfinite(W[i])) {
      *msg = "voxax: sample weights must be finite and >= 0 (row " + std::to_string(i) + ")";
      return false;
    }
  return true;
}

ffi::Error CvtAssign(ffi::ThreadPool pool, ffi::Buffer<ffi::F64> seeds,
                     ffi::Buffer<ffi::F64> points, ffi::Buffer<ffi::F64> weights,
                     ffi::Buffer<ffi::S32> hint, ffi::ResultBuffer<ffi::S32> idx,
                     ffi::ResultBuffer<ffi::F64> moments, ffi::ResultBuffer<ffi::S32> count,
                     ffi::ResultBuffer<ffi::F64> energy) {
  return guarded("the CVT assignment", [&]() -> ffi::Error {
    auto sd = seeds.dimensions(), pd = points.dimensions();
    if (sd.size() != 2 || sd[1] != 3)
      return ffi::Error::InvalidArgument("voxax: seeds must have shape (n, 3)");
    if (pd.size() != 2 || pd[1] != 3)
      return ffi::Error::InvalidArgument("voxax: points must have shape (m, 3)");
    const int64_t n = sd[0], m = pd[0];
    auto is_vec = [](auto dims, int64_t len) { return dims.size() == 1 && dims[0] == len; };
    if (!is_vec(weights.dimensions(), m) || !is_vec(hint.dimensions(), m))
      return ffi::Error::InvalidArgument("voxax: weights and hint must have shape (m,)");
    auto md = moments->dimensions();
    if (!is_vec(idx->dimensions(), m) || md.size() != 2 || md[0] != n || md[1] != 4 ||
        !is_vec(count->dimensions(), n) || energy->element_count() != 1)
      return ffi::Error::InvalidArgument(
          "voxax: assignment outputs must have shapes (m,), (n, 4), (n,), (1,)");
    std::string msg;
    if (!check_assign(seeds.typed_data(), n, points.typed_data(), weights.typed_data(), m, &msg))
      return ffi::Error::InvalidArgument(msg);
    cvt::assign_moments(
        seeds.typed_data(), n, points.typed_data(), weights.typed_data(), m, hint.typed_data(),
        idx->typed_data(), moments->typed_data(), count->typed_data(), energy->typed_data(),
        [&](int64_t chunks, auto&& body) { ParallelFor::run(&pool, chunks, body); });
    return ffi::Error::Success();
  });
}

}  // namespace
}  // namespace voxax

extern "C" __attribute__((visibility("default"))) int voxax_cvt_assign_host(
    const double* S, int64_t n, const double* X, const double* W, int64_t m, const int32_t* hint,
    int32_t threads, int32_t* idx, double* moments, int32_t* count, double* energy, char* err,
    int64_t errlen) {
  return voxax::host_guarded("the CVT assignment", err, errlen, [&](std::string* msg) {
    if (!voxax::check_assign(S, n, X, W, m, msg)) return false;
    voxax::cvt::assign_moments(
        S, n, X, W, m, hint, idx, moments, count, energy, [&](int64_t chunks, auto&& body) {
          voxax::spatial::parallel_chunks(chunks, 1, threads,
                                          [&](int64_t c, int64_t, int64_t) { body(c); });
        });
    return true;
  });
}

#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_cvt_assign, voxax::CvtAssign,
                              xla::ffi::Ffi::Bind()
                                  .Ctx<xla::ffi::ThreadPool>()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F64>>()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F64>>()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F64>>()
                                  .Arg<xla::ffi::Buffer<xla::ffi::S32>>()
                                  .Ret<xla::ffi::Buffer<xla::ffi::S32>>()
                                  .Ret<xla::ffi::Buffer<xla::ffi::F64>>()
                                  .Ret<xla::ffi::Buffer<xla::ffi::S32>>()
                                  .Ret<xla::ffi::Buffer<xla::ffi::F64>>());

#pragma GCC visibility pop

// Nearest-seed assignment with region moments (csrc/cvt/assign.h): the XLA FFI handler (the
// host entry point for ctypes is in assign_host.cc; both check through assign_checks.h).
//
//   voxax_cvt_assign(seeds (n, 3) f64, points (m, 3) f64, weights (m,) f64, hint (m,) s32)
//       -> idx (m,) s32, moments (n, 4) f64, count (n,) s32, energy (1,) f64

#include <cmath>
#include <cstdint>
#include <string>

#include "common/errors.h"
#include "common/ffi_bind.h"
#include "common/parallel.h"
#include "cvt/assign.h"
#include "cvt/assign_checks.h"

namespace voxax {
namespace {

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
    if (!cvt::assign_moments(
            seeds.typed_data(), n, points.typed_data(), weights.typed_data(), m, hint.typed_data(),
            idx->typed_data(), moments->typed_data(), count->typed_data(), energy->typed_data(),
            [&](int64_t chunks, auto&& body) { ParallelFor::run(&pool, chunks, body); }, &msg))
      return ffi::Error::InvalidArgument(msg);
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_cvt_assign, CvtAssign)

}  // namespace voxax

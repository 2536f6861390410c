// XLA FFI handler that validates the input of the winding numbers under jit (their values
// are computed by JAX there, so that they stay differentiable):
//
// voxax_winding_check(vertices (..., V, d) f32/f64, faces (..., F, k) s32, points (..., d)
//                     f32/f64) -> flag () s32 (0)
//
// Fails with InvalidArgument where a vertex or point coordinate is NaN, infinite or beyond
// 1e75 in magnitude, or a face index lies outside [0, V) (indices beyond int32 arrive
// clipped to -1 or 2^31 - 1, so they fail here as well).

#include <cmath>
#include <string>

#include "common/constants.h"
#include "common/errors.h"
#include "common/ffi_bind.h"

namespace voxax {
namespace {

template <typename T>
ffi::Error check_values(const T* x, size_t count, const char* what) {
  for (size_t i = 0; i < count; ++i) {
    const double v = static_cast<double>(x[i]);
    if (!std::isfinite(v))
      return ffi::Error::InvalidArgument(std::string("voxax.winding_number: `") + what +
                                         "` contain NaN or Inf (flat index " + std::to_string(i) +
                                         ")");
    if (std::fabs(v) > kMaxAbsCoordinate)
      return ffi::Error::InvalidArgument(std::string("voxax.winding_number: `") + what +
                                         "` coordinates must have magnitude <= 1e75 (flat index " +
                                         std::to_string(i) + ")");
  }
  return ffi::Error::Success();
}

ffi::Error check_any(const ffi::AnyBuffer& x, const char* what) {
  switch (x.element_type()) {
    case ffi::DataType::F32:
      return check_values(x.typed_data<float>(), x.element_count(), what);
    case ffi::DataType::F64:
      return check_values(x.typed_data<double>(), x.element_count(), what);
    default:
      return ffi::Error::InvalidArgument(std::string("voxax.winding_number: `") + what +
                                         "` must be float32 or float64");
  }
}

ffi::Error WindingCheck(ffi::AnyBuffer vertices, ffi::Buffer<ffi::S32> faces, ffi::AnyBuffer points,
                        ffi::ResultBuffer<ffi::S32> flag) {
  return guarded("the winding numbers' checks", [&]() -> ffi::Error {
    const auto vd = vertices.dimensions();
    if (vd.size() < 2)
      return ffi::Error::InvalidArgument("voxax.winding_number: `vertices` must be (..., V, d)");
    const int64_t nv = vd[vd.size() - 2];
    ffi::Error err = check_any(vertices, "vertices");
    if (err.failure()) return err;
    err = check_any(points, "points");
    if (err.failure()) return err;
    const int32_t* F = faces.typed_data();
    for (size_t i = 0; i < faces.element_count(); ++i)
      if (F[i] < 0 || F[i] >= nv)
        return ffi::Error::InvalidArgument(
            "voxax.winding_number: face indices out of range: they must lie in [0, " +
            std::to_string(nv) + ") (flat index " + std::to_string(i) + ")");
    if (flag->element_count() != 1)
      return ffi::Error::InvalidArgument("voxax.winding_number: the check returns one flag");
    flag->typed_data()[0] = 0;
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_winding_check, WindingCheck)

}  // namespace voxax

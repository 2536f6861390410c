// XLA FFI handler that checks the values of a float array under jit, for the pure-JAX
// entry points whose input values Python cannot see while tracing:
//
// voxax_finite_check(x (...) f32/f64) -> flag () s32 (0; one per item under vmap)
//   attributes: `where` (the public function, e.g. "voxax.energies.height_field_hull"),
//   `name` (the argument), `max_abs` (the largest magnitude accepted; inf for any),
//   `positive` (s32: 1 where every value must also be > 0).
//
// Fails with InvalidArgument "<where>: `<name>` must be finite ..." at the first NaN or
// infinite element, "... magnitude <= <max_abs> ..." at the first one beyond `max_abs`, or
// "... must be > 0 ..." at the first one that is not a positive normal float when
// `positive` (subnormal values are refused too: XLA's threads treat them as 0).
// The caller ties its result to the flag, so that the check runs before the result is used.

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <string_view>

#include "common/errors.h"
#include "common/ffi_bind.h"

namespace voxax {
namespace {

constexpr char kWhere[] = "where";
constexpr char kName[] = "name";
constexpr char kMaxAbs[] = "max_abs";
constexpr char kPositive[] = "positive";

std::string prefix(std::string_view where, std::string_view name) {
  return std::string(where) + ": `" + std::string(name) + "` ";
}

// Whether x is a positive normal float, from its bits: the same answer on threads that
// treat subnormal operands as zero (XLA's) and on others.
inline bool positive_normal(float x) {
  uint32_t b;
  std::memcpy(&b, &x, sizeof b);
  return (b >> 31) == 0 && ((b >> 23) & 0xffu) != 0;
}
inline bool positive_normal(double x) {
  uint64_t b;
  std::memcpy(&b, &x, sizeof b);
  return (b >> 63) == 0 && ((b >> 52) & 0x7ffu) != 0;
}

template <typename T>
ffi::Error check_values(const T* x, size_t count, std::string_view where, std::string_view name,
                        double max_abs, bool positive) {
  for (size_t i = 0; i < count; ++i) {
    const double v = static_cast<double>(x[i]);
    if (!std::isfinite(v))
      return ffi::Error::InvalidArgument(prefix(where, name) +
                                         "must be finite (it contains NaN or Inf at flat index " +
                                         std::to_string(i) + ")");
    if (std::fabs(v) > max_abs) {
      char bound[32];
      std::snprintf(bound, sizeof bound, "%g", max_abs);
      return ffi::Error::InvalidArgument(prefix(where, name) + "must have magnitude <= " + bound +
                                         " (flat index " + std::to_string(i) + ")");
    }
    if (positive && !positive_normal(x[i]))
      return ffi::Error::InvalidArgument(prefix(where, name) + "must be > 0 (flat index " +
                                         std::to_string(i) + ": zero, negative or subnormal)");
  }
  return ffi::Error::Success();
}

ffi::Error FiniteCheck(ffi::AnyBuffer x, ffi::ResultBuffer<ffi::S32> flag,
                       ffi::Attr<std::string_view, kWhere> where_attr,
                       ffi::Attr<std::string_view, kName> name_attr,
                       ffi::Attr<double, kMaxAbs> max_abs_attr,
                       ffi::Attr<int32_t, kPositive> positive_attr) {
  return guarded("the finite check", [&]() -> ffi::Error {
    const std::string_view where = *where_attr, name = *name_attr;
    const double max_abs = *max_abs_attr;
    const bool positive = *positive_attr != 0;
    ffi::Error err = ffi::Error::Success();
    switch (x.element_type()) {
      case ffi::DataType::F32:
        err =
            check_values(x.typed_data<float>(), x.element_count(), where, name, max_abs, positive);
        break;
      case ffi::DataType::F64:
        err =
            check_values(x.typed_data<double>(), x.element_count(), where, name, max_abs, positive);
        break;
      default:
        return ffi::Error::InvalidArgument(prefix(where, name) + "must be float32 or float64");
    }
    if (err.failure()) return err;
    int32_t* out = flag->typed_data();
    for (size_t i = 0; i < flag->element_count(); ++i) out[i] = 0;
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_finite_check, FiniteCheck)

}  // namespace voxax

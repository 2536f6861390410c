// Input validation inside the kernels, so that bad values are reported with a
// clear message under jit as well, and nothing is read out of bounds.
#pragma once

#include <cmath>
#include <cstdint>
#include <string>

#include "common/constants.h"
#include "xla/ffi/api/ffi.h"

namespace voxax {

namespace ffi = xla::ffi;

template <typename T>
ffi::Error check_vertices(const T* V, int64_t count, int64_t batch_item) {
  for (int64_t i = 0; i < count; ++i) {
    const double x = static_cast<double>(V[i]);
    if (!std::isfinite(x)) {
      return ffi::Error::InvalidArgument("voxax: vertices contain NaN or Inf (batch item " +
                                         std::to_string(batch_item) + ", flat index " +
                                         std::to_string(i) + ")");
    }
    if (std::fabs(x) > kMaxAbsCoordinate) {
      return ffi::Error::InvalidArgument(
          "voxax: vertex coordinate magnitude exceeds 1e75 (batch item " +
          std::to_string(batch_item) + ", flat index " + std::to_string(i) + ")");
    }
  }
  return ffi::Error::Success();
}

inline ffi::Error check_faces(const int32_t* F, int64_t count, int64_t num_vertices,
                              int64_t batch_item) {
  for (int64_t i = 0; i < count; ++i) {
    const int64_t idx = F[i];
    if (idx < 0 || idx >= num_vertices) {
      return ffi::Error::InvalidArgument("voxax: face index " + std::to_string(idx) +
                                         " is out of range [0, " + std::to_string(num_vertices) +
                                         ") (batch item " + std::to_string(batch_item) +
                                         ", flat index " + std::to_string(i) + ")");
    }
  }
  return ffi::Error::Success();
}

}  // namespace voxax

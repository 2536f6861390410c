// The checks of the nearest-seed assignment's two entry points (assign_ffi.cc, assign_host.cc).

#ifndef VOXAX_CVT_ASSIGN_CHECKS_H_
#define VOXAX_CVT_ASSIGN_CHECKS_H_

#include <cmath>
#include <cstdint>
#include <string>

#include "common/host_errors.h"

namespace voxax {
namespace cvt {

// The seeds and the counts: false with a message on bad input.
inline bool check_assign(const double* S, int64_t n, int64_t m, std::string* msg) {
  if (n < 1 || n > INT32_MAX) {
    *msg = "voxax: the assignment needs between 1 and 2^31 - 1 seeds";
    return false;
  }
  if (m < 0) {
    *msg = "voxax: negative sample count";
    return false;
  }
  return check_host_coordinates(S, 3 * n, "seeds", msg) &&
         check_coordinate_scale(S, 3 * n, "seeds", msg);
}

// The weights: false with a message (the first bad row) on bad input.
inline bool check_assign_weights(const double* W, int64_t m, std::string* msg) {
  for (int64_t i = 0; i < m; ++i)
    if (!(W[i] >= 0.0) || !std::isfinite(W[i])) {
      *msg = "voxax: sample weights must be finite and >= 0 (row " + std::to_string(i) + ")";
      return false;
    }
  return true;
}

}  // namespace cvt
}  // namespace voxax

#endif  // VOXAX_CVT_ASSIGN_CHECKS_H_

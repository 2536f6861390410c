// Input checks shared by the k-nearest-neighbour entry points (the ctypes entry point
// in knn_host.cc and the XLA FFI handler in knn_ffi.cc), so both refuse the same input
// with the same message.
#pragma once

#include <cstdint>
#include <string>

#include "common/host_errors.h"
#include "spatial/knn.h"

namespace voxax {
namespace spatial {

// n data points S (n, 3), m queries Q (m, 3), k neighbours each. False with a message in
// msg for input the search cannot take: k outside [1, kMaxNeighbours], a negative count,
// more points than int32 indices hold, non-finite or out-of-range coordinates, or data
// points too small to compute with.
inline bool check_knn_inputs(const double* S, int64_t n, const double* Q, int64_t m, int64_t k,
                             std::string* msg) {
  if (k < 1 || k > kMaxNeighbours) {
    *msg = "voxax: k must lie in [1, " + std::to_string(kMaxNeighbours) + "], got " +
           std::to_string(k);
    return false;
  }
  if (n < 0 || m < 0) {
    *msg = "voxax: point and query counts must be >= 0";
    return false;
  }
  if (n > INT32_MAX) {
    *msg = "voxax: at most 2^31 - 1 points";
    return false;
  }
  return check_host_coordinates(S, 3 * n, "points", msg) &&
         check_coordinate_scale(S, 3 * n, "points", msg) &&
         check_host_coordinates(Q, 3 * m, "queries", msg);
}

}  // namespace spatial
}  // namespace voxax

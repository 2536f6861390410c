// Input checks shared by the k-nearest-neighbour entry points (the ctypes entry point
// in knn_host.cc and the XLA FFI handler in knn_ffi.cc), so both refuse the same input
// with the same message, in the form of the Python checks of voxax.nearest_neighbors.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>

#include "common/constants.h"
#include "common/host_errors.h"
#include "spatial/knn_tree.h"

namespace voxax {
namespace spatial {

inline bool check_knn_rows(const double* x, int64_t rows, const char* what, std::string* msg) {
  const std::string head = std::string("voxax.nearest_neighbors: `") + what + "` must ";
  for (int64_t i = 0; i < 3 * rows; ++i) {
    if (!std::isfinite(x[i])) {
      *msg = head + "be finite: row " + std::to_string(i / 3) + " holds NaN or Inf";
      return false;
    }
    if (std::fabs(x[i]) > kMaxAbsCoordinate) {
      *msg = head + "be at most 1e75 in magnitude: row " + std::to_string(i / 3) + " exceeds it";
      return false;
    }
  }
  return true;
}

// n data points S (n, 3), m queries Q (m, 3), k neighbours each. False with a message in
// msg for input the search cannot take: k outside [1, kMaxNeighbours], a negative count,
// more points than int32 indices hold, non-finite or out-of-range coordinates, or data
// points all too small to compute with (see common/constants.h).
inline bool check_knn_inputs(const double* S, int64_t n, const double* Q, int64_t m, int64_t k,
                             std::string* msg) {
  if (k < 1 || k > kMaxNeighbours) {
    *msg = "voxax.nearest_neighbors: `k` must lie in [1, " + std::to_string(kMaxNeighbours) +
           "], got " + std::to_string(k);
    return false;
  }
  if (n < 0 || m < 0) {
    *msg = "voxax.nearest_neighbors: the point and query counts must be >= 0";
    return false;
  }
  if (n > INT32_MAX) {
    *msg = "voxax.nearest_neighbors: `points` must hold at most 2^31 - 1 rows";
    return false;
  }
  if (!check_knn_rows(S, n, "points", msg) || !check_knn_rows(Q, m, "queries", msg)) return false;
  double largest = 0.0;
  if (below_coordinate_scale(S, 3 * n, &largest)) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.3g", largest);
    *msg = std::string("voxax.nearest_neighbors: `points` must not all be below 1e-75 in ") +
           "magnitude (largest " + buf + "): scale the input";
    return false;
  }
  return true;
}

}  // namespace spatial
}  // namespace voxax

// Error reporting and input checks of the eager host entry points: plain C functions called through
// ctypes, which return 0 on success and 1 on failure with a message in a caller-owned
// buffer. `host_guarded` runs the body and turns every exception into a message of the
// same categories as the FFI handlers' `guarded` (common/errors.h), so no exception ever
// crosses the C boundary.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <exception>
#include <new>
#include <stdexcept>
#include <string>

#include "common/constants.h"
#include "common/errors.h"

namespace voxax {

// Copies `msg` (truncated) into err[0:errlen] and returns the failure status 1.
inline int host_fail(char* err, int64_t errlen, const std::string& msg) noexcept {
  if (err && errlen > 0) {
    const size_t n = std::min<size_t>(msg.size(), static_cast<size_t>(errlen - 1));
    std::memcpy(err, msg.data(), n);
    err[n] = '\0';
  }
  return 1;
}

// Runs body(&msg), which returns false with a message in msg for invalid input, and
// reports any exception it throws; `where` names the entry point in messages.
template <typename Body>
int host_guarded(const char* where, char* err, int64_t errlen, Body&& body) noexcept {
  try {
    std::string msg;
    if (!body(&msg)) return host_fail(err, errlen, msg);
    return 0;
  } catch (const std::bad_alloc&) {
    return host_fail(err, errlen, std::string("voxax: out of memory in ") + where);
  } catch (const std::length_error&) {
    return host_fail(err, errlen, std::string("voxax: out of memory in ") + where);
  } catch (const InvalidInput& e) {
    return host_fail(err, errlen, e.what());
  } catch (const std::exception& e) {
    try {
      return host_fail(err, errlen,
                       std::string("voxax: internal error in ") + where + ": " + e.what());
    } catch (...) {
      return host_fail(err, errlen, "");
    }
  } catch (...) {
    return host_fail(err, errlen, "");
  }
}

// Checks that `count` coordinates (rows of 3) are finite and within the package's bound;
// on failure writes the message (naming `what` and the row) into msg and returns false.
inline bool check_host_coordinates(const double* x, int64_t count, const char* what,
                                   std::string* msg) {
  for (int64_t i = 0; i < count; ++i) {
    if (!std::isfinite(x[i])) {
      *msg =
          std::string("voxax: ") + what + " contain NaN or Inf (row " + std::to_string(i / 3) + ")";
      return false;
    }
    if (std::fabs(x[i]) > kMaxAbsCoordinate) {
      *msg = std::string("voxax: ") + what + " coordinate magnitude exceeds 1e75 (row " +
             std::to_string(i / 3) + ")";
      return false;
    }
  }
  return true;
}

// Checks that the `nf` triangles' vertex indices lie in [0, nv); on failure writes the
// message (the index and the face) into msg and returns false.
inline bool check_host_faces(const int32_t* F, int64_t nf, int64_t nv, std::string* msg) {
  for (int64_t i = 0; i < 3 * nf; ++i) {
    if (F[i] < 0 || F[i] >= nv) {
      *msg = "voxax: face index " + std::to_string(F[i]) + " is out of range [0, " +
             std::to_string(nv) + ") (face " + std::to_string(i / 3) + ")";
      return false;
    }
  }
  return true;
}

// Whether the largest magnitude in x[0:count] (finite values) is non-zero and below
// kMinLargestAbsCoordinate, that magnitude in *largest. It is read from the bit patterns
// (the order of non-negative doubles is the order of their bits), so subnormal values
// count also on threads that treat subnormal operands as zero: XLA's CPU threads set
// denormals-are-zero, where fabs and comparisons would see a set of subnormals as zeros.
inline bool below_coordinate_scale(const double* x, int64_t count, double* largest) {
  constexpr uint64_t kMagnitude = ~(uint64_t{1} << 63);
  uint64_t top = 0, limit = 0;
  for (int64_t i = 0; i < count; ++i) {
    uint64_t bits;
    std::memcpy(&bits, x + i, sizeof bits);
    top = std::max(top, bits & kMagnitude);
  }
  const double bound = kMinLargestAbsCoordinate;
  std::memcpy(&limit, &bound, sizeof limit);
  std::memcpy(largest, &top, sizeof top);
  return top != 0 && top < limit;
}

// Rejects a coordinate array whose largest magnitude is non-zero and below
// kMinLargestAbsCoordinate (the whole set is too small to compute with; see constants.h).
inline bool check_coordinate_scale(const double* x, int64_t count, const char* what,
                                   std::string* msg) {
  double largest = 0.0;
  if (below_coordinate_scale(x, count, &largest)) {
    char buf[64];
    std::snprintf(buf, sizeof buf, "%.3g", largest);
    *msg = std::string("voxax: ") + what + " are all below 1e-75 in magnitude (largest " + buf +
           "): scale the input";
    return false;
  }
  return true;
}

}  // namespace voxax

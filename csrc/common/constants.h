// Numerical bounds the kernels enforce. The Python package defines the same
// values in voxax/_constants.py; `voxax_constants` (constants.cc) exports these
// so that a test can check that both sides agree.
#pragma once

#include <cstdint>

namespace voxax {

// The largest coordinate magnitude the kernels accept: squared lengths of
// triangle normals (fourth powers of coordinates) stay finite in double.
constexpr double kMaxAbsCoordinate = 1e75;

// The spatial queries (BVH, kNN) reject a set of coordinates whose largest magnitude is
// non-zero and below this: their squared distances and fourth powers would leave the
// normal double range, where XLA's threads (flush-to-zero) and plain threads disagree.
constexpr double kMinLargestAbsCoordinate = 1e-75;

// Accepted range of a grid cell's volume (its area in 2D): cell sizes, their
// inverses and the products the kernels form stay finite and non-zero.
constexpr double kMinCellVolume = 1e-300;
constexpr double kMaxCellVolume = 1e300;

// The most cells along one grid axis.
constexpr int64_t kMaxCellsPerAxis = int64_t{1} << 31;

}  // namespace voxax

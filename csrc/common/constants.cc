// Exports the kernels' numerical bounds to Python (loaded with ctypes), so that
// a test can check them against voxax/_constants.py.

#include "common/constants.h"

extern "C" {

// Writes up to n of the bounds, in this order, to out and returns how many
// bounds there are (call with n = 0 to ask):
//   0: kMaxAbsCoordinate, 1: kMinCellVolume, 2: kMaxCellVolume,
//   3: kMaxCellsPerAxis.
__attribute__((visibility("default"))) int voxax_constants(double* out, int n) {
  const double values[] = {voxax::kMaxAbsCoordinate, voxax::kMinCellVolume, voxax::kMaxCellVolume,
                           static_cast<double>(voxax::kMaxCellsPerAxis)};
  const int count = static_cast<int>(sizeof(values) / sizeof(values[0]));
  for (int i = 0; i < n && i < count; ++i) out[i] = values[i];
  return count;
}

}  // extern "C"

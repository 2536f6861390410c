// What the marching-cubes kernel's two entry points (contour_ffi.cc, contour_host.cc) share.

#ifndef VOXAX_CONTOUR_CONTOUR_CHECKS_H_
#define VOXAX_CONTOUR_CONTOUR_CHECKS_H_

#include <cstdint>
#include <string>

#include "contour/marching_cubes.h"

namespace voxax {
namespace contour {

constexpr int64_t kInt32Max = 2147483647;

inline std::string shape_error(const Shape& sh) {
  (void)sh;
  return "voxax.isosurface: the grid has more than 2^31 - 1 cells";
}

}  // namespace contour
}  // namespace voxax

#endif  // VOXAX_CONTOUR_CONTOUR_CHECKS_H_

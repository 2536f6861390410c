// Exact crossings of a triangle mesh with axis-aligned lines ("dexels").
//
// A line parallel to axis `a` is given by its coordinates (p_u, p_v) on the two other
// axes u = (a + 1) % 3, v = (a + 2) % 3. It crosses a triangle when the point lies inside
// the triangle's projection onto the (u, v) plane. The inside test uses the exact orient2d
// predicate with one simulation-of-simplicity rule: the line through (p_u, p_v) is treated
// as passing through (p_u + d, p_v + d^2) for an infinitesimal d > 0. The perturbed line
// never meets an edge or a vertex, so a line through an edge or a vertex shared by
// consistently oriented triangles crosses exactly one of them, and triangles whose
// projection has zero area are never crossed. The sign of a crossing is the sign of the
// triangle normal's component along `a`: +1 where the line leaves a closed outward-oriented
// solid, -1 where it enters.
#pragma once

#include <algorithm>
#include <cstdint>

#include "intersect/predicates.h"

namespace voxax {
namespace raster {

// The sign of orient2d(a, b, q) with q perturbed to (q_u + d, q_v + d^2).
// orient2d(a, b, q) = (b_u - a_u)(q_v - a_v) - (b_v - a_v)(q_u - a_u); the perturbation adds
// -(b_v - a_v) d + (b_u - a_u) d^2, so on an exact zero the first non-zero term decides.
// Swapping a and b negates every term, so a shared edge is seen with opposite signs from
// its two triangles.
inline int orient_perturbed(const double* a, const double* b, const double* q) {
  const int s = exact::orient2d(a, b, q);
  if (s != 0) return s;
  if (b[1] != a[1]) return b[1] < a[1] ? 1 : -1;
  if (b[0] != a[0]) return b[0] > a[0] ? 1 : -1;
  return 0;  // a == b: only in a triangle of zero projected area, which is skipped
}

struct Crossing {
  double depth;  // coordinate along the line's axis
  int64_t line;  // line index
  int32_t face;
  int8_t sign;
};

// Orders crossings by line, then depth, then face: a total order, so the sorted output
// does not depend on the order in which they were found.
inline bool crossing_less(const Crossing& x, const Crossing& y) {
  if (x.line != y.line) return x.line < y.line;
  if (x.depth != y.depth) return x.depth < y.depth;
  return x.face < y.face;
}

// Projected triangle corners p[i] = (x_i[u], x_i[v]) and their coordinates z[i] along the
// axis. Returns the crossing sign (0 when the line misses) and the depth at the crossing.
// The depth is the barycentric interpolation of z with weights clamped to the triangle, so
// it lies within the triangle's extent along the axis even where rounding would not.
inline int cross_triangle(const double p[3][2], const double z[3], int orientation, const double* q,
                          double* depth) {
  const int s0 = orient_perturbed(p[1], p[2], q);
  if (s0 != orientation) return 0;
  const int s1 = orient_perturbed(p[2], p[0], q);
  if (s1 != orientation) return 0;
  const int s2 = orient_perturbed(p[0], p[1], q);
  if (s2 != orientation) return 0;
  double w[3];
  for (int i = 0; i < 3; ++i) {
    const double* a = p[(i + 1) % 3];
    const double* b = p[(i + 2) % 3];
    const double area = (b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]);
    w[i] = std::max(0.0, area * orientation);
  }
  const double total = w[0] + w[1] + w[2];
  if (total > 0.0) {
    *depth = (w[0] * z[0] + w[1] * z[1] + w[2] * z[2]) / total;
  } else {  // the line passes (numerically) through a corner
    const double* c = p[0];
    int best = 0;
    double d_best = std::abs(c[0] - q[0]) + std::abs(c[1] - q[1]);
    for (int i = 1; i < 3; ++i) {
      const double d = std::abs(p[i][0] - q[0]) + std::abs(p[i][1] - q[1]);
      if (d < d_best) {
        d_best = d;
        best = i;
      }
    }
    *depth = z[best];
  }
  return orientation;
}

}  // namespace raster
}  // namespace voxax

// Exact crossings of a triangle mesh with axis-aligned lines ("dexels").
//
// A line parallel to axis `a` is given by its coordinates on the two other axes. It
// crosses a triangle when that point lies inside the triangle's projection onto the plane
// of the two axes. The inside test uses the exact orient2d predicate with one
// simulation-of-simplicity rule for all three families of lines: every point p is treated
// as p + (d, d^2, d^3) for an infinitesimal d > 0 (x moves most, then y, then z), so a
// line through (b, c) on its two other axes, in increasing axis order, passes through
// (b + d^i, c + d^j) with i < j. The perturbed line never meets an edge or a vertex, so a
// line through an edge or a vertex shared by consistently oriented triangles crosses
// exactly one of them, triangles whose projection has zero area are never crossed, and
// lines of different axes through one grid node agree on which side of the surface the
// node lies. The sign of a crossing is the sign of the triangle normal's component along
// `a`: +1 where the line leaves a closed outward-oriented solid, -1 where it enters.
#pragma once

#include <algorithm>
#include <cstdint>

#include "intersect/predicates.h"

namespace voxax {
namespace raster {

// The sign of orient2d(a, b, q) in the (u, v) plane with q perturbed to (q_u + d, q_v + d^2)
// when u_first (u is the lower axis, which moves most), to (q_u + d^2, q_v + d) otherwise.
// orient2d(a, b, q) = (b_u - a_u)(q_v - a_v) - (b_v - a_v)(q_u - a_u); the perturbation
// adds -(b_v - a_v) e_u + (b_u - a_u) e_v, so on an exact zero the term of the larger
// perturbation decides, then the other. Swapping a and b negates every term, so a shared
// edge is seen with opposite signs from its two triangles.
inline int orient_perturbed(const double* a, const double* b, const double* q, bool u_first) {
  const int s = exact::orient2d(a, b, q);
  if (s != 0) return s;
  const int du = b[0] > a[0] ? 1 : (b[0] < a[0] ? -1 : 0);  // sign of b_u - a_u
  const int dv = b[1] > a[1] ? 1 : (b[1] < a[1] ? -1 : 0);  // sign of b_v - a_v
  if (u_first) return dv != 0 ? -dv : du;
  return du != 0 ? du : -dv;  // 0 only when a == b: a triangle of zero projected area
}

// Positions in strictly increasing line coordinates L[0..n), the same as std::lower_bound
// (`lower`) and std::upper_bound (`upper`) give: a guess for evenly spaced lines (a grid's)
// and a short walk to the exact position; unevenly spaced lines fall back to the binary
// search.
class LineSearch {
 public:
  LineSearch(const double* L, int64_t n) : L_(L), n_(n) {
    if (n >= 2 && L[n - 1] > L[0]) scale_ = static_cast<double>(n - 1) / (L[n - 1] - L[0]);
  }
  int64_t lower(double x) const { return find(x, false); }
  int64_t upper(double x) const { return find(x, true); }

 private:
  int64_t find(double x, bool upper) const {
    // Whether L[i] lies before the position: L[i] < x (lower), L[i] <= x (upper).
    auto before = [&](int64_t i) { return upper ? L_[i] <= x : L_[i] < x; };
    if (scale_ > 0) {
      const double g = (x - L_[0]) * scale_;
      int64_t i = g > 0 ? (g < static_cast<double>(n_) ? static_cast<int64_t>(g) : n_) : 0;
      for (int step = 0; step < 4; ++step) {
        if (i > 0 && !before(i - 1))
          --i;
        else if (i < n_ && before(i))
          ++i;
        else
          return i;  // before(i - 1) and not before(i): the partition point
      }
    }
    return (upper ? std::upper_bound(L_, L_ + n_, x) : std::lower_bound(L_, L_ + n_, x)) - L_;
  }
  const double* L_;
  int64_t n_;
  double scale_ = 0.0;
};

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
                          bool u_first, double* depth) {
  const int s0 = orient_perturbed(p[1], p[2], q, u_first);
  if (s0 != orientation) return 0;
  const int s1 = orient_perturbed(p[2], p[0], q, u_first);
  if (s1 != orientation) return 0;
  const int s2 = orient_perturbed(p[0], p[1], q, u_first);
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

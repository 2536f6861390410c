// Generalised winding numbers of a triangle mesh at points, in float64.
//
// The exact sum: w(p) = (1 / 4 pi) sum_t Omega_t(p), the signed solid angles of the
// triangles by the formula of Van Oosterom and Strackee (1983), added in face order; a
// point in the plane of a triangle (zero triple product) gets 0 from it, so points on a
// closed surface get the average of the two sides (1/2 on a face).
//
// Closed meshes: where every edge {i, j} is used as often from i to j as from j to i
// (the faces form a cycle: closed, or closed up to faces paired with their reverses),
// the solid-angle sum is the integer signed crossing count of any ray from p. One ray per
// point, through the BVH, gives it in O(log F); where that ray meets an edge or a vertex
// exactly, or p lies within rounding of a face it meets, the point falls back to the
// exact sum, so the result is always the solid-angle sum's value: the integer, or the
// half-integers of points on the surface.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace voxax {
namespace spatial {

// The signed solid angle of triangle (A, B, C) at p, in [-2 pi, 2 pi].
inline double solid_angle(const double* p, const double* A, const double* B, const double* C) {
  double a[3], b[3], c[3];
  for (int i = 0; i < 3; ++i) {
    a[i] = A[i] - p[i];
    b[i] = B[i] - p[i];
    c[i] = C[i] - p[i];
  }
  const double la = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  const double lb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
  const double lc = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
  const double bc[3] = {b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2],
                        b[0] * c[1] - b[1] * c[0]};
  const double num = a[0] * bc[0] + a[1] * bc[1] + a[2] * bc[2];
  if (num == 0.0) return 0.0;
  const double ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const double ac = a[0] * c[0] + a[1] * c[1] + a[2] * c[2];
  const double bcd = b[0] * c[0] + b[1] * c[1] + b[2] * c[2];
  const double den = la * lb * lc + ab * lc + ac * lb + bcd * la;
  return 2.0 * std::atan2(num, den);
}

// The exact sum at p over faces F (nf, 3) of vertices V.
inline double winding_sum(const double* p, const double* V, const int32_t* F, int64_t nf) {
  double s = 0.0;
  for (int64_t f = 0; f < nf; ++f)
    s += solid_angle(p, V + 3 * static_cast<int64_t>(F[3 * f]),
                     V + 3 * static_cast<int64_t>(F[3 * f + 1]),
                     V + 3 * static_cast<int64_t>(F[3 * f + 2]));
  return s / (4.0 * 3.14159265358979323846);
}

// Whether the faces form a cycle: every undirected edge used equally often in both
// directions (by vertex index; degenerate faces included, an edge {i, i} cancels itself).
inline bool faces_closed(const int32_t* F, int64_t nf) {
  std::vector<uint64_t> up, down;
  up.reserve(3 * nf);
  down.reserve(3 * nf);
  for (int64_t f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = static_cast<uint32_t>(F[3 * f + k]);
      const uint32_t j = static_cast<uint32_t>(F[3 * f + (k + 1) % 3]);
      if (i == j) continue;
      if (i < j)
        up.push_back(uint64_t{i} << 32 | j);
      else
        down.push_back(uint64_t{j} << 32 | i);
    }
  if (up.size() != down.size()) return false;
  std::sort(up.begin(), up.end());
  std::sort(down.begin(), down.end());
  return up == down;
}

}  // namespace spatial
}  // namespace voxax

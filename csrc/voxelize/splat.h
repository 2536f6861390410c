// Pieces shared by the backward (the closed-form sub-triangle splat) and its transpose,
// the tangent: the barycentric frame of a triangle and the area and first moment of each
// piece it is clipped into.
#pragma once

#include <cmath>
#include <cstdint>

#include "voxelize/clip.h"

namespace voxax {

// The area (signed along the unit normal nh) and the first moment relative to `origin` of
// a convex planar piece Q, by a fan from its first corner.
inline double fan_moments(const Poly<3>& Q, const double nh[3], const double* origin, double M[3]) {
  double A = 0;
  M[0] = M[1] = M[2] = 0;
  const double* q0 = Q.v[0];
  for (int m = 1; m + 1 < Q.count; ++m) {
    const double* q1 = Q.v[m];
    const double* q2 = Q.v[m + 1];
    double u[3], w[3];
    for (int k = 0; k < 3; ++k) {
      u[k] = q1[k] - q0[k];
      w[k] = q2[k] - q0[k];
    }
    const double area =
        0.5 * (nh[0] * (u[1] * w[2] - u[2] * w[1]) + nh[1] * (u[2] * w[0] - u[0] * w[2]) +
               nh[2] * (u[0] * w[1] - u[1] * w[0]));
    A += area;
    for (int k = 0; k < 3; ++k)
      M[k] +=
          area * ((q0[k] - origin[k]) + (q1[k] - origin[k]) + (q2[k] - origin[k])) * (1.0 / 3.0);
  }
  return A;
}

// A triangle's corners in float64, its unit normal nh, and the rows of its barycentric
// map: beta_1 = r1 . (p - a0), beta_2 = r2 . (p - a0) with r1 = (e2 x N) / |N|^2 and
// r2 = (N x e1) / |N|^2 (exact for slivers too).
struct TriangleFrame {
  double p[3][3];
  double nh[3], r1[3], r2[3];
  const double* a0() const { return p[0]; }

  // Loads corners f[0..2] of V; returns false for a triangle without a finite,
  // non-zero normal (whose pieces have no area).
  template <typename T>
  bool load(const T* V, const int32_t* f) {
    for (int c = 0; c < 3; ++c)
      for (int a = 0; a < 3; ++a) p[c][a] = static_cast<double>(V[3 * int64_t(f[c]) + a]);
    double e1[3], e2[3], N[3];
    for (int a = 0; a < 3; ++a) {
      e1[a] = p[1][a] - p[0][a];
      e2[a] = p[2][a] - p[0][a];
    }
    N[0] = e1[1] * e2[2] - e1[2] * e2[1];
    N[1] = e1[2] * e2[0] - e1[0] * e2[2];
    N[2] = e1[0] * e2[1] - e1[1] * e2[0];
    const double len = std::sqrt(N[0] * N[0] + N[1] * N[1] + N[2] * N[2]);
    if (!(len > 0) || !std::isfinite(len)) return false;
    for (int a = 0; a < 3; ++a) nh[a] = N[a] / len;
    const double inv_nn = 1.0 / (len * len);
    r1[0] = (e2[1] * N[2] - e2[2] * N[1]) * inv_nn;
    r1[1] = (e2[2] * N[0] - e2[0] * N[2]) * inv_nn;
    r1[2] = (e2[0] * N[1] - e2[1] * N[0]) * inv_nn;
    r2[0] = (N[1] * e1[2] - N[2] * e1[1]) * inv_nn;
    r2[1] = (N[2] * e1[0] - N[0] * e1[2]) * inv_nn;
    r2[2] = (N[0] * e1[1] - N[1] * e1[0]) * inv_nn;
    return true;
  }

  // The triangle as a polygon, ready for clipping.
  void to_poly(Poly<3>* P) const {
    P->count = 3;
    for (int c = 0; c < 3; ++c)
      for (int a = 0; a < 3; ++a) P->v[c][a] = p[c][a];
  }

  // The integrals of the barycentric coordinates beta_0, beta_1, beta_2 over a piece Q
  // of the triangle: its area A (signed along nh) and first moment M relative to a0, by
  // a fan from Q's first corner, give beta_1 = r1 . M, beta_2 = r2 . M, beta_0 = A - both.
  void piece_integrals(const Poly<3>& Q, double* beta) const {
    double M[3];
    const double A = fan_moments(Q, nh, a0(), M);
    beta[1] = r1[0] * M[0] + r1[1] * M[1] + r1[2] * M[2];
    beta[2] = r2[0] * M[0] + r2[1] * M[1] + r2[2] * M[2];
    beta[0] = A - beta[1] - beta[2];
  }
};

}  // namespace voxax

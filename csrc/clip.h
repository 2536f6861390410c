// Convex polygon clipping against axis-aligned planes (Sutherland-Hodgman),
// with linear attributes carried along.
#pragma once

#include <cstdint>

namespace voxax {

// A convex polygon with up to kMaxVerts vertices of N doubles each. The first
// entries of a vertex are its coordinates; the rest are attributes that vary
// linearly over the polygon (for example barycentric coordinates).
// A triangle clipped by six planes has at most 9 vertices.
constexpr int kMaxVerts = 12;

template <int N>
struct Poly {
  int count = 0;
  double v[kMaxVerts][N];

  Poly() = default;
  Poly(const Poly& o) { *this = o; }
  // Copies only the vertices in use.
  Poly& operator=(const Poly& o) {
    count = o.count;
    for (int i = 0; i < count; ++i)
      for (int k = 0; k < N; ++k) v[i][k] = o.v[i][k];
    return *this;
  }

  double min(int a) const {
    double m = v[0][a];
    for (int i = 1; i < count; ++i) m = v[i][a] < m ? v[i][a] : m;
    return m;
  }
  double max(int a) const {
    double m = v[0][a];
    for (int i = 1; i < count; ++i) m = v[i][a] > m ? v[i][a] : m;
    return m;
  }
};

// Point on the segment p-q where coordinate `a` equals c. The point is
// computed from the endpoint with the smaller coordinate, so the edge shared
// by two neighbouring cells is cut at bit-identical points from both sides.
template <int N>
inline void cut(const double* p, const double* q, int a, double c, double* out) {
  if (q[a] < p[a]) {
    const double* t = p;
    p = q;
    q = t;
  }
  double t = (c - p[a]) / (q[a] - p[a]);
  for (int k = 0; k < N; ++k) out[k] = p[k] + t * (q[k] - p[k]);
  out[a] = c;
}

// Splits `in` at coordinate a == c into the part below (a <= c) and the part
// above (a >= c) in one pass.
template <int N>
inline void split(const Poly<N>& in, int a, double c, Poly<N>* below, Poly<N>* above) {
  below->count = 0;
  above->count = 0;
  const int n = in.count;
  for (int i = 0; i < n; ++i) {
    const double* p = in.v[i];
    const double* q = in.v[i + 1 == n ? 0 : i + 1];
    const bool p_lo = p[a] <= c, p_hi = p[a] >= c;
    if (p_lo && below->count < kMaxVerts) {
      for (int k = 0; k < N; ++k) below->v[below->count][k] = p[k];
      ++below->count;
    }
    if (p_hi && above->count < kMaxVerts) {
      for (int k = 0; k < N; ++k) above->v[above->count][k] = p[k];
      ++above->count;
    }
    // The edge crosses the plane strictly: both parts get the crossing point.
    if ((p[a] < c && q[a] > c) || (p[a] > c && q[a] < c)) {
      double x[N];
      cut<N>(p, q, a, c, x);
      if (below->count < kMaxVerts) {
        for (int k = 0; k < N; ++k) below->v[below->count][k] = x[k];
        ++below->count;
      }
      if (above->count < kMaxVerts) {
        for (int k = 0; k < N; ++k) above->v[above->count][k] = x[k];
        ++above->count;
      }
    }
  }
}

}  // namespace voxax

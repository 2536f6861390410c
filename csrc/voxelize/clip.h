// Convex polygon clipping against axis-aligned planes (Sutherland-Hodgman),
// with linear attributes carried along, and the sweep that splits a polygon
// into the cells of a grid along one axis.
#pragma once

#include <algorithm>
#include <cstdint>
#include <stdexcept>

#include "common/grid.h"

namespace voxax {

// How many vertices clipping can give a triangle, and why kMaxVerts bounds it.
//
// Call a polygon v_0 ... v_{n-1} *unimodal* when, for every axis b and every
// level c, the vertices with v[b] > c are cyclically consecutive. Every
// triangle is unimodal: any subset of three cyclic positions is consecutive.
//
// (1) `split` keeps polygons unimodal. Along axis b the old boundary, walked
//     as a closed polyline, is a continuous function f, and {f > c} is one arc
//     when {v[b] > c} is consecutive. Each output of `split` lists old
//     vertices and cut points in boundary order, and every coordinate of a cut
//     point lies between those of its edge's endpoints (`cut_within` clamps it there;
//     on the split axis it is the level itself, strictly between them). So
//     each output's coordinates along b are values of f at points taken in
//     boundary order, and those lying on one arc are consecutive.
// (2) Splitting a unimodal n-gon at level c of axis a cuts at most the two
//     edges that leave the consecutive run {v[a] > c}, and cuts only when
//     vertices lie strictly on both sides, each of which is missing from one
//     output: each output has at most n + 1 vertices.
// (3) `sweep` (and the forward's z loop, which works the same way) cuts a
//     polygon Q of m vertices at non-decreasing levels c_1 <= c_2 <= ... of
//     one axis a, keeps the upper part `rest` and visits lower parts. Cut
//     points get v[a] = c exactly, so rest_k holds Q's vertices with
//     v[a] >= c_k and at most two cut points at level c_k (earlier cut points
//     at lower levels fall below c_k and are dropped); it holds cut points
//     only when a vertex of Q lies below c_k. Hence |rest_k| <= m + 1, and a
//     visited piece, the lower part of a rest, has at most m + 2 vertices.
// (4) Every clipped piece comes from a triangle swept along x, then y, then z
//     (forward: sweep, sweep, add_column_3d; backward: three sweeps), so it
//     has at most 3 + 2 + 2 + 2 = 9 vertices.
constexpr int max_clipped_vertices(int initial, int axes) { return initial + 2 * axes; }

// A convex polygon with up to kMaxVerts vertices of N doubles each. The first
// entries of a vertex are its coordinates; the rest are attributes that vary
// linearly over the polygon (for example barycentric coordinates).
constexpr int kMaxVerts = 9;
static_assert(kMaxVerts >= max_clipped_vertices(3, 3),
              "a triangle clipped to a voxel has up to 9 vertices");

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
  // Appends a vertex. The bound above makes overflow impossible; the check
  // keeps memory safe even so and reports a broken invariant as an error.
  void push(const double* x) {
    if (count == kMaxVerts) throw std::logic_error("polygon clipping exceeded its vertex bound");
    for (int k = 0; k < N; ++k) v[count][k] = x[k];
    ++count;
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

// `cut`, with every entry clamped to the range of the endpoints' (rounding
// can put it just outside when t is within an ulp of 1), as the vertex bound
// above needs. The clamp changes nothing where `cut` is already in range.
template <int N>
inline void cut_within(const double* p, const double* q, int a, double c, double* out) {
  cut<N>(p, q, a, c, out);
  for (int k = 0; k < N; ++k) {
    const double lo = p[k] < q[k] ? p[k] : q[k], hi = p[k] < q[k] ? q[k] : p[k];
    out[k] = out[k] < lo ? lo : (out[k] > hi ? hi : out[k]);
  }
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
    if (p[a] <= c) below->push(p);
    if (p[a] >= c) above->push(p);
    // The edge crosses the plane strictly: both parts get the crossing point.
    if ((p[a] < c && q[a] > c) || (p[a] > c && q[a] < c)) {
      double x[N];
      cut_within<N>(p, q, a, c, x);
      below->push(x);
      above->push(x);
    }
  }
}

// Clips segment S (2 points) to lo <= coordinate a <= hi; returns false if empty.
template <int N>
inline bool clip_segment(const Poly<N>& S, int a, double lo, double hi, Poly<N>* out) {
  const double* p = S.v[0];
  const double* q = S.v[1];
  double mn = std::min(p[a], q[a]), mx = std::max(p[a], q[a]);
  if (mx < lo || mn > hi) return false;
  *out = S;
  for (int e = 0; e < 2; ++e) {
    double* r = out->v[e];
    if (r[a] < lo)
      cut<N>(p, q, a, lo, r);
    else if (r[a] > hi)
      cut<N>(p, q, a, hi, r);
  }
  return true;
}

// Sweeps polygon P across the cells [c0, c1] along axis a, calling
// visit(i, piece) with the part of P in each cell. Cells are half-open,
// [lo, hi), except the last one along each axis, which is closed: a piece
// lying flat in the upper plane of cell i (a face exactly on a grid plane)
// belongs to cell i + 1, so it is counted once.
template <int N, typename Visit>
inline void sweep(const GridSpec& g, const Poly<N>& P, int a, int64_t c0, int64_t c1,
                  Visit&& visit) {
  Poly<N> rest, piece, upper;
  const Poly<N>* cur = &P;
  if (P.min(a) < g.plane(a, c0)) {
    split<N>(P, a, g.plane(a, c0), &piece, &rest);
    cur = &rest;
  }
  for (int64_t i = c0; i <= c1 && cur->count >= 3; ++i) {
    const double hi = g.plane(a, i + 1);
    const double mn = cur->min(a), mx = cur->max(a);
    if (mn >= hi && i + 1 < g.cells_to_end(a)) continue;  // entirely in later cells
    if (mx <= hi) {
      visit(i, *cur);
      return;
    }
    split<N>(*cur, a, hi, &piece, &upper);
    if (piece.count >= 3) visit(i, piece);
    rest = upper;
    cur = &rest;
  }
}

}  // namespace voxax

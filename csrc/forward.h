// Forward: exact box-filtered winding numbers by shadow volumes.
//
// A triangle with normal N counts sign(N.z) for every point below it. Each
// triangle is clipped into the grid's columns and slabs; a piece P in voxel
// (i, j, k) adds its own share b = a_P (zbar - z_k) / |voxel| to voxel k and
// tau = a_P / (hx hy) to every voxel below, where a_P is the signed area of
// P's xy-projection. Both go into one buffer of per-column differences:
// A[k] += b, A[k-1] += tau - b; a reverse prefix sum along z gives W.
//
// Work is partitioned into tiles of whole columns. Triangles are binned to
// the tiles their xy bounding box touches; each tile is zeroed, filled and
// prefix-summed in a thread-local double buffer while it is in cache, then
// written to the output once. A tile is always processed by one thread in
// bin order, so results are identical bit for bit for any thread count.
#pragma once

#include <cstring>
#include <vector>

#include "clip.h"
#include "common.h"

namespace voxax {

struct Tiling {
  int64_t tx = 1, ty = 1;  // columns per tile along x (and y in 3D)
  int64_t ntx = 1, nty = 1;
  int64_t count() const { return ntx * nty; }
};

inline Tiling make_tiling(const GridSpec& g) {
  Tiling t;
  // Aim for about 256 KiB of double scratch per tile.
  const int64_t target_cells = 32768;
  int64_t cols = std::max<int64_t>(1, target_cells / g.column_length());
  if (g.dim == 3) {
    int64_t side = 1;
    while ((side * 2) * (side * 2) <= cols) side *= 2;
    t.ty = std::min<int64_t>(side, g.n[1]);
    t.tx = std::min<int64_t>(std::max<int64_t>(1, cols / t.ty), g.n[0]);
    t.ntx = (g.n[0] + t.tx - 1) / t.tx;
    t.nty = (g.n[1] + t.ty - 1) / t.ty;
  } else {
    t.tx = std::min<int64_t>(cols, g.n[0]);
    t.ty = 1;
    t.ntx = (g.n[0] + t.tx - 1) / t.tx;
    t.nty = 1;
  }
  return t;
}

// Triangles (or segments) binned to tiles in ascending index order.
struct Bins {
  std::vector<int64_t> start;  // tiles + 1 offsets
  std::vector<int32_t> items;
};

// Cell range [c0, c1] along axis a touched by [mn, mx], widened by one cell
// and clamped to the grid. Returns false when it misses the grid.
inline bool cell_range(const GridSpec& g, int a, double mn, double mx, int64_t* c0,
                       int64_t* c1) {
  if (mx < g.lo[a] || mn > g.hi[a]) return false;
  *c0 = std::max<int64_t>(0, g.cell_of(a, mn) - 1);
  *c1 = std::min<int64_t>(g.n[a] - 1, g.cell_of(a, mx) + 1);
  return *c0 <= *c1;
}

// ---------------------------------------------------------------------------
// 3D

// Adds the pieces of polygon P (inside column cell with corner (xc, yc)) to
// the difference buffer `col` of that column.
inline void add_column_3d(const GridSpec& g, const Poly<3>& P, double xc, double yc,
                          double* col) {
  const int64_t nz = g.n[2];
  const double inv_area = 1.0 / (g.h[0] * g.h[1]);
  const double inv_vol = inv_area / g.h[2];
  const double ztop = g.hi[2];
  double zmin = P.min(2), zmax = P.max(2);
  if (zmax <= g.lo[2]) return;  // entirely below the grid

  // Signed projected area and integral of (z - zref) over a polygon, by a fan
  // of triangles in coordinates relative to the cell corner.
  auto integrate = [xc, yc](const Poly<3>& Q, double zref, double* area, double* zint) {
    double A = 0, I = 0;
    const double x0 = Q.v[0][0] - xc, y0 = Q.v[0][1] - yc, f0 = Q.v[0][2] - zref;
    for (int m = 1; m + 1 < Q.count; ++m) {
      double x1 = Q.v[m][0] - xc - x0, y1 = Q.v[m][1] - yc - y0;
      double x2 = Q.v[m + 1][0] - xc - x0, y2 = Q.v[m + 1][1] - yc - y0;
      double cr = 0.5 * (x1 * y2 - x2 * y1);
      A += cr;
      I += cr * (f0 + (Q.v[m][2] - zref) + (Q.v[m + 1][2] - zref)) * (1.0 / 3.0);
    }
    *area = A;
    *zint = I;
  };

  if (zmin >= ztop) {  // entirely above: the whole column is in its shadow
    double A, I;
    integrate(P, 0.0, &A, &I);
    col[nz - 1] += A * inv_area;
    return;
  }
  int64_t k0, k1;
  if (!cell_range(g, 2, zmin, zmax, &k0, &k1)) return;
  Poly<3> rest = P, piece, tmp;
  bool clipped_low = false;
  for (int64_t k = k0; k <= k1; ++k) {
    const double zl = g.plane(2, k), zh = g.plane(2, k + 1);
    if (rest.count < 3) break;
    if (!clipped_low && rest.min(2) < zl) {
      clip<3>(rest, 2, zl, true, &tmp);
      rest = tmp;
      if (rest.count < 3) break;
    }
    clipped_low = true;
    const Poly<3>* Q = &rest;
    bool more = rest.max(2) > zh;
    if (more) {
      clip<3>(rest, 2, zh, false, &piece);
      Q = &piece;
    }
    if (Q->count >= 3) {
      double A, I;
      integrate(*Q, zl, &A, &I);
      double b = I * inv_vol, tau = A * inv_area;
      col[k] += b;
      if (k > 0) col[k - 1] += tau - b;
    }
    if (!more) {
      rest.count = 0;
      break;
    }
    clip<3>(rest, 2, zh, true, &tmp);
    rest = tmp;
  }
  if (rest.count >= 3 && rest.max(2) > ztop) {
    if (rest.min(2) < ztop) {
      clip<3>(rest, 2, ztop, true, &tmp);
      rest = tmp;
    }
    if (rest.count >= 3) {
      double A, I;
      integrate(rest, 0.0, &A, &I);
      col[nz - 1] += A * inv_area;
    }
  }
}

// Loads triangle t of a batch item as a polygon; returns false when it has no
// shadow (vertical or degenerate).
template <typename T>
inline bool load_triangle(const T* V, const int32_t* F, int64_t t, Poly<3>* P) {
  const int32_t* f = F + 3 * t;
  for (int c = 0; c < 3; ++c)
    for (int a = 0; a < 3; ++a) P->v[c][a] = static_cast<double>(V[3 * int64_t(f[c]) + a]);
  P->count = 3;
  double nz = (P->v[1][0] - P->v[0][0]) * (P->v[2][1] - P->v[0][1]) -
              (P->v[1][1] - P->v[0][1]) * (P->v[2][0] - P->v[0][0]);
  return nz != 0.0;
}

template <typename T>
void bin_triangles_3d(const GridSpec& g, const Tiling& tl, const T* V, const int32_t* F,
                      int64_t nf, Bins* bins) {
  bins->start.assign(tl.count() + 1, 0);
  auto visit = [&](auto&& emit) {
    Poly<3> P;
    for (int64_t t = 0; t < nf; ++t) {
      if (!load_triangle(V, F, t, &P)) continue;
      if (P.max(2) <= g.lo[2]) continue;
      int64_t i0, i1, j0, j1;
      if (!cell_range(g, 0, P.min(0), P.max(0), &i0, &i1)) continue;
      if (!cell_range(g, 1, P.min(1), P.max(1), &j0, &j1)) continue;
      for (int64_t ti = i0 / tl.tx; ti <= i1 / tl.tx; ++ti)
        for (int64_t tj = j0 / tl.ty; tj <= j1 / tl.ty; ++tj) emit(ti * tl.nty + tj, t);
    }
  };
  visit([&](int64_t tile, int64_t) { ++bins->start[tile + 1]; });
  for (int64_t i = 0; i < tl.count(); ++i) bins->start[i + 1] += bins->start[i];
  bins->items.resize(bins->start[tl.count()]);
  std::vector<int64_t> fill(bins->start.begin(), bins->start.end() - 1);
  visit([&](int64_t tile, int64_t t) { bins->items[fill[tile]++] = static_cast<int32_t>(t); });
}

template <typename T>
void forward_tile_3d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V,
                     const int32_t* F, const Bins& bins, std::vector<double>& buf, T* out) {
  const int64_t ti = tile / tl.nty, tj = tile % tl.nty;
  const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
  const int64_t nz = g.n[2], wy = jb - ja;
  buf.assign((ib - ia) * wy * nz, 0.0);

  Poly<3> P, Px, Pxy;
  for (int64_t e = bins.start[tile]; e < bins.start[tile + 1]; ++e) {
    load_triangle(V, F, bins.items[e], &P);
    int64_t i0, i1;
    if (!cell_range(g, 0, P.min(0), P.max(0), &i0, &i1)) continue;
    i0 = std::max(i0, ia);
    i1 = std::min(i1, ib - 1);
    for (int64_t i = i0; i <= i1; ++i) {
      const double xl = g.plane(0, i);
      clip_slab<3>(P, 0, xl, g.plane(0, i + 1), &Px);
      if (Px.count < 3) continue;
      int64_t j0, j1;
      if (!cell_range(g, 1, Px.min(1), Px.max(1), &j0, &j1)) continue;
      j0 = std::max(j0, ja);
      j1 = std::min(j1, jb - 1);
      for (int64_t j = j0; j <= j1; ++j) {
        const double yl = g.plane(1, j);
        clip_slab<3>(Px, 1, yl, g.plane(1, j + 1), &Pxy);
        if (Pxy.count < 3) continue;
        add_column_3d(g, Pxy, xl, yl, buf.data() + ((i - ia) * wy + (j - ja)) * nz);
      }
    }
  }
  // Reverse prefix sums in double; each output voxel is written exactly once.
  for (int64_t i = ia; i < ib; ++i) {
    for (int64_t j = ja; j < jb; ++j) {
      const double* col = buf.data() + ((i - ia) * wy + (j - ja)) * nz;
      T* o = out + (i * g.n[1] + j) * nz;
      double s = 0;
      for (int64_t k = nz - 1; k >= 0; --k) {
        s += col[k];
        o[k] = static_cast<T>(s);
      }
    }
  }
}

// ---------------------------------------------------------------------------
// 2D: closed polylines, rays along +y, columns along x.

template <typename T>
inline bool load_segment(const T* V, const int32_t* F, int64_t s, Poly<2>* P) {
  const int32_t* f = F + 2 * s;
  for (int c = 0; c < 2; ++c)
    for (int a = 0; a < 2; ++a) P->v[c][a] = static_cast<double>(V[2 * int64_t(f[c]) + a]);
  P->count = 2;
  return P->v[0][0] != P->v[1][0];
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
    if (r[a] < lo) cut<N>(p, q, a, lo, r);
    else if (r[a] > hi) cut<N>(p, q, a, hi, r);
  }
  return true;
}

inline void add_column_2d(const GridSpec& g, const Poly<2>& S, double* col) {
  const int64_t ny = g.n[1];
  const double inv_len = 1.0 / g.h[0];
  const double inv_area = inv_len / g.h[1];
  double ymin = std::min(S.v[0][1], S.v[1][1]), ymax = std::max(S.v[0][1], S.v[1][1]);
  if (ymax <= g.lo[1]) return;
  // Signed x-extent: positive for segments running in -x (top of a CCW loop).
  if (ymin >= g.hi[1]) {
    col[ny - 1] += (S.v[0][0] - S.v[1][0]) * inv_len;
    return;
  }
  int64_t k0, k1;
  if (!cell_range(g, 1, ymin, ymax, &k0, &k1)) return;
  Poly<2> piece;
  for (int64_t k = k0; k <= k1; ++k) {
    const double yl = g.plane(1, k), yh = g.plane(1, k + 1);
    if (!clip_segment(S, 1, yl, yh, &piece)) continue;
    double a = piece.v[0][0] - piece.v[1][0];
    if (a == 0.0) continue;
    double ybar = 0.5 * ((piece.v[0][1] - yl) + (piece.v[1][1] - yl));
    double b = a * ybar * inv_area, tau = a * inv_len;
    col[k] += b;
    if (k > 0) col[k - 1] += tau - b;
  }
  if (ymax > g.hi[1] && clip_segment(S, 1, g.hi[1], std::max(ymax, g.hi[1]), &piece)) {
    col[ny - 1] += (piece.v[0][0] - piece.v[1][0]) * inv_len;
  }
}

template <typename T>
void bin_segments_2d(const GridSpec& g, const Tiling& tl, const T* V, const int32_t* F,
                     int64_t nf, Bins* bins) {
  bins->start.assign(tl.count() + 1, 0);
  auto visit = [&](auto&& emit) {
    Poly<2> S;
    for (int64_t s = 0; s < nf; ++s) {
      if (!load_segment(V, F, s, &S)) continue;
      if (std::max(S.v[0][1], S.v[1][1]) <= g.lo[1]) continue;
      int64_t i0, i1;
      if (!cell_range(g, 0, S.min(0), S.max(0), &i0, &i1)) continue;
      for (int64_t ti = i0 / tl.tx; ti <= i1 / tl.tx; ++ti) emit(ti, s);
    }
  };
  visit([&](int64_t tile, int64_t) { ++bins->start[tile + 1]; });
  for (int64_t i = 0; i < tl.count(); ++i) bins->start[i + 1] += bins->start[i];
  bins->items.resize(bins->start[tl.count()]);
  std::vector<int64_t> fill(bins->start.begin(), bins->start.end() - 1);
  visit([&](int64_t tile, int64_t s) { bins->items[fill[tile]++] = static_cast<int32_t>(s); });
}

template <typename T>
void forward_tile_2d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V,
                     const int32_t* F, const Bins& bins, std::vector<double>& buf, T* out) {
  const int64_t ia = tile * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ny = g.n[1];
  buf.assign((ib - ia) * ny, 0.0);
  Poly<2> S, Sx;
  for (int64_t e = bins.start[tile]; e < bins.start[tile + 1]; ++e) {
    load_segment(V, F, bins.items[e], &S);
    int64_t i0, i1;
    if (!cell_range(g, 0, S.min(0), S.max(0), &i0, &i1)) continue;
    i0 = std::max(i0, ia);
    i1 = std::min(i1, ib - 1);
    for (int64_t i = i0; i <= i1; ++i) {
      if (!clip_segment(S, 0, g.plane(0, i), g.plane(0, i + 1), &Sx)) continue;
      if (Sx.v[0][0] == Sx.v[1][0]) continue;
      add_column_2d(g, Sx, buf.data() + (i - ia) * ny);
    }
  }
  for (int64_t i = ia; i < ib; ++i) {
    const double* col = buf.data() + (i - ia) * ny;
    T* o = out + i * ny;
    double s = 0;
    for (int64_t k = ny - 1; k >= 0; --k) {
      s += col[k];
      o[k] = static_cast<T>(s);
    }
  }
}

}  // namespace voxax

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
//
// Scratch memory is bounded: each worker of a call owns one TileScratch for
// the duration of the call (freed when the call returns), sized for the
// largest tile it processes: about kTileCells doubles, or one column when a
// column is longer than that.
#pragma once

#include <algorithm>
#include <cstdint>
#include <vector>

#include "common/grid.h"
#include "common/parallel.h"
#include "voxelize/clip.h"

namespace voxax {

struct Tiling {
  int64_t tx = 1, ty = 1;  // columns per tile along x (and y in 3D)
  int64_t ntx = 1, nty = 1;
  int64_t count() const { return ntx * nty; }
};

// Cells per tile the tiling aims for: 256 KiB of double scratch.
constexpr int64_t kTileCells = 32768;

inline Tiling make_tiling(const GridSpec& g) {
  Tiling t;
  int64_t cols = std::max<int64_t>(1, kTileCells / g.column_length());
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

// ---------------------------------------------------------------------------
// 3D

// Signed projected area of Q and the integral of (z - zref) over it, by a fan
// of triangles in coordinates relative to (xc, yc).
inline void integrate_3d(const Poly<3>& Q, double xc, double yc, double zref, double* area,
                         double* zint) {
  double A = 0, I = 0;
  const double x0 = Q.v[0][0] - xc, y0 = Q.v[0][1] - yc, f0 = Q.v[0][2] - zref;
  for (int m = 1; m + 1 < Q.count; ++m) {
    const double x1 = Q.v[m][0] - xc - x0, y1 = Q.v[m][1] - yc - y0;
    const double x2 = Q.v[m + 1][0] - xc - x0, y2 = Q.v[m + 1][1] - yc - y0;
    const double cr = 0.5 * (x1 * y2 - x2 * y1);
    A += cr;
    I += cr * (f0 + (Q.v[m][2] - zref) + (Q.v[m + 1][2] - zref)) * (1.0 / 3.0);
  }
  *area = A;
  *zint = I;
}

// A column of the tile's difference buffer, with the range of entries written
// so far: untouched entries stay zero, so finishing the column only needs to
// read [lo, hi].
struct Column {
  double* d;
  int64_t* lo;
  int64_t* hi;
  void add(int64_t k, double v) const {
    d[k] += v;
    if (k < *lo) *lo = k;
    if (k > *hi) *hi = k;
  }
  // A value for a cell no piece lies in (the part of a pass-through value below a
  // piece's own cell, or a piece above the grid's top): the same sum.
  void add_below(int64_t k, double v) const { add(k, v); }
};

// Adds the pieces of polygon P (inside the column cell with corner (xc, yc))
// to the difference buffer `col` of that column: `add` for the own share of the
// cell a piece lies in, `add_below` for the cells below it (and the column's top
// for the parts above the grid), in the order the pieces come.
template <typename Col>
inline void add_column_3d(const GridSpec& g, const Poly<3>& P, double xc, double yc,
                          const Col& col) {
  const int64_t nz = g.n[2];
  const double inv_area = 1.0 / (g.h[0] * g.h[1]);
  const double inv_vol = inv_area / g.h[2];
  const double zbot = g.lo[2], ztop = g.hi[2];
  const double zmin = P.min(2), zmax = P.max(2);
  double A, I;
  if (zmax <= zbot) return;  // entirely below the grid
  if (zmin >= ztop) {        // entirely above: the whole column is in its shadow
    integrate_3d(P, xc, yc, 0.0, &A, &I);
    col.add_below(nz - 1, A * inv_area);
    return;
  }
  int64_t k0 = 0, k1 = -1;
  if (!g.span(2, zmin, zmax, &k0, &k1)) return;
  Poly<3> rest, piece, upper;
  const Poly<3>* cur = &P;
  if (zmin < g.plane(2, k0)) {
    split<3>(P, 2, g.plane(2, k0), &piece, &rest);  // drop the part below the grid
    cur = &rest;
  }
  for (int64_t k = k0; k <= k1; ++k) {
    const double zl = g.plane(2, k), zh = g.plane(2, k + 1);
    const Poly<3>* Q = cur;
    bool last = cur->max(2) <= zh;
    if (!last) {
      split<3>(*cur, 2, zh, &piece, &upper);
      Q = &piece;
    }
    if (Q->count >= 3) {
      integrate_3d(*Q, xc, yc, zl, &A, &I);
      const double b = I * inv_vol, tau = A * inv_area;
      col.add(k, b);
      if (k > 0) col.add_below(k - 1, tau - b);
    }
    if (last) return;
    rest = upper;
    cur = &rest;
    if (cur->count < 3) return;
  }
  // What is left lies above the grid's top.
  integrate_3d(*cur, xc, yc, 0.0, &A, &I);
  col.add_below(nz - 1, A * inv_area);
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

// Bins faces to tiles. `ranges(f, r)` fills r = {ti0, ti1, tj0, tj1} with the
// tile range of face f, or returns false when the face contributes nothing.
// Faces are counted and filled in parallel over fixed chunks (independent of
// the thread count), so every tile lists its faces in ascending order.
template <typename Ranges>
void bin_faces(ffi::ThreadPool* pool, const Tiling& tl, int64_t nf, Ranges&& ranges, Bins* bins) {
  const int64_t tiles = tl.count();
  const int64_t chunks = std::max<int64_t>(1, std::min<int64_t>(32, nf / 8192));
  const int64_t per = (nf + chunks - 1) / chunks;
  std::vector<int64_t> counts(chunks * tiles, 0);
  ParallelFor::run(pool, chunks, [&](int64_t c) {
    int64_t* cnt = counts.data() + c * tiles;
    int32_t r[4];
    for (int64_t f = c * per; f < std::min(nf, (c + 1) * per); ++f) {
      if (!ranges(f, r)) continue;
      for (int32_t ti = r[0]; ti <= r[1]; ++ti)
        for (int32_t tj = r[2]; tj <= r[3]; ++tj) ++cnt[ti * tl.nty + tj];
    }
  });
  bins->start.assign(tiles + 1, 0);
  for (int64_t t = 0; t < tiles; ++t) {
    int64_t s = bins->start[t];
    for (int64_t c = 0; c < chunks; ++c) {
      int64_t n = counts[c * tiles + t];
      counts[c * tiles + t] = s;  // becomes this chunk's fill position
      s += n;
    }
    bins->start[t + 1] = s;
  }
  bins->items.resize(bins->start[tiles]);
  // The second pass recomputes the ranges (cheaper than storing them).
  ParallelFor::run(pool, chunks, [&](int64_t c) {
    int64_t* pos = counts.data() + c * tiles;
    int32_t r[4];
    for (int64_t f = c * per; f < std::min(nf, (c + 1) * per); ++f) {
      if (!ranges(f, r)) continue;
      for (int32_t ti = r[0]; ti <= r[1]; ++ti)
        for (int32_t tj = r[2]; tj <= r[3]; ++tj)
          bins->items[pos[ti * tl.nty + tj]++] = static_cast<int32_t>(f);
    }
  });
}

template <typename T>
void bin_triangles_3d(ffi::ThreadPool* pool, const GridSpec& g, const Tiling& tl, const T* V,
                      const int32_t* F, int64_t nf, Bins* bins) {
  bin_faces(
      pool, tl, nf,
      [&](int64_t t, int32_t* r) {
        Poly<3> P;
        if (!load_triangle(V, F, t, &P)) return false;
        if (P.max(2) <= g.lo[2]) return false;
        int64_t i0, i1, j0, j1;
        if (!g.span(0, P.min(0), P.max(0), &i0, &i1)) return false;
        if (!g.span(1, P.min(1), P.max(1), &j0, &j1)) return false;
        r[0] = static_cast<int32_t>(i0 / tl.tx);
        r[1] = static_cast<int32_t>(i1 / tl.tx);
        r[2] = static_cast<int32_t>(j0 / tl.ty);
        r[3] = static_cast<int32_t>(j1 / tl.ty);
        return true;
      },
      bins);
}

// Stores [first, last) of a column: out[k] = T(src ? src[k] : value). Plain
// stores: the output is a fresh allocation whose pages the OS zeroes into the
// cache on first touch, so streaming stores would only add memory traffic.
template <typename T>
inline void store_range(T* out, int64_t first, int64_t last, const double* src, double value) {
  if (src) {
    for (int64_t k = first; k < last; ++k) out[k] = static_cast<T>(src[k]);
  } else {
    const T v = static_cast<T>(value);
    for (int64_t k = first; k < last; ++k) out[k] = v;
  }
}

// Finishes a column of differences whose non-zero entries lie in [lo, hi]:
// writes the reverse prefix sums W[k] = sum of col[k'] for k' >= k (in double)
// to out, and leaves col all zero again for the next tile. Above hi W is 0;
// below lo it is the column total.
template <typename T>
inline void finish_column(double* col, int64_t lo, int64_t hi, int64_t n, T* out) {
  if (hi < lo) {
    store_range<T>(out, 0, n, nullptr, 0.0);
    return;
  }
  double s = 0;
  for (int64_t k = hi; k >= lo; --k) {
    s += col[k];
    col[k] = s;
  }
  store_range<T>(out, 0, lo, nullptr, s);
  store_range<T>(out, lo, hi + 1, col, 0.0);
  store_range<T>(out, hi + 1, n, nullptr, 0.0);
  std::fill(col + lo, col + hi + 1, 0.0);
}

// A worker's scratch for its tiles: the difference buffer (all zero between
// tiles) and each column's written range. It grows to the largest tile the
// worker processes and lives as long as the call that owns it.
struct TileScratch {
  std::vector<double> buf;
  std::vector<int64_t> lo, hi;
  void prepare(int64_t columns, int64_t length) {
    if (static_cast<int64_t>(buf.size()) < columns * length) buf.resize(columns * length, 0.0);
    lo.assign(columns, length);
    hi.assign(columns, -1);
  }
  Column column(int64_t c, int64_t length) {
    return Column{buf.data() + c * length, lo.data() + c, hi.data() + c};
  }
};

// Clips P (whose cells along x are [i0, i1]) into the columns (i, j) of the tile
// [ia, ib) x [ja, jb) that it overlaps, sweeping slabs in x (from P's first cell, so
// that the pieces are the same for any tiling and any window), then in y, and calls
// fn(i, j, piece) for each.
template <typename Fn>
void sweep_tile_columns(const GridSpec& g, const Poly<3>& P, int64_t i0, int64_t i1, int64_t ia,
                        int64_t ib, int64_t ja, int64_t jb, Fn&& fn) {
  i1 = std::min(i1, ib - 1);
  if (std::max(i0, ia) > i1) return;
  // From P's own first cell, not the tile's: the pieces do not depend on the tiling.
  sweep<3>(g, P, 0, g.first_cell(0, P.min(0)), i1, [&](int64_t i, const Poly<3>& Px) {
    if (i < ia) return;
    int64_t ya, yb;
    if (!g.span(1, Px.min(1), Px.max(1), &ya, &yb)) return;
    ya = std::max(ya, ja);
    yb = std::min(yb, jb - 1);
    if (ya > yb) return;
    sweep<3>(g, Px, 1, ya, yb, [&](int64_t j, const Poly<3>& Q) { fn(i, j, Q); });
  });
}

// Adds the pieces of the triangles binned to one tile to the columns of the tile:
// column_of(c) is the column sink (with `add` and `add_below`) of the tile's column
// c = (i - ia) * wy + (j - ja). Triangles come in bin order and each one's pieces in
// sweep order, the same for every tiling of the same grid's x axis and thread count.
template <typename T, typename ColumnOf>
void tile_pieces_3d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V, const int32_t* F,
                    const Bins& bins, ColumnOf&& column_of) {
  const int64_t ti = tile / tl.nty, tj = tile % tl.nty;
  const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
  const int64_t wy = jb - ja;
  const double inv_area = 1.0 / (g.h[0] * g.h[1]);
  const double inv_vol = inv_area / g.h[2];
  Poly<3> P;
  for (int64_t e = bins.start[tile]; e < bins.start[tile + 1]; ++e) {
    load_triangle(V, F, bins.items[e], &P);
    int64_t i0, i1, j0, j1;
    const double x0 = P.min(0), x1 = P.max(0);
    if (!g.span(0, x0, x1, &i0, &i1)) continue;
    // Fast path: the triangle lies in one voxel of this tile (common on fine
    // meshes). Its own share and pass-through value need no clipping.
    if (i0 == i1 && i0 >= ia && i0 < ib && x0 >= g.plane(0, i0) && x1 <= g.plane(0, i0 + 1)) {
      const double y0 = P.min(1), y1 = P.max(1);
      int64_t k0, k1;
      if (g.span(1, y0, y1, &j0, &j1) && j0 == j1 && j0 >= ja && j0 < jb && y0 >= g.plane(1, j0) &&
          y1 <= g.plane(1, j0 + 1)) {
        const double z0 = P.min(2), z1 = P.max(2);
        const auto col = column_of((i0 - ia) * wy + (j0 - ja));
        if (g.span(2, z0, z1, &k0, &k1) && k0 == k1 && z0 >= g.plane(2, k0) &&
            z1 <= g.plane(2, k0 + 1)) {
          const double (*q)[3] = P.v;
          const double A = 0.5 * ((q[1][0] - q[0][0]) * (q[2][1] - q[0][1]) -
                                  (q[2][0] - q[0][0]) * (q[1][1] - q[0][1]));
          const double zl = g.plane(2, k0);
          const double b =
              A * ((q[0][2] - zl) + (q[1][2] - zl) + (q[2][2] - zl)) * (1.0 / 3.0) * inv_vol;
          col.add(k0, b);
          if (k0 > 0) col.add_below(k0 - 1, A * inv_area - b);
        } else {
          add_column_3d(g, P, g.plane(0, i0), g.plane(1, j0), col);
        }
        continue;
      }
    }
    // Sweep the slabs of this tile in x, then in y, splitting off one cell at a time.
    sweep_tile_columns(g, P, i0, i1, ia, ib, ja, jb, [&](int64_t i, int64_t j, const Poly<3>& Q) {
      add_column_3d(g, Q, g.plane(0, i), g.plane(1, j), column_of((i - ia) * wy + (j - ja)));
    });
  }
}

template <typename T>
void forward_tile_3d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V,
                     const int32_t* F, const Bins& bins, TileScratch& scratch, T* out) {
  const int64_t ti = tile / tl.nty, tj = tile % tl.nty;
  const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
  const int64_t nz = g.n[2], wy = jb - ja;
  scratch.prepare((ib - ia) * wy, nz);
  tile_pieces_3d(g, tl, tile, V, F, bins, [&](int64_t c) { return scratch.column(c, nz); });
  for (int64_t i = ia; i < ib; ++i) {
    for (int64_t j = ja; j < jb; ++j) {
      const int64_t c = (i - ia) * wy + (j - ja);
      finish_column(scratch.buf.data() + c * nz, scratch.lo[c], scratch.hi[c], nz,
                    out + (i * g.n[1] + j) * nz);
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

inline void add_column_2d(const GridSpec& g, const Poly<2>& S, const Column& col) {
  const int64_t ny = g.n[1];
  const double inv_len = 1.0 / g.h[0];
  const double inv_area = inv_len / g.h[1];
  double ymin = std::min(S.v[0][1], S.v[1][1]), ymax = std::max(S.v[0][1], S.v[1][1]);
  if (ymax <= g.lo[1]) return;
  // Signed x-extent: positive for segments running in -x (top of a CCW loop).
  if (ymin >= g.hi[1]) {
    col.add(ny - 1, (S.v[0][0] - S.v[1][0]) * inv_len);
    return;
  }
  int64_t k0, k1;
  if (!g.span(1, ymin, ymax, &k0, &k1)) return;
  Poly<2> piece;
  for (int64_t k = k0; k <= k1; ++k) {
    const double yl = g.plane(1, k), yh = g.plane(1, k + 1);
    if (!clip_segment(S, 1, yl, yh, &piece)) continue;
    // Half-open cells: a piece lying on the upper line belongs to the cell above.
    if (k + 1 < ny && std::min(piece.v[0][1], piece.v[1][1]) >= yh) continue;
    double a = piece.v[0][0] - piece.v[1][0];
    if (a == 0.0) continue;
    double ybar = 0.5 * ((piece.v[0][1] - yl) + (piece.v[1][1] - yl));
    double b = a * ybar * inv_area, tau = a * inv_len;
    col.add(k, b);
    if (k > 0) col.add(k - 1, tau - b);
  }
  if (ymax > g.hi[1] && clip_segment(S, 1, g.hi[1], std::max(ymax, g.hi[1]), &piece)) {
    col.add(ny - 1, (piece.v[0][0] - piece.v[1][0]) * inv_len);
  }
}

template <typename T>
void bin_segments_2d(ffi::ThreadPool* pool, const GridSpec& g, const Tiling& tl, const T* V,
                     const int32_t* F, int64_t nf, Bins* bins) {
  bin_faces(
      pool, tl, nf,
      [&](int64_t s, int32_t* r) {
        Poly<2> S;
        if (!load_segment(V, F, s, &S)) return false;
        if (std::max(S.v[0][1], S.v[1][1]) <= g.lo[1]) return false;
        int64_t i0, i1;
        if (!g.span(0, S.min(0), S.max(0), &i0, &i1)) return false;
        r[0] = static_cast<int32_t>(i0 / tl.tx);
        r[1] = static_cast<int32_t>(i1 / tl.tx);
        r[2] = 0;
        r[3] = 0;
        return true;
      },
      bins);
}

template <typename T>
void forward_tile_2d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V,
                     const int32_t* F, const Bins& bins, TileScratch& scratch, T* out) {
  const int64_t ia = tile * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ny = g.n[1];
  scratch.prepare(ib - ia, ny);
  Poly<2> S, Sx;
  for (int64_t e = bins.start[tile]; e < bins.start[tile + 1]; ++e) {
    load_segment(V, F, bins.items[e], &S);
    int64_t i0, i1;
    if (!g.span(0, S.min(0), S.max(0), &i0, &i1)) continue;
    i0 = std::max(i0, ia);
    i1 = std::min(i1, ib - 1);
    for (int64_t i = i0; i <= i1; ++i) {
      if (!clip_segment(S, 0, g.plane(0, i), g.plane(0, i + 1), &Sx)) continue;
      if (Sx.v[0][0] == Sx.v[1][0]) continue;
      add_column_2d(g, Sx, scratch.column(i - ia, ny));
    }
  }
  for (int64_t i = ia; i < ib; ++i)
    finish_column(scratch.buf.data() + (i - ia) * ny, scratch.lo[i - ia], scratch.hi[i - ia], ny,
                  out + i * ny);
}

}  // namespace voxax

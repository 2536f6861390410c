// Sparse voxelization: the forward's values at the cells the surface touches, and
// the runs of equal values between them along each column, without a dense grid.
//
// The pieces are the dense forward's (tile_pieces_3d: the same tiling, the same bins,
// the same clipping), and so are the sums: each tile adds its pieces' shares to a
// difference buffer in the same order, and a column's reverse prefix sum is taken
// over the cells that received a value only (the keys). Between keys the dense
// prefix sum adds zeros, which changes nothing, so every value equals the dense
// kernel's bit for bit. A key is either a cell a piece lies in (a boundary cell) or
// the top cell of a run: the cell below a piece's own cell, or the column's top cell
// for pieces above the grid. A run holds the value of its top key down to the next
// key below it (or the column's bottom); above a column's highest key every value is
// zero. Memory and work grow with the number of keys, not with the grid's size,
// apart from one difference buffer of a tile per worker.
//
// A boundary cell is a cell that a piece of the surface lies in: a piece of the
// forward's clipping (its own share) or of the backward's full 3D clipping, vertical
// faces included (surface_pieces_in_tile). Only these cells change when the surface
// moves, so the derivatives go through the same closed-form splat as the dense
// kernels with the cotangent read from (backward) and the tangent added to (forward
// mode) the boundary cells alone; the runs' values have derivative zero.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#include "common/grid.h"
#include "voxelize/forward.h"
#include "voxelize/splat.h"

namespace voxax {

// The key flags of a tile cell (any flag: the cell is a key).
constexpr uint8_t kKey = 1;       // a value was added
constexpr uint8_t kBoundary = 2;  // a piece lies in the cell

// A worker's scratch for its tiles: the difference buffer and the key flags (all
// zero between tiles) and the keys of the current tile (tile cell indices
// c * nz + k in the order they were first written).
struct SparseTileScratch {
  std::vector<double> buf;
  std::vector<uint8_t> flags;
  std::vector<int64_t> keys;
  std::vector<double> sums;
  void prepare(int64_t cells) {
    if (static_cast<int64_t>(buf.size()) < cells) {
      buf.resize(cells, 0.0);
      flags.resize(cells, 0);
    }
    keys.clear();
  }
};

// A column sink of tile_pieces_3d that records its keys.
struct SparseColumn {
  double* d;
  uint8_t* flags;
  std::vector<int64_t>* keys;
  int64_t base;  // the column's first tile cell
  void mark(int64_t k, uint8_t f) const {
    if (!flags[k]) keys->push_back(base + k);
    flags[k] |= f;
  }
  void add(int64_t k, double v) const {
    d[k] += v;
    mark(k, kKey | kBoundary);
  }
  void add_below(int64_t k, double v) const {
    d[k] += v;
    mark(k, kKey);
  }
};

// The boundary cells and runs of the columns (i, j) of one x index i, in (j, k) order.
template <typename T>
struct SparseRow {
  std::vector<int32_t> cells;  // (i, j, k) per boundary cell
  std::vector<T> values;
  std::vector<int32_t> runs;  // (i, j, k_start, k_stop) per run
  std::vector<T> run_values;
  void clear() {
    std::vector<int32_t>().swap(cells);
    std::vector<T>().swap(values);
    std::vector<int32_t>().swap(runs);
    std::vector<T>().swap(run_values);
  }
};

template <typename T>
inline bool is_plus_zero(T v) {
  return v == T(0) && !std::signbit(v);
}

// Finishes a tile: each column's reverse prefix sum over its keys, appended to the rows
// of its x index (rows[i - ia]), and the scratch left all zero again.
template <typename T>
void finish_sparse_tile(int64_t nz, int64_t ia, int64_t ja, int64_t wy, SparseTileScratch& s,
                        SparseRow<T>* rows) {
  std::vector<int64_t>& keys = s.keys;
  std::sort(keys.begin(), keys.end());
  s.sums.resize(keys.size());
  size_t a = 0;
  while (a < keys.size()) {
    const int64_t c = keys[a] / nz;
    size_t e = a + 1;
    while (e < keys.size() && keys[e] / nz == c) ++e;
    double* d = s.buf.data() + c * nz;
    uint8_t* fl = s.flags.data() + c * nz;
    double sum = 0;
    for (size_t q = e; q-- > a;) {
      const int64_t k = keys[q] - c * nz;
      sum += d[k];
      d[k] = 0.0;
      s.sums[q] = sum;
    }
    const int32_t i = static_cast<int32_t>(ia + c / wy), j = static_cast<int32_t>(ja + c % wy);
    SparseRow<T>& row = rows[c / wy];
    int64_t below = 0;  // the lowest cell no key covers yet
    for (size_t q = a; q < e; ++q) {
      const int64_t k = keys[q] - c * nz;
      const bool boundary = fl[k] & kBoundary;
      fl[k] = 0;
      const T v = static_cast<T>(s.sums[q]);
      const int64_t stop = boundary ? k : k + 1;
      if (stop > below && !is_plus_zero(v)) {
        row.runs.insert(row.runs.end(),
                        {i, j, static_cast<int32_t>(below), static_cast<int32_t>(stop)});
        row.run_values.push_back(v);
      }
      if (boundary) {
        row.cells.insert(row.cells.end(), {i, j, static_cast<int32_t>(k)});
        row.values.push_back(v);
      }
      below = k + 1;
    }
    a = e;
  }
}

// The pieces of triangle P (of the backward's full 3D clipping: x from the triangle's
// first cell, y from its first cell in each x slab, then z) that lie in the columns
// [ia, ib) x [ja, jb): visit(i, j, k, piece). The same pieces as backward_triangles_3d,
// whatever the tile.
template <typename Visit>
void surface_pieces_in_tile(const GridSpec& g, const Poly<3>& P, int64_t ia, int64_t ib, int64_t ja,
                            int64_t jb, Visit&& visit) {
  int64_t i0, i1, j0, j1, k0, k1;
  if (!g.span(0, P.min(0), P.max(0), &i0, &i1) || !g.span(1, P.min(1), P.max(1), &j0, &j1) ||
      !g.span(2, P.min(2), P.max(2), &k0, &k1))
    return;
  i1 = std::min(i1, ib - 1);
  if (std::max(i0, ia) > i1 || j0 >= jb || j1 < ja) return;
  sweep<3>(g, P, 0, g.first_cell(0, P.min(0)), i1, [&](int64_t i, const Poly<3>& Px) {
    if (i < ia) return;
    int64_t ya, yb;
    if (!g.span(1, Px.min(1), Px.max(1), &ya, &yb)) return;
    yb = std::min(yb, jb - 1);
    if (yb < ja) return;
    sweep<3>(g, Px, 1, ya, yb, [&](int64_t j, const Poly<3>& Pxy) {
      if (j < ja) return;
      int64_t ka, kb;
      if (!g.span(2, Pxy.min(2), Pxy.max(2), &ka, &kb)) return;
      sweep<3>(g, Pxy, 2, ka, kb, [&](int64_t k, const Poly<3>& Q) { visit(i, j, k, Q); });
    });
  });
}

// All tiles of the tile row ti (columns ia <= i < ib, every j) of one batch item, into
// rows[i - ia]. `bins` are the forward's (faces with a shadow), `touch` every face's
// with a normal (bin_tangent_faces).
template <typename T>
void sparse_tile_row(const GridSpec& g, const Tiling& tl, int64_t ti, const T* V, const int32_t* F,
                     const Bins& bins, const Bins& touch, SparseTileScratch& s,
                     SparseRow<T>* rows) {
  const int64_t nz = g.n[2];
  const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  TriangleFrame frame;
  Poly<3> P;
  for (int64_t tj = 0; tj < tl.nty; ++tj) {
    const int64_t tile = ti * tl.nty + tj;
    const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
    const int64_t wy = jb - ja;
    s.prepare((ib - ia) * wy * nz);
    tile_pieces_3d(g, tl, tile, V, F, bins, [&](int64_t c) {
      return SparseColumn{s.buf.data() + c * nz, s.flags.data() + c * nz, &s.keys, c * nz};
    });
    for (int64_t e = touch.start[tile]; e < touch.start[tile + 1]; ++e) {
      if (!frame.load(V, F + 3 * int64_t(touch.items[e]))) continue;
      frame.to_poly(&P);
      surface_pieces_in_tile(g, P, ia, ib, ja, jb,
                             [&](int64_t i, int64_t j, int64_t k, const Poly<3>&) {
                               const int64_t c = ((i - ia) * wy + (j - ja)) * nz + k;
                               if (!s.flags[c]) s.keys.push_back(c);
                               s.flags[c] |= kBoundary;
                             });
    }
    finish_sparse_tile(nz, ia, ja, wy, s, rows);
  }
}

// ---------------------------------------------------------------------------
// Looking cells up among the boundary cells (the derivatives' input).

// One batch item's boundary cells: `count` (i, j, k) triples in ascending order.
struct SparseCells {
  const int32_t* cells = nullptr;
  int64_t count = 0;

  static bool less3(const int32_t* a, int32_t i, int32_t j, int32_t k) {
    if (a[0] != i) return a[0] < i;
    if (a[1] != j) return a[1] < j;
    return a[2] < k;
  }
  // The first cell in [lo, hi) not lexicographically below (i, j, k).
  int64_t lower(int64_t lo, int64_t hi, int32_t i, int32_t j, int32_t k) const {
    while (lo < hi) {
      const int64_t mid = lo + (hi - lo) / 2;
      if (less3(cells + 3 * mid, i, j, k))
        lo = mid + 1;
      else
        hi = mid;
    }
    return lo;
  }

  // Column (i, j)'s cells [c0, c1); slot(k) is the index of cell (i, j, k), or -1.
  struct Column {
    const SparseCells* s;
    int64_t c0, c1;
    int32_t i, j;
    int64_t slot(int64_t k) const {
      const int32_t kk = static_cast<int32_t>(k);
      const int64_t c = s->lower(c0, c1, i, j, kk);
      return c < c1 && s->cells[3 * c + 2] == kk ? c : -1;
    }
  };

  Column column(int64_t i, int64_t j) const {
    const int32_t ii = static_cast<int32_t>(i), jj = static_cast<int32_t>(j);
    Column c{this, 0, 0, ii, jj};
    c.c0 = lower(0, count, ii, jj, INT32_MIN);
    c.c1 = lower(c.c0, count, ii, jj, INT32_MAX);
    if (c.c1 < count && cells[3 * c.c1] == ii && cells[3 * c.c1 + 1] == jj) ++c.c1;
    return c;
  }
};

}  // namespace voxax

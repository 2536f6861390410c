// Tangent (forward mode): the directional derivative of every voxel.
//
// The backward gathers, for every face corner m, the integral over the
// surface inside each voxel of g * beta_m * nhat / |voxel|. The tangent
// scatters the same quantity: for per-corner velocities t_m, a piece P of a
// face inside voxel v adds
//   dW[v] += (1 / |voxel|) * integral over P of nhat . (sum_m beta_m t_m)
//          = (1 / |voxel|) * sum_m (nhat . t_m) * area(P) * beta_m(centroid of P).
// The two kernels are exact transposes of each other (the same pieces and the
// same per-piece weights), so <u, J t> = <J^T u, t> up to rounding.
//
// Work is partitioned into tiles of whole columns (the forward's tiling), and
// faces are binned to the tiles they touch; each tile is accumulated by one
// thread, in bin order, in a double buffer and written to the output once, so
// results are identical bit for bit for any thread count.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

#include "common/batch.h"
#include "common/constants.h"
#include "common/errors.h"
#include "common/grid.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "voxelize/clip.h"
#include "voxelize/forward.h"
#include "voxelize/splat.h"

namespace voxax {

// Bins every face that can have a piece inside the grid (vertical ones
// included) to the column tiles its bounding box touches.
// Loads triangle t (vertices V, faces F) into `frame` and its polygon `P`, with the normal
// speed of each corner in `c`: its unit normal dotted with the corner tangents `TC`
// (3 x 3 per triangle, corner-major). False when the triangle is degenerate or does not
// move along its normal (it adds nothing to the tangent).
template <typename T>
inline bool load_moving_triangle(const T* V, const int32_t* F, const T* TC, int64_t t,
                                 TriangleFrame* frame, Poly<3>* P, double c[3]) {
  if (!frame->load(V, F + 3 * t)) return false;
  const double* nh = frame->nh;
  const T* tc = TC + 9 * t;
  for (int m = 0; m < 3; ++m)
    c[m] = nh[0] * static_cast<double>(tc[3 * m]) + nh[1] * static_cast<double>(tc[3 * m + 1]) +
           nh[2] * static_cast<double>(tc[3 * m + 2]);
  if (c[0] == 0.0 && c[1] == 0.0 && c[2] == 0.0) return false;
  frame->to_poly(P);
  return true;
}

template <typename T>
void bin_tangent_faces(ffi::ThreadPool* pool, const GridSpec& g, const Tiling& tl, int dim,
                       const T* V, const int32_t* F, int64_t nf, Bins* bins) {
  bin_faces(
      pool, tl, nf,
      [&](int64_t f, int32_t* r) {
        const int32_t* idx = F + dim * f;
        double mn[3] = {0, 0, 0}, mx[3] = {0, 0, 0};
        for (int a = 0; a < dim; ++a) {
          mn[a] = mx[a] = static_cast<double>(V[dim * int64_t(idx[0]) + a]);
          for (int c = 1; c < dim; ++c) {
            const double x = static_cast<double>(V[dim * int64_t(idx[c]) + a]);
            mn[a] = std::min(mn[a], x);
            mx[a] = std::max(mx[a], x);
          }
        }
        int64_t c0[3] = {0, 0, 0}, c1[3] = {0, 0, 0};
        for (int a = 0; a < dim; ++a)
          if (!g.span(a, mn[a], mx[a], &c0[a], &c1[a])) return false;
        r[0] = static_cast<int32_t>(c0[0] / tl.tx);
        r[1] = static_cast<int32_t>(c1[0] / tl.tx);
        r[2] = dim == 3 ? static_cast<int32_t>(c0[1] / tl.ty) : 0;
        r[3] = dim == 3 ? static_cast<int32_t>(c1[1] / tl.ty) : 0;
        return true;
      },
      bins);
}

// Adds the tangent of the triangles binned to one tile into `acc`, the tile's
// cells ((i - ia) * wy + (j - ja)) * nz + k. TC holds per-corner tangents
// (F, 3, 3) of this batch item.
template <typename T>
void tangent_tile_3d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V,
                     const int32_t* F, const T* TC, const Bins& bins, double* acc) {
  const int64_t ti = tile / tl.nty, tj = tile % tl.nty;
  const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
  const int64_t nz = g.n[2], wy = jb - ja;
  const double inv_vol = 1.0 / g.cell_volume();
  Poly<3> P;
  TriangleFrame frame;
  for (int64_t e = bins.start[tile]; e < bins.start[tile + 1]; ++e) {
    const int64_t t = bins.items[e];
    double c[3];  // the normal speed of each corner
    if (!load_moving_triangle(V, F, TC, t, &frame, &P, c)) continue;
    int64_t i0, i1, j0, j1, k0, k1;
    if (!g.span(0, P.min(0), P.max(0), &i0, &i1) || !g.span(1, P.min(1), P.max(1), &j0, &j1) ||
        !g.span(2, P.min(2), P.max(2), &k0, &k1))
      continue;
    sweep_tile_columns(g, P, i0, i1, ia, ib, ja, jb, [&](int64_t i, int64_t j, const Poly<3>& Pxy) {
      int64_t ka, kb;
      if (!g.span(2, Pxy.min(2), Pxy.max(2), &ka, &kb)) return;
      double* col = acc + ((i - ia) * wy + (j - ja)) * nz;
      sweep<3>(g, Pxy, 2, ka, kb, [&](int64_t k, const Poly<3>& Q) {
        double beta[3];
        frame.piece_integrals(Q, beta);
        col[k] += inv_vol * (beta[0] * c[0] + beta[1] * c[1] + beta[2] * c[2]);
      });
    });
  }
}

// 2D: segments with per-corner tangents (F, 2, 2); tiles of whole columns along x.
template <typename T>
void tangent_tile_2d(const GridSpec& g, const Tiling& tl, int64_t tile, const T* V,
                     const int32_t* F, const T* TC, const Bins& bins, double* acc) {
  const int64_t ia = tile * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
  const int64_t ny = g.n[1];
  const double inv_area = 1.0 / g.cell_volume();
  Poly<3> S, Sx, Sy;
  for (int64_t e = bins.start[tile]; e < bins.start[tile + 1]; ++e) {
    const int64_t s = bins.items[e];
    const int32_t* f = F + 2 * s;
    double p[2][2];
    for (int q = 0; q < 2; ++q)
      for (int a = 0; a < 2; ++a) p[q][a] = static_cast<double>(V[2 * int64_t(f[q]) + a]);
    const double dx = p[1][0] - p[0][0], dy = p[1][1] - p[0][1];
    const double len = std::sqrt(dx * dx + dy * dy);
    if (!(len > 0) || !std::isfinite(len)) continue;
    const double nh[2] = {dy / len, -dx / len};
    const T* tc = TC + 4 * s;
    const double c0 = nh[0] * static_cast<double>(tc[0]) + nh[1] * static_cast<double>(tc[1]);
    const double c1 = nh[0] * static_cast<double>(tc[2]) + nh[1] * static_cast<double>(tc[3]);
    if (c0 == 0.0 && c1 == 0.0) continue;
    S.count = 2;
    for (int q = 0; q < 2; ++q) {
      S.v[q][0] = p[q][0];
      S.v[q][1] = p[q][1];
      S.v[q][2] = q == 1 ? 1.0 : 0.0;  // beta_1
    }
    int64_t i0, i1, j0, j1;
    if (!g.span(0, S.min(0), S.max(0), &i0, &i1)) continue;
    i0 = std::max(i0, ia);
    i1 = std::min(i1, ib - 1);
    for (int64_t i = i0; i <= i1; ++i) {
      if (!clip_segment(S, 0, g.plane(0, i), g.plane(0, i + 1), &Sx)) continue;
      if (i + 1 < g.cells_to_end(0) && Sx.min(0) >= g.plane(0, i + 1)) continue;
      if (!g.span(1, Sx.min(1), Sx.max(1), &j0, &j1)) continue;
      double* col = acc + (i - ia) * ny;
      for (int64_t j = j0; j <= j1; ++j) {
        if (!clip_segment(Sx, 1, g.plane(1, j), g.plane(1, j + 1), &Sy)) continue;
        if (j + 1 < g.n[1] && Sy.min(1) >= g.plane(1, j + 1)) continue;
        const double ex = Sy.v[1][0] - Sy.v[0][0], ey = Sy.v[1][1] - Sy.v[0][1];
        const double L = ex * (dx / len) + ey * (dy / len);  // signed length along the segment
        const double b1 = 0.5 * (Sy.v[0][2] + Sy.v[1][2]);
        col[j] += inv_area * L * ((1.0 - b1) * c0 + b1 * c1);
      }
    }
  }
}

// Per-thread accumulation buffer of one tile.
struct TangentScratch {
  std::vector<double> buf;
  double* zeroed(int64_t cells) {
    if (static_cast<int64_t>(buf.size()) < cells) buf.resize(cells);
    std::fill(buf.begin(), buf.begin() + cells, 0.0);
    return buf.data();
  }
};

// Writes the tile's accumulated cells to the output grid of one batch item.
template <typename T>
void store_tile(const GridSpec& g, const Tiling& tl, int64_t tile, const double* acc, T* out) {
  const int64_t len = g.column_length();
  if (g.dim == 3) {
    const int64_t ti = tile / tl.nty, tj = tile % tl.nty;
    const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
    const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
    const int64_t wy = jb - ja;
    for (int64_t i = ia; i < ib; ++i)
      for (int64_t j = ja; j < jb; ++j) {
        const double* src = acc + ((i - ia) * wy + (j - ja)) * len;
        T* dst = out + (i * g.n[1] + j) * len;
        for (int64_t k = 0; k < len; ++k) dst[k] = static_cast<T>(src[k]);
      }
  } else {
    const int64_t ia = tile * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
    for (int64_t i = ia; i < ib; ++i)
      for (int64_t k = 0; k < len; ++k) out[i * len + k] = static_cast<T>(acc[(i - ia) * len + k]);
  }
}

}  // namespace voxax

// Backward: the closed-form sub-triangle splat.
//
// Moving the surface changes a voxel's average only through the part of the
// surface inside it. Each triangle is clipped in full 3D against the voxels
// (vertical triangles included) and every piece P in voxel v adds
//   g[v] / |voxel| * area(P) * nhat * beta_m(centroid of P)
// to corner m. Barycentric coordinates are carried through the clipping as
// linear attributes, so area(P) * beta_m(centroid) is integrated exactly over
// the fan of P. Only the cotangent values of voxels that pieces fall in are
// read. Triangles are independent: each writes its own three corners.
#pragma once

#include <cmath>
#include <cstdint>

#include "common/grid.h"
#include "voxelize/clip.h"
#include "voxelize/splat.h"

namespace voxax {

// Corner gradients of triangles [t0, t1) of one batch item into out (F, 3, 3).
// For a piece P, area(P) * beta_m(centroid of P) is the integral of beta_m
// over P; beta is affine, so it is evaluated at the piece's area centroid
// through the triangle's barycentric map beta_m(p) = r_m . (p - a).
// The cotangent is read through cotangent_of(i, j), which gives column (i, j)'s
// accessor: called with k, it returns the cotangent of cell (i, j, k) as a double.
template <typename T, typename CotangentOf>
void backward_triangles_3d_by(const GridSpec& g, const T* V, const int32_t* F,
                              CotangentOf&& cotangent_of, int64_t t0, int64_t t1, T* out) {
  const double inv_vol = 1.0 / g.cell_volume();
  Poly<3> P;
  TriangleFrame frame;
  for (int64_t t = t0; t < t1; ++t) {
    T* o = out + t * 9;
    if (!frame.load(V, F + 3 * t)) {
      for (int c = 0; c < 9; ++c) o[c] = static_cast<T>(0);
      continue;
    }
    frame.to_poly(&P);
    // Integrals over the surface of g * beta_m / |voxel|, m = 0, 1, 2.
    double acc[3] = {0, 0, 0};
    int64_t i0, i1, j0, j1, k0, k1;
    if (g.span(0, P.min(0), P.max(0), &i0, &i1) && g.span(1, P.min(1), P.max(1), &j0, &j1) &&
        g.span(2, P.min(2), P.max(2), &k0, &k1)) {
      sweep<3>(g, P, 0, g.first_cell(0, P.min(0)), i1, [&](int64_t i, const Poly<3>& Px) {
        if (i < 0) return;  // left of a window
        int64_t ja, jb;
        if (!g.span(1, Px.min(1), Px.max(1), &ja, &jb)) return;
        sweep<3>(g, Px, 1, ja, jb, [&](int64_t j, const Poly<3>& Pxy) {
          int64_t ka, kb;
          if (!g.span(2, Pxy.min(2), Pxy.max(2), &ka, &kb)) return;
          const auto Gcol = cotangent_of(i, j);
          sweep<3>(g, Pxy, 2, ka, kb, [&](int64_t k, const Poly<3>& Q) {
            const double gv = Gcol(k);
            if (gv == 0.0) return;
            double beta[3];
            frame.piece_integrals(Q, beta);
            const double s = gv * inv_vol;
            for (int m = 0; m < 3; ++m) acc[m] += s * beta[m];
          });
        });
      });
    }
    for (int c = 0; c < 3; ++c)
      for (int a = 0; a < 3; ++a) o[c * 3 + a] = static_cast<T>(acc[c] * frame.nh[a]);
  }
}

// The dense cotangent G (*grid) of one batch item.
template <typename T>
void backward_triangles_3d(const GridSpec& g, const T* V, const int32_t* F, const T* G, int64_t t0,
                           int64_t t1, T* out) {
  const int64_t ny = g.n[1], nz = g.n[2];
  backward_triangles_3d_by(
      g, V, F,
      [&](int64_t i, int64_t j) {
        const T* col = G + (i * ny + j) * nz;
        return [col](int64_t k) { return static_cast<double>(col[k]); };
      },
      t0, t1, out);
}

// Corner gradients of segments [s0, s1) of one batch item into out (F, 2, 2).
template <typename T>
void backward_segments_2d(const GridSpec& g, const T* V, const int32_t* F, const T* G, int64_t s0,
                          int64_t s1, T* out) {
  const double inv_area = 1.0 / g.cell_volume();
  const int64_t ny = g.n[1];
  Poly<3> S, Sx, Sy;
  for (int64_t s = s0; s < s1; ++s) {
    const int32_t* f = F + 2 * s;
    double p[2][2];
    for (int c = 0; c < 2; ++c)
      for (int a = 0; a < 2; ++a) p[c][a] = static_cast<double>(V[2 * int64_t(f[c]) + a]);
    const double dx = p[1][0] - p[0][0], dy = p[1][1] - p[0][1];
    const double len = std::sqrt(dx * dx + dy * dy);
    double acc[2] = {0, 0};
    if (len > 0 && std::isfinite(len)) {
      const double nh[2] = {dy / len, -dx / len};
      S.count = 2;
      for (int c = 0; c < 2; ++c) {
        S.v[c][0] = p[c][0];
        S.v[c][1] = p[c][1];
        S.v[c][2] = c == 1 ? 1.0 : 0.0;  // beta_1
      }
      int64_t i0, i1, j0, j1;
      if (g.span(0, S.min(0), S.max(0), &i0, &i1)) {
        for (int64_t i = i0; i <= i1; ++i) {
          if (!clip_segment(S, 0, g.plane(0, i), g.plane(0, i + 1), &Sx)) continue;
          if (i + 1 < g.cells_to_end(0) && Sx.min(0) >= g.plane(0, i + 1)) continue;
          if (!g.span(1, Sx.min(1), Sx.max(1), &j0, &j1)) continue;
          for (int64_t j = j0; j <= j1; ++j) {
            const double gv = static_cast<double>(G[i * ny + j]);
            if (gv == 0.0) continue;
            if (!clip_segment(Sx, 1, g.plane(1, j), g.plane(1, j + 1), &Sy)) continue;
            if (j + 1 < g.n[1] && Sy.min(1) >= g.plane(1, j + 1)) continue;
            const double ex = Sy.v[1][0] - Sy.v[0][0], ey = Sy.v[1][1] - Sy.v[0][1];
            const double L = ex * (dx / len) + ey * (dy / len);  // signed length along the segment
            const double b1 = 0.5 * (Sy.v[0][2] + Sy.v[1][2]);
            const double w = gv * inv_area * L;
            acc[0] += w * (1.0 - b1);
            acc[1] += w * b1;
          }
        }
      }
      for (int c = 0; c < 2; ++c)
        for (int a = 0; a < 2; ++a) out[(s * 2 + c) * 2 + a] = static_cast<T>(acc[c] * nh[a]);
      continue;
    }
    for (int c = 0; c < 4; ++c) out[s * 4 + c] = static_cast<T>(0);
  }
}

}  // namespace voxax

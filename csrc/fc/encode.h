// Faithful Contouring encoder: the surface pieces of every active cell and
// one QEF anchor per cell (or per connected component of its pieces).
//
// Every triangle is clipped into the cells it meets with the voxelizer's exact
// sweep (`clip.h`: x, then y, then z; half-open cells, the last one closed), so
// the pieces of a triangle partition it. For each piece the encoder records
// its area A, its area centroid and the triangle's unit normal. A cell's anchor
// minimizes, in cell-local coordinates u = (x - centre) / h (per axis),
//
//   sum_i w_i [lambda_n (n_i' . (u - u_i))^2 + lambda_d |u - u_i|^2],
//   w_i = A_i^p / sum A^p,
//
// where n_i' is the normal of the piece's plane in local coordinates
// (normalize(n_i * h)). The normal equations (lambda_d I + lambda_n sum w n'n'^T) u
// = lambda_d sum w u_i + lambda_n sum w n'n'^T u_i are solved by Cholesky
// (lambda_d > 0 keeps the matrix positive definite). When the solution leaves
// the cell it is clamped to the cell and moved to the closest point of the
// cell's own pieces (which lie in the closed cell). The token normal is
// normalize(sum w_i n_i) in world coordinates.
//
// Work is split into slabs of whole x-columns, processed independently: the
// triangles are binned to slabs in ascending order, each slab's pieces are
// sorted by (cell, face), and the slabs' outputs are concatenated in slab
// order, so the output is sorted by the C-order cell index and does not depend
// on the thread count.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <ctime>
#include <numeric>
#include <utility>
#include <vector>

#include "common/grid.h"
#include "spatial/bvh.h"
#include "voxelize/clip.h"
#include "voxelize/forward.h"
#include "voxelize/splat.h"

namespace voxax {
namespace fc {

struct Params {
  double lambda_n = 1.0;
  double lambda_d = 1e-3;
  double power = 1.0;
  bool clamp = true;
  bool components = false;  // one anchor per connected component of a cell's pieces
  bool faces = false;       // record each row's faces
  // Per face, bit k set when its edge k (corners k, k + 1) is an open boundary of the mesh
  // (used by this face alone), or null.
  const uint8_t* open = nullptr;
  // Cells (sorted) whose pieces get one anchor even with `components`.
  const int64_t* joined = nullptr;
  int64_t njoined = 0;
};

// One piece of a triangle in a cell: d is the area centroid relative to the
// cell centre (world units), n the triangle's unit normal.
struct Piece {
  int64_t cell;
  int32_t face;
  double area;
  double d[3];
  double n[3];
};

// Rows of a slab (or of the whole result after concatenation).
struct Rows {
  std::vector<int64_t> index;       // C-order cell index
  std::vector<int32_t> component;   // component within the cell (0 with one anchor per cell)
  std::vector<double> offset;       // (K, 3) anchor in cell units, within [-0.5, 0.5]
  std::vector<double> normal;       // (K, 3)
  std::vector<double> area;         // (K,) total piece area
  std::vector<int32_t> clamped;     // (K,) whether the anchor was clamped and projected
  std::vector<int64_t> face_count;  // (K,) faces of each row (when Params::faces)
  std::vector<int32_t> faces;
  // Pieces (for the partition checks).
  std::vector<int64_t> p_cell;
  std::vector<int32_t> p_face;
  std::vector<double> p_area, p_centroid;

  size_t size() const { return index.size(); }
};

// CPU time of the calling thread in seconds (for the stage times of VOXAX_FC_PROFILE, which
// should not count the time other processes take on a shared machine).
inline double thread_seconds() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return static_cast<double>(ts.tv_sec) + 1e-9 * static_cast<double>(ts.tv_nsec);
}

inline void load_tri(const double* V, const int32_t* F, int64_t t, double p[3][3]) {
  for (int c = 0; c < 3; ++c)
    for (int a = 0; a < 3; ++a) p[c][a] = V[3 * int64_t(F[3 * t + c]) + a];
}

// Unit normal of a triangle; false when degenerate.
inline bool unit_normal(const double p[3][3], double nh[3]) {
  double e1[3], e2[3];
  for (int a = 0; a < 3; ++a) {
    e1[a] = p[1][a] - p[0][a];
    e2[a] = p[2][a] - p[0][a];
  }
  const double N[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                       e1[0] * e2[1] - e1[1] * e2[0]};
  const double len = std::sqrt(N[0] * N[0] + N[1] * N[1] + N[2] * N[2]);
  if (!(len > 0) || !std::isfinite(len)) return false;
  for (int a = 0; a < 3; ++a) nh[a] = N[a] / len;
  return true;
}

inline double cell_centre(const GridSpec& g, int a, int64_t i) {
  return g.lo[a] + (static_cast<double>(i) + 0.5) * g.h[a];
}

// Calls visit(i, j, k, piece) for every piece of triangle p in the cells with
// i in [ia, ib) (the sweep of the voxelizer's backward kernel).
template <typename Visit>
inline void clip_triangle(const GridSpec& g, const double p[3][3], int64_t ia, int64_t ib,
                          Visit&& visit) {
  Poly<3> P;
  P.count = 3;
  for (int c = 0; c < 3; ++c)
    for (int a = 0; a < 3; ++a) P.v[c][a] = p[c][a];
  int64_t i0, i1, j0, j1, k0, k1;
  if (!g.span(0, P.min(0), P.max(0), &i0, &i1) || !g.span(1, P.min(1), P.max(1), &j0, &j1) ||
      !g.span(2, P.min(2), P.max(2), &k0, &k1))
    return;
  i0 = std::max(i0, ia);
  i1 = std::min(i1, ib - 1);
  if (i0 > i1) return;
  // A triangle inside one cell (below its upper planes) is its own piece: the sweeps would
  // pass it on unsplit, so it is visited as it is (most triangles of a fine mesh).
  if (i0 == i1 && j0 == j1 && k0 == k1) {
    const int64_t c[3] = {i0, j0, k0};
    bool inside = true;
    for (int a = 0; a < 3 && inside; ++a)
      inside = P.min(a) >= g.plane(a, c[a]) && P.max(a) < g.plane(a, c[a] + 1);
    if (inside) {
      visit(i0, j0, k0, P);
      return;
    }
  }
  sweep<3>(g, P, 0, i0, i1, [&](int64_t i, const Poly<3>& Px) {
    int64_t ja, jb;
    if (!g.span(1, Px.min(1), Px.max(1), &ja, &jb)) return;
    sweep<3>(g, Px, 1, ja, jb, [&](int64_t j, const Poly<3>& Pxy) {
      int64_t ka, kb;
      if (!g.span(2, Pxy.min(2), Pxy.max(2), &ka, &kb)) return;
      sweep<3>(g, Pxy, 2, ka, kb, [&](int64_t k, const Poly<3>& Q) { visit(i, j, k, Q); });
    });
  });
}

// Area and centroid offset (from `centre`) of a convex piece in the plane of
// unit normal nh, by a fan from its first vertex.
inline double piece_moments(const Poly<3>& Q, const double nh[3], const double centre[3],
                            double d[3]) {
  double M[3];
  const double* q0 = Q.v[0];
  const double A = fan_moments(Q, nh, q0, M);
  if (A > 0)
    for (int a = 0; a < 3; ++a) d[a] = (q0[a] - centre[a]) + M[a] / A;
  return A;
}

// Closest point to x on triangle t clipped to the closed cell (i, j, k);
// returns the squared distance (infinity when the clipped piece is empty).
inline double closest_on_piece(const GridSpec& g, const double* V, const int32_t* F, int32_t t,
                               const int64_t cell[3], const double x[3], double q[3]) {
  Poly<3> P, below, above;
  P.count = 3;
  double p[3][3];
  load_tri(V, F, t, p);
  for (int c = 0; c < 3; ++c)
    for (int a = 0; a < 3; ++a) P.v[c][a] = p[c][a];
  for (int a = 0; a < 3 && P.count >= 3; ++a) {
    split<3>(P, a, g.plane(a, cell[a]), &below, &above);
    P = above;
    if (P.count < 3) break;
    split<3>(P, a, g.plane(a, cell[a] + 1), &below, &above);
    P = below;
  }
  double best = INFINITY;
  if (P.count < 3) return best;
  for (int m = 1; m + 1 < P.count; ++m) {
    double bary[3], r[3];
    const double d2 = spatial::closest_on_triangle(x, P.v[0], P.v[m], P.v[m + 1], bary, r);
    if (d2 < best) {
      best = d2;
      for (int a = 0; a < 3; ++a) q[a] = r[a];
    }
  }
  return best;
}

// Solves the 3x3 symmetric positive definite system M u = b (M as xx, xy, xz,
// yy, yz, zz) by Cholesky; false when M is not numerically positive definite.
inline bool cholesky3(const double M[6], const double b[3], double u[3]) {
  const double l00 = std::sqrt(M[0]);
  if (!(l00 > 0)) return false;
  const double l10 = M[1] / l00, l20 = M[2] / l00;
  const double s11 = M[3] - l10 * l10;
  if (!(s11 > 0)) return false;
  const double l11 = std::sqrt(s11);
  const double l21 = (M[4] - l20 * l10) / l11;
  const double s22 = M[5] - l20 * l20 - l21 * l21;
  if (!(s22 > 0)) return false;
  const double l22 = std::sqrt(s22);
  const double y0 = b[0] / l00;
  const double y1 = (b[1] - l10 * y0) / l11;
  const double y2 = (b[2] - l20 * y0 - l21 * y1) / l22;
  u[2] = y2 / l22;
  u[1] = (y1 - l21 * u[2]) / l11;
  u[0] = (y0 - l10 * u[1] - l20 * u[2]) / l00;
  return std::isfinite(u[0]) && std::isfinite(u[1]) && std::isfinite(u[2]);
}

// Adds the open boundary edges of face t inside the closed cell ijk to the line terms
// B = sum L (I - d d^T) and Bm = sum L (I - d d^T) m (cell-local coordinates; L the
// clipped length, d its direction, m its midpoint).
inline void add_boundary(const GridSpec& g, const double* V, const int32_t* F, int32_t t,
                         uint8_t bits, const int64_t ijk[3], const double centre[3], double B[6],
                         double Bm[3], double* Ltot) {
  double p[3][3];
  load_tri(V, F, t, p);
  for (int k = 0; k < 3; ++k) {
    if (!(bits & (1u << k))) continue;
    const double* a = p[k];
    const double* b = p[(k + 1) % 3];
    double t0 = 0, t1 = 1;
    bool empty = false;
    for (int ax = 0; ax < 3 && !empty; ++ax) {
      const double lo = g.plane(ax, ijk[ax]), hi = g.plane(ax, ijk[ax] + 1);
      const double d = b[ax] - a[ax];
      if (d == 0) {
        empty = a[ax] < lo || a[ax] > hi;
      } else {
        double s0 = (lo - a[ax]) / d, s1 = (hi - a[ax]) / d;
        if (s0 > s1) std::swap(s0, s1);
        t0 = std::max(t0, s0);
        t1 = std::min(t1, s1);
        empty = !(t0 < t1);
      }
    }
    if (empty) continue;
    double u0[3], u1[3], dir[3], len = 0;
    for (int ax = 0; ax < 3; ++ax) {
      u0[ax] = (a[ax] + t0 * (b[ax] - a[ax]) - centre[ax]) * g.inv_h[ax];
      u1[ax] = (a[ax] + t1 * (b[ax] - a[ax]) - centre[ax]) * g.inv_h[ax];
      dir[ax] = u1[ax] - u0[ax];
      len += dir[ax] * dir[ax];
    }
    len = std::sqrt(len);
    if (!(len > 0) || !std::isfinite(len)) continue;
    for (int ax = 0; ax < 3; ++ax) dir[ax] /= len;
    const double P[6] = {1 - dir[0] * dir[0], -dir[0] * dir[1], -dir[0] * dir[2],
                         1 - dir[1] * dir[1], -dir[1] * dir[2], 1 - dir[2] * dir[2]};
    const double m[3] = {0.5 * (u0[0] + u1[0]), 0.5 * (u0[1] + u1[1]), 0.5 * (u0[2] + u1[2])};
    for (int e = 0; e < 6; ++e) B[e] += len * P[e];
    Bm[0] += len * (P[0] * m[0] + P[1] * m[1] + P[2] * m[2]);
    Bm[1] += len * (P[1] * m[0] + P[3] * m[1] + P[4] * m[2]);
    Bm[2] += len * (P[2] * m[0] + P[4] * m[1] + P[5] * m[2]);
    *Ltot += len;
  }
}

// Solves one anchor from pieces `ids` (indices into `pieces`, all of one cell)
// and appends its row.
inline void solve_row(const GridSpec& g, const Params& prm, const double* V, const int32_t* F,
                      const std::vector<Piece>& pieces, const std::vector<int32_t>& ids,
                      int32_t component, Rows* out) {
  const int64_t cell = pieces[ids[0]].cell;
  const int64_t ny = g.n[1], nz = g.n[2];
  const int64_t ijk[3] = {cell / (ny * nz), (cell / nz) % ny, cell % nz};
  double S0 = 0, Snn[6] = {0, 0, 0, 0, 0, 0}, Sc[3] = {0, 0, 0}, Snnc[3] = {0, 0, 0},
         Sn[3] = {0, 0, 0}, area = 0;
  auto weight = [&](double A) {
    if (prm.power == 1.0) return A;
    if (prm.power == 0.0) return 1.0;
    return std::pow(A, prm.power);
  };
  double wsum = 0;
  for (int32_t id : ids) wsum += weight(pieces[id].area);
  const bool uniform = !(wsum > 0) || !std::isfinite(wsum);
  for (int32_t id : ids) {
    const Piece& pc = pieces[id];
    const double w = uniform ? 1.0 : weight(pc.area);
    area += pc.area;
    double nl[3], u[3], len = 0;
    for (int a = 0; a < 3; ++a) {
      nl[a] = pc.n[a] * g.h[a];
      len += nl[a] * nl[a];
      u[a] = pc.d[a] * g.inv_h[a];
    }
    len = std::sqrt(len);
    for (int a = 0; a < 3; ++a) nl[a] /= len;
    const double nu = nl[0] * u[0] + nl[1] * u[1] + nl[2] * u[2];
    S0 += w;
    Snn[0] += w * nl[0] * nl[0];
    Snn[1] += w * nl[0] * nl[1];
    Snn[2] += w * nl[0] * nl[2];
    Snn[3] += w * nl[1] * nl[1];
    Snn[4] += w * nl[1] * nl[2];
    Snn[5] += w * nl[2] * nl[2];
    for (int a = 0; a < 3; ++a) {
      Sc[a] += w * u[a];
      Snnc[a] += w * nl[a] * nu;
      Sn[a] += w * pc.n[a];
    }
  }
  double M[6] = {prm.lambda_d * S0 + prm.lambda_n * Snn[0],
                 prm.lambda_n * Snn[1],
                 prm.lambda_n * Snn[2],
                 prm.lambda_d * S0 + prm.lambda_n * Snn[3],
                 prm.lambda_n * Snn[4],
                 prm.lambda_d * S0 + prm.lambda_n * Snn[5]};
  double b[3] = {prm.lambda_d * Sc[0] + prm.lambda_n * Snnc[0],
                 prm.lambda_d * Sc[1] + prm.lambda_n * Snnc[1],
                 prm.lambda_d * Sc[2] + prm.lambda_n * Snnc[2]};
  if (prm.open) {
    // Open boundaries in the cell: lines the anchor should lie on, with the weight of
    // the tangent planes (lambda_n, normalized by the total boundary length).
    double B[6] = {0, 0, 0, 0, 0, 0}, Bm[3] = {0, 0, 0}, L = 0;
    const double centre[3] = {cell_centre(g, 0, ijk[0]), cell_centre(g, 1, ijk[1]),
                              cell_centre(g, 2, ijk[2])};
    for (int32_t id : ids) {
      const uint8_t bits = prm.open[pieces[id].face];
      if (bits) add_boundary(g, V, F, pieces[id].face, bits, ijk, centre, B, Bm, &L);
    }
    if (L > 0) {
      const double s = prm.lambda_n * S0 / L;
      for (int e = 0; e < 6; ++e) M[e] += s * B[e];
      for (int a = 0; a < 3; ++a) b[a] += s * Bm[a];
    }
  }
  double u[3];
  if (!cholesky3(M, b, u))
    for (int a = 0; a < 3; ++a) u[a] = Sc[a] / S0;  // the mean centroid
  bool moved = false;
  for (int a = 0; a < 3; ++a) {
    if (!(u[a] >= -0.5)) {
      u[a] = -0.5;
      moved = true;
    } else if (u[a] > 0.5) {
      u[a] = 0.5;
      moved = true;
    }
  }
  if (moved && prm.clamp) {
    double x[3], centre[3], best = INFINITY, q[3], bq[3] = {0, 0, 0};
    for (int a = 0; a < 3; ++a) {
      centre[a] = cell_centre(g, a, ijk[a]);
      x[a] = centre[a] + u[a] * g.h[a];
    }
    for (int32_t id : ids) {
      const double d2 = closest_on_piece(g, V, F, pieces[id].face, ijk, x, q);
      if (d2 < best) {
        best = d2;
        for (int a = 0; a < 3; ++a) bq[a] = q[a];
      }
    }
    if (best < INFINITY)
      for (int a = 0; a < 3; ++a)
        u[a] = std::min(0.5, std::max(-0.5, (bq[a] - centre[a]) * g.inv_h[a]));
  }
  double nn = std::sqrt(Sn[0] * Sn[0] + Sn[1] * Sn[1] + Sn[2] * Sn[2]);
  double nrm[3];
  if (nn > 0 && std::isfinite(nn)) {
    for (int a = 0; a < 3; ++a) nrm[a] = Sn[a] / nn;
  } else {  // opposite normals cancel: take the largest piece's
    int32_t big = ids[0];
    for (int32_t id : ids)
      if (pieces[id].area > pieces[big].area) big = id;
    for (int a = 0; a < 3; ++a) nrm[a] = pieces[big].n[a];
  }
  out->index.push_back(cell);
  out->component.push_back(component);
  for (int a = 0; a < 3; ++a) {
    out->offset.push_back(u[a]);
    out->normal.push_back(nrm[a]);
  }
  out->area.push_back(area);
  out->clamped.push_back(moved ? 1 : 0);
  if (prm.faces) {
    out->face_count.push_back(static_cast<int64_t>(ids.size()));
    for (int32_t id : ids) out->faces.push_back(pieces[id].face);
  }
}

// Per face, bit k set when its edge k (corners k, k + 1) belongs to no other face. The
// face edges are bucketed by their lower vertex (a counting sort, each with its upper
// vertex beside it), and each bucket, a vertex's few edges, is scanned for repeats of the
// upper vertex.
inline std::vector<uint8_t> open_edges(const int32_t* F, int64_t nf) {
  int64_t nv = 0;
  for (int64_t i = 0; i < 3 * nf; ++i) nv = std::max<int64_t>(nv, int64_t(F[i]) + 1);
  std::vector<int64_t> start(nv + 1, 0);
  for (int64_t t = 0; t < nf; ++t)
    for (int k = 0; k < 3; ++k) ++start[std::min(F[3 * t + k], F[3 * t + (k + 1) % 3]) + 1];
  for (int64_t v = 0; v < nv; ++v) start[v + 1] += start[v];
  std::vector<int64_t> edge(3 * nf);  // 3 t + k, bucketed by the lower vertex
  std::vector<int32_t> up(3 * nf);    // the upper vertex of each bucketed edge
  {
    std::vector<int64_t> fill(start.begin(), start.end() - 1);
    for (int64_t t = 0; t < nf; ++t)
      for (int k = 0; k < 3; ++k) {
        const int32_t a = F[3 * t + k], b = F[3 * t + (k + 1) % 3];
        const int64_t at = fill[std::min(a, b)]++;
        edge[at] = 3 * t + k;
        up[at] = std::max(a, b);
      }
  }
  std::vector<uint8_t> bits(nf, 0);
  auto mark = [&](int64_t e) { bits[e / 3] |= static_cast<uint8_t>(1u << (e % 3)); };
  std::vector<std::pair<int32_t, int64_t>> big;
  for (int64_t v = 0; v < nv; ++v) {
    const int64_t b = start[v], e = start[v + 1];
    if (e - b <= 32) {
      for (int64_t i = b; i < e; ++i) {
        bool shared = false;
        for (int64_t j = b; j < e && !shared; ++j) shared = j != i && up[j] == up[i];
        if (!shared) mark(edge[i]);
      }
    } else {  // a vertex of high degree: sort its edges by the upper vertex
      big.clear();
      for (int64_t i = b; i < e; ++i) big.emplace_back(up[i], edge[i]);
      std::sort(big.begin(), big.end());
      for (size_t i = 0; i < big.size(); ++i) {
        const bool prev = i > 0 && big[i - 1].first == big[i].first;
        const bool next = i + 1 < big.size() && big[i + 1].first == big[i].first;
        if (!prev && !next) mark(big[i].second);
      }
    }
  }
  return bits;
}

// Whether segment ab meets the closed box [lo, hi] (slab test).
inline bool segment_meets_box(const double* a, const double* b, const double lo[3],
                              const double hi[3]) {
  double t0 = 0, t1 = 1;
  for (int ax = 0; ax < 3; ++ax) {
    const double d = b[ax] - a[ax];
    if (d == 0) {
      if (a[ax] < lo[ax] || a[ax] > hi[ax]) return false;
      continue;
    }
    double s0 = (lo[ax] - a[ax]) / d, s1 = (hi[ax] - a[ax]) / d;
    if (s0 > s1) std::swap(s0, s1);
    t0 = std::max(t0, s0);
    t1 = std::min(t1, s1);
    if (t0 > t1) return false;
  }
  return true;
}

// Whether the pieces of faces s and t in the closed cell [lo, hi] are joined: the faces
// share a mesh edge (two vertex indices) and that edge passes through the cell.
inline bool joined_in_cell(const double* V, const int32_t* F, int32_t s, int32_t t,
                           const double lo[3], const double hi[3]) {
  int32_t common[2] = {0, 0};
  int n = 0;
  for (int c = 0; c < 3; ++c)
    for (int e = 0; e < 3; ++e)
      if (F[3 * int64_t(s) + c] == F[3 * int64_t(t) + e]) {
        if (n < 2) common[n] = F[3 * int64_t(s) + c];
        ++n;
        break;
      }
  if (n < 2) return false;
  return segment_meets_box(V + 3 * int64_t(common[0]), V + 3 * int64_t(common[1]), lo, hi);
}

// Sorts `keys` stably by their high 32 bits, of which only the lowest `bits` may be set
// (least significant digit first, 11-bit digits).
inline void radix_sort_high(std::vector<uint64_t>* keys, int bits) {
  constexpr int kDigit = 11;
  std::vector<uint64_t> tmp(keys->size());
  for (int shift = 0; shift < bits; shift += kDigit) {
    std::vector<size_t> count((size_t{1} << kDigit) + 1, 0);
    for (uint64_t k : *keys) ++count[((k >> (32 + shift)) & ((1u << kDigit) - 1)) + 1];
    for (size_t d = 1; d < count.size(); ++d) count[d] += count[d - 1];
    for (uint64_t k : *keys) tmp[count[(k >> (32 + shift)) & ((1u << kDigit) - 1)]++] = k;
    keys->swap(tmp);
  }
}

// The rows of the cells of one slab [ia, ib). With `pieces_only`, records the
// pieces instead.
inline void encode_slab(const GridSpec& g, const Params& prm, const double* V, const int32_t* F,
                        const Bins& bins, int64_t slab, int64_t ia, int64_t ib, bool pieces_only,
                        Rows* out, double* seconds = nullptr) {
  double t0 = seconds ? thread_seconds() : 0.0;
  auto lap = [&](int k) {
    if (!seconds) return;
    const double t = thread_seconds();
    seconds[k] += t - t0;
    t0 = t;
  };
  std::vector<Piece> pieces;
  pieces.reserve(static_cast<size_t>(bins.start[slab + 1] - bins.start[slab]));
  const int64_t ny = g.n[1], nz = g.n[2];
  for (int64_t e = bins.start[slab]; e < bins.start[slab + 1]; ++e) {
    const int32_t t = bins.items[e];
    double p[3][3], nh[3];
    load_tri(V, F, t, p);
    if (!unit_normal(p, nh)) continue;
    clip_triangle(g, p, ia, ib, [&](int64_t i, int64_t j, int64_t k, const Poly<3>& Q) {
      const double centre[3] = {cell_centre(g, 0, i), cell_centre(g, 1, j), cell_centre(g, 2, k)};
      Piece pc;
      pc.area = piece_moments(Q, nh, centre, pc.d);
      if (!(pc.area > 0) || !std::isfinite(pc.area)) return;
      pc.cell = (i * ny + j) * nz + k;
      pc.face = t;
      for (int a = 0; a < 3; ++a) pc.n[a] = nh[a];
      pieces.push_back(pc);
    });
  }
  lap(0);
  // Sort by (cell, face). The pieces come in increasing face order (the bins list faces in
  // increasing order, and a face has one piece per cell), so a stable radix sort of packed
  // keys (cell within the slab, position) by the cell gives the (cell, face) order; the
  // pieces stay where they are and are visited through `order`.
  const int64_t base = ia * ny * nz;
  const int64_t span = (ib - ia) * ny * nz;
  std::vector<uint32_t> order(pieces.size());
  if (span <= INT64_C(0xFFFFFFFF) && pieces.size() <= size_t{0x7FFFFFFF}) {
    std::vector<uint64_t> key(pieces.size());
    for (size_t r = 0; r < pieces.size(); ++r)
      key[r] = (static_cast<uint64_t>(pieces[r].cell - base) << 32) | r;
    int bits = 0;
    while (bits < 32 && (INT64_C(1) << bits) < span) ++bits;
    radix_sort_high(&key, bits);
    for (size_t r = 0; r < key.size(); ++r) order[r] = static_cast<uint32_t>(key[r]);
  } else {
    std::iota(order.begin(), order.end(), 0u);
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
      return pieces[a].cell < pieces[b].cell ||
             (pieces[a].cell == pieces[b].cell && pieces[a].face < pieces[b].face);
    });
  }
  lap(1);
  if (pieces_only) {
    for (uint32_t r : order) {
      const Piece& pc = pieces[r];
      const int64_t ijk[3] = {pc.cell / (ny * nz), (pc.cell / nz) % ny, pc.cell % nz};
      out->p_cell.push_back(pc.cell);
      out->p_face.push_back(pc.face);
      out->p_area.push_back(pc.area);
      for (int a = 0; a < 3; ++a) {
        const double c = cell_centre(g, a, ijk[a]) + pc.d[a];
        out->p_centroid.push_back(
            std::min(g.plane(a, ijk[a] + 1), std::max(g.plane(a, ijk[a]), c)));
      }
    }
    return;
  }
  std::vector<int32_t> ids, parent;
  std::vector<std::vector<int32_t>> groups;
  size_t s = 0;
  while (s < order.size()) {
    size_t e = s;
    while (e < order.size() && pieces[order[e]].cell == pieces[order[s]].cell) ++e;
    const int32_t m = static_cast<int32_t>(e - s);
    const int64_t cell = pieces[order[s]].cell;
    if (!prm.components || m == 1 ||
        std::binary_search(prm.joined, prm.joined + prm.njoined, cell)) {
      ids.resize(m);
      for (int32_t r = 0; r < m; ++r) ids[r] = static_cast<int32_t>(order[s + r]);
      solve_row(g, prm, V, F, pieces, ids, 0, out);
    } else {
      // Union-find over pieces whose faces share a mesh edge; components are
      // numbered by their lowest face.
      const int64_t ijk[3] = {cell / (ny * nz), (cell / nz) % ny, cell % nz};
      double lo[3], hi[3];
      for (int a = 0; a < 3; ++a) {
        lo[a] = g.plane(a, ijk[a]);
        hi[a] = g.plane(a, ijk[a] + 1);
      }
      parent.resize(m);
      std::iota(parent.begin(), parent.end(), 0);
      auto find = [&](int32_t x) {
        while (parent[x] != x) x = parent[x] = parent[parent[x]];
        return x;
      };
      for (int32_t a = 0; a < m; ++a)
        for (int32_t b = a + 1; b < m; ++b)
          if (joined_in_cell(V, F, pieces[order[s + a]].face, pieces[order[s + b]].face, lo, hi)) {
            const int32_t ra = find(a), rb = find(b);
            if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
          }
      int32_t comp = 0;
      for (int32_t a = 0; a < m; ++a) {
        if (find(a) != a) continue;
        ids.clear();
        for (int32_t b = a; b < m; ++b)
          if (find(b) == a) ids.push_back(static_cast<int32_t>(order[s + b]));
        solve_row(g, prm, V, F, pieces, ids, comp++, out);
      }
    }
    s = e;
  }
  lap(2);
}

}  // namespace fc
}  // namespace voxax

// A bounding volume hierarchy over triangles, in float64: closest points on the
// mesh and ray hits (first, any, all).
//
// Build: binned surface-area heuristic over triangle centroids (kBins bins per
// axis, leaves of at most kMaxLeaf triangles unless the centroids coincide),
// single-threaded and deterministic. The triangles are stored in tree order as
// nine doubles each, next to their original face indices.
//
// Traversal layout: one 128-byte record per inner node holds both children's
// boxes in float (rounded outwards, so they contain the float64 boxes) and a flat
// cylinder per child (disk around the area-weighted mean normal of its
// triangles, thickened to contain their vertices). Closest-point searches prune
// with the larger of the box and cylinder distances; the cylinder's distance is
// shrunk by a margin far above its rounding and that of the point-triangle
// distance, so no node holding the answer (or a tie) is ever pruned. On a smooth
// surface the cylinder sticks out towards a far point only by the patch's
// thickness where the box sticks out by its own size, which is what keeps the
// search for points far from the surface to a few nodes per level.
//
// Closest point: the exact point-triangle distance by region classification
// (vertex, edge and face regions of the triangle, tested on the dot products of
// the point with the edges), with a fallback to the three edges as segments for
// triangles whose area is negligible (|n|^2 <= 1e-24 * e_max^4), so degenerate
// triangles are handled and never divide by zero. Equal distances resolve to
// the lowest face index.
//
// Rays: the watertight ray-triangle test of Woop, Benthin and Wald (2013). The
// ray is translated to the origin, its largest direction component becomes z,
// and a shear maps the ray onto the z axis; the three 2D edge functions of the
// sheared triangle then decide the hit. A shared edge yields bit-for-bit negated
// edge functions in its two triangles, so no ray slips between them. Where an
// edge function is exactly zero (the ray meets an edge or a vertex), a
// tie-breaking rule on the edge's sheared 2D direction counts the hit for
// exactly one of two consistently oriented triangles sharing that edge. Rays in
// a triangle's plane never hit it. Box tests use the robust slab test with the
// far distance scaled by 1 + 2 gamma_3 (Ize 2013).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

namespace voxax {
namespace spatial {

// Two doubles processed together (SSE2 on x86-64; plain code elsewhere): the traversals
// evaluate both children of a record at once.
typedef double V2d __attribute__((vector_size(16)));
typedef long long V2l __attribute__((vector_size(16)));
inline V2d v2_load(const float* f) {
  return V2d{static_cast<double>(f[0]), static_cast<double>(f[1])};
}
inline V2d v2_splat(double x) { return V2d{x, x}; }
inline V2d v2_select(V2l m, V2d a, V2d b) {  // m ? a : b, lane by lane
#if defined(__GNUC__) && !defined(__clang__)
  return m ? a : b;
#else
  return (V2d)(((V2l)a & m) | ((V2l)b & ~m));
#endif
}
inline V2d v2_max(V2d a, V2d b) { return v2_select(a > b, a, b); }  // a > b ? a : b
inline V2d v2_min(V2d a, V2d b) { return v2_select(a < b, a, b); }  // a < b ? a : b
inline V2d v2_sqrt(V2d x) {
#if defined(__SSE2__) && defined(__GNUC__) && !defined(__clang__)
  return __builtin_ia32_sqrtpd(x);
#else
  return V2d{std::sqrt(x[0]), std::sqrt(x[1])};
#endif
}

struct Box3 {
  double lo[3] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity(),
                  std::numeric_limits<double>::infinity()};
  double hi[3] = {-std::numeric_limits<double>::infinity(),
                  -std::numeric_limits<double>::infinity(),
                  -std::numeric_limits<double>::infinity()};
  void grow(const double* p) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], p[a]);
      hi[a] = std::max(hi[a], p[a]);
    }
  }
  void grow(const Box3& b) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], b.lo[a]);
      hi[a] = std::max(hi[a], b.hi[a]);
    }
  }
  bool empty() const { return !(lo[0] <= hi[0]); }
  double half_area() const {
    if (empty()) return 0.0;
    const double x = hi[0] - lo[0], y = hi[1] - lo[1], z = hi[2] - lo[2];
    return x * y + y * z + z * x;
  }
  // Squared distance from p to the box (0 inside).
  double dist2(const double* p) const {
    double s = 0.0;
    for (int a = 0; a < 3; ++a) {
      double d = 0.0;
      if (p[a] < lo[a])
        d = lo[a] - p[a];
      else if (p[a] > hi[a])
        d = p[a] - hi[a];
      s += d * d;
    }
    return s;
  }
};

struct Node {
  Box3 box;
  int32_t first = 0;  // leaf: first triangle; inner: index of the left child
  int32_t count = 0;  // leaf: number of triangles (> 0); inner: 0 (right child = left + 1)
};

struct ClosestResult {
  double dist2 = std::numeric_limits<double>::infinity();
  int32_t face = -1;
  int32_t slot = -1;  // position of the face in tree order (a warm start for a nearby query)
  double bary[3] = {0, 0, 0};
  double point[3] = {0, 0, 0};
};

struct RayHit {
  double t = std::numeric_limits<double>::infinity();
  int32_t face = -1;
  double bary[3] = {0, 0, 0};
  int8_t sign = 0;  // -1: the ray crosses against the face normal (enters), +1: along it
};

// Writes ray i's hit into the output arrays (t, face, barycentrics, sign), or no hit
// (t = inf, face -1, zeros) when `hit` is false.
template <typename Sign>
inline void store_hit(bool hit, const RayHit& h, int64_t i, double* t, int32_t* face, double* bary,
                      Sign* sign) {
  t[i] = hit ? h.t : std::numeric_limits<double>::infinity();
  face[i] = hit ? h.face : -1;
  sign[i] = static_cast<Sign>(hit ? h.sign : 0);
  for (int a = 0; a < 3; ++a) bary[3 * i + a] = hit ? h.bary[a] : 0.0;
}

// Closest point of triangle (a, b, c) to p. Writes barycentrics (of a, b, c)
// and the point; returns the squared distance.
inline double closest_on_segment(const double* p, const double* a, const double* b, double* t_out,
                                 double* q) {
  double ab[3], ap[3];
  for (int i = 0; i < 3; ++i) {
    ab[i] = b[i] - a[i];
    ap[i] = p[i] - a[i];
  }
  const double len2 = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
  double t = 0.0;
  if (len2 > 0.0) {
    t = (ap[0] * ab[0] + ap[1] * ab[1] + ap[2] * ab[2]) / len2;
    t = std::min(1.0, std::max(0.0, t));
  }
  double d2 = 0.0;
  for (int i = 0; i < 3; ++i) {
    q[i] = a[i] + t * ab[i];
    const double d = p[i] - q[i];
    d2 += d * d;
  }
  *t_out = t;
  return d2;
}

// Whether a triangle's area is negligible: |n|^2 <= 1e-24 e_max^4 (then it is
// treated as the union of its edges).
inline bool triangle_degenerate(const double* a, const double* b, const double* c) {
  double ab[3], ac[3], bc[3];
  for (int i = 0; i < 3; ++i) {
    ab[i] = b[i] - a[i];
    ac[i] = c[i] - a[i];
    bc[i] = c[i] - b[i];
  }
  const double n[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2],
                       ab[0] * ac[1] - ab[1] * ac[0]};
  const double n2 = n[0] * n[0] + n[1] * n[1] + n[2] * n[2];
  const double lab = ab[0] * ab[0] + ab[1] * ab[1] + ab[2] * ab[2];
  const double lac = ac[0] * ac[0] + ac[1] * ac[1] + ac[2] * ac[2];
  const double lbc = bc[0] * bc[0] + bc[1] * bc[1] + bc[2] * bc[2];
  const double emax = std::max(lab, std::max(lac, lbc));
  return !(n2 > 1e-24 * emax * emax);
}

inline double closest_on_triangle(const double* p, const double* a, const double* b,
                                  const double* c, double* bary, double* q, bool degenerate);
inline double closest_on_triangle(const double* p, const double* a, const double* b,
                                  const double* c, double* bary, double* q) {
  return closest_on_triangle(p, a, b, c, bary, q, triangle_degenerate(a, b, c));
}
// The closest point of the triangle's edges (as segments) to p: always finite.
inline double closest_on_edges(const double* p, const double* a, const double* b, const double* c,
                               double* bary, double* q) {
  double best = std::numeric_limits<double>::infinity(), t, tmp[3];
  const double* ends[3][2] = {{a, b}, {b, c}, {c, a}};
  for (int e = 0; e < 3; ++e) {
    const double d2 = closest_on_segment(p, ends[e][0], ends[e][1], &t, tmp);
    if (d2 < best) {
      best = d2;
      double w[3] = {0, 0, 0};
      w[e] = 1.0 - t;
      w[(e + 1) % 3] = t;
      for (int i = 0; i < 3; ++i) {
        bary[i] = w[i];
        q[i] = tmp[i];
      }
    }
  }
  return best;
}

inline double closest_by_regions(const double* p, const double* a, const double* b, const double* c,
                                 double* bary, double* q);

// Far from a triangle (|p - a| e_max >> |n|, beyond about 1e15 times its size) the
// dot products of the region classification cancel: its weights can come out as 0 / 0,
// 1 / 0 or far outside [0, 1], and the point as NaN. Such a result is replaced by the
// closest point of the edges, which is finite and, at that range, as close as rounding
// can tell (any point of the triangle is). Weights a few ulps outside [0, 1] near an
// edge are kept (the point stays on the triangle within rounding).
inline double closest_on_triangle(const double* p, const double* a, const double* b,
                                  const double* c, double* bary, double* q, bool degenerate) {
  if (degenerate) return closest_on_edges(p, a, b, c, bary, q);
  const double d2 = closest_by_regions(p, a, b, c, bary, q);
  constexpr double kSlack = 1e-9;
  bool ok = d2 < std::numeric_limits<double>::infinity();
  for (int i = 0; i < 3; ++i) ok = ok && bary[i] >= -kSlack && bary[i] <= 1.0 + kSlack;
  return ok ? d2 : closest_on_edges(p, a, b, c, bary, q);
}

// The region classification (the vertex, edge and face regions of the triangle, tested
// on the dot products of p - a, p - b and p - c with the edges ab and ac).
inline double closest_by_regions(const double* p, const double* a, const double* b, const double* c,
                                 double* bary, double* q) {
  double ab[3], ac[3], ap[3];
  for (int i = 0; i < 3; ++i) {
    ab[i] = b[i] - a[i];
    ac[i] = c[i] - a[i];
    ap[i] = p[i] - a[i];
  }
  auto dot = [](const double* u, const double* v) {
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2];
  };
  auto finish = [&](double wa, double wb, double wc) {
    bary[0] = wa;
    bary[1] = wb;
    bary[2] = wc;
    double d2 = 0.0;
    for (int i = 0; i < 3; ++i) {
      q[i] = wa * a[i] + wb * b[i] + wc * c[i];
      const double d = p[i] - q[i];
      d2 += d * d;
    }
    return d2;
  };
  // Vertex region of a.
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  if (d1 <= 0.0 && d2 <= 0.0) return finish(1, 0, 0);
  // Vertex region of b.
  double bp[3];
  for (int i = 0; i < 3; ++i) bp[i] = p[i] - b[i];
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  if (d3 >= 0.0 && d4 <= d3) return finish(0, 1, 0);
  // Edge region of ab.
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) {
    const double v = d1 / (d1 - d3);  // d1 - d3 = |ab|^2 > 0 here
    return finish(1 - v, v, 0);
  }
  // Vertex region of c.
  double cp[3];
  for (int i = 0; i < 3; ++i) cp[i] = p[i] - c[i];
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  if (d6 >= 0.0 && d5 <= d6) return finish(0, 0, 1);
  // Edge region of ac.
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) {
    const double w = d2 / (d2 - d6);
    return finish(1 - w, 0, w);
  }
  // Edge region of bc.
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return finish(0, 1 - w, w);
  }
  // Face region: va + vb + vc = |n|^2 > 0.
  const double denom = 1.0 / (va + vb + vc);
  const double v = vb * denom, w = vc * denom;
  return finish(1 - v - w, v, w);
}

// A ray prepared for the watertight test and the slab test.
struct Ray {
  double org[3], dir[3];
  double tmin, tmax;
  int kx, ky, kz;
  double sx, sy, sz;
  double inv[3];
  bool flat[3];  // dir[a] == 0
};

inline Ray make_ray(const double* o, const double* d, double tmin, double tmax) {
  Ray r;
  for (int a = 0; a < 3; ++a) {
    r.org[a] = o[a];
    r.dir[a] = d[a];
    r.flat[a] = d[a] == 0.0;
    r.inv[a] = r.flat[a] ? 0.0 : 1.0 / d[a];
  }
  r.tmin = tmin;
  r.tmax = tmax;
  const double ax = std::fabs(d[0]), ay = std::fabs(d[1]), az = std::fabs(d[2]);
  r.kz = (ax >= ay && ax >= az) ? 0 : (ay >= az ? 1 : 2);
  r.kx = (r.kz + 1) % 3;
  r.ky = (r.kx + 1) % 3;
  if (d[r.kz] < 0.0) std::swap(r.kx, r.ky);  // keep the winding
  r.sx = d[r.kx] / d[r.kz];
  r.sy = d[r.ky] / d[r.kz];
  r.sz = 1.0 / d[r.kz];
  return r;
}

// Robust slab test: the entry distance, or +inf when the box is missed within
// [tmin, tfar].
inline double ray_box(const Ray& r, const Box3& b, double tfar) {
  constexpr double kGrow =
      1.0 + 2.0 * (3.0 * 1.1102230246251565e-16 / (1.0 - 3.0 * 1.1102230246251565e-16));
  double t0 = r.tmin, t1 = tfar;
  for (int a = 0; a < 3; ++a) {
    if (r.flat[a]) {
      if (r.org[a] < b.lo[a] || r.org[a] > b.hi[a]) return std::numeric_limits<double>::infinity();
      continue;
    }
    double tn = (b.lo[a] - r.org[a]) * r.inv[a];
    double tf = (b.hi[a] - r.org[a]) * r.inv[a];
    if (tn > tf) std::swap(tn, tf);
    tf *= kGrow;
    t0 = tn > t0 ? tn : t0;
    t1 = tf < t1 ? tf : t1;
    if (t0 > t1) return std::numeric_limits<double>::infinity();
  }
  return t0;
}

// Whether a zero edge function counts as inside: exactly one of an edge
// direction (dx, dy) != 0 and its reverse passes.
inline bool edge_owns(double dx, double dy) { return dy > 0.0 || (dy == 0.0 && dx > 0.0); }

// The watertight test. On a hit within [r.tmin, tmax] fills *hit and returns true.
inline bool ray_triangle(const Ray& r, const double* tri, double tmax, RayHit* hit) {
  const double* A = tri;
  const double* B = tri + 3;
  const double* C = tri + 6;
  double a[3], b[3], c[3];
  for (int i = 0; i < 3; ++i) {
    a[i] = A[i] - r.org[i];
    b[i] = B[i] - r.org[i];
    c[i] = C[i] - r.org[i];
  }
  const double ax = a[r.kx] - r.sx * a[r.kz], ay = a[r.ky] - r.sy * a[r.kz];
  const double bx = b[r.kx] - r.sx * b[r.kz], by = b[r.ky] - r.sy * b[r.kz];
  const double cx = c[r.kx] - r.sx * c[r.kz], cy = c[r.ky] - r.sy * c[r.kz];
  const double U = cx * by - cy * bx;  // edge c -> b (weight of a)
  const double V = ax * cy - ay * cx;  // edge a -> c (weight of b)
  const double W = bx * ay - by * ax;  // edge b -> a (weight of c)
  if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
  const double det = U + V + W;
  if (det == 0.0) return false;
  const double s = det > 0.0 ? 1.0 : -1.0;
  // Zero edge functions: the ray meets that edge; one owner per edge direction.
  if (U == 0.0 && !edge_owns(s * (bx - cx), s * (by - cy))) return false;
  if (V == 0.0 && !edge_owns(s * (cx - ax), s * (cy - ay))) return false;
  if (W == 0.0 && !edge_owns(s * (ax - bx), s * (ay - by))) return false;
  const double az = r.sz * a[r.kz], bz = r.sz * b[r.kz], cz = r.sz * c[r.kz];
  const double T = U * az + V * bz + W * cz;
  const double t = T / det;
  if (!(t >= r.tmin && t <= tmax)) return false;
  hit->t = t;
  hit->bary[0] = U / det;
  hit->bary[1] = V / det;
  hit->bary[2] = W / det;
  // The sign of the crossing from the geometric normal (exactly where it is not tiny).
  double ab[3], ac[3];
  for (int i = 0; i < 3; ++i) {
    ab[i] = B[i] - A[i];
    ac[i] = C[i] - A[i];
  }
  const double nd = (ab[1] * ac[2] - ab[2] * ac[1]) * r.dir[0] +
                    (ab[2] * ac[0] - ab[0] * ac[2]) * r.dir[1] +
                    (ab[0] * ac[1] - ab[1] * ac[0]) * r.dir[2];
  hit->sign = nd < 0.0 ? -1 : (nd > 0.0 ? 1 : 0);
  return true;
}

// The crossing of a ray with a triangle for winding numbers, decided only where it is
// clear-cut: +1 (the ray leaves through the triangle's front, along its normal: the
// sheared triangle's area is negative), -1 (it enters), 0 (a clear miss, or a hit at t < -margin),
// or kUnclear where an edge function is exactly 0 (the ray meets an edge or a vertex, or lies in
// the triangle's plane) or the hit lies within `margin` of the origin. The edge functions are the
// watertight test's, computed per vertex and per edge exactly as in ray_triangle, so two triangles
// sharing an edge see it with negated bits: on a closed chain the decided crossings of one ray sum
// to the winding number at its origin.
constexpr int kUnclear = 2;
inline int ray_crossing(const Ray& r, const double* tri, double margin) {
  double a[3], b[3], c[3];
  bool near_box = true;
  for (int i = 0; i < 3; ++i) {
    a[i] = tri[i] - r.org[i];
    b[i] = tri[3 + i] - r.org[i];
    c[i] = tri[6 + i] - r.org[i];
    near_box = near_box && std::min(a[i], std::min(b[i], c[i])) <= margin &&
               std::max(a[i], std::max(b[i], c[i])) >= -margin;
  }
  if (near_box) {
    // The origin within `margin` of the triangle's box and plane (on the surface, or
    // within rounding of it): unclear, whatever the ray does there.
    const double e1[3] = {b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    const double e2[3] = {c[0] - a[0], c[1] - a[1], c[2] - a[2]};
    const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2],
                         e1[0] * e2[1] - e1[1] * e2[0]};
    const double nn = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
    if (!(std::fabs(n[0] * a[0] + n[1] * a[1] + n[2] * a[2]) > margin * nn)) return kUnclear;
  }
  const double ax = a[r.kx] - r.sx * a[r.kz], ay = a[r.ky] - r.sy * a[r.kz];
  const double bx = b[r.kx] - r.sx * b[r.kz], by = b[r.ky] - r.sy * b[r.kz];
  const double cx = c[r.kx] - r.sx * c[r.kz], cy = c[r.ky] - r.sy * c[r.kz];
  const double U = cx * by - cy * bx;
  const double V = ax * cy - ay * cx;
  const double W = bx * ay - by * ax;
  if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return 0;
  if (U == 0.0 || V == 0.0 || W == 0.0) return kUnclear;
  const double det = U + V + W;  // U, V, W share a strict sign: det != 0
  const double T = U * (r.sz * a[r.kz]) + V * (r.sz * b[r.kz]) + W * (r.sz * c[r.kz]);
  const double t = T / det;
  if (t > margin) return det > 0.0 ? -1 : 1;
  if (t < -margin) return 0;
  return kUnclear;
}

class Bvh {
 public:
  static constexpr int kBins = 16;
  static constexpr int kMaxLeaf = 4;

  // V: (nv, 3), F: (nf, 3), both validated by the caller.
  void build(const double* V, const int32_t* F, int64_t nf) {
    const int32_t n = static_cast<int32_t>(nf);
    tris_.assign(static_cast<size_t>(n) * 9, 0.0);
    ids_.resize(n);
    degenerate_.assign(n, 0);
    tri_boxes_.assign(n, Box3());
    nodes_.clear();
    std::vector<Box3> boxes(n);
    std::vector<std::array<double, 3>> cent(n);
    std::vector<int32_t> order(n);
    for (int32_t f = 0; f < n; ++f) {
      order[f] = f;
      for (int k = 0; k < 3; ++k)
        boxes[f].grow(V + 3 * static_cast<int64_t>(F[3 * int64_t(f) + k]));
      for (int a = 0; a < 3; ++a) cent[f][a] = 0.5 * (boxes[f].lo[a] + boxes[f].hi[a]);
    }
    if (n == 0) return;
    nodes_.reserve(2 * static_cast<size_t>(n / kMaxLeaf + 1));
    ranges_.assign(2 * static_cast<size_t>(n) + 1, {0, 0});
    nodes_.emplace_back();
    struct Task {
      int32_t node, begin, end;
    };
    std::vector<Task> stack{{0, 0, n}};
    while (!stack.empty()) {
      const Task task = stack.back();
      stack.pop_back();
      Node& node = nodes_[task.node];
      Box3 cb;
      for (int32_t i = task.begin; i < task.end; ++i) {
        node.box.grow(boxes[order[i]]);
        cb.grow(cent[order[i]].data());
      }
      const int32_t count = task.end - task.begin;
      int32_t mid = -1;
      if (count > kMaxLeaf) mid = split(boxes, cent, order, task.begin, task.end, node.box, cb);
      ranges_[task.node] = {task.begin, task.end};
      if (mid < 0) {
        nodes_[task.node].first = task.begin;
        nodes_[task.node].count = count;
        continue;
      }
      const int32_t left = static_cast<int32_t>(nodes_.size());
      nodes_[task.node].first = left;
      nodes_[task.node].count = 0;
      nodes_.emplace_back();
      nodes_.emplace_back();
      stack.push_back({left + 1, mid, task.end});
      stack.push_back({left, task.begin, mid});
    }
    for (int32_t i = 0; i < n; ++i) {
      const int32_t f = order[i];
      ids_[i] = f;
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a)
          tris_[9 * static_cast<size_t>(i) + 3 * k + a] =
              V[3 * static_cast<int64_t>(F[3 * int64_t(f) + k]) + a];
      const double* t = &tris_[9 * static_cast<size_t>(i)];
      degenerate_[i] = triangle_degenerate(t, t + 3, t + 6) ? 1 : 0;
      tri_boxes_[i] = boxes[f];
    }
    build_pairs();
  }

  int64_t node_count() const { return static_cast<int64_t>(nodes_.size()); }
  int64_t face_count() const { return static_cast<int64_t>(ids_.size()); }

  // The closest point to p. `hint` (a slot from an earlier result, or -1) seeds the
  // search with that triangle's distance; the answer does not depend on it: it is
  // always the smallest (distance, face index). With `cap2` finite, only triangles at
  // squared distance <= cap2 count: where there is none the result is the default one
  // (face -1, infinite distance), found after a search pruned at that distance.
  ClosestResult closest(const double* p, int32_t hint = -1,
                        double cap2 = std::numeric_limits<double>::infinity()) const {
    ClosestResult best;
    if (nodes_.empty()) return best;
    const bool capped = cap2 < std::numeric_limits<double>::infinity();
    if (capped) {
      best.dist2 = cap2;
      best.face = std::numeric_limits<int32_t>::max();  // above every face: ties at cap2 win
    }
    double bary[3], q[3];
    // the closest point of slot i (just computed into bary and q) becomes the answer
    auto take = [&](int32_t i, double d2) {
      best.dist2 = d2;
      best.face = ids_[i];
      best.slot = i;
      for (int a = 0; a < 3; ++a) {
        best.bary[a] = bary[a];
        best.point[a] = q[a];
      }
    };
    if (hint >= 0 && hint < static_cast<int32_t>(ids_.size())) {
      const double* t = &tris_[9 * static_cast<size_t>(hint)];
      const double d2 = closest_on_triangle(p, t, t + 3, t + 6, bary, q, degenerate_[hint] != 0);
      if (!capped || d2 <= cap2) take(hint, d2);
    }
    // Entries: (ref, count, lower bound); count > 0 marks a leaf.
    struct Entry {
      int32_t ref, count;
      double lower;
    };
    Entry stack[128];
    int sp = 0;
    const double mq = slab_margin(p);
    const V2d p0 = v2_splat(p[0]), p1 = v2_splat(p[1]), p2 = v2_splat(p[2]), vmq = v2_splat(mq);
    stack[sp++] = {root_ref_, root_count_, root_lower(p, mq)};
    while (sp > 0) {
      const Entry e = stack[--sp];
      if (e.lower > best.dist2) continue;
      if (e.count > 0) {
        for (int32_t i = e.ref; i < e.ref + e.count; ++i) {
          const FSlab& ts = tri_slabs_[i];
          if (slab_dist2(ts.c, ts.n, ts.r, ts.h, p, 1, mq) > best.dist2) continue;
          const double* t = &tris_[9 * static_cast<size_t>(i)];
          const double d2 = closest_on_triangle(p, t, t + 3, t + 6, bary, q, degenerate_[i] != 0);
          if (d2 < best.dist2 || (d2 == best.dist2 && ids_[i] < best.face)) take(i, d2);
        }
        continue;
      }
      const Pair& pr = pairs_[e.ref];
      const V2d lower = pair_lower(pr, p0, p1, p2, vmq);
      const double dl = lower[0], dr = lower[1];
      // Push the farther child first so that the nearer one is visited first.
      if (sp + 2 > 128) {  // cannot happen for trees of depth < 128; stay safe
        const ClosestResult all = brute_closest(p);
        return capped && !(all.dist2 <= cap2) ? ClosestResult() : all;
      }
      const Entry el{pr.ref[0], pr.count[0], dl}, er{pr.ref[1], pr.count[1], dr};
      if (dl <= dr) {
        if (dr <= best.dist2) stack[sp++] = er;
        if (dl <= best.dist2) stack[sp++] = el;
      } else {
        if (dl <= best.dist2) stack[sp++] = el;
        if (dr <= best.dist2) stack[sp++] = er;
      }
    }
    if (capped && best.face == std::numeric_limits<int32_t>::max()) return ClosestResult();
    return best;
  }

  // mode 0: first hit (smallest t, ties to the lowest face index); mode 1: any hit.
  bool first_hit(const Ray& ray, bool any, RayHit* out) const {
    RayHit best;
    best.t = ray.tmax;
    bool found = false;
    if (nodes_.empty()) return false;
    constexpr double inf = std::numeric_limits<double>::infinity();
    struct Entry {
      int32_t ref, count;
      double t;
    };
    Entry stack[128];
    int sp = 0;
    const double t_root = ray_box(ray, root_box_, ray.tmax);
    if (t_root == inf) return false;
    const bool pairwise = !(ray.flat[0] || ray.flat[1] || ray.flat[2]);
    const RayPair rp = ray_pair(ray);
    stack[sp++] = {root_ref_, root_count_, t_root};
    RayHit h;
    while (sp > 0) {
      const Entry e = stack[--sp];
      // Boxes are culled against the best t with a relative margin: a triangle's computed
      // t and its box's slab distance round differently, and a hit a few ulps before the
      // best one must not be culled (the result is the smallest computed t).
      const double cull = best.t + 1e-9 * std::fabs(best.t);
      if (e.t > cull) continue;
      if (e.count > 0) {
        for (int32_t i = e.ref; i < e.ref + e.count; ++i) {
          if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], best.t, &h)) {
            if (!found || h.t < best.t || (h.t == best.t && ids_[i] < best.face)) {
              best = h;
              best.face = ids_[i];
              found = true;
              if (any) {
                *out = best;
                return true;
              }
            }
          }
        }
        continue;
      }
      if (sp + 2 > 128) return brute_first(ray, any, out);
      const Pair& pr = pairs_[e.ref];
      double tl, tr;
      if (pairwise) {
        const V2d tt = pair_ray_boxes(rp, pr, cull);
        tl = tt[0];
        tr = tt[1];
      } else {
        tl = pair_ray_box(ray, pr, 0, cull);
        tr = pair_ray_box(ray, pr, 1, cull);
      }
      const Entry el{pr.ref[0], pr.count[0], tl}, er{pr.ref[1], pr.count[1], tr};
      if (tl <= tr) {
        if (tr != inf) stack[sp++] = er;
        if (tl != inf) stack[sp++] = el;
      } else {
        if (tl != inf) stack[sp++] = el;
        if (tr != inf) stack[sp++] = er;
      }
    }
    if (found) *out = best;
    return found;
  }

  // Every hit within [tmin, tmax], appended to *out sorted by (t, face).
  void all_hits(const Ray& ray, std::vector<RayHit>* out) const {
    const size_t start = out->size();
    if (nodes_.empty()) return;
    int32_t stack[128];
    int sp = 0;
    stack[sp++] = 0;
    RayHit h;
    while (sp > 0) {
      const Node& node = nodes_[stack[--sp]];
      if (ray_box(ray, node.box, ray.tmax) == std::numeric_limits<double>::infinity()) continue;
      if (node.count > 0) {
        for (int32_t i = node.first; i < node.first + node.count; ++i) {
          if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], ray.tmax, &h)) {
            h.face = ids_[i];
            out->push_back(h);
          }
        }
        continue;
      }
      if (sp + 2 > 128) {
        out->resize(start);
        for (int32_t i = 0; i < static_cast<int32_t>(ids_.size()); ++i)
          if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], ray.tmax, &h)) {
            h.face = ids_[i];
            out->push_back(h);
          }
        break;
      }
      stack[sp++] = node.first + 1;
      stack[sp++] = node.first;
    }
    std::sort(out->begin() + start, out->end(), [](const RayHit& x, const RayHit& y) {
      return x.t < y.t || (x.t == y.t && x.face < y.face);
    });
  }

  // The sum of ray_crossing over every triangle whose box the ray (from r.tmin, which
  // should be -margin) meets, through the float records (their boxes contain the double
  // ones). Returns false (and leaves *sum) where a crossing is unclear.
  bool crossings(const Ray& ray, double margin, int64_t* sum) const {
    constexpr double inf = std::numeric_limits<double>::infinity();
    int64_t s = 0;
    if (nodes_.empty() || ray_box(ray, root_box_, ray.tmax) == inf) {
      *sum = 0;
      return true;
    }
    struct Entry {
      int32_t ref, count;
    };
    Entry stack[128];
    int sp = 0;
    const bool pairwise = !(ray.flat[0] || ray.flat[1] || ray.flat[2]);
    const RayPair rp = ray_pair(ray);
    stack[sp++] = {root_ref_, root_count_};
    while (sp > 0) {
      const Entry e = stack[--sp];
      if (e.count > 0) {
        for (int32_t i = e.ref; i < e.ref + e.count; ++i) {
          const int c = ray_crossing(ray, &tris_[9 * static_cast<size_t>(i)], margin);
          if (c == kUnclear) return false;
          s += c;
        }
        continue;
      }
      if (sp + 2 > 128) return false;
      const Pair& pr = pairs_[e.ref];
      double tl, tr;
      if (pairwise) {
        const V2d tt = pair_ray_boxes(rp, pr, ray.tmax);
        tl = tt[0];
        tr = tt[1];
      } else {
        tl = pair_ray_box(ray, pr, 0, ray.tmax);
        tr = pair_ray_box(ray, pr, 1, ray.tmax);
      }
      if (tr != inf) stack[sp++] = {pr.ref[1], pr.count[1]};
      if (tl != inf) stack[sp++] = {pr.ref[0], pr.count[0]};
    }
    *sum = s;
    return true;
  }

  // The largest |coordinate| of the root box (0 for an empty tree).
  double extent() const {
    if (nodes_.empty()) return 0.0;
    double m = 0.0;
    for (int a = 0; a < 3; ++a)
      m = std::max(m, std::max(std::fabs(root_box_.lo[a]), std::fabs(root_box_.hi[a])));
    return m;
  }

 private:
  std::vector<Node> nodes_;
  std::vector<double> tris_;
  std::vector<int32_t> ids_;
  std::vector<uint8_t> degenerate_;
  std::vector<Box3> tri_boxes_;
  std::vector<std::array<int32_t, 2>>
      ranges_;  // per node: its triangles in tree order (build only)

  // The traversal layout: one 128-byte record per inner node with the bounds of
  // both children in float, rounded outwards (a float box contains the double
  // one, so it never prunes what the double box keeps). The boxes and the child
  // references fill the first cache line, which is all a ray reads; closest-point
  // searches read the slabs in the second line too.
  struct alignas(64) Pair {
    float lo[3][2], hi[3][2];  // [axis][child]
    int32_t ref[2];            // inner child: its Pair index; leaf: its first triangle
    int32_t count[2];          // leaf: number of triangles; inner: 0
    float c[3][2], n[3][2];    // slab centre and axis per child
    float r[2], h[2];          // slab radius and half-thickness per child
  };
  static_assert(sizeof(Pair) == 128, "Pair must fill two cache lines");
  static_assert(offsetof(Pair, count) + sizeof(Pair::count) <= 64,
                "a ray reads one cache line per record");
  struct FSlab {
    float c[3] = {0, 0, 0}, n[3] = {0, 0, 1};
    float r = std::numeric_limits<float>::infinity(), h = std::numeric_limits<float>::infinity();
  };
  std::vector<Pair> pairs_;
  std::vector<FSlab> tri_slabs_;  // per triangle in tree order: its plane and circumscribing disk
  Box3 root_box_;
  double cmax_ = 0.0;  // the largest |coordinate| of a finite slab's centre
  FSlab root_slab_;
  int32_t root_ref_ = 0, root_count_ = 0;

  // Outward float roundings, defined for every double (beyond the float range they
  // saturate to the largest float or to infinity on the safe side). They never return a
  // subnormal float: XLA's threads run with flush-to-zero and denormals-are-zero, so a
  // subnormal bound would read as 0 there and no longer bound anything. Below the normal
  // range they round outwards to 0 or to the smallest normal float instead.
  static float round_down(double x) {
    constexpr double kMax = std::numeric_limits<float>::max();
    constexpr float kMin = std::numeric_limits<float>::min();
    if (x > kMax) return std::numeric_limits<float>::max();
    if (!(x >= -kMax)) return -std::numeric_limits<float>::infinity();
    if (std::fabs(x) < kMin) return x >= 0.0 ? 0.0f : -kMin;
    float f = static_cast<float>(x);
    if (static_cast<double>(f) > x) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
    if (std::fabs(f) < kMin) f = f >= 0.0f ? 0.0f : -kMin;
    return f;
  }
  static float round_up(double x) {
    constexpr double kMax = std::numeric_limits<float>::max();
    constexpr float kMin = std::numeric_limits<float>::min();
    if (x < -kMax) return -std::numeric_limits<float>::max();
    if (!(x <= kMax)) return std::numeric_limits<float>::infinity();
    if (std::fabs(x) < kMin) return x <= 0.0 ? 0.0f : kMin;
    float f = static_cast<float>(x);
    if (static_cast<double>(f) < x) f = std::nextafter(f, std::numeric_limits<float>::infinity());
    if (std::fabs(f) < kMin) f = f <= 0.0f ? 0.0f : kMin;
    return f;
  }
  // The nearest float, or 0 below the normal range (see above): a value stored once and
  // then used exactly, as float and as double, by every thread.
  static float to_normal_float(double x) {
    const float f = static_cast<float>(x);
    return std::fabs(f) < std::numeric_limits<float>::min() ? 0.0f : f;
  }

  // The slab of node k: axis along the area-weighted mean normal of its
  // triangles, centre at the box centre (both rounded to float and then used
  // exactly), radius and half-thickness the largest radial and axial offsets of
  // its vertices from them, rounded up. Nodes without a dominant normal get an
  // infinite slab (it prunes nothing).
  FSlab make_slab(int32_t k) const {
    return make_slab_range(ranges_[k][0], ranges_[k][1], nodes_[k].box);
  }
  FSlab make_slab_range(int32_t b, int32_t e, const Box3& box) const {
    FSlab sl;
    double m[3] = {0, 0, 0}, area = 0.0;
    for (int32_t i = b; i < e; ++i) {
      const double* t = &tris_[9 * static_cast<size_t>(i)];
      double ab[3], ac[3];
      for (int a = 0; a < 3; ++a) {
        ab[a] = t[3 + a] - t[a];
        ac[a] = t[6 + a] - t[a];
      }
      const double cr[3] = {ab[1] * ac[2] - ab[2] * ac[1], ab[2] * ac[0] - ab[0] * ac[2],
                            ab[0] * ac[1] - ab[1] * ac[0]};
      for (int a = 0; a < 3; ++a) m[a] += cr[a];
      area += std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
    }
    const double len = std::sqrt(m[0] * m[0] + m[1] * m[1] + m[2] * m[2]);
    if (!(len > 0.25 * area) || !std::isfinite(len)) return sl;
    double c[3], n[3];
    for (int a = 0; a < 3; ++a)  // far from the float range: no slab (the box still prunes)
      if (!(std::fabs(0.5 * (box.lo[a] + box.hi[a])) < 1e30)) return sl;
    for (int a = 0; a < 3; ++a) {
      sl.n[a] = to_normal_float(m[a] / len);
      sl.c[a] = to_normal_float(0.5 * (box.lo[a] + box.hi[a]));
      n[a] = sl.n[a];
      c[a] = sl.c[a];
    }
    double hmax = 0.0, rmax2 = 0.0;
    for (int32_t i = b; i < e; ++i) {
      const double* t = &tris_[9 * static_cast<size_t>(i)];
      for (int v = 0; v < 3; ++v) {
        const double w[3] = {t[3 * v] - c[0], t[3 * v + 1] - c[1], t[3 * v + 2] - c[2]};
        const double a = n[0] * w[0] + n[1] * w[1] + n[2] * w[2];
        const double u[3] = {w[0] - a * n[0], w[1] - a * n[1], w[2] - a * n[2]};
        hmax = std::max(hmax, std::fabs(a));
        rmax2 = std::max(rmax2, u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
      }
    }
    const double cm = std::max(std::fabs(c[0]), std::max(std::fabs(c[1]), std::fabs(c[2])));
    const double rr = std::sqrt(rmax2);
    // The offsets above carry rounding errors of a few ulps of this scale.
    const double margin = 1e-12 * (cm + rr + hmax);
    const FSlab none;
    if (!std::isfinite(cm + rr + hmax) || !(cm < 1e30)) return none;
    sl.r = round_up(rr + margin);
    sl.h = round_up(hmax + margin);
    return sl;
  }

  void build_pairs() {
    pairs_.clear();
    if (nodes_.empty()) return;
    const size_t nn = nodes_.size();
    std::vector<int32_t> pair_of(nn, -1);
    int32_t np = 0;
    for (size_t k = 0; k < nn; ++k)
      if (nodes_[k].count == 0) pair_of[k] = np++;
    pairs_.assign(np, Pair());
    auto ref = [&](int32_t k, int32_t* r, int32_t* c) {
      if (nodes_[k].count > 0) {
        *r = nodes_[k].first;
        *c = nodes_[k].count;
      } else {
        *r = pair_of[k];
        *c = 0;
      }
    };
    tri_slabs_.resize(ids_.size());
    for (size_t i = 0; i < ids_.size(); ++i)
      tri_slabs_[i] =
          make_slab_range(static_cast<int32_t>(i), static_cast<int32_t>(i) + 1, tri_boxes_[i]);
    root_box_ = nodes_[0].box;
    root_slab_ = make_slab(0);
    ref(0, &root_ref_, &root_count_);
    for (size_t k = 0; k < nn; ++k) {
      if (nodes_[k].count != 0) continue;
      Pair& pr = pairs_[pair_of[k]];
      for (int j = 0; j < 2; ++j) {
        const int32_t ch = nodes_[k].first + j;
        const Box3& bx = nodes_[ch].box;
        for (int a = 0; a < 3; ++a) {
          pr.lo[a][j] = round_down(bx.lo[a]);
          pr.hi[a][j] = round_up(bx.hi[a]);
        }
        const FSlab sl = make_slab(ch);
        for (int a = 0; a < 3; ++a) {
          pr.c[a][j] = sl.c[a];
          pr.n[a][j] = sl.n[a];
        }
        pr.r[j] = sl.r;
        pr.h[j] = sl.h;
        ref(ch, &pr.ref[j], &pr.count[j]);
      }
    }
    cmax_ = 0.0;
    auto grow_cmax = [&](const float* c, int stride, float r, float h) {
      if (!(r < std::numeric_limits<float>::infinity()) ||
          !(h < std::numeric_limits<float>::infinity()))
        return;
      for (int a = 0; a < 3; ++a)
        cmax_ = std::max(cmax_, static_cast<double>(std::fabs(c[a * stride])));
    };
    grow_cmax(root_slab_.c, 1, root_slab_.r, root_slab_.h);
    for (const Pair& pr : pairs_)
      for (int j = 0; j < 2; ++j) grow_cmax(&pr.c[0][j], 2, pr.r[j], pr.h[j]);
    for (const FSlab& ts : tri_slabs_) grow_cmax(ts.c, 1, ts.r, ts.h);
    ranges_.clear();
    ranges_.shrink_to_fit();
  }

  // Squared distance from p to child j's box (the Box3::dist2 formula on the float box).
  static double pair_box_dist2(const Pair& pr, int j, const double* p) {
    double s = 0.0;
    for (int a = 0; a < 3; ++a) {
      const double d = std::max(std::max(static_cast<double>(pr.lo[a][j]) - p[a],
                                         p[a] - static_cast<double>(pr.hi[a][j])),
                                0.0);
      s += d * d;
    }
    return s;
  }

  // The part of the slab margin that depends only on the point: 1e-11 (max |p| + the
  // largest |centre| of any finite slab). The margin of a slab is this plus 1e-11 (r + h),
  // at least the 1e-11 (|p| + |c| + r + h) that bounds the rounding of slab_dist2 and of
  // the point-triangle distance, so hoisting it out of the traversal only lowers bounds.
  double slab_margin(const double* p) const {
    return 1e-11 * (std::max(std::fabs(p[0]), std::max(std::fabs(p[1]), std::fabs(p[2]))) + cmax_);
  }

  // A lower bound of the squared distance from p to a slab: the squared
  // distance to the cylinder, with both of its components shrunk by the absolute
  // margin mq + 1e-11 (r + h) (see slab_margin), and the sum shrunk by 4e-6 relatively
  // (the float axis is unit only to 1e-7). One square root, and none when p is within
  // the disk's radius. An infinite slab gives 0.
  static double slab_dist2(const float* c, const float* n, double r, double h, const double* p,
                           int stride, double mq) {
    const double c0 = c[0], c1 = c[stride], c2 = c[2 * stride];
    const double n0 = n[0], n1 = n[stride], n2 = n[2 * stride];
    const double w0 = p[0] - c0, w1 = p[1] - c1, w2 = p[2] - c2;
    const double a = n0 * w0 + n1 * w1 + n2 * w2;
    const double u0 = w0 - a * n0, u1 = w1 - a * n1, u2 = w2 - a * n2;
    const double rho2 = u0 * u0 + u1 * u1 + u2 * u2;
    const double m = mq + 1e-11 * (r + h);
    const double dn = std::max(std::fabs(a) - h - m, 0.0);
    double dr = 0.0;
    if (rho2 > r * r) dr = std::max(std::sqrt(rho2) - r - m, 0.0);
    return (dn * dn + dr * dr) * (1.0 - 4e-6);
  }

  // ray_box on child j's float box (converted exactly to double).
  static double pair_ray_box(const Ray& r, const Pair& pr, int j, double tfar) {
    Box3 b;
    for (int a = 0; a < 3; ++a) {
      b.lo[a] = pr.lo[a][j];
      b.hi[a] = pr.hi[a][j];
    }
    return ray_box(r, b, tfar);
  }

  // A ray without a zero direction component, for the slab test of both children of a
  // record at once: per axis the near plane is lo for a positive direction and hi for a
  // negative one, which is the order ray_box's swap gives, so the entry distances equal
  // ray_box's bit for bit (the same operations in the same order).
  struct RayPair {
    V2d org[3], inv[3];
    double tmin;
    bool neg[3];
  };
  static RayPair ray_pair(const Ray& r) {
    RayPair s;
    for (int a = 0; a < 3; ++a) {
      s.org[a] = v2_splat(r.org[a]);
      s.inv[a] = v2_splat(r.inv[a]);
      s.neg[a] = r.inv[a] < 0.0;
    }
    s.tmin = r.tmin;
    return s;
  }
  static V2d pair_ray_boxes(const RayPair& s, const Pair& pr, double tfar) {
    constexpr double kGrow =
        1.0 + 2.0 * (3.0 * 1.1102230246251565e-16 / (1.0 - 3.0 * 1.1102230246251565e-16));
    V2d t0 = v2_splat(s.tmin), t1 = v2_splat(tfar);
    for (int a = 0; a < 3; ++a) {
      const V2d lo = v2_load(pr.lo[a]), hi = v2_load(pr.hi[a]);
      const V2d tn = ((s.neg[a] ? hi : lo) - s.org[a]) * s.inv[a];
      const V2d tf = ((s.neg[a] ? lo : hi) - s.org[a]) * s.inv[a] * kGrow;
      t0 = v2_max(tn, t0);
      t1 = v2_min(tf, t1);
    }
    return v2_select(t0 > t1, v2_splat(std::numeric_limits<double>::infinity()), t0);
  }

  // Both children's lower bounds of the squared distance from p, at once: the larger of
  // the distance to the float box and slab_dist2 (the same formulas, evaluated lane by
  // lane; an infinite slab gives 0). mq: slab_margin(p).
  static V2d pair_lower(const Pair& pr, V2d p0, V2d p1, V2d p2, V2d mq) {
    const V2d z = v2_splat(0.0);
    const V2d b0 = v2_max(v2_max(v2_load(pr.lo[0]) - p0, p0 - v2_load(pr.hi[0])), z);
    const V2d b1 = v2_max(v2_max(v2_load(pr.lo[1]) - p1, p1 - v2_load(pr.hi[1])), z);
    const V2d b2 = v2_max(v2_max(v2_load(pr.lo[2]) - p2, p2 - v2_load(pr.hi[2])), z);
    const V2d box = b0 * b0 + b1 * b1 + b2 * b2;
    const V2d n0 = v2_load(pr.n[0]), n1 = v2_load(pr.n[1]), n2 = v2_load(pr.n[2]);
    const V2d w0 = p0 - v2_load(pr.c[0]), w1 = p1 - v2_load(pr.c[1]), w2 = p2 - v2_load(pr.c[2]);
    const V2d a = n0 * w0 + n1 * w1 + n2 * w2;
    const V2d u0 = w0 - a * n0, u1 = w1 - a * n1, u2 = w2 - a * n2;
    const V2d rho2 = u0 * u0 + u1 * u1 + u2 * u2;
    const V2d r = v2_load(pr.r), h = v2_load(pr.h);
    const V2d m = mq + 1e-11 * (r + h);
    const V2d dn = v2_max(v2_select(a < 0.0, -a, a) - h - m, z);
    const V2d dr = v2_max(v2_sqrt(rho2) - r - m, z);
    return v2_max(box, (dn * dn + dr * dr) * (1.0 - 4e-6));
  }

  double root_lower(const double* p, double mq) const {
    const double d = root_box_.dist2(p);
    return std::max(d,
                    slab_dist2(root_slab_.c, root_slab_.n, root_slab_.r, root_slab_.h, p, 1, mq));
  }

  ClosestResult brute_closest(const double* p) const {
    ClosestResult best;
    double bary[3], q[3];
    for (size_t i = 0; i < ids_.size(); ++i) {
      const double* t = &tris_[9 * i];
      const double d2 = closest_on_triangle(p, t, t + 3, t + 6, bary, q);
      if (d2 < best.dist2 || (d2 == best.dist2 && ids_[i] < best.face)) {
        best.dist2 = d2;
        best.face = ids_[i];
        best.slot = static_cast<int32_t>(i);
        for (int a = 0; a < 3; ++a) {
          best.bary[a] = bary[a];
          best.point[a] = q[a];
        }
      }
    }
    return best;
  }

  bool brute_first(const Ray& ray, bool any, RayHit* out) const {
    RayHit best, h;
    bool found = false;
    best.t = ray.tmax;
    for (size_t i = 0; i < ids_.size(); ++i) {
      if (ray_triangle(ray, &tris_[9 * i], best.t, &h) &&
          (!found || h.t < best.t || (h.t == best.t && ids_[i] < best.face))) {
        best = h;
        best.face = ids_[i];
        found = true;
        if (any) break;
      }
    }
    if (found) *out = best;
    return found;
  }

  // Binned SAH split of order[begin, end). Returns the split position, or -1 for a leaf.
  int32_t split(const std::vector<Box3>& boxes, const std::vector<std::array<double, 3>>& cent,
                std::vector<int32_t>& order, int32_t begin, int32_t end, const Box3& nb,
                const Box3& cb) {
    const int32_t count = end - begin;
    double best_cost = std::numeric_limits<double>::infinity();
    int best_axis = -1, best_bin = -1;
    for (int a = 0; a < 3; ++a) {
      const double extent = cb.hi[a] - cb.lo[a];
      if (!(extent > 0.0)) continue;
      const double scale = kBins / extent;
      Box3 bb[kBins];
      int32_t bn[kBins] = {0};
      for (int32_t i = begin; i < end; ++i) {
        const int32_t f = order[i];
        int k = static_cast<int>((cent[f][a] - cb.lo[a]) * scale);
        k = std::min(kBins - 1, std::max(0, k));
        bn[k]++;
        bb[k].grow(boxes[f]);
      }
      double right_area[kBins];
      int32_t right_n[kBins];
      Box3 acc;
      int32_t accn = 0;
      for (int k = kBins - 1; k > 0; --k) {
        acc.grow(bb[k]);
        accn += bn[k];
        right_area[k] = acc.half_area();
        right_n[k] = accn;
      }
      Box3 left;
      int32_t ln = 0;
      for (int k = 1; k < kBins; ++k) {
        left.grow(bb[k - 1]);
        ln += bn[k - 1];
        if (ln == 0 || right_n[k] == 0) continue;
        const double cost = left.half_area() * ln + right_area[k] * right_n[k];
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_bin = k;
        }
      }
    }
    const double parent = nb.half_area();
    if (best_axis < 0) {
      // All centroids coincide: split by position so leaves stay small.
      if (count <= 4 * kMaxLeaf) return -1;
      return begin + count / 2;
    }
    // SAH: traversal cost 1, intersection cost 1 per triangle.
    const double split_cost = 1.0 + (parent > 0.0 ? best_cost / parent : 0.5 * count);
    if (split_cost >= count && count <= 4 * kMaxLeaf) return -1;
    const int a = best_axis;
    const double extent = cb.hi[a] - cb.lo[a];
    const double scale = kBins / extent;
    auto mid_it = std::partition(order.begin() + begin, order.begin() + end, [&](int32_t f) {
      int k = static_cast<int>((cent[f][a] - cb.lo[a]) * scale);
      k = std::min(kBins - 1, std::max(0, k));
      return k < best_bin;
    });
    const int32_t mid = static_cast<int32_t>(mid_it - order.begin());
    if (mid == begin || mid == end) return begin + count / 2;
    return mid;
  }
};

}  // namespace spatial
}  // namespace voxax

// The exact triangle primitives of the BVH, in float64: boxes, the closest point of a
// triangle to a point, and the watertight ray-triangle test.
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
// far distance scaled by 1 + 2 gamma_3 (Ize 2013; by 1 - 2 gamma_3 where it is negative).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

namespace voxax {
namespace spatial {

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

// The robust slab test's factors: a far distance is raised by 2 gamma_3 of its magnitude
// whatever its sign (scaled by 1 + 2 gamma_3 when positive, by 1 - 2 gamma_3 when negative,
// so that a box behind the origin, met with tmin < 0, is not lost to rounding either).
constexpr double kGrow =
    1.0 + 2.0 * (3.0 * 1.1102230246251565e-16 / (1.0 - 3.0 * 1.1102230246251565e-16));
constexpr double kShrink = 2.0 - kGrow;

// Robust slab test: the entry distance, or +inf when the box is missed within
// [tmin, tfar].
inline double ray_box(const Ray& r, const Box3& b, double tfar) {
  double t0 = r.tmin, t1 = tfar;
  for (int a = 0; a < 3; ++a) {
    if (r.flat[a]) {
      if (r.org[a] < b.lo[a] || r.org[a] > b.hi[a]) return std::numeric_limits<double>::infinity();
      continue;
    }
    double tn = (b.lo[a] - r.org[a]) * r.inv[a];
    double tf = (b.hi[a] - r.org[a]) * r.inv[a];
    if (tn > tf) std::swap(tn, tf);
    tf *= tf < 0.0 ? kShrink : kGrow;
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

}  // namespace spatial
}  // namespace voxax

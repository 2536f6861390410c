// Exact intersection tests between closed triangles, segments and points in 3D, built on
// the exact orientation predicates only (no constructed points), so every verdict is exact
// for the float64 inputs.
//
// Triangles are closed point sets: touching (a vertex on a face, an edge on an edge, a
// shared boundary) counts as intersecting. A degenerate triangle (its corners collinear or
// equal) is the segment or point it spans.

#pragma once

#include <algorithm>

#include "intersect/predicates.h"

namespace voxax {
namespace tritri {

using exact::orient2d;
using exact::orient3d;

struct P2 {
  double v[2];
};

// Drops coordinate `axis`.
inline P2 project(const double* p, int axis) {
  P2 r;
  r.v[0] = p[axis == 0 ? 1 : 0];
  r.v[1] = p[axis == 2 ? 1 : 2];
  return r;
}

// The axis to drop so that triangle (a, b, c) stays non-degenerate in 2D, or -1 when its
// corners are collinear (exactly).
inline int good_axis(const double* a, const double* b, const double* c) {
  for (int axis = 2; axis >= 0; --axis) {
    const P2 pa = project(a, axis), pb = project(b, axis), pc = project(c, axis);
    if (orient2d(pa.v, pb.v, pc.v) != 0) return axis;
  }
  return -1;
}

inline bool degenerate(const double* a, const double* b, const double* c) {
  return good_axis(a, b, c) < 0;
}

// Is the 2D point c on the closed segment [a, b], given that a, b, c are collinear?
inline bool on_collinear_segment(const double* a, const double* b, const double* c) {
  return std::min(a[0], b[0]) <= c[0] && c[0] <= std::max(a[0], b[0]) &&
         std::min(a[1], b[1]) <= c[1] && c[1] <= std::max(a[1], b[1]);
}

// Closed 2D segments [a, b] and [c, d] (either may be a point).
inline bool segments_2d(const double* a, const double* b, const double* c, const double* d) {
  const int o1 = orient2d(a, b, c), o2 = orient2d(a, b, d);
  const int o3 = orient2d(c, d, a), o4 = orient2d(c, d, b);
  if (o1 * o2 < 0 && o3 * o4 < 0) return true;
  if (o1 == 0 && on_collinear_segment(a, b, c)) return true;
  if (o2 == 0 && on_collinear_segment(a, b, d)) return true;
  if (o3 == 0 && on_collinear_segment(c, d, a)) return true;
  if (o4 == 0 && on_collinear_segment(c, d, b)) return true;
  return false;
}

// Closed 2D point x in the closed non-degenerate triangle (a, b, c).
inline bool point_in_triangle_2d(const double* a, const double* b, const double* c,
                                 const double* x) {
  const int s1 = orient2d(a, b, x), s2 = orient2d(b, c, x), s3 = orient2d(c, a, x);
  return (s1 >= 0 && s2 >= 0 && s3 >= 0) || (s1 <= 0 && s2 <= 0 && s3 <= 0);
}

// Closed segment [a, b] (possibly a point) against the closed non-degenerate triangle
// (p, q, r), all in 3D.
inline bool segment_triangle(const double* a, const double* b, const double* p, const double* q,
                             const double* r) {
  const int oa = orient3d(p, q, r, a), ob = orient3d(p, q, r, b);
  if (oa * ob > 0) return false;
  if (oa == 0 && ob == 0) {
    const int axis = good_axis(p, q, r);
    const P2 pp = project(p, axis), pq = project(q, axis), pr = project(r, axis);
    const P2 pa = project(a, axis), pb = project(b, axis);
    if (point_in_triangle_2d(pp.v, pq.v, pr.v, pa.v)) return true;
    if (point_in_triangle_2d(pp.v, pq.v, pr.v, pb.v)) return true;
    return segments_2d(pa.v, pb.v, pp.v, pq.v) || segments_2d(pa.v, pb.v, pq.v, pr.v) ||
           segments_2d(pa.v, pb.v, pr.v, pp.v);
  }
  // The segment meets the plane in exactly one point; is it inside the closed triangle?
  const int s1 = orient3d(a, b, p, q), s2 = orient3d(a, b, q, r), s3 = orient3d(a, b, r, p);
  return (s1 >= 0 && s2 >= 0 && s3 >= 0) || (s1 <= 0 && s2 <= 0 && s3 <= 0);
}

// Is c on the closed segment [a, b], given that a, b, c are collinear (3D)?
inline bool on_collinear_segment_3d(const double* a, const double* b, const double* c) {
  for (int k = 0; k < 3; ++k)
    if (c[k] < std::min(a[k], b[k]) || c[k] > std::max(a[k], b[k])) return false;
  return true;
}

inline bool equal3(const double* a, const double* b) {
  return a[0] == b[0] && a[1] == b[1] && a[2] == b[2];
}

// Are the 3D points a, b, c collinear (or coincident)?
inline bool collinear_3d(const double* a, const double* b, const double* c) {
  return degenerate(a, b, c);
}

// Closed 3D segments [a, b] and [c, d] (either may be a point).
inline bool segments_3d(const double* a, const double* b, const double* c, const double* d) {
  if (equal3(a, b)) {
    if (equal3(c, d)) return equal3(a, c);
    return collinear_3d(c, d, a) && on_collinear_segment_3d(c, d, a);
  }
  if (equal3(c, d)) return collinear_3d(a, b, c) && on_collinear_segment_3d(a, b, c);
  if (orient3d(a, b, c, d) != 0) return false;  // skew lines
  // Coplanar. If some triple is not collinear, it fixes a projection that is injective on
  // the common plane.
  const double* pts[4] = {a, b, c, d};
  for (int drop = 0; drop < 4; ++drop) {
    const double* t[3];
    int n = 0;
    for (int i = 0; i < 4; ++i)
      if (i != drop) t[n++] = pts[i];
    const int axis = good_axis(t[0], t[1], t[2]);
    if (axis >= 0) {
      const P2 pa = project(a, axis), pb = project(b, axis), pc = project(c, axis),
               pd = project(d, axis);
      return segments_2d(pa.v, pb.v, pc.v, pd.v);
    }
  }
  // All four collinear: overlapping intervals on the common line (compare along every
  // axis; on a line, the order along any axis with a spread agrees with the line's).
  return on_collinear_segment_3d(a, b, c) || on_collinear_segment_3d(a, b, d) ||
         on_collinear_segment_3d(c, d, a) || on_collinear_segment_3d(c, d, b);
}

// Closed triangles (a0, a1, a2) and (b0, b1, b2), either possibly degenerate.
inline bool triangles(const double* const a[3], const double* const b[3]) {
  const bool da = degenerate(a[0], a[1], a[2]);
  const bool db = degenerate(b[0], b[1], b[2]);
  // Quick rejection: one triangle strictly on one side of the other's plane.
  if (!db) {
    const int s0 = orient3d(b[0], b[1], b[2], a[0]), s1 = orient3d(b[0], b[1], b[2], a[1]),
              s2 = orient3d(b[0], b[1], b[2], a[2]);
    if ((s0 > 0 && s1 > 0 && s2 > 0) || (s0 < 0 && s1 < 0 && s2 < 0)) return false;
  }
  if (!da) {
    const int s0 = orient3d(a[0], a[1], a[2], b[0]), s1 = orient3d(a[0], a[1], a[2], b[1]),
              s2 = orient3d(a[0], a[1], a[2], b[2]);
    if ((s0 > 0 && s1 > 0 && s2 > 0) || (s0 < 0 && s1 < 0 && s2 < 0)) return false;
  }
  if (da && db) {
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        if (segments_3d(a[i], a[(i + 1) % 3], b[j], b[(j + 1) % 3])) return true;
    return false;
  }
  if (!db)
    for (int i = 0; i < 3; ++i)
      if (segment_triangle(a[i], a[(i + 1) % 3], b[0], b[1], b[2])) return true;
  if (!da)
    for (int j = 0; j < 3; ++j)
      if (segment_triangle(b[j], b[(j + 1) % 3], a[0], a[1], a[2])) return true;
  return false;
}

// Two non-degenerate triangles (u, v, a) and (u, v, b) share the edge u-v: do they overlap
// beyond it (fold through each other)? Only when coplanar with a and b on the same side of
// the line u-v.
inline bool fold_across_edge(const double* u, const double* v, const double* a, const double* b) {
  if (orient3d(u, v, a, b) != 0) return false;
  const int axis = good_axis(u, v, a);
  const P2 pu = project(u, axis), pv = project(v, axis), pa = project(a, axis),
           pb = project(b, axis);
  return orient2d(pu.v, pv.v, pa.v) * orient2d(pu.v, pv.v, pb.v) > 0;
}

// Does the segment from s (a corner of the non-degenerate triangle (s, p, q)) towards x
// run into that triangle beyond s?
inline bool ray_into_corner(const double* s, const double* p, const double* q, const double* x) {
  if (orient3d(s, p, q, x) != 0) return false;
  const int axis = good_axis(s, p, q);
  const P2 ps = project(s, axis), pp = project(p, axis), pq = project(q, axis),
           px = project(x, axis);
  const int o = orient2d(ps.v, pp.v, pq.v);
  return orient2d(ps.v, pp.v, px.v) * o >= 0 && orient2d(ps.v, px.v, pq.v) * o >= 0;
}

// Two non-degenerate triangles (s, a1, a2) and (s, b1, b2) share only the corner s: do
// they meet anywhere else?
inline bool meet_beyond_vertex(const double* s, const double* a1, const double* a2,
                               const double* b1, const double* b2) {
  // One triangle's other corners strictly on one side of the other's plane: they meet in s only.
  const int o1 = orient3d(s, b1, b2, a1), o2 = orient3d(s, b1, b2, a2);
  if (o1 * o2 > 0) return false;
  const int o3 = orient3d(s, a1, a2, b1), o4 = orient3d(s, a1, a2, b2);
  if (o3 * o4 > 0) return false;
  if (segment_triangle(a1, a2, s, b1, b2)) return true;
  if (segment_triangle(b1, b2, s, a1, a2)) return true;
  return ray_into_corner(s, b1, b2, a1) || ray_into_corner(s, b1, b2, a2) ||
         ray_into_corner(s, a1, a2, b1) || ray_into_corner(s, a1, a2, b2);
}

}  // namespace tritri
}  // namespace voxax

// The closest-point query of Bvh (bvh_tree.h): a nearest-first search pruned by the
// larger of the box and cylinder bounds, with a brute-force fallback.
#pragma once

#include <cstddef>
#include <cstdint>
#include <limits>

#include "spatial/bvh_tree.h"
#include "spatial/bvh_triangle.h"

namespace voxax {
namespace spatial {

inline ClosestResult Bvh::closest(const double* p, int32_t hint, double cap2) const {
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

inline ClosestResult Bvh::brute_closest(const double* p) const {
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

}  // namespace spatial
}  // namespace voxax

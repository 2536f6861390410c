// The ray queries of Bvh (bvh_tree.h): the first or any hit, every hit, and the summed
// crossings of winding numbers, with a brute-force fallback.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

#include "spatial/bvh_tree.h"
#include "spatial/bvh_triangle.h"

namespace voxax {
namespace spatial {

inline bool Bvh::first_hit(const Ray& ray, bool any, RayHit* out) const {
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
    const RayRec& pr = rays_[e.ref];
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
    // the children's records or triangles start loading now (a hint: no effect on results)
    if (tl != inf) prefetch_ref(el.ref, el.count);
    if (tr != inf) prefetch_ref(er.ref, er.count);
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

inline void Bvh::all_hits(const Ray& ray, std::vector<RayHit>* out) const {
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

inline bool Bvh::crossings(const Ray& ray, double margin, int64_t* sum) const {
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
    const RayRec& pr = rays_[e.ref];
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

inline bool Bvh::brute_first(const Ray& ray, bool any, RayHit* out) const {
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

}  // namespace spatial
}  // namespace voxax

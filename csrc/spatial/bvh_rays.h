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
#if VOXAX_RAY_AVX2
  if (ray_avx2_) return first_hit_avx2(ray, any, out);
#endif
  return first_hit_path<false>(ray, any, out);
}

#if VOXAX_RAY_AVX2
inline bool Bvh::first_hit_avx2(const Ray& ray, bool any, RayHit* out) const {
  return first_hit_path<true>(ray, any, out);
}
#endif

template <bool kAvx2>
inline bool Bvh::first_hit_path(const Ray& ray, bool any, RayHit* out) const {
  RayHit best;
  best.t = ray.tmax;
  bool found = false;
  if (nodes_.empty()) return false;
  constexpr double inf = std::numeric_limits<double>::infinity();
  // The stack as two arrays of 8-byte values (entry distance; reference and count packed),
  // each written and read with 8-byte moves: a 16-byte entry struct is copied with 16-byte
  // moves that cannot take their data from the two narrower stores that wrote it (a stall
  // on every push and pop).
  constexpr int kStack = 192;
  double stack_t[kStack];
  uint64_t stack_rc[kStack];
  auto pack = [](int32_t ref, int32_t count) {
    return static_cast<uint64_t>(static_cast<uint32_t>(ref)) |
           static_cast<uint64_t>(static_cast<uint32_t>(count)) << 32;
  };
  int sp = 0;
  const double t_root = ray_box(ray, root_box_, ray.tmax);
  if (t_root == inf) return false;
  const bool pairwise = !(ray.flat[0] || ray.flat[1] || ray.flat[2]);
  // First hits (not any hits, whose answer is the first found and so depends on the order)
  // go down the QNodes in float where that is conservative (FRay): the same answer.
  const FRay fr = fray(ray);
  const bool use_float = !any && fr.ok;
  RayPair rp;
  if (!use_float) rp = ray_pair(ray);
  double cull_seen = std::numeric_limits<double>::quiet_NaN();
  float cull_f = std::numeric_limits<float>::infinity();
  // Boxes are culled against the best t with a relative margin: a triangle's computed
  // t and its box's slab distance round differently, and a hit a few ulps before the
  // best one must not be culled (the result is the smallest computed t).
  double cull = best.t + 1e-9 * std::fabs(best.t);
  // The node visited: the root (a leaf, or Quad or QNode 0), then the nearest child met, taken
  // without a round trip through the stack (the order is that of pushing every child met
  // and popping the nearest, and so is the stack's depth at every record).
  int32_t eref = root_count_ > 0 ? root_ref_ : 0, ecount = root_count_;
  RayHit h;
  for (;;) {
    if (ecount > 0) {
      for (int32_t i = eref; i < eref + ecount; ++i) {
        if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], best.t, &h)) {
          if (!found || h.t < best.t || (h.t == best.t && ids_[i] < best.face)) {
            best = h;
            best.face = ids_[i];
            found = true;
            if (any) {
              *out = best;
              return true;
            }
            cull = best.t + 1e-9 * std::fabs(best.t);
          }
        }
      }
    } else {
      // the children met, pushed in order of decreasing t by insertion (ties keep the slot
      // order on the way up), so that the nearest is visited first
      const int base = sp;
      if (use_float) {
        if (sp + kFWidth > kStack) return brute_first(ray, any, out);
        const QNode& fq = qnodes_[eref];
        alignas(32) float tc[kFWidth];
        if (cull != cull_seen) {
          cull_seen = cull;
          cull_f = up_float(cull);
        }
        int mask;  // (cull_f >= cull)
#if VOXAX_RAY_AVX2
        if constexpr (kAvx2)
          mask = qnode_entries_avx2(fr, fq, cull_f, tc);
        else
#endif
          mask = qnode_entries(fr, fq, cull_f, tc);
        while (mask != 0) {
          const int j = __builtin_ctz(static_cast<unsigned>(mask));
          mask &= mask - 1;
          const double tj = tc[j];
          const int32_t rj = fq.ref[j];
          prefetch_fref(rj);
          const uint64_t rc = rj < 0 ? pack(~rj, fq.count[j]) : pack(rj, 0);
          int at = sp++;
          while (at > base && stack_t[at - 1] <= tj) {
            stack_t[at] = stack_t[at - 1];
            stack_rc[at] = stack_rc[at - 1];
            --at;
          }
          stack_t[at] = tj;
          stack_rc[at] = rc;
        }
      } else {
        if (sp + kQuadWidth > kStack) return brute_first(ray, any, out);
        const Quad& qd = quads_[eref];
        for (int half = 0; half < kQuadWidth / 2; ++half) {
          const RayRec& pr = qd.half[half];
          double t2[2];
          record_entries(ray, rp, pairwise, pr, cull, t2);
          for (int j = 0; j < 2; ++j)
            if (pr.count[j] >= 0 && t2[j] != inf) {
              // the records or triangles start loading now (a hint: no effect on results)
              prefetch_ref(pr.ref[j], pr.count[j]);
              int at = sp++;
              while (at > base && stack_t[at - 1] <= t2[j]) {
                stack_t[at] = stack_t[at - 1];
                stack_rc[at] = stack_rc[at - 1];
                --at;
              }
              stack_t[at] = t2[j];
              stack_rc[at] = pack(pr.ref[j], pr.count[j]);
            }
        }
      }
      if (sp > base) {  // the nearest child met: within the cull distance, which is unchanged
        --sp;
        const uint64_t erc = stack_rc[sp];
        eref = static_cast<int32_t>(static_cast<uint32_t>(erc));
        ecount = static_cast<int32_t>(static_cast<uint32_t>(erc >> 32));
        continue;
      }
    }
    // the next entry of the stack not beyond the cull distance
    for (;;) {
      if (sp == 0) {
        if (found) *out = best;
        return found;
      }
      --sp;
      if (!(stack_t[sp] > cull)) break;
    }
    const uint64_t erc = stack_rc[sp];
    eref = static_cast<int32_t>(static_cast<uint32_t>(erc));
    ecount = static_cast<int32_t>(static_cast<uint32_t>(erc >> 32));
  }
}

inline void Bvh::all_hits(const Ray& ray, std::vector<RayHit>* out) const {
  constexpr double inf = std::numeric_limits<double>::infinity();
  const size_t start = out->size();
  if (nodes_.empty() || ray_box(ray, root_box_, ray.tmax) == inf) return;
  QuadWalk w(*this, ray);
  RayHit h;
  while (w.sp > 0) {
    const QuadWalk::Entry e = w.stack[--w.sp];
    if (e.count > 0) {
      for (int32_t i = e.ref; i < e.ref + e.count; ++i) {
        if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], ray.tmax, &h)) {
          h.face = ids_[i];
          out->push_back(h);
        }
      }
      continue;
    }
    if (w.full()) {  // every triangle instead
      out->resize(start);
      for (int32_t i = 0; i < static_cast<int32_t>(ids_.size()); ++i)
        if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], ray.tmax, &h)) {
          h.face = ids_[i];
          out->push_back(h);
        }
      break;
    }
    w.push_children(ray, quads_[e.ref]);
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
  QuadWalk w(*this, ray);
  while (w.sp > 0) {
    const QuadWalk::Entry e = w.stack[--w.sp];
    if (e.count > 0) {
      for (int32_t i = e.ref; i < e.ref + e.count; ++i) {
        const int c = ray_crossing(ray, &tris_[9 * static_cast<size_t>(i)], margin);
        if (c == kUnclear) return false;
        s += c;
      }
      continue;
    }
    if (w.full()) return false;
    w.push_children(ray, quads_[e.ref]);
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

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

#if VOXAX_RAY_AVX2
// The triangles among tris[0 .. count) (at most 4, 9 doubles each) that ray_triangle may
// hit within [r.tmin, tmax], as a mask: ray_triangle's edge functions, determinant and t
// for the four at once, the same operations in the same order (products and sums rounded
// apart, no fused multiply-add), so the same values bit for bit. A triangle is left out
// only where ray_triangle returns false for it (its edge functions differ in sign, its
// determinant is 0, or t is outside the interval); one with a zero edge function (the
// ray meets an edge or a vertex, decided by ray_triangle's tie rule) is kept.
__attribute__((target("avx2"))) inline int leaf_candidates_avx2(const Ray& r, const double* tris,
                                                                int count, double tmax) {
  const double* p[4];
  for (int l = 0; l < 4; ++l) p[l] = tris + 9 * (l < count ? l : count - 1);
  __m256d a[3][3];  // [vertex][x, y, z in the ray's frame], translated to the ray's origin
  const int ax_of[3] = {r.kx, r.ky, r.kz};
  for (int v = 0; v < 3; ++v)
    for (int k = 0; k < 3; ++k) {
      const int c = 3 * v + ax_of[k];
      a[v][k] = _mm256_sub_pd(_mm256_set_pd(p[3][c], p[2][c], p[1][c], p[0][c]),
                              _mm256_set1_pd(r.org[ax_of[k]]));
    }
  const __m256d sx = _mm256_set1_pd(r.sx), sy = _mm256_set1_pd(r.sy), sz = _mm256_set1_pd(r.sz);
  __m256d x[3], y[3];
  for (int v = 0; v < 3; ++v) {
    x[v] = _mm256_sub_pd(a[v][0], _mm256_mul_pd(sx, a[v][2]));
    y[v] = _mm256_sub_pd(a[v][1], _mm256_mul_pd(sy, a[v][2]));
  }
  const __m256d U = _mm256_sub_pd(_mm256_mul_pd(x[2], y[1]), _mm256_mul_pd(y[2], x[1]));
  const __m256d V = _mm256_sub_pd(_mm256_mul_pd(x[0], y[2]), _mm256_mul_pd(y[0], x[2]));
  const __m256d W = _mm256_sub_pd(_mm256_mul_pd(x[1], y[0]), _mm256_mul_pd(y[1], x[0]));
  const __m256d zero = _mm256_setzero_pd();
  const int neg = _mm256_movemask_pd(_mm256_or_pd(
      _mm256_or_pd(_mm256_cmp_pd(U, zero, _CMP_LT_OQ), _mm256_cmp_pd(V, zero, _CMP_LT_OQ)),
      _mm256_cmp_pd(W, zero, _CMP_LT_OQ)));
  const int pos = _mm256_movemask_pd(_mm256_or_pd(
      _mm256_or_pd(_mm256_cmp_pd(U, zero, _CMP_GT_OQ), _mm256_cmp_pd(V, zero, _CMP_GT_OQ)),
      _mm256_cmp_pd(W, zero, _CMP_GT_OQ)));
  const int edge = _mm256_movemask_pd(_mm256_or_pd(
      _mm256_or_pd(_mm256_cmp_pd(U, zero, _CMP_EQ_OQ), _mm256_cmp_pd(V, zero, _CMP_EQ_OQ)),
      _mm256_cmp_pd(W, zero, _CMP_EQ_OQ)));
  const __m256d det = _mm256_add_pd(_mm256_add_pd(U, V), W);
  const __m256d T = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(U, _mm256_mul_pd(sz, a[0][2])),
                                                _mm256_mul_pd(V, _mm256_mul_pd(sz, a[1][2]))),
                                  _mm256_mul_pd(W, _mm256_mul_pd(sz, a[2][2])));
  const __m256d t = _mm256_div_pd(T, det);
  const int in =
      _mm256_movemask_pd(_mm256_and_pd(_mm256_cmp_pd(t, _mm256_set1_pd(r.tmin), _CMP_GE_OQ),
                                       _mm256_cmp_pd(t, _mm256_set1_pd(tmax), _CMP_LE_OQ)));
  const int flat = _mm256_movemask_pd(_mm256_cmp_pd(det, zero, _CMP_EQ_OQ));
  const int valid = (1 << (count < 4 ? count : 4)) - 1;
  return valid & ~(neg & pos) & ~flat & (in | edge);
}
#endif

// The state of one ray's traversal between steps. The stack as two arrays of 8-byte values
// (entry distance; reference and count packed), each written and read with 8-byte moves: a
// 16-byte entry struct is copied with 16-byte moves that cannot take their data from the
// two narrower stores that wrote it (a stall on every push and pop).
struct Bvh::HitWalk {
  static constexpr int kStack = 192;
  Ray ray;
  RayHit best;
  FRay fr;
  RayPair rp;
  // Boxes are culled against the best t with a relative margin: a triangle's computed t
  // and its box's slab distance round differently, and a hit a few ulps before the best
  // one must not be culled (the result is the smallest computed t).
  double cull;
  float cull_f;  // a float >= cull
  // the node visited next: a leaf (ecount > 0: its first triangle), or a QNode or Quad
  int32_t eref, ecount;
  int sp;
  bool found, any, use_float, pairwise, overflow;
  double stack_t[kStack];
  uint64_t stack_rc[kStack];
};

inline bool Bvh::walk_start(HitWalk* w, const Ray& ray, bool any) const {
  w->ray = ray;
  w->best = RayHit();
  w->best.t = ray.tmax;
  w->found = false;
  w->any = any;
  w->overflow = false;
  w->sp = 0;
  if (nodes_.empty()) return false;
  constexpr double inf = std::numeric_limits<double>::infinity();
  if (ray_box(ray, root_box_, ray.tmax) == inf) return false;
  w->pairwise = !(ray.flat[0] || ray.flat[1] || ray.flat[2]);
  // First hits (not any hits, whose answer is the first found and so depends on the order)
  // go down the QNodes in float where that is conservative (FRay): the same answer.
  w->fr = fray(ray);
  w->use_float = !any && w->fr.ok;
  if (!w->use_float) w->rp = ray_pair(ray);
  w->cull = w->best.t + 1e-9 * std::fabs(w->best.t);
  w->cull_f = up_float(w->cull);
  // The root first (a leaf, or Quad or QNode 0), then the nearest child met, taken without
  // a round trip through the stack (the order is that of pushing every child met and
  // popping the nearest, and so is the stack's depth at every record).
  w->eref = root_count_ > 0 ? root_ref_ : 0;
  w->ecount = root_count_;
  return true;
}

inline bool Bvh::walk_result(const HitWalk& w, RayHit* out) const {
  if (w.overflow) return brute_first(w.ray, w.any, out);
  if (w.found) {
    *out = w.best;
    out->face = ids_[w.best.face];
  }
  return w.found;
}

template <bool kAvx2>
inline bool Bvh::walk_step(HitWalk* w) const {
  constexpr double inf = std::numeric_limits<double>::infinity();
  constexpr int kStack = HitWalk::kStack;
  auto pack = [](int32_t ref, int32_t count) {
    return static_cast<uint64_t>(static_cast<uint32_t>(ref)) |
           static_cast<uint64_t>(static_cast<uint32_t>(count)) << 32;
  };
  const Ray& ray = w->ray;
  double* stack_t = w->stack_t;
  uint64_t* stack_rc = w->stack_rc;
  int sp = w->sp;
  const int32_t eref = w->eref, ecount = w->ecount;
  // a child met, inserted above the entries of this record at or before it (so the stack
  // holds them in order of decreasing t, ties in the order met)
  auto push = [&](int base, double t, uint64_t rc) {
    int at = sp++;
    while (at > base && stack_t[at - 1] <= t) {
      stack_t[at] = stack_t[at - 1];
      stack_rc[at] = stack_rc[at - 1];
      --at;
    }
    stack_t[at] = t;
    stack_rc[at] = rc;
  };
  // the entry at the top of the stack visited next
  auto visit_top = [&]() {
    const uint64_t erc = stack_rc[--sp];
    w->eref = static_cast<int32_t>(static_cast<uint32_t>(erc));
    w->ecount = static_cast<int32_t>(static_cast<uint32_t>(erc >> 32));
    w->sp = sp;
    return true;
  };
  if (ecount > 0) {
    RayHit h;
    // the triangles in order, each where ray_triangle may hit it (all, or by the AVX2
    // filter four at a time)
    auto test = [&](int32_t i) {
      if (ray_triangle(ray, &tris_[9 * static_cast<size_t>(i)], w->best.t, &h)) {
        if (!w->found || h.t < w->best.t || (h.t == w->best.t && ids_[i] < ids_[w->best.face])) {
          w->best = h;
          w->best.face = i;  // its place in tree order until the walk ends
          __builtin_prefetch(&ids_[i]);
          w->found = true;
          if (w->any) return false;
          w->cull = w->best.t + 1e-9 * std::fabs(w->best.t);
          w->cull_f = up_float(w->cull);
        }
      }
      return true;
    };
#if VOXAX_RAY_AVX2
    if constexpr (kAvx2) {
      for (int32_t i = eref; i < eref + ecount; i += 4) {
        int m = leaf_candidates_avx2(ray, &tris_[9 * static_cast<size_t>(i)], eref + ecount - i,
                                     w->best.t);
        while (m != 0) {
          const int l = __builtin_ctz(static_cast<unsigned>(m));
          m &= m - 1;
          if (!test(i + l)) return false;
        }
      }
    } else
#endif
      for (int32_t i = eref; i < eref + ecount; ++i)
        if (!test(i)) return false;
  } else {
    // the children met, pushed in order of decreasing t by insertion (ties keep the slot
    // order on the way up), so that the nearest is visited first
    const int base = sp;
    if (w->use_float) {
      if (sp + kFWidth > kStack) {
        w->overflow = true;
        return false;
      }
      const QNode& fq = qnodes_[eref];
      alignas(32) float tc[kFWidth];
      int mask;
#if VOXAX_RAY_AVX2
      if constexpr (kAvx2)
        mask = qnode_entries_avx2(w->fr, fq, w->cull_f, tc);
      else
#endif
        mask = qnode_entries(w->fr, fq, w->cull_f, tc);
      if (mask != 0 && (mask & (mask - 1)) == 0) {  // one child met: visited next
        const int j = __builtin_ctz(static_cast<unsigned>(mask));
        const int32_t rj = fq.ref[j];
        prefetch_fref(rj);
        w->eref = rj < 0 ? ~rj : rj;
        w->ecount = rj < 0 ? fq.count[j] : 0;
        return true;
      }
      while (mask != 0) {
        const int j = __builtin_ctz(static_cast<unsigned>(mask));
        mask &= mask - 1;
        const double tj = tc[j];
        const int32_t rj = fq.ref[j];
        prefetch_fref(rj);
        push(base, tj, rj < 0 ? pack(~rj, fq.count[j]) : pack(rj, 0));
      }
    } else {
      if (sp + kQuadWidth > kStack) {
        w->overflow = true;
        return false;
      }
      const Quad& qd = quads_[eref];
      for (int half = 0; half < kQuadWidth / 2; ++half) {
        const RayRec& pr = qd.half[half];
        double t2[2];
        record_entries(ray, w->rp, w->pairwise, pr, w->cull, t2);
        for (int j = 0; j < 2; ++j)
          if (pr.count[j] >= 0 && t2[j] != inf) {
            // the records or triangles start loading now (a hint: no effect on results)
            prefetch_ref(pr.ref[j], pr.count[j]);
            push(base, t2[j], pack(pr.ref[j], pr.count[j]));
          }
      }
    }
    // the nearest child met: within the cull distance, which is unchanged
    if (sp > base) return visit_top();
  }
  // the next entry of the stack not beyond the cull distance
  while (sp > 0 && stack_t[sp - 1] > w->cull) --sp;
  return sp > 0 && visit_top();
}

template <class Make, class Store>
inline void Bvh::first_hits(int64_t b, int64_t e, bool any, Make&& make, Store&& store) const {
#if VOXAX_RAY_AVX2
  if (ray_avx2_) return first_hits_avx2(b, e, any, make, store);
#endif
  first_hits_lanes<false>(b, e, any, make, store);
}

// Several rays in flight, a step of each in turn: a traversal's next record or triangles
// are loaded from memory (most of its time on a large tree) while the other rays take
// their steps. Each ray goes through the same steps as alone, so its result is the same.
template <bool kAvx2, class Make, class Store>
inline void Bvh::first_hits_lanes(int64_t b, int64_t e, bool any, Make& make, Store& store) const {
  constexpr int kLanes = 8;
  HitWalk lanes[kLanes];
  int64_t ray_of[kLanes];
  int live[kLanes];
  int n_live = 0;
  int64_t next = b;
  RayHit h;
  // Starts the next ray that needs a traversal in lane l (rays that miss the root box are
  // answered at once); false when none is left.
  auto start = [&](int l) {
    while (next < e) {
      const int64_t j = next++;
      if (walk_start(&lanes[l], make(j), any)) {
        ray_of[l] = j;
        return true;
      }
      store(j, walk_result(lanes[l], &h), h);
    }
    return false;
  };
  for (int l = 0; l < kLanes && start(l); ++l) live[n_live++] = l;
  while (n_live > 0) {
    for (int k = 0; k < n_live;) {
      const int l = live[k];
      if (walk_step<kAvx2>(&lanes[l])) {
        ++k;
        continue;
      }
      store(ray_of[l], walk_result(lanes[l], &h), h);
      if (start(l))
        ++k;
      else
        live[k] = live[--n_live];
    }
  }
}

#if VOXAX_RAY_AVX2
template <class Make, class Store>
inline void Bvh::first_hits_avx2(int64_t b, int64_t e, bool any, Make& make, Store& store) const {
  first_hits_lanes<true>(b, e, any, make, store);
}
#endif

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

// A bounding volume hierarchy over triangles, in float64: the tree (class Bvh), its
// build and its traversal layout. The queries are defined in bvh_closest.h and
// bvh_rays.h; include bvh.h for all of it.
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
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <new>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

// The first hits' traversal has a second version for x86-64 CPUs with AVX2, chosen at run
// time per tree (Bvh::build; `ray_avx2`): the library itself stays compiled for the
// baseline (SSE2).
#if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
#define VOXAX_RAY_AVX2 1
#include <immintrin.h>
#else
#define VOXAX_RAY_AVX2 0
#endif

#include "spatial/bvh_triangle.h"

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

// Four floats processed together (SSE on x86-64; plain code elsewhere): the float box test
// of first hits evaluates the eight children of a QNode as two groups of four.
typedef float V4f __attribute__((vector_size(16)));
typedef int V4i __attribute__((vector_size(16)));
inline V4f v4_splat(float x) { return V4f{x, x, x, x}; }
inline V4f v4_load(const float* f) {
  V4f v;
  std::memcpy(&v, f, sizeof(v));
  return v;
}
inline V4f v4_max(V4f a, V4f b) {  // a > b ? a : b, lane by lane
#if defined(__SSE__) && defined(__GNUC__) && !defined(__clang__)
  return __builtin_ia32_maxps(a, b);
#else
  return V4f{a[0] > b[0] ? a[0] : b[0], a[1] > b[1] ? a[1] : b[1], a[2] > b[2] ? a[2] : b[2],
             a[3] > b[3] ? a[3] : b[3]};
#endif
}
inline V4f v4_min(V4f a, V4f b) {  // a < b ? a : b, lane by lane
#if defined(__SSE__) && defined(__GNUC__) && !defined(__clang__)
  return __builtin_ia32_minps(a, b);
#else
  return V4f{a[0] < b[0] ? a[0] : b[0], a[1] < b[1] ? a[1] : b[1], a[2] < b[2] ? a[2] : b[2],
             a[3] < b[3] ? a[3] : b[3]};
#endif
}
// Bit k set where lane k of a <= b.
inline int v4_le_mask(V4f a, V4f b) {
#if defined(__SSE__) && defined(__GNUC__) && !defined(__clang__)
  return __builtin_ia32_movmskps(__builtin_ia32_cmpleps(a, b));
#else
  return (a[0] <= b[0] ? 1 : 0) | (a[1] <= b[1] ? 2 : 0) | (a[2] <= b[2] ? 4 : 0) |
         (a[3] <= b[3] ? 8 : 0);
#endif
}

// Eight bytes to eight floats (two vectors).
inline void u8x8_to_float(const uint8_t* p, V4f* out) {
#if defined(__SSE2__) && defined(__GNUC__) && !defined(__clang__)
  typedef long long V2ll __attribute__((vector_size(16)));
  typedef char V16c __attribute__((vector_size(16)));
  typedef short V8s __attribute__((vector_size(16)));
  long long bits;
  std::memcpy(&bits, p, 8);
  const V16c b = (V16c)(V2ll{bits, 0});
  const V16c z = {};
  const V8s w = (V8s)__builtin_ia32_punpcklbw128(b, z);
  const V8s zs = {};
  out[0] = __builtin_ia32_cvtdq2ps((V4i)__builtin_ia32_punpcklwd128(w, zs));
  out[1] = __builtin_ia32_cvtdq2ps((V4i)__builtin_ia32_punpckhwd128(w, zs));
#else
  out[0] = V4f{float(p[0]), float(p[1]), float(p[2]), float(p[3])};
  out[1] = V4f{float(p[4]), float(p[5]), float(p[6]), float(p[7])};
#endif
}

// The allocator of the large arrays that ray traversals read at random (triangles, their
// ids, the Quads): 64-byte aligned, and from 2 MiB on aligned to 2 MiB and (on Linux)
// marked for transparent huge pages, so that the traversals' loads rarely miss the TLB
// (a hint: no effect on results).
template <typename T>
struct LargeAlloc {
  typedef T value_type;
  LargeAlloc() = default;
  template <typename U>
  LargeAlloc(const LargeAlloc<U>&) {}
  T* allocate(size_t n) {
    constexpr size_t kHuge = size_t(1) << 21;
    // at most PTRDIFF_MAX bytes once rounded up to the alignment
    constexpr size_t kMaxBytes =
        static_cast<size_t>(std::numeric_limits<std::ptrdiff_t>::max()) - kHuge;
    if (n > kMaxBytes / sizeof(T)) throw std::bad_alloc();
    const size_t bytes = n * sizeof(T);
    const size_t align = bytes >= kHuge ? kHuge : std::max<size_t>(64, alignof(T));
    const size_t rounded = std::max(align, (bytes + align - 1) / align * align);  // never 0
    void* p = std::aligned_alloc(align, rounded);
    if (!p) throw std::bad_alloc();
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (bytes >= kHuge) madvise(p, rounded, MADV_HUGEPAGE);
#endif
    return static_cast<T*>(p);
  }
  void deallocate(T* p, size_t) { std::free(p); }
  template <typename U>
  bool operator==(const LargeAlloc<U>&) const {
    return true;
  }
  template <typename U>
  bool operator!=(const LargeAlloc<U>&) const {
    return false;
  }
};
template <typename T>
using LargeVector = std::vector<T, LargeAlloc<T>>;

struct Node {
  Box3 box;
  int32_t first = 0;  // leaf: first triangle; inner: index of the left child
  int32_t count = 0;  // leaf: number of triangles (> 0); inner: 0 (right child = left + 1)
};

class Bvh {
 public:
  static constexpr int kBins = 16;
  // Small leaves: a ray's leaf visits load fewer triangles (72 bytes each, mostly from
  // memory on a large mesh), for more (cached) records on the way down. Against 4, first
  // hits on 1.5M faces took 0.90 of the time, closest points the same, the build 1.26x.
  static constexpr int kMaxLeaf = 2;

  // V: (nv, 3), F: (nf, 3), both validated by the caller.
  void build(const double* V, const int32_t* F, int64_t nf) {
    const int32_t n = static_cast<int32_t>(nf);
    tris_.assign(static_cast<size_t>(n) * 9, 0.0);
    ids_.resize(n);
    degenerate_.assign(n, 0);
    tri_boxes_.assign(n, Box3());
    nodes_.clear();
    ray_avx2_ = choose_ray_avx2();
    // the faces' boxes and centroids, kept in tree order as the splits partition them (each
    // node's scans read its range in sequence)
    std::vector<BuildItem> items(n);
    for (int32_t f = 0; f < n; ++f) {
      BuildItem& it = items[f];
      it.face = f;
      for (int k = 0; k < 3; ++k) it.box.grow(V + 3 * static_cast<int64_t>(F[3 * int64_t(f) + k]));
      for (int a = 0; a < 3; ++a) it.cent[a] = 0.5 * (it.box.lo[a] + it.box.hi[a]);
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
        node.box.grow(items[i].box);
        cb.grow(items[i].cent);
      }
      const int32_t count = task.end - task.begin;
      int32_t mid = -1;
      if (count > kMaxLeaf) mid = split(items, task.begin, task.end, node.box, cb);
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
      const int32_t f = items[i].face;
      ids_[i] = f;
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a)
          tris_[9 * static_cast<size_t>(i) + 3 * k + a] =
              V[3 * static_cast<int64_t>(F[3 * int64_t(f) + k]) + a];
      const double* t = &tris_[9 * static_cast<size_t>(i)];
      degenerate_[i] = triangle_degenerate(t, t + 3, t + 6) ? 1 : 0;
      tri_boxes_[i] = items[i].box;
    }
    build_pairs();
  }

  int64_t node_count() const { return static_cast<int64_t>(nodes_.size()); }
  int64_t face_count() const { return static_cast<int64_t>(ids_.size()); }
  // The number of QNodes (0: first hits take the float64 test on the Quads for every ray).
  int64_t float_record_count() const { return static_cast<int64_t>(qnodes_.size()); }

  // The closest point to p. `hint` (a slot from an earlier result, or -1) seeds the
  // search with that triangle's distance; the answer does not depend on it: it is
  // always the smallest (distance, face index). With `cap2` finite, only triangles at
  // squared distance <= cap2 count: where there is none the result is the default one
  // (face -1, infinite distance), found after a search pruned at that distance.
  ClosestResult closest(const double* p, int32_t hint = -1,
                        double cap2 = std::numeric_limits<double>::infinity()) const;

  // The first hits (smallest t, ties to the lowest face index; with `any`, any hit) of rays
  // b..e-1, several traced at once (see first_hits_lanes): make(j) gives ray j, then
  // store(j, found, hit) takes its result (in no particular order of j). Each ray's result
  // does not depend on the others.
  template <class Make, class Store>
  void first_hits(int64_t b, int64_t e, bool any, Make&& make, Store&& store) const;
  // Whether first hits take the AVX2 traversal (the CPU has AVX2 and VOXAX_NO_AVX2 is unset
  // or 0 when the tree was built): the same results either way.
  bool ray_avx2() const { return ray_avx2_; }

  // Every hit within [tmin, tmax], appended to *out sorted by (t, face).
  void all_hits(const Ray& ray, std::vector<RayHit>* out) const;

  // The sum of ray_crossing over every triangle whose box the ray (from r.tmin, which
  // should be -margin) meets, through the float records (their boxes contain the double
  // ones). Returns false (and leaves *sum) where a crossing is unclear.
  bool crossings(const Ray& ray, double margin, int64_t* sum) const;

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
  LargeVector<double> tris_;
  LargeVector<int32_t> ids_;
  std::vector<uint8_t> degenerate_;
  std::vector<Box3> tri_boxes_;
  std::vector<std::array<int32_t, 2>>
      ranges_;  // per node: its triangles in tree order (build only)

  // The traversal layout: one 128-byte record per inner node with the bounds of
  // both children in float, rounded outwards (a float box contains the double
  // one, so it never prunes what the double box keeps). The boxes and the child
  // references fill the first cache line, the slabs of closest-point searches the
  // second. Rays read Quads instead (below).
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
  // Two children's boxes and references (as in a Pair's first line): half of a Quad.
  struct alignas(64) RayRec {
    float lo[3][2], hi[3][2];
    int32_t ref[2], count[2];
  };
  static_assert(sizeof(RayRec) == 64, "RayRec must fill one cache line");
  struct FSlab {
    float c[3] = {0, 0, 0}, n[3] = {0, 0, 1};
    float r = std::numeric_limits<float>::infinity(), h = std::numeric_limits<float>::infinity();
  };
  std::vector<Pair> pairs_;
  // The ray traversals' four-wide tree (first and any hits, crossings): a Pair with its
  // children's Pairs collapsed into one record of up to four children (two RayRecs: two
  // adjacent cache lines, and half the levels of the Pairs); an inner child refers to a
  // Quad, an unused slot has count -1 and an empty box.
  static constexpr int kQuadWidth = 4;  // children per Quad (even: RayRecs hold two)
  struct alignas(64) Quad {
    RayRec half[kQuadWidth / 2];
  };
  LargeVector<Quad> quads_;
  // The first hits' tree: records (QNodes) of up to eight children, a Pair with its inner
  // children opened by largest box area while slots are left (as in a Quad). The bounds
  // are taken relative to the root box's centre fcentre_ (each rounded outwards from the
  // Pair's float bound minus the centre, in float: an FNode, built and then dropped), then
  // quantised to 8 bits on a grid of the QNode's own per axis, rounded outwards exactly
  // (make_qnodes): eight children in two cache lines, tested in float where that is
  // conservative (FRay). Empty where a bound is beyond 2^60 from the centre, or a leaf has
  // over 127 triangles: first hits then take the float64 test on the Quads.
  static constexpr int kFWidth = 8;
  struct FNode {
    float lo[3][kFWidth], hi[3][kFWidth];  // [axis][child]
    // a leaf: ~(its first triangle) and its count; an inner child: its FNode and 0; an
    // unused slot: ~0 and 0, and an empty box
    int32_t ref[kFWidth], aux[kFWidth];
  };
  struct alignas(64) QNode {
    // child k's box on axis a: base + q[0][a][k] scale to base + q[1][a][k] scale
    uint8_t q[2][3][kFWidth];
    float base[4], scale[4];  // per axis (the fourth unused): scale a power of two
    int32_t ref[kFWidth];     // as the FNode's
    int8_t count[kFWidth];    // a leaf's count, 0 for an inner child or an unused slot
    uint8_t used;             // bit k: slot k holds a child
  };
  static_assert(sizeof(QNode) == 128, "QNode must fill two cache lines");
  LargeVector<QNode> qnodes_;
  double fcentre_[3] = {0, 0, 0};
  double qmax_[3] = {0, 0, 0};    // per axis the largest |base| + 255 scale of a QNode
  double fext_ = 0.0;             // the root box's largest extent
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
  // A float >= x, as round_up but cheaper (no library call) where |x| is within [2^-100,
  // 2^100]: x moved up by 2^-20 of its magnitude, then rounded to the nearest float (a
  // relative error of at most 2^-24), so still above x.
  static float up_float(double x) {
    constexpr double kLo = 7.888609052210118e-31, kHi = 1.2676506002282294e30;  // 2^-100, 2^100
    const double ax = std::fabs(x);
    if (!(ax >= kLo && ax <= kHi)) return round_up(x);
    return static_cast<float>(x + ax * (1.0 / 1048576.0));
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
    quads_.clear();
    // at most one Quad per Pair: no reallocation (the pages of the capacity not used are
    // never touched)
    quads_.reserve(pairs_.size());
    if (root_count_ == 0) make_quad(root_ref_);
    qnodes_.clear();
    if (root_count_ == 0) {
      fext_ = 0.0;
      for (int a = 0; a < 3; ++a) {
        fcentre_[a] = 0.5 * root_box_.lo[a] + 0.5 * root_box_.hi[a];
        fext_ = std::max(fext_, root_box_.hi[a] - root_box_.lo[a]);
      }
      bool ok = true;
      std::vector<FNode> fn;
      fn.reserve(quads_.size());  // a hint: an FNode takes up to 7 Pairs, a Quad 3
      make_fnode(root_ref_, &fn, &ok);
      if (ok) make_qnodes(fn);
    }
    ranges_.clear();
    ranges_.shrink_to_fit();
  }

  struct ChildRef {
    int32_t pair, j;  // child j of Pair `pair`
  };

  // The children of a wide record over Pair p: p's two, then repeatedly the inner child
  // of largest box area replaced by its own two, while fewer than `width` are held.
  // Writes them to kids[0:n] and returns n.
  int open_children(int32_t p, ChildRef* kids, int width) const {
    int slot = 0;
    kids[slot++] = {p, 0};
    kids[slot++] = {p, 1};
    while (slot < width) {
      int pick = -1;
      double area = -1.0;
      for (int k = 0; k < slot; ++k) {
        const Pair& src = pairs_[kids[k].pair];
        const int j = kids[k].j;
        if (src.count[j] != 0) continue;
        double e[3];
        for (int a = 0; a < 3; ++a)
          e[a] = static_cast<double>(src.hi[a][j]) - static_cast<double>(src.lo[a][j]);
        const double ar = e[0] * e[1] + e[1] * e[2] + e[2] * e[0];
        if (ar > area) {
          area = ar;
          pick = k;
        }
      }
      if (pick < 0) break;
      const int32_t c = pairs_[kids[pick].pair].ref[kids[pick].j];
      kids[pick] = {c, 0};
      kids[slot++] = {c, 1};
    }
    return slot;
  }

  // Appends the Quad of Pair p (and those below it, depth first); returns its index. Its
  // children: `open_children`'s.
  int32_t make_quad(int32_t p) {
    const int32_t q = static_cast<int32_t>(quads_.size());
    quads_.emplace_back();
    ChildRef kids[kQuadWidth];
    const int slot = open_children(p, kids, kQuadWidth);
    for (int k = 0; k < kQuadWidth; ++k) {
      RayRec& h = quads_[q].half[k / 2];
      const int lane = k % 2;
      if (k >= slot) {
        for (int a = 0; a < 3; ++a) {
          h.lo[a][lane] = std::numeric_limits<float>::infinity();
          h.hi[a][lane] = -std::numeric_limits<float>::infinity();
        }
        h.ref[lane] = 0;
        h.count[lane] = -1;
        continue;
      }
      const Pair& src = pairs_[kids[k].pair];
      const int j = kids[k].j;
      for (int a = 0; a < 3; ++a) {
        h.lo[a][lane] = src.lo[a][j];
        h.hi[a][lane] = src.hi[a][j];
      }
      h.count[lane] = src.count[j];
      h.ref[lane] = src.ref[j];
    }
    // inner children: their own Quads (after this one's slots are set: quads_ may move)
    for (int k = 0; k < slot; ++k) {
      if (quads_[q].half[k / 2].count[k % 2] != 0) continue;
      const int32_t child = make_quad(quads_[q].half[k / 2].ref[k % 2]);
      quads_[q].half[k / 2].ref[k % 2] = child;
    }
    return q;
  }

  // x - c rounded down (up: up) to a float: the difference rounded to nearest, its
  // rounding error (exact, by Knuth's two-sum), one step outwards where that rounding went
  // inwards, and the outward rounding to float.
  static float relative_bound(double x, double c, bool up) {
    const double s = x - c;
    const double bb = s - x;
    const double err = (x - (s - bb)) + (-c - bb);  // (x - c) - s exactly
    double r = s;
    if (!up && err < 0.0) r = std::nextafter(s, -std::numeric_limits<double>::infinity());
    if (up && err > 0.0) r = std::nextafter(s, std::numeric_limits<double>::infinity());
    return up ? round_up(r) : round_down(r);
  }

  // Appends the FNode of Pair p (and those below it, depth first) to *out; returns its
  // index. *ok turns false where a bound is beyond the float path's range.
  int32_t make_fnode(int32_t p, std::vector<FNode>* out, bool* ok) {
    constexpr double kLimit = 1152921504606846976.0;  // 2^60
    const int32_t q = static_cast<int32_t>(out->size());
    out->emplace_back();
    ChildRef kids[kFWidth];
    const int slot = open_children(p, kids, kFWidth);
    FNode f;
    for (int k = 0; k < kFWidth; ++k) {
      f.ref[k] = ~0;
      f.aux[k] = 0;
      for (int a = 0; a < 3; ++a) {
        f.lo[a][k] = std::numeric_limits<float>::infinity();
        f.hi[a][k] = -std::numeric_limits<float>::infinity();
      }
      if (k >= slot) continue;
      const Pair& src = pairs_[kids[k].pair];
      const int j = kids[k].j;
      for (int a = 0; a < 3; ++a) {
        f.lo[a][k] = relative_bound(src.lo[a][j], fcentre_[a], false);
        f.hi[a][k] = relative_bound(src.hi[a][j], fcentre_[a], true);
        const double m = std::max(std::fabs(static_cast<double>(f.lo[a][k])),
                                  std::fabs(static_cast<double>(f.hi[a][k])));
        if (!(m <= kLimit)) *ok = false;  // (NaN included)
      }
      if (src.count[j] > 127) *ok = false;
      if (src.count[j] > 0) {
        f.ref[k] = ~src.ref[j];
        f.aux[k] = src.count[j];
      }
    }
    (*out)[q] = f;
    for (int k = 0; k < slot; ++k) {
      const Pair& src = pairs_[kids[k].pair];
      const int j = kids[k].j;
      if (src.count[j] != 0) continue;
      const int32_t child = make_fnode(src.ref[j], out, ok);
      (*out)[q].ref[k] = child;
    }
    return q;
  }

  // The QNodes of the FNodes (same indices), or none where a grid does not fit. Per node
  // and axis the grid: scale the smallest power of two at least 2^-100, the children's
  // extent / 255 and |lowest bound| 2^-23 (so that base, a multiple of it, is a float);
  // base the lowest bound rounded down to a multiple of it; each bound to the grid point
  // below (lo) or above (hi) it, in exact integer arithmetic (double), so the quantised
  // box contains the float one.
  void make_qnodes(const std::vector<FNode>& fn) {
    qnodes_.resize(fn.size());  // cleared again where a grid does not fit
    QNode* out = qnodes_.data();
    for (int a = 0; a < 3; ++a) qmax_[a] = 0.0;
    for (size_t i = 0; i < fn.size(); ++i) {
      const FNode& f = fn[i];
      QNode& q = out[i];
      std::memset(&q, 0, sizeof(q));
      q.used = 0;
      for (int k = 0; k < kFWidth; ++k) {
        q.ref[k] = f.ref[k];
        q.count[k] = static_cast<int8_t>(f.ref[k] < 0 ? f.aux[k] : 0);
        if (f.lo[0][k] <= f.hi[0][k]) q.used |= static_cast<uint8_t>(1u << k);
      }
      for (int a = 0; a < 3; ++a) {
        double lo = std::numeric_limits<double>::infinity(), hi = -lo;
        for (int k = 0; k < kFWidth; ++k)
          if (q.used >> k & 1) {
            lo = std::min(lo, static_cast<double>(f.lo[a][k]));
            hi = std::max(hi, static_cast<double>(f.hi[a][k]));
          }
        if (q.used == 0) lo = hi = 0.0;
        double sc = std::max(
            {(hi - lo) / 255.0, std::fabs(lo) * 1.1920928955078125e-07, 7.888609052210118e-31});
        int ex = 0;
        std::frexp(sc, &ex);
        sc = std::ldexp(1.0, ex);  // a power of two >= sc
        for (int tries = 0;; ++tries) {
          const double m = std::floor(lo / sc);
          bool fits = std::fabs(m) <= 16777216.0;
          for (int k = 0; k < kFWidth && fits; ++k) {
            if (!(q.used >> k & 1)) continue;
            const double ql = std::floor(static_cast<double>(f.lo[a][k]) / sc) - m;
            const double qh = std::ceil(static_cast<double>(f.hi[a][k]) / sc) - m;
            fits = ql >= 0.0 && qh <= 255.0 && ql <= qh;
            if (fits) {
              q.q[0][a][k] = static_cast<uint8_t>(ql);
              q.q[1][a][k] = static_cast<uint8_t>(qh);
            }
          }
          if (fits) {
            q.base[a] = static_cast<float>(m * sc);
            q.scale[a] = static_cast<float>(sc);
            if (static_cast<double>(q.base[a]) != m * sc || static_cast<double>(q.scale[a]) != sc) {
              qnodes_.clear();
              return;
            }
            qmax_[a] = std::max(qmax_[a], std::fabs(m * sc) + 255.0 * sc);
            break;
          }
          if (tries > 4 || !(sc < 1e300)) {
            qnodes_.clear();
            return;
          }
          sc *= 2.0;
        }
        for (int k = 0; k < kFWidth; ++k)
          if (!(q.used >> k & 1)) {
            q.q[0][a][k] = 255;
            q.q[1][a][k] = 0;
          }
      }
      q.base[3] = 0.0f;
      q.scale[3] = 0.0f;
    }
    for (int a = 0; a < 3; ++a)
      if (!(qmax_[a] <= 1152921504606846976.0)) qnodes_.clear();
  }

  // A ray for the float test of QNodes, where it is conservative. Per axis, with o the
  // origin minus fcentre_ and inv the reciprocal direction (both rounded to the nearest
  // float), the distance of grid point q, q (scale inv) + (base - o) inv - e (near) or + e
  // (far), computed in float, is within 6 u (Q + |o|) |inv| + 2.1 u e of its exact value
  // (u = 2^-24, Q = |base| + 255 scale: the roundings of o, inv and four operations; the
  // product scale inv is exact), plus 2^-100 (|inv| + 1) for results below the normal
  // range flushed to zero (XLA's threads). With e = 10 u (2 Q + |o|) |inv| (1 + 2^-20) +
  // 2^-100 (|inv| + 1) that leaves a margin above the float64 test's own rounding (its far
  // distance grown by 1 + 2 gamma_3, a few 1e-16 relatively), and the quantised boxes
  // contain the Quads' float boxes: every box the float64 test on the Quads keeps is kept,
  // each entry distance is at most the float64 one, and so the first hit is the same.
  // Rays where that bound does not hold, or where e is too wide to prune (over 2^-12 of
  // the root box's extent, as distance along the axis), are not `ok` and take the float64
  // test: a zero direction component, |inv| outside [2^-60, 2^60], |o| beyond 2^60.
  struct FRay {
    V4f org, inv, grow;  // per axis (lane 3 unused)
    float tmin;
    int32_t near[3], far[3];  // byte offsets of the near and far bounds of axis a
    bool ok;
  };
  FRay fray(const Ray& r) const {
    FRay s;
    s.org = s.inv = s.grow = v4_splat(0.0f);
    constexpr double kLimit = 1152921504606846976.0;  // 2^60
    constexpr double kTiny = 7.888609052210118e-31;   // 2^-100
    constexpr double kU = 5.9604644775390625e-08;     // 2^-24
    s.ok = !qnodes_.empty();
    for (int a = 0; a < 3 && s.ok; ++a) {
      const double o = r.org[a] - fcentre_[a];
      const double inv = r.inv[a];
      const double ai = std::fabs(inv);
      if (r.flat[a] || !(ai >= 1.0 / kLimit && ai <= kLimit && std::fabs(o) <= kLimit)) {
        s.ok = false;
        break;
      }
      const double e = 10.0 * kU * (2.0 * qmax_[a] + std::fabs(o)) * ai * (1.0 + 1.0 / 1048576.0) +
                       kTiny * (ai + 1.0);
      if (!(e <= fext_ * (1.0 / 4096.0) * ai)) {
        s.ok = false;
        break;
      }
      s.org[a] = static_cast<float>(o);
      s.inv[a] = static_cast<float>(inv);
      s.grow[a] = up_float(e);
      const bool neg = inv < 0.0;
      s.near[a] = (neg ? 3 * kFWidth : 0) + kFWidth * a;
      s.far[a] = (neg ? 0 : 3 * kFWidth) + kFWidth * a;
    }
    s.tmin = round_down(r.tmin);
    return s;
  }

  // The entry distances (lower bounds) of the children of a QNode within [tmin, tfar]
  // (tfar: a float at least the cull distance), and the mask of those met. Per axis the
  // distance of grid point q is q (scale inv) + (base - o) inv, the first product exact.
  static int qnode_entries(const FRay& s, const QNode& q, float tfar, float* t) {
    const V4f base = v4_load(q.base), scale = v4_load(q.scale);
    const V4f A = scale * s.inv;
    const V4f B = (base - s.org) * s.inv;
    const V4f cn = B - s.grow, cf = B + s.grow;
    const uint8_t* qb = q.q[0][0];
    V4f t0[2] = {v4_splat(s.tmin), v4_splat(s.tmin)};
    V4f t1[2] = {v4_splat(tfar), v4_splat(tfar)};
    for (int a = 0; a < 3; ++a) {
      V4f qn[2], qf[2];
      u8x8_to_float(qb + s.near[a], qn);
      u8x8_to_float(qb + s.far[a], qf);
      const V4f Aa = v4_splat(A[a]), na = v4_splat(cn[a]), fa = v4_splat(cf[a]);
      for (int g = 0; g < 2; ++g) {
        t0[g] = v4_max(qn[g] * Aa + na, t0[g]);
        t1[g] = v4_min(qf[g] * Aa + fa, t1[g]);
      }
    }
    std::memcpy(t, &t0[0], sizeof(V4f));
    std::memcpy(t + 4, &t0[1], sizeof(V4f));
    return (v4_le_mask(t0[0], t1[0]) | v4_le_mask(t0[1], t1[1]) << 4) & q.used;
  }

#if VOXAX_RAY_AVX2
  // qnode_entries with the eight children in one 256-bit vector: the same operations on
  // the same values lane by lane (products and sums rounded apart, no fused multiply-add),
  // so the same distances and mask bit for bit.
  __attribute__((target("avx2"))) static int qnode_entries_avx2(const FRay& s, const QNode& q,
                                                                float tfar, float* t) {
    const V4f base = v4_load(q.base), scale = v4_load(q.scale);
    alignas(16) float A[4], cn[4], cf[4];
    {
      const V4f a4 = scale * s.inv;
      const V4f b4 = (base - s.org) * s.inv;
      const V4f n4 = b4 - s.grow, f4 = b4 + s.grow;
      std::memcpy(A, &a4, sizeof(A));
      std::memcpy(cn, &n4, sizeof(cn));
      std::memcpy(cf, &f4, sizeof(cf));
    }
    const uint8_t* qb = q.q[0][0];
    __m256 t0 = _mm256_set1_ps(s.tmin), t1 = _mm256_set1_ps(tfar);
    for (int a = 0; a < 3; ++a) {
      const __m256 qn = _mm256_cvtepi32_ps(
          _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(qb + s.near[a]))));
      const __m256 qf = _mm256_cvtepi32_ps(
          _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(qb + s.far[a]))));
      const __m256 Aa = _mm256_set1_ps(A[a]);
      t0 = _mm256_max_ps(_mm256_add_ps(_mm256_mul_ps(qn, Aa), _mm256_set1_ps(cn[a])), t0);
      t1 = _mm256_min_ps(_mm256_add_ps(_mm256_mul_ps(qf, Aa), _mm256_set1_ps(cf[a])), t1);
    }
    _mm256_storeu_ps(t, t0);
    return _mm256_movemask_ps(_mm256_cmp_ps(t0, t1, _CMP_LE_OQ)) & q.used;
  }
#endif

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
  // Starts loading what a ray visits next at a Quad's slot: the Quad of an inner child,
  // or a leaf's first triangles (a hint: no effect on results).
  void prefetch_ref(int32_t ref, int32_t count) const {
    if (count > 0) {
      const double* t = &tris_[9 * static_cast<size_t>(ref)];
      __builtin_prefetch(t);
      __builtin_prefetch(t + 8);
    } else {
      const char* q = reinterpret_cast<const char*>(&quads_[static_cast<size_t>(ref)]);
      __builtin_prefetch(q);
      __builtin_prefetch(q + 64);
    }
  }

  // prefetch_ref for a QNode's slot (ref < 0: a leaf's ~first triangle).
  void prefetch_fref(int32_t ref) const {
    if (ref < 0) {
      const char* t = reinterpret_cast<const char*>(&tris_[9 * static_cast<size_t>(~ref)]);
      __builtin_prefetch(t);
      __builtin_prefetch(t + 64);
    } else {
      const char* q = reinterpret_cast<const char*>(&qnodes_[static_cast<size_t>(ref)]);
      __builtin_prefetch(q);
      __builtin_prefetch(q + 64);
    }
  }

  template <typename Rec>
  static double pair_ray_box(const Ray& r, const Rec& pr, int j, double tfar) {
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
    // per axis the byte offsets of the near and the far bounds in a record whose lo[3][2]
    // and hi[3][2] (float) start at 0 and 24 (RayRec, Pair): a load, not a branch
    int32_t near[3], far[3];
  };
  static RayPair ray_pair(const Ray& r) {
    RayPair s;
    for (int a = 0; a < 3; ++a) {
      s.org[a] = v2_splat(r.org[a]);
      s.inv[a] = v2_splat(r.inv[a]);
      const bool neg = r.inv[a] < 0.0;
      s.near[a] = (neg ? 24 : 0) + 8 * a;
      s.far[a] = (neg ? 0 : 24) + 8 * a;
    }
    s.tmin = r.tmin;
    return s;
  }
  template <typename Rec>
  static V2d pair_ray_boxes(const RayPair& s, const Rec& pr, double tfar) {
    V2d t0 = v2_splat(s.tmin), t1 = v2_splat(tfar);
    static_assert(offsetof(Rec, lo) == 0 && offsetof(Rec, hi) == 24, "bounds at 0 and 24");
    const char* base = reinterpret_cast<const char*>(&pr);
    for (int a = 0; a < 3; ++a) {
      const V2d near = v2_load(reinterpret_cast<const float*>(base + s.near[a]));
      const V2d far = v2_load(reinterpret_cast<const float*>(base + s.far[a]));
      const V2d tn = (near - s.org[a]) * s.inv[a];
      const V2d f = (far - s.org[a]) * s.inv[a];
      const V2d tf = f * v2_select(f < 0.0, v2_splat(kShrink), v2_splat(kGrow));
      t0 = v2_max(tn, t0);
      t1 = v2_min(tf, t1);
    }
    return v2_select(t0 > t1, v2_splat(std::numeric_limits<double>::infinity()), t0);
  }

  // The entry distances of the two children of a record within [tmin, tfar] (inf for one
  // missed, and for an unused slot): both at once, or one by one for a ray with a zero
  // direction component (`pairwise` false).
  static void record_entries(const Ray& ray, const RayPair& rp, bool pairwise, const RayRec& pr,
                             double tfar, double* t2) {
    if (pairwise) {
      const V2d tt = pair_ray_boxes(rp, pr, tfar);
      t2[0] = tt[0];
      t2[1] = tt[1];
    } else {
      for (int j = 0; j < 2; ++j)
        t2[j] = pr.count[j] < 0 ? std::numeric_limits<double>::infinity()
                                : pair_ray_box(ray, pr, j, tfar);
    }
  }

  // A traversal that visits every child a ray meets (all hits, crossings): a stack of
  // {ref, count} (a leaf's triangles, or a Quad), starting at the root.
  struct QuadWalk {
    struct Entry {
      int32_t ref, count;
    };
    static constexpr int kStack = 192;
    Entry stack[kStack];
    int sp = 0;
    bool pairwise;
    RayPair rp;
    QuadWalk(const Bvh& bvh, const Ray& ray)
        : pairwise(!(ray.flat[0] || ray.flat[1] || ray.flat[2])), rp(ray_pair(ray)) {
      // the root: a leaf, or Quad 0
      stack[sp++] = {bvh.root_count_ > 0 ? bvh.root_ref_ : 0, bvh.root_count_};
    }
    bool full() const { return sp + kQuadWidth > kStack; }
    // Pushes every child of qd the ray meets within [tmin, tmax], the last slot first (so
    // the first is popped first).
    void push_children(const Ray& ray, const Quad& qd) {
      for (int half = kQuadWidth / 2 - 1; half >= 0; --half) {
        const RayRec& pr = qd.half[half];
        double t2[2];
        record_entries(ray, rp, pairwise, pr, ray.tmax, t2);
        for (int j = 1; j >= 0; --j)
          if (pr.count[j] >= 0 && t2[j] != std::numeric_limits<double>::infinity())
            stack[sp++] = {pr.ref[j], pr.count[j]};
      }
    }
  };

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

  ClosestResult brute_closest(const double* p) const;

  bool brute_first(const Ray& ray, bool any, RayHit* out) const;
  // A first- (or any-) hit traversal as a sequence of steps, each the visit of one QNode,
  // Quad or leaf (bvh_rays.h): walk_start, then walk_step until it returns false, then
  // walk_result. Several rays' walks are interleaved (first_hits_lanes), each taking the
  // same steps as it would alone.
  struct HitWalk;
  bool walk_start(HitWalk* w, const Ray& ray, bool any) const;
  template <bool kAvx2>
  bool walk_step(HitWalk* w) const;
  bool walk_result(const HitWalk& w, RayHit* out) const;
  // The traversals, kAvx2 with the QNodes' test in AVX2 (inlined into the *_avx2 functions,
  // compiled for AVX2 as a whole: the rest is the same scalar code, which rounds the same
  // there, with no fused multiply-add).
  template <bool kAvx2, class Make, class Store>
  void first_hits_lanes(int64_t b, int64_t e, bool any, Make& make, Store& store) const;
#if VOXAX_RAY_AVX2
  template <class Make, class Store>
  __attribute__((target("avx2"), flatten)) void first_hits_avx2(int64_t b, int64_t e, bool any,
                                                                Make& make, Store& store) const;
#endif
  bool ray_avx2_ = false;
  static bool choose_ray_avx2() {
#if VOXAX_RAY_AVX2
    __builtin_cpu_init();
    if (!__builtin_cpu_supports("avx2")) return false;
    const char* no = std::getenv("VOXAX_NO_AVX2");
    return no == nullptr || no[0] == '\0' || std::strcmp(no, "0") == 0;
#else
    return false;
#endif
  }

  // A face during the build: its box and the box's centre.
  struct BuildItem {
    Box3 box;
    double cent[3];
    int32_t face;
  };
  // Binned SAH split of items[begin, end). Returns the split position, or -1 for a leaf.
  int32_t split(std::vector<BuildItem>& items, int32_t begin, int32_t end, const Box3& nb,
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
        int k = static_cast<int>((items[i].cent[a] - cb.lo[a]) * scale);
        k = std::min(kBins - 1, std::max(0, k));
        bn[k]++;
        bb[k].grow(items[i].box);
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
    auto mid_it =
        std::partition(items.begin() + begin, items.begin() + end, [&](const BuildItem& it) {
          int k = static_cast<int>((it.cent[a] - cb.lo[a]) * scale);
          k = std::min(kBins - 1, std::max(0, k));
          return k < best_bin;
        });
    const int32_t mid = static_cast<int32_t>(mid_it - items.begin());
    if (mid == begin || mid == end) return begin + count / 2;
    return mid;
  }
};

}  // namespace spatial
}  // namespace voxax

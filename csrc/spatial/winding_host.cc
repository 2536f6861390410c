// Eager host entry point of the winding numbers (see spatial/winding.h), a plain C ABI for
// ctypes. Validates its input, catches every exception and reports failures as a
// non-zero status with a message in `err`.
//
//   voxax_winding_number(V (nv, 3) f64, nv, F (nf, 3) i32, nf, P (n, 3) f64, n, mode,
//                        accuracy, threads, out (n,) f64, stats (2,) i64, err, errlen)
//     mode 0: one ray per point where the faces form a cycle; where they do not but their
//     boundary has at most a quarter as many edges as there are faces, one ray through the
//     faces and a cap over the boundary, reversed, plus the cap's sum; the hierarchy of
//     boundaries (WindingTree) elsewhere and for the points a ray leaves unclear (the plain
//     sum where they are few); mode 1: the plain solid-angle sum everywhere (face by face).
//     accuracy (finite, >= 0; mode 0 only): 0 for the exact sums, eps > 0 for the
//     error-bounded far-field expansion (WindingTree::eval_approx: within eps of the
//     solid-angle sum, up to rounding) of the cap (of more than kExactCap triangles) and
//     of the hierarchy. stats: [faces form a cycle, points decided by a ray].

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "common/host_pool.h"
#include "spatial/winding.h"
#include "spatial/winding_rays.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {

constexpr int64_t kChunk = 256;  // points per task: fixed, so results do not depend on threads
// Up to this many points left unclear by their rays take the plain sum (O(faces) each)
// instead of the hierarchy, whose build costs about as much as a few dozen plain sums.
constexpr int64_t kPlainPoints = 16;
// Caps of at most this many triangles take their exact sum also with `accuracy`.
constexpr int64_t kExactCap = 48;

// The direction of every ray: no component zero and far from any axis or diagonal plane,
// so that the faces of axis-aligned and lattice meshes are rarely met at an edge.
constexpr double kDir[3] = {0.5380366873043318, 0.6914262851176237, 0.4820538419276491};

}  // namespace

VOXAX_EXPORT int voxax_winding_number(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                                      const double* P, int64_t n, int32_t mode, double accuracy,
                                      int32_t threads, double* out, int64_t* stats, char* err,
                                      int64_t errlen) {
  return voxax::host_guarded("the winding numbers", err, errlen, [&](std::string* msg) {
    if (nv < 0 || nf < 0 || n < 0 || nf > INT32_MAX / 2) {
      *msg = "voxax: the winding numbers take at most 2^30 faces";
      return false;
    }
    if (mode != 0 && mode != 1) {
      *msg = "voxax: the winding numbers' mode must be 0 or 1";
      return false;
    }
    if (!(accuracy >= 0.0) || !std::isfinite(accuracy)) {
      *msg = "voxax.winding_number: `accuracy` must be a finite number >= 0";
      return false;
    }
    if (mode == 1 && accuracy != 0.0) {
      *msg = "voxax: the winding numbers' plain sum (mode 1) takes accuracy 0";
      return false;
    }
    if (!voxax::check_host_coordinates(V, 3 * nv, "vertices", msg) ||
        !voxax::check_host_coordinates(P, 3 * n, "points", msg))
      return false;
    if (!voxax::check_host_faces(F, nf, nv, msg)) return false;
    const std::vector<voxax::spatial::BoundaryEdge> boundary =
        voxax::spatial::boundary_edges(F, nf);
    const bool closed = boundary.empty();
    // Open meshes with a small boundary: a cap C over it (dC = dS), so that S - C is closed
    // and w_S = (the crossing count of a ray through S - C) + w_C, the cap's sum only.
    std::vector<int32_t> cap;
    bool capped = false;
    if (mode == 0 && !closed && nf > 0 && static_cast<int64_t>(boundary.size()) * 4 <= nf) {
      capped = voxax::spatial::boundary_cap(boundary, &cap) &&
               static_cast<int64_t>(cap.size() / 3) * 4 <= nf;
      if (!capped) cap.clear();
    }
    const int64_t ncap = static_cast<int64_t>(cap.size() / 3);
    const bool rays = mode == 0 && nf > 0 && (closed || capped);
    const bool approx = mode == 0 && accuracy > 0.0;
    // a cap of few triangles: its exact sum is cheaper than its hierarchy (and meets any eps)
    const bool cap_approx = approx && ncap > kExactCap;
    voxax::spatial::ColumnTree column;
    voxax::spatial::WindingTree cap_tree;
    voxax::spatial::CapSum cap_sum;
    if (rays) {
      if (capped) {  // S and C reversed
        std::vector<int32_t> all(F, F + 3 * nf);
        all.reserve(3 * (nf + ncap));
        for (int64_t t = 0; t < ncap; ++t) {
          all.push_back(cap[3 * t]);
          all.push_back(cap[3 * t + 2]);
          all.push_back(cap[3 * t + 1]);
        }
        column.build(V, all.data(), nf + ncap, kDir);
        if (cap_approx) {
          cap_tree.build(V, cap.data(), ncap);
          cap_tree.build_moments();
        } else {
          cap_sum.build(V, cap);
        }
      } else {
        column.build(V, F, nf, kDir);
      }
    }
    const double extent = column.extent();
    // 1: the point still needs the sum (every point, unless a ray decides it)
    std::vector<uint8_t> pending(n, 1);
    if (rays)
      voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
        std::vector<double> work(4 * cap_sum.vertex_count());
        for (int64_t i = b; i < e; ++i) {
          const double* p = P + 3 * i;
          // Hits within this distance of p are unclear: far above the rounding of t.
          const double scale =
              extent + std::max(std::fabs(p[0]), std::max(std::fabs(p[1]), std::fabs(p[2])));
          const double margin = 1e-9 * scale;
          int64_t sum = 0;
          if (column.crossings(p, margin, &sum)) {
            double w = static_cast<double>(sum);
            if (capped)
              w += cap_approx ? cap_tree.eval_approx(p, accuracy)
                              : cap_sum.eval(p, work.data()) / (4.0 * 3.14159265358979323846);
            out[i] = w;
            pending[i] = 0;
          }
        }
      });
    int64_t by_ray = 0;
    for (int64_t i = 0; i < n; ++i) by_ray += pending[i] == 0;
    if (by_ray < n) {
      // A few points: their plain sums, cheaper than the hierarchy's build.
      const bool plain = mode == 1 || n - by_ray <= kPlainPoints;
      voxax::spatial::WindingTree tree;
      if (!plain) tree.build(V, F, nf);
      if (!plain && approx) tree.build_moments();
      voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
        for (int64_t i = b; i < e; ++i)
          if (pending[i])
            out[i] = plain    ? voxax::spatial::winding_sum(P + 3 * i, V, F, nf)
                     : approx ? tree.eval_approx(P + 3 * i, accuracy)
                              : tree.eval(P + 3 * i);
      });
    }
    if (stats) {
      stats[0] = closed ? 1 : 0;
      stats[1] = by_ray;
    }
    return true;
  });
}

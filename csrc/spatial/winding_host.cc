// Eager host entry point of the winding numbers (see spatial/winding.h), a plain C ABI for
// ctypes. Validates its input, catches every exception and reports failures as a
// non-zero status with a message in `err`.
//
//   voxax_winding_number(V (nv, 3) f64, nv, F (nf, 3) i32, nf, P (n, 3) f64, n, mode,
//                        accuracy, threads, out (n,) f64, stats (2,) i64, err, errlen)
//     mode 0: one ray per point where the faces form a cycle, the hierarchy of boundaries
//     (WindingTree) elsewhere and for the points a ray leaves unclear; mode 1: the plain
//     solid-angle sum everywhere (face by face). accuracy (finite, >= 0; mode 0 only): 0
//     for the exact hierarchy, eps > 0 for its error-bounded far-field expansion
//     (WindingTree::eval_approx: within eps of the solid-angle sum, up to rounding) at the
//     points that do not take a ray. stats: [faces form a cycle, points decided by a ray].

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "common/host_pool.h"
#include "spatial/bvh.h"
#include "spatial/winding.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {

constexpr int64_t kChunk = 256;  // points per task: fixed, so results do not depend on threads

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
    const bool closed = voxax::spatial::faces_closed(F, nf);
    const bool rays = mode == 0 && closed && nf > 0;
    voxax::spatial::Bvh bvh;
    if (rays) bvh.build(V, F, nf);
    const double extent = bvh.extent();
    // 1: the point still needs the sum (every point, unless a ray decides it)
    std::vector<uint8_t> pending(n, 1);
    if (rays)
      voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
        for (int64_t i = b; i < e; ++i) {
          const double* p = P + 3 * i;
          // Hits within this distance of p are unclear: far above the rounding of t.
          const double scale =
              extent + std::max(std::fabs(p[0]), std::max(std::fabs(p[1]), std::fabs(p[2])));
          const double margin = 1e-9 * scale;
          const auto ray =
              voxax::spatial::make_ray(p, kDir, -margin, std::numeric_limits<double>::infinity());
          int64_t sum = 0;
          if (bvh.crossings(ray, margin, &sum)) {
            out[i] = static_cast<double>(sum);
            pending[i] = 0;
          }
        }
      });
    int64_t by_ray = 0;
    for (int64_t i = 0; i < n; ++i) by_ray += pending[i] == 0;
    if (by_ray < n) {
      voxax::spatial::WindingTree tree;
      if (mode == 0) tree.build(V, F, nf);
      const bool approx = mode == 0 && accuracy > 0.0;
      if (approx) tree.build_moments();
      voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
        for (int64_t i = b; i < e; ++i)
          if (pending[i])
            out[i] = approx      ? tree.eval_approx(P + 3 * i, accuracy)
                     : mode == 0 ? tree.eval(P + 3 * i)
                                 : voxax::spatial::winding_sum(P + 3 * i, V, F, nf);
      });
    }
    if (stats) {
      stats[0] = closed ? 1 : 0;
      stats[1] = by_ray;
    }
    return true;
  });
}

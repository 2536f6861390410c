// The eager host entry point of the k-nearest-neighbour search, a plain C ABI for
// ctypes (which releases the GIL while it runs). It validates its input, catches every
// exception and reports failures as status 1 with a message in `err`.
//
//   voxax_knn_host(S (n, 3) f64, n, Q (m, 3) f64, m, k, threads, idx (m, k) i32,
//                  dist (m, k) f64, err, errlen) -> 0 or 1 (message in err)

#include <cstdint>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "common/host_pool.h"
#include "spatial/knn.h"
#include "spatial/knn_checks.h"

namespace {

constexpr int64_t kChunk = 256;  // queries per task: fixed, so results do not depend on threads

}  // namespace

extern "C" __attribute__((visibility("default"))) int voxax_knn_host(const double* S, int64_t n,
                                                                     const double* Q, int64_t m,
                                                                     int32_t k, int32_t threads,
                                                                     int32_t* idx, double* dist,
                                                                     char* err, int64_t errlen) {
  return voxax::host_guarded("the kNN kernel", err, errlen, [&](std::string* msg) {
    if (!voxax::spatial::check_knn_inputs(S, n, Q, m, k, msg)) return false;
    voxax::spatial::PointGrid grid;
    grid.build(S, n, true, voxax::spatial::knn_points_per_cell(k));
    const std::vector<int64_t> order = voxax::spatial::query_order(Q, m);
    voxax::spatial::parallel_chunks(m, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      voxax::spatial::query_run(grid, Q, order.data(), b, e, k, idx, dist);
    });
    return true;
  });
}

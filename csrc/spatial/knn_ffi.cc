// The XLA FFI handler of the k-nearest-neighbour search (the jit path).
//
//   voxax_knn(points (N, 3) f64, queries (M, 3) f64) -> idx (M, k) s32, dist (M, k) f64
//       (k from the output shape, 1 <= k <= 32)

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "common/errors.h"
#include "common/ffi_bind.h"
#include "common/parallel.h"
#include "spatial/knn.h"
#include "spatial/knn_checks.h"

namespace voxax {
namespace {

constexpr int64_t kKnnChunk = 256;

ffi::Error Knn(ffi::ThreadPool pool, ffi::Buffer<ffi::F64> points, ffi::Buffer<ffi::F64> queries,
               ffi::ResultBuffer<ffi::S32> idx, ffi::ResultBuffer<ffi::F64> dist) {
  return guarded("the kNN kernel", [&]() -> ffi::Error {
    auto pd = points.dimensions(), qd = queries.dimensions(), od = idx->dimensions();
    if (pd.size() != 2 || pd[1] != 3)
      return ffi::Error::InvalidArgument(
          "voxax.nearest_neighbors: `points` must have shape (N, 3)");
    if (qd.size() != 2 || qd[1] != 3)
      return ffi::Error::InvalidArgument(
          "voxax.nearest_neighbors: `queries` must have shape (M, 3)");
    if (od.size() != 2 || od[0] != qd[0] || dist->dimensions().size() != 2 ||
        dist->dimensions()[0] != qd[0] || dist->dimensions()[1] != od[1])
      return ffi::Error::InvalidArgument(
          "voxax.nearest_neighbors: the outputs must have shape (M, k)");
    const int64_t k = od[1];
    std::string msg;
    if (!spatial::check_knn_inputs(points.typed_data(), pd[0], queries.typed_data(), qd[0], k,
                                   &msg))
      return ffi::Error::InvalidArgument(msg);
    spatial::PointGrid grid;
    grid.build(points.typed_data(), pd[0], true, spatial::knn_points_per_cell(k));
    const double* Q = queries.typed_data();
    int32_t* I = idx->typed_data();
    double* D = dist->typed_data();
    const int64_t m = qd[0];
    const int64_t chunks = (m + kKnnChunk - 1) / kKnnChunk;
    const std::vector<int64_t> order = spatial::query_order(Q, m);
    ParallelFor::run(&pool, chunks, [&](int64_t c) {
      spatial::query_run(grid, Q, order.data(), c * kKnnChunk, std::min(m, (c + 1) * kKnnChunk),
                         static_cast<int>(k), I, D);
    });
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_knn, Knn)

}  // namespace voxax

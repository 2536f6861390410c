// k nearest neighbours: a host entry point for ctypes and an XLA FFI handler.
//
//   voxax_knn_host(S (n, 3) f64, n, Q (m, 3) f64, m, k, threads, idx (m, k) i32,
//                  dist (m, k) f64, err, errlen) -> 0 or 1 (message in err)
//   voxax_knn(points (N, 3) f64, queries (M, 3) f64) -> idx (M, k) s32, dist (M, k) f64
//       (k from the output shape, 1 <= k <= 32)

#include <cmath>
#include <cstring>
#include <string>

#include "common/batch.h"
#include "common/constants.h"
#include "common/errors.h"
#include "common/grid.h"
#include "common/host_errors.h"
#include "common/host_pool.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "spatial/knn.h"

namespace voxax {
namespace {

constexpr int64_t kKnnChunk = 256;

ffi::Error Knn(ffi::ThreadPool pool, ffi::Buffer<ffi::F64> points, ffi::Buffer<ffi::F64> queries,
               ffi::ResultBuffer<ffi::S32> idx, ffi::ResultBuffer<ffi::F64> dist) {
  return guarded("the kNN kernel", [&]() -> ffi::Error {
    auto pd = points.dimensions(), qd = queries.dimensions(), od = idx->dimensions();
    if (pd.size() != 2 || pd[1] != 3)
      return ffi::Error::InvalidArgument("voxax: points must have shape (N, 3)");
    if (qd.size() != 2 || qd[1] != 3)
      return ffi::Error::InvalidArgument("voxax: queries must have shape (M, 3)");
    if (od.size() != 2 || od[0] != qd[0] || dist->dimensions().size() != 2 ||
        dist->dimensions()[0] != qd[0] || dist->dimensions()[1] != od[1])
      return ffi::Error::InvalidArgument("voxax: kNN outputs must have shape (M, k)");
    const int64_t k = od[1];
    if (k < 1 || k > spatial::kMaxNeighbours)
      return ffi::Error::InvalidArgument("voxax: k must lie in [1, 32], got " + std::to_string(k));
    if (pd[0] > INT32_MAX) return ffi::Error::InvalidArgument("voxax: at most 2^31 - 1 points");
    std::string msg;
    if (!check_host_coordinates(points.typed_data(), 3 * pd[0], "points", &msg) ||
        !check_coordinate_scale(points.typed_data(), 3 * pd[0], "points", &msg) ||
        !check_host_coordinates(queries.typed_data(), 3 * qd[0], "queries", &msg))
      return ffi::Error::InvalidArgument(msg);
    spatial::PointGrid grid;
    grid.build(points.typed_data(), pd[0]);
    const double* Q = queries.typed_data();
    int32_t* I = idx->typed_data();
    double* D = dist->typed_data();
    const int64_t m = qd[0];
    const int64_t chunks = (m + kKnnChunk - 1) / kKnnChunk;
    ParallelFor::run(&pool, chunks, [&](int64_t c) {
      for (int64_t i = c * kKnnChunk; i < std::min(m, (c + 1) * kKnnChunk); ++i)
        grid.query(Q + 3 * i, static_cast<int>(k), I + k * i, D + k * i);
    });
    return ffi::Error::Success();
  });
}

}  // namespace
}  // namespace voxax

extern "C" __attribute__((visibility("default"))) int voxax_knn_host(const double* S, int64_t n,
                                                                     const double* Q, int64_t m,
                                                                     int32_t k, int32_t threads,
                                                                     int32_t* idx, double* dist,
                                                                     char* err, int64_t errlen) {
  return voxax::host_guarded("the kNN kernel", err, errlen, [&](std::string* msg) {
    if (k < 1 || k > voxax::spatial::kMaxNeighbours) {
      *msg = "voxax: k must lie in [1, 32]";
      return false;
    }
    if (n < 0 || n > INT32_MAX || m < 0) {
      *msg = "voxax: at most 2^31 - 1 points";
      return false;
    }
    if (!voxax::check_host_coordinates(S, 3 * n, "points", msg) ||
        !voxax::check_coordinate_scale(S, 3 * n, "points", msg) ||
        !voxax::check_host_coordinates(Q, 3 * m, "queries", msg))
      return false;
    voxax::spatial::PointGrid grid;
    grid.build(S, n);
    voxax::spatial::parallel_chunks(
        m, voxax::kKnnChunk, threads, [&](int64_t, int64_t b, int64_t e) {
          for (int64_t i = b; i < e; ++i)
            grid.query(Q + 3 * i, k, idx + int64_t{k} * i, dist + int64_t{k} * i);
        });
    return true;
  });
}

#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_knn, voxax::Knn,
                              xla::ffi::Ffi::Bind()
                                  .Ctx<xla::ffi::ThreadPool>()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F64>>()
                                  .Arg<xla::ffi::Buffer<xla::ffi::F64>>()
                                  .Ret<xla::ffi::Buffer<xla::ffi::S32>>()
                                  .Ret<xla::ffi::Buffer<xla::ffi::F64>>());

#pragma GCC visibility pop

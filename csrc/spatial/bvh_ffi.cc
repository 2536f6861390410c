// XLA FFI handlers of the BVH queries with static output shapes, for jit:
//
// voxax_closest_points(vertices (V, 3) f64, faces (F, 3) s32, points (P, 3) f64)
//     -> distance (P,) f64, face (P,) s32, barycentric (P, 3) f64, point (P, 3) f64
// voxax_first_hits(vertices, faces, origins (R, 3) f64, directions (R, 3) f64; attrs t_min, t_max)
//     -> t (R,) f64 (+inf on a miss), face (R,) s32 (-1), barycentric (R, 3) f64, sign (R,) s32
//
// Each call builds its BVH, then answers the queries in fixed chunks on XLA's
// intra-op pool (results do not depend on the thread count). Every input is
// validated; failures return InvalidArgument with a message.

#include <cmath>
#include <initializer_list>
#include <limits>
#include <string>

#include "common/batch.h"
#include "common/constants.h"
#include "common/errors.h"
#include "common/ffi_bind.h"
#include "common/grid.h"
#include "common/host_errors.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "spatial/bvh.h"

namespace voxax {
namespace {

constexpr int64_t kQueryChunk = 256;

ffi::Error check_rows3(const ffi::Buffer<ffi::F64>& x, const char* what, int64_t* rows) {
  auto d = x.dimensions();
  if (d.size() != 2 || d[1] != 3)
    return ffi::Error::InvalidArgument(std::string("voxax: ") + what +
                                       " must have shape (N, 3), got " + dims_str(d));
  *rows = d[0];
  std::string msg;
  if (!check_host_coordinates(x.typed_data(), 3 * d[0], what, &msg))
    return ffi::Error::InvalidArgument(msg);
  return ffi::Error::Success();
}

ffi::Error build(const ffi::Buffer<ffi::F64>& vertices, const ffi::Buffer<ffi::S32>& faces,
                 spatial::Bvh* bvh) {
  int64_t nv = 0;
  ffi::Error err = check_rows3(vertices, "vertices", &nv);
  if (err.failure()) return err;
  std::string msg;
  if (!check_coordinate_scale(vertices.typed_data(), 3 * nv, "vertices", &msg))
    return ffi::Error::InvalidArgument(msg);
  auto fd = faces.dimensions();
  if (fd.size() != 2 || fd[1] != 3)
    return ffi::Error::InvalidArgument("voxax: faces must have shape (F, 3), got " + dims_str(fd));
  if (fd[0] > (int64_t{1} << 30))
    return ffi::Error::InvalidArgument("voxax: the BVH takes at most 2^30 faces");
  if (!check_host_faces(faces.typed_data(), fd[0], nv, &msg))
    return ffi::Error::InvalidArgument(msg);
  bvh->build(vertices.typed_data(), faces.typed_data(), fd[0]);
  return ffi::Error::Success();
}

// Checks that the outputs hold `per_row` values each for each of the n rows (their
// element counts in `counts`), then builds the BVH.
ffi::Error build_for(const ffi::Buffer<ffi::F64>& vertices, const ffi::Buffer<ffi::S32>& faces,
                     int64_t n, std::initializer_list<size_t> counts,
                     std::initializer_list<int64_t> per_row, const char* what, spatial::Bvh* bvh) {
  auto r = per_row.begin();
  for (size_t count : counts)
    if (count != static_cast<size_t>(*r++ * n))
      return ffi::Error::InvalidArgument(std::string("voxax: ") + what);
  return build(vertices, faces, bvh);
}

ffi::Error ClosestPoints(ffi::ThreadPool pool, ffi::Buffer<ffi::F64> vertices,
                         ffi::Buffer<ffi::S32> faces, ffi::Buffer<ffi::F64> points,
                         ffi::ResultBuffer<ffi::F64> dist, ffi::ResultBuffer<ffi::S32> face,
                         ffi::ResultBuffer<ffi::F64> bary, ffi::ResultBuffer<ffi::F64> point) {
  return guarded("the BVH", [&]() -> ffi::Error {
    int64_t n = 0;
    ffi::Error err = check_rows3(points, "points", &n);
    if (err.failure()) return err;
    spatial::Bvh bvh;
    err = build_for(vertices, faces, n,
                    {dist->element_count(), face->element_count(), bary->element_count(),
                     point->element_count()},
                    {1, 1, 3, 3}, "closest-point outputs do not match the points", &bvh);
    if (err.failure()) return err;
    const double* P = points.typed_data();
    double* D = dist->typed_data();
    int32_t* Fo = face->typed_data();
    double* B = bary->typed_data();
    double* Q = point->typed_data();
    const int64_t chunks = (n + kQueryChunk - 1) / kQueryChunk;
    ParallelFor::run(&pool, chunks, [&](int64_t c) {
      int32_t hint = -1;
      for (int64_t i = c * kQueryChunk; i < std::min(n, (c + 1) * kQueryChunk); ++i) {
        const auto r = bvh.closest(P + 3 * i, hint);
        hint = r.slot;
        D[i] = std::sqrt(r.dist2);
        Fo[i] = r.face;
        for (int a = 0; a < 3; ++a) {
          B[3 * i + a] = r.bary[a];
          Q[3 * i + a] = r.point[a];
        }
      }
    });
    return ffi::Error::Success();
  });
}

constexpr char kTMin[] = "t_min";
constexpr char kTMax[] = "t_max";

ffi::Error FirstHits(ffi::ThreadPool pool, ffi::Buffer<ffi::F64> vertices,
                     ffi::Buffer<ffi::S32> faces, ffi::Buffer<ffi::F64> origins,
                     ffi::Buffer<ffi::F64> directions, ffi::ResultBuffer<ffi::F64> t,
                     ffi::ResultBuffer<ffi::S32> face, ffi::ResultBuffer<ffi::F64> bary,
                     ffi::ResultBuffer<ffi::S32> sign, ffi::Attr<double, kTMin> t_min_attr,
                     ffi::Attr<double, kTMax> t_max_attr) {
  const double t_min = *t_min_attr, t_max = *t_max_attr;
  return guarded("the BVH", [&]() -> ffi::Error {
    int64_t n = 0, nd = 0;
    ffi::Error err = check_rows3(origins, "ray origins", &n);
    if (err.failure()) return err;
    err = check_rows3(directions, "ray directions", &nd);
    if (err.failure()) return err;
    if (nd != n)
      return ffi::Error::InvalidArgument("voxax: ray origins and directions differ in length");
    if (std::isnan(t_min) || std::isnan(t_max) || !(t_min <= t_max))
      return ffi::Error::InvalidArgument("voxax: the ray interval needs t_min <= t_max (no NaN)");
    const double* O = origins.typed_data();
    const double* Dd = directions.typed_data();
    for (int64_t i = 0; i < n; ++i)
      if (Dd[3 * i] == 0.0 && Dd[3 * i + 1] == 0.0 && Dd[3 * i + 2] == 0.0)
        return ffi::Error::InvalidArgument("voxax: ray direction " + std::to_string(i) +
                                           " is zero");
    spatial::Bvh bvh;
    err = build_for(
        vertices, faces, n,
        {t->element_count(), face->element_count(), bary->element_count(), sign->element_count()},
        {1, 1, 3, 1}, "ray-hit outputs do not match the rays", &bvh);
    if (err.failure()) return err;
    const int64_t chunks = (n + kQueryChunk - 1) / kQueryChunk;
    ParallelFor::run(&pool, chunks, [&](int64_t c) {
      bvh.first_hits(
          c * kQueryChunk, std::min(n, (c + 1) * kQueryChunk), false,
          [&](int64_t i) { return spatial::make_ray(O + 3 * i, Dd + 3 * i, t_min, t_max); },
          [&](int64_t i, bool found, const spatial::RayHit& h) {
            spatial::store_hit(found, h, i, t->typed_data(), face->typed_data(), bary->typed_data(),
                               sign->typed_data());
          });
    });
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_closest_points, ClosestPoints)
VOXAX_FFI_HANDLER(voxax_first_hits, FirstHits)

}  // namespace voxax

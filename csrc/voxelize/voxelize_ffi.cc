// XLA FFI handlers of voxax: the forward voxelization and its backward.
//
// voxax_forward(vertices (..., V, d), faces (..., F, d) int32) -> W (..., *grid)
// voxax_backward(vertices, faces, cotangent (..., *grid)) -> corners (..., F, d, d)
// with d = 3 (triangles) or 2 (segments), float32 or float64, and the grid
// given by attributes x0, x1, nx, y0, y1, ny, z0, z1, nz (z ignored in 2D).
// Leading axes are batch axes; each is 1 (broadcast) or the output's size.
//
// Each handler checks, in this order and before it allocates anything sized
// by the attributes: ranks and dtypes, the grid attributes, the grid against
// the shapes of the output and cotangent buffers, batch axes; then it builds
// the plane tables and checks the values (finite, bounded vertices; face
// indices in range). All of it runs inside `guarded`, so every failure
// returns an ffi::Error of its category (see common/errors.h).

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

#include "common/batch.h"
#include "common/errors.h"
#include "common/ffi_bind.h"
#include "common/grid.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "voxelize/backward.h"
#include "voxelize/forward.h"
#include "voxelize/problem.h"

namespace voxax {
namespace {

// Shapes (the output: the grid's for the forward, (..., F, d, d) for the backward,
// whose cotangent has the grid's shape), then the plane tables, then values.
ffi::Error prepare(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                   const ffi::AnyBuffer* cotangent, const ffi::AnyBuffer& out,
                   const GridAttributes& at, Problem* pb) {
  ffi::Error err = check_mesh_shapes(vertices, faces, out, cotangent ? 3 : 0, at, pb);
  if (err.failure()) return err;
  if (cotangent && cotangent->element_type() != vertices.element_type())
    return ffi::Error::InvalidArgument("voxax: cotangent dtype must match the vertices");
  const auto od = out.dimensions();
  const size_t nb = pb->batch.out.size();
  if (!cotangent) {
    err = check_grid_axes(od, nb, *pb, "output");
  } else {
    if (od[nb] != pb->nf || od[nb + 1] != pb->dim || od[nb + 2] != pb->dim)
      return ffi::Error::InvalidArgument(
          "voxax: backward output must have shape (..., F, d, d), got " + dims_str(od));
    // The cotangent's batch axes broadcast like the inputs' (a vmap of a gradient
    // passes a size-1 axis when the cotangent does not vary).
    err = check_extra_batch(cotangent->dimensions(), pb->dim, "cotangent", pb);
    if (err.failure()) return err;
    err = check_grid_axes(cotangent->dimensions(), nb, *pb, "cotangent");
  }
  if (err.failure()) return err;
  pb->grid.build_planes();
  return check_mesh_values(vertices, faces, *pb);
}

template <typename T>
void forward_impl(ffi::ThreadPool* pool, const Problem& pb, const T* V, const int32_t* F, T* out) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * pb.dim, fstride = pb.nf * pb.dim;
  const Tiling tl = make_tiling(g);
  std::vector<Bins> bins(B);
  for (int64_t b = 0; b < B; ++b) {
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    if (pb.dim == 3)
      bin_triangles_3d(pool, g, tl, Vb, Fb, pb.nf, &bins[b]);
    else
      bin_segments_2d(pool, g, tl, Vb, Fb, pb.nf, &bins[b]);
  }
  const int64_t tiles = tl.count();
  const int64_t tasks = B * tiles;
  std::vector<TileScratch> scratch(ParallelFor::workers(pool, tasks));
  ParallelFor::run(pool, tasks, [&](int64_t task, int worker) {
    const int64_t b = task / tiles, tile = task % tiles;
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    T* ob = out + b * g.cell_count();
    if (pb.dim == 3)
      forward_tile_3d(g, tl, tile, Vb, Fb, bins[b], scratch[worker], ob);
    else
      forward_tile_2d(g, tl, tile, Vb, Fb, bins[b], scratch[worker], ob);
  });
}

template <typename T>
void backward_impl(ffi::ThreadPool* pool, const Problem& pb, const T* V, const int32_t* F,
                   const T* G, T* out) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * pb.dim, fstride = pb.nf * pb.dim;
  const int64_t ostride = pb.nf * pb.dim * pb.dim;
  constexpr int64_t kChunk = 64;
  const int64_t chunks = (pb.nf + kChunk - 1) / kChunk;
  ParallelFor::run(pool, B * chunks, [&](int64_t task) {
    const int64_t b = task / chunks, c = task % chunks;
    const int64_t t0 = c * kChunk, t1 = std::min(pb.nf, t0 + kChunk);
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    const T* Gb = G + Batch::source(pb.batch.out, pb.extra_batch, b) * g.cell_count();
    T* ob = out + b * ostride;
    if (pb.dim == 3)
      backward_triangles_3d(g, Vb, Fb, Gb, t0, t1, ob);
    else
      backward_segments_2d(g, Vb, Fb, Gb, t0, t1, ob);
  });
}

ffi::Error Forward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                   ffi::Result<ffi::AnyBuffer> out, double x0, double x1, int64_t nx, double y0,
                   double y1, int64_t ny, double z0, double z1, int64_t nz, int64_t x_first,
                   int64_t x_count) {
  return guarded("the forward kernel", [&]() {
    Problem pb;
    ffi::Error err = prepare(vertices, faces, nullptr, *out,
                             {x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count}, &pb);
    if (err.failure()) return err;
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      forward_impl<T>(&pool, pb, vertices.typed_data<T>(), faces.typed_data<int32_t>(),
                      out->typed_data<T>());
    });
    return ffi::Error::Success();
  });
}

ffi::Error Backward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                    ffi::AnyBuffer cotangent, ffi::Result<ffi::AnyBuffer> out, double x0, double x1,
                    int64_t nx, double y0, double y1, int64_t ny, double z0, double z1, int64_t nz,
                    int64_t x_first, int64_t x_count) {
  return guarded("the backward kernel", [&]() {
    Problem pb;
    ffi::Error err = prepare(vertices, faces, &cotangent, *out,
                             {x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count}, &pb);
    if (err.failure()) return err;
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      backward_impl<T>(&pool, pb, vertices.typed_data<T>(), faces.typed_data<int32_t>(),
                       cotangent.typed_data<T>(), out->typed_data<T>());
    });
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_forward, Forward, voxelize_binding<0>())
VOXAX_FFI_HANDLER(voxax_backward, Backward, voxelize_binding<1>())

}  // namespace voxax

// XLA FFI handler of the voxelization's tangent (forward-mode derivative).
//
// voxax_tangent(vertices (..., V, d), faces (..., F, d) int32,
//               corner tangents (..., F, d, d)) -> dW (..., *grid)
// with d = 3 (triangles) or 2 (segments), float32 or float64, and the grid
// given by the attributes x0, x1, nx, y0, y1, ny, z0, z1, nz (z ignored in
// 2D). corner_tangents[..., f, c, :] is the velocity of corner c of face f.
// Leading axes are batch axes; each is 1 (broadcast) or the output's size.
// It is the transpose of voxax_backward.

#include <map>
#include <new>
#include <string>
#include <utility>
#include <vector>

#include "common/batch.h"
#include "common/constants.h"
#include "common/errors.h"
#include "common/ffi_bind.h"
#include "common/grid.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "voxelize/problem.h"
#include "voxelize/tangent.h"

namespace voxax {
namespace {

template <typename T>
void tangent_impl(ffi::ThreadPool* pool, const Problem& pb, const T* V, const int32_t* F,
                  const T* TC, T* out) {
  const GridSpec& g = pb.grid;
  const Batch& batch = pb.batch;
  const int dim = pb.dim;
  const int64_t nf = pb.nf;
  const int64_t B = batch.size();
  const int64_t vstride = pb.nv * dim, fstride = nf * dim, tstride = nf * dim * dim;
  const Tiling tl = make_tiling(g);
  // Bins depend on the vertices and faces only: one set per distinct pair
  // (a batch of tangents on one mesh, as in jacfwd, bins once).
  std::map<std::pair<int64_t, int64_t>, size_t> which;
  std::vector<size_t> bin_of(B);
  std::vector<Bins> bins;
  for (int64_t b = 0; b < B; ++b) {
    const auto key = std::make_pair(batch.vsrc(b), batch.fsrc(b));
    auto it = which.find(key);
    if (it == which.end()) {
      bins.emplace_back();
      bin_tangent_faces(pool, g, tl, dim, V + key.first * vstride, F + key.second * fstride, nf,
                        &bins.back());
      it = which.emplace(key, bins.size() - 1).first;
    }
    bin_of[b] = it->second;
  }
  const int64_t tiles = tl.count();
  // Scratch memory is bounded: one buffer per worker of this call, freed when it returns.
  std::vector<TangentScratch> scratch(ParallelFor::workers(pool, B * tiles));
  ParallelFor::run(pool, B * tiles, [&](int64_t task, int worker) {
    const int64_t b = task / tiles, tile = task % tiles;
    const T* Vb = V + batch.vsrc(b) * vstride;
    const int32_t* Fb = F + batch.fsrc(b) * fstride;
    const T* Tb = TC + Batch::source(batch.out, pb.extra_batch, b) * tstride;
    double* acc = scratch[worker].zeroed(tl.tx * tl.ty * g.column_length());
    if (dim == 3)
      tangent_tile_3d(g, tl, tile, Vb, Fb, Tb, bins[bin_of[b]], acc);
    else
      tangent_tile_2d(g, tl, tile, Vb, Fb, Tb, bins[bin_of[b]], acc);
    store_tile(g, tl, tile, acc, out + b * g.cell_count());
  });
}

template <typename T>
ffi::Error check_tangents(const T* TC, int64_t count) {
  for (int64_t i = 0; i < count; ++i)
    if (!std::isfinite(static_cast<double>(TC[i])))
      return ffi::Error::InvalidArgument("voxax: tangents contain NaN or Inf (flat index " +
                                         std::to_string(i) + ")");
  return ffi::Error::Success();
}

ffi::Error Tangent(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                   ffi::AnyBuffer tangents, ffi::Result<ffi::AnyBuffer> out, double x0, double x1,
                   int64_t nx, double y0, double y1, int64_t ny, double z0, double z1, int64_t nz,
                   int64_t x_first, int64_t x_count) {
  return guarded("the tangent kernel", [&]() {
    Problem pb;
    ffi::Error err = check_mesh_shapes(vertices, faces, *out, 0,
                                       {x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count}, &pb);
    if (err.failure()) return err;
    const auto vt = vertices.element_type();
    if (tangents.element_type() != vt)
      return ffi::Error::InvalidArgument(
          "voxax: tangent and output dtypes must match the vertices");
    const size_t nb = pb.batch.out.size();
    err = check_grid_axes(out->dimensions(), nb, pb, "output");
    if (err.failure()) return err;
    const auto td = tangents.dimensions();
    const int64_t d = pb.dim;
    if (td.size() != nb + 3 || td[nb] != pb.nf || td[nb + 1] != d || td[nb + 2] != d)
      return ffi::Error::InvalidArgument(
          "voxax: corner tangents must have shape (..., F, d, d) = (..., " + std::to_string(pb.nf) +
          ", " + std::to_string(d) + ", " + std::to_string(d) + "), got " + dims_str(td));
    err = check_extra_batch(td, 3, "tangent", &pb);
    if (err.failure()) return err;
    pb.grid.build_planes();
    err = check_mesh_values(vertices, faces, pb);
    if (err.failure()) return err;
    int64_t tcount = pb.nf * d * d;
    for (int64_t n : pb.extra_batch) tcount *= n;
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      err = check_tangents(tangents.typed_data<T>(), tcount);
    });
    if (err.failure()) return err;
    if (pb.batch.size() == 0) return ffi::Error::Success();
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      tangent_impl<T>(&pool, pb, vertices.typed_data<T>(), faces.typed_data<int32_t>(),
                      tangents.typed_data<T>(), out->typed_data<T>());
    });
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_tangent, Tangent, voxelize_binding<1>())

}  // namespace voxax

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
#include "common/grid.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "voxelize/tangent.h"

namespace voxax {
namespace {

template <typename T>
ffi::Error tangent_impl(ffi::ThreadPool* pool, const GridSpec& g, const Batch& batch,
                        const std::vector<int64_t>& tdim, int dim, int64_t nv, int64_t nf,
                        const T* V, const int32_t* F, const T* TC, T* out) {
  const int64_t B = batch.size();
  const int64_t vstride = nv * dim, fstride = nf * dim, tstride = nf * dim * dim;
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
  ParallelFor::run(pool, B * tiles, [&](int64_t task) {
    thread_local TangentScratch scratch;
    const int64_t b = task / tiles, tile = task % tiles;
    const T* Vb = V + batch.vsrc(b) * vstride;
    const int32_t* Fb = F + batch.fsrc(b) * fstride;
    const T* Tb = TC + Batch::source(batch.out, tdim, b) * tstride;
    double* acc = scratch.zeroed(tl.tx * tl.ty * g.column_length());
    if (dim == 3)
      tangent_tile_3d(g, tl, tile, Vb, Fb, Tb, bins[bin_of[b]], acc);
    else
      tangent_tile_2d(g, tl, tile, Vb, Fb, Tb, bins[bin_of[b]], acc);
    store_tile(g, tl, tile, acc, out + b * g.cell_count());
  });
  return ffi::Error::Success();
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
                   int64_t nx, double y0, double y1, int64_t ny, double z0, double z1, int64_t nz) {
  try {
    const auto vd = vertices.dimensions();
    const auto fd = faces.dimensions();
    const auto td = tangents.dimensions();
    const auto od = out->dimensions();
    if (vd.size() < 2)
      return ffi::Error::InvalidArgument("voxax: vertices must have shape (..., V, d)");
    if (fd.size() < 2)
      return ffi::Error::InvalidArgument("voxax: faces must have shape (..., F, d)");
    const int64_t d = vd[vd.size() - 1];
    if (d != 2 && d != 3)
      return ffi::Error::InvalidArgument(
          "voxax: vertices must have 2 or 3 coordinates, got shape " + dims_str(vd));
    const int dim = static_cast<int>(d);
    if (fd[fd.size() - 1] != d)
      return ffi::Error::InvalidArgument("voxax: faces " + dims_str(fd) + " must have " +
                                         std::to_string(d) + " indices per face for " +
                                         std::to_string(d) + "D vertices");
    const auto vt = vertices.element_type();
    if (vt != ffi::DataType::F32 && vt != ffi::DataType::F64)
      return ffi::Error::InvalidArgument("voxax: vertices must be float32 or float64");
    if (faces.element_type() != ffi::DataType::S32)
      return ffi::Error::InvalidArgument("voxax: faces must be int32");
    if (tangents.element_type() != vt || out->element_type() != vt)
      return ffi::Error::InvalidArgument(
          "voxax: tangent and output dtypes must match the vertices");
    const int64_t nv = vd[vd.size() - 2], nf = fd[fd.size() - 2];
    if (nv > INT32_MAX || nf > INT32_MAX)
      return ffi::Error::InvalidArgument(
          "voxax: at most 2^31 - 1 vertices and faces are supported");
    GridSpec g;
    ffi::Error err = check_grid(dim, x0, x1, nx, y0, y1, ny, z0, z1, nz, &g);
    if (err.failure()) return err;
    g.build_planes();
    Batch batch;
    err = make_batch(vd, fd, od, static_cast<size_t>(dim), &batch);
    if (err.failure()) return err;
    const size_t nb = batch.out.size();
    for (int a = 0; a < dim; ++a)
      if (od[nb + a] != g.n[a])
        return ffi::Error::InvalidArgument("voxax: output shape " + dims_str(od) +
                                           " does not match the grid");
    if (td.size() != nb + 3 || td[nb] != nf || td[nb + 1] != d || td[nb + 2] != d)
      return ffi::Error::InvalidArgument(
          "voxax: corner tangents must have shape (..., F, d, d) = (..., " + std::to_string(nf) +
          ", " + std::to_string(d) + ", " + std::to_string(d) + "), got " + dims_str(td));
    std::vector<int64_t> tdim(td.begin(), td.begin() + nb);
    int64_t tcount = 1;
    for (size_t a = 0; a < nb; ++a) {
      if (tdim[a] != 1 && tdim[a] != batch.out[a])
        return ffi::Error::InvalidArgument("voxax: tangent batch axes " + dims_str(td) +
                                           " do not broadcast to the output " + dims_str(od));
      tcount *= tdim[a];
    }
    const int64_t vcount = nv * d, fcount = nf * d, tsize = tcount * nf * d * d;
    for (int64_t b = 0; b < batch.vertex_count(); ++b) {
      err = vt == ffi::DataType::F32
                ? check_vertices(vertices.typed_data<float>() + b * vcount, vcount, b)
                : check_vertices(vertices.typed_data<double>() + b * vcount, vcount, b);
      if (err.failure()) return err;
    }
    for (int64_t b = 0; b < batch.face_count(); ++b) {
      err = check_faces(faces.typed_data<int32_t>() + b * fcount, fcount, nv, b);
      if (err.failure()) return err;
    }
    err = vt == ffi::DataType::F32 ? check_tangents(tangents.typed_data<float>(), tsize)
                                   : check_tangents(tangents.typed_data<double>(), tsize);
    if (err.failure()) return err;
    if (batch.size() == 0) return ffi::Error::Success();
    if (vt == ffi::DataType::F32)
      return tangent_impl<float>(&pool, g, batch, tdim, dim, nv, nf, vertices.typed_data<float>(),
                                 faces.typed_data<int32_t>(), tangents.typed_data<float>(),
                                 out->typed_data<float>());
    return tangent_impl<double>(&pool, g, batch, tdim, dim, nv, nf, vertices.typed_data<double>(),
                                faces.typed_data<int32_t>(), tangents.typed_data<double>(),
                                out->typed_data<double>());
  } catch (const std::bad_alloc&) {
    return ffi::Error(ffi::ErrorCode::kResourceExhausted,
                      "voxax: out of memory in the tangent kernel");
  } catch (const std::exception& e) {
    return ffi::Error(ffi::ErrorCode::kInternal,
                      std::string("voxax: tangent kernel failed: ") + e.what());
  } catch (...) {
    return ffi::Error(ffi::ErrorCode::kInternal, "voxax: tangent kernel failed");
  }
}

}  // namespace
}  // namespace voxax

#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_tangent, voxax::Tangent,
                              xla::ffi::Ffi::Bind()
                                  .Ctx<xla::ffi::ThreadPool>()
                                  .Arg<xla::ffi::AnyBuffer>()
                                  .Arg<xla::ffi::AnyBuffer>()
                                  .Arg<xla::ffi::AnyBuffer>()
                                  .Ret<xla::ffi::AnyBuffer>()
                                  .Attr<double>("x0")
                                  .Attr<double>("x1")
                                  .Attr<int64_t>("nx")
                                  .Attr<double>("y0")
                                  .Attr<double>("y1")
                                  .Attr<int64_t>("ny")
                                  .Attr<double>("z0")
                                  .Attr<double>("z1")
                                  .Attr<int64_t>("nz"));

#pragma GCC visibility pop

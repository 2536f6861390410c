// XLA FFI handlers of voxax: the forward voxelization and its backward.
//
// voxax_forward(vertices (..., V, d), faces (..., F, d) int32) -> W (..., *grid)
// voxax_backward(vertices, faces, cotangent (..., *grid)) -> corners (..., F, d, d)
// with d = 3 (triangles) or 2 (segments), float32 or float64, and the grid
// given by attributes x0, x1, nx, y0, y1, ny, z0, z1, nz (z ignored in 2D).
// Leading axes are batch axes; each is 1 (broadcast) or the output's size.

#include <new>
#include <utility>
#include <vector>

#include "backward.h"
#include "common.h"
#include "forward.h"
#include "validate.h"

namespace voxax {
namespace {

struct Problem {
  GridSpec grid;
  Batch batch;
  int dim = 3;
  int64_t nv = 0, nf = 0;
};

// Shapes, dtypes and values shared by forward and backward.
ffi::Error prepare(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                   ffi::Span<const int64_t> out_dims, bool backward, double x0,
                   double x1, int64_t nx, double y0, double y1, int64_t ny, double z0,
                   double z1, int64_t nz, Problem* pb) {
  auto vd = vertices.dimensions();
  auto fd = faces.dimensions();
  if (vd.size() < 2) return ffi::Error::InvalidArgument("voxax: vertices must have shape (..., V, d)");
  if (fd.size() < 2) return ffi::Error::InvalidArgument("voxax: faces must have shape (..., F, d)");
  const int64_t d = vd[vd.size() - 1];
  if (d != 2 && d != 3)
    return ffi::Error::InvalidArgument("voxax: vertices must have 2 or 3 coordinates, got shape " +
                                       dims_str(vd));
  if (fd[fd.size() - 1] != d)
    return ffi::Error::InvalidArgument("voxax: faces " + dims_str(fd) + " must have " +
                                       std::to_string(d) + " indices per face for " +
                                       std::to_string(d) + "D vertices");
  auto vt = vertices.element_type();
  if (vt != ffi::DataType::F32 && vt != ffi::DataType::F64)
    return ffi::Error::InvalidArgument("voxax: vertices must be float32 or float64");
  if (faces.element_type() != ffi::DataType::S32)
    return ffi::Error::InvalidArgument("voxax: faces must be int32");
  pb->dim = static_cast<int>(d);
  pb->nv = vd[vd.size() - 2];
  pb->nf = fd[fd.size() - 2];
  if (pb->nv > INT32_MAX || pb->nf > INT32_MAX)
    return ffi::Error::InvalidArgument("voxax: at most 2^31 - 1 vertices and faces are supported");
  ffi::Error err = make_grid(pb->dim, x0, x1, nx, y0, y1, ny, z0, z1, nz, &pb->grid);
  if (err.failure()) return err;
  const size_t trailing = backward ? 3 : static_cast<size_t>(pb->dim);
  err = make_batch(vd, fd, out_dims, trailing, &pb->batch);
  if (err.failure()) return err;
  if (!backward) {
    for (int a = 0; a < pb->dim; ++a)
      if (out_dims[out_dims.size() - pb->dim + a] != pb->grid.n[a])
        return ffi::Error::InvalidArgument("voxax: output shape " + dims_str(out_dims) +
                                           " does not match the grid");
  }
  // Values: every vertex set finite, every face set in range.
  const int64_t vcount = pb->nv * d, fcount = pb->nf * d;
  for (int64_t b = 0; b < pb->batch.vertex_count(); ++b) {
    err = vt == ffi::DataType::F32
              ? check_vertices(vertices.typed_data<float>() + b * vcount, vcount, b)
              : check_vertices(vertices.typed_data<double>() + b * vcount, vcount, b);
    if (err.failure()) return err;
  }
  for (int64_t b = 0; b < pb->batch.face_count(); ++b) {
    err = check_faces(faces.typed_data<int32_t>() + b * fcount, fcount, pb->nv, b);
    if (err.failure()) return err;
  }
  return ffi::Error::Success();
}

template <typename T>
ffi::Error forward_impl(ffi::ThreadPool* pool, const Problem& pb, const T* V,
                        const int32_t* F, T* out) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * pb.dim, fstride = pb.nf * pb.dim;
  const Tiling tl = make_tiling(g);
  std::vector<Bins> bins(B);
  for (int64_t b = 0; b < B; ++b) {
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    const bool binned = pb.dim == 3 ? bin_triangles_3d(pool, g, tl, Vb, Fb, pb.nf, &bins[b])
                                    : bin_segments_2d(pool, g, tl, Vb, Fb, pb.nf, &bins[b]);
    if (!binned)
      return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax: out of memory while binning faces");
  }
  const int64_t tiles = tl.count();
  bool ok = ParallelFor::run(pool, B * tiles, [&](int64_t task) {
    thread_local TileScratch scratch;
    const int64_t b = task / tiles, tile = task % tiles;
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    T* ob = out + b * g.cell_count();
    if (pb.dim == 3) forward_tile_3d(g, tl, tile, Vb, Fb, bins[b], scratch, ob);
    else forward_tile_2d(g, tl, tile, Vb, Fb, bins[b], scratch, ob);
  });
  if (!ok) return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax: out of memory in the forward kernel");
  return ffi::Error::Success();
}

template <typename T>
ffi::Error backward_impl(ffi::ThreadPool* pool, const Problem& pb,
                         const std::vector<int64_t>& gdim, const T* V,
                         const int32_t* F, const T* G, T* out) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * pb.dim, fstride = pb.nf * pb.dim;
  const int64_t ostride = pb.nf * pb.dim * pb.dim;
  constexpr int64_t kChunk = 64;
  const int64_t chunks = (pb.nf + kChunk - 1) / kChunk;
  bool ok = ParallelFor::run(pool, B * chunks, [&](int64_t task) {
    const int64_t b = task / chunks, c = task % chunks;
    const int64_t t0 = c * kChunk, t1 = std::min(pb.nf, t0 + kChunk);
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    const T* Gb = G + Batch::source(pb.batch.out, gdim, b) * g.cell_count();
    T* ob = out + b * ostride;
    if (pb.dim == 3) backward_triangles_3d(g, Vb, Fb, Gb, t0, t1, ob);
    else backward_segments_2d(g, Vb, Fb, Gb, t0, t1, ob);
  });
  if (!ok) return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax: out of memory in the backward kernel");
  return ffi::Error::Success();
}

ffi::Error Forward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                   ffi::Result<ffi::AnyBuffer> out, double x0, double x1, int64_t nx,
                   double y0, double y1, int64_t ny, double z0, double z1, int64_t nz) {
  Problem pb;
  ffi::Error err = prepare(vertices, faces, out->dimensions(), false, x0, x1, nx, y0, y1, ny,
                           z0, z1, nz, &pb);
  if (err.failure()) return err;
  if (out->element_type() != vertices.element_type())
    return ffi::Error::InvalidArgument("voxax: output dtype must match the vertices");
  try {
    if (vertices.element_type() == ffi::DataType::F32)
      return forward_impl<float>(&pool, pb, vertices.typed_data<float>(),
                                 faces.typed_data<int32_t>(), out->typed_data<float>());
    return forward_impl<double>(&pool, pb, vertices.typed_data<double>(),
                                faces.typed_data<int32_t>(), out->typed_data<double>());
  } catch (const std::bad_alloc&) {
    return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax: out of memory in the forward kernel");
  }
}

ffi::Error Backward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                    ffi::AnyBuffer cotangent, ffi::Result<ffi::AnyBuffer> out, double x0,
                    double x1, int64_t nx, double y0, double y1, int64_t ny, double z0,
                    double z1, int64_t nz) {
  Problem pb;
  ffi::Error err = prepare(vertices, faces, out->dimensions(), true, x0, x1, nx, y0, y1, ny,
                           z0, z1, nz, &pb);
  if (err.failure()) return err;
  const auto od = out->dimensions();
  const auto gd = cotangent.dimensions();
  if (out->element_type() != vertices.element_type() ||
      cotangent.element_type() != vertices.element_type())
    return ffi::Error::InvalidArgument("voxax: cotangent and output dtypes must match the vertices");
  const size_t nb = pb.batch.out.size();
  if (od.size() != nb + 3 || od[nb] != pb.nf || od[nb + 1] != pb.dim || od[nb + 2] != pb.dim)
    return ffi::Error::InvalidArgument("voxax: backward output must have shape (..., F, d, d), got " +
                                       dims_str(od));
  if (gd.size() != nb + static_cast<size_t>(pb.dim))
    return ffi::Error::InvalidArgument("voxax: cotangent " + dims_str(gd) + " has the wrong rank");
  // The cotangent's batch axes broadcast like the inputs' (a vmap of a
  // gradient passes a size-1 axis when the cotangent does not vary).
  std::vector<int64_t> gdim(gd.begin(), gd.begin() + nb);
  for (size_t a = 0; a < nb; ++a)
    if (gdim[a] != 1 && gdim[a] != pb.batch.out[a])
      return ffi::Error::InvalidArgument("voxax: cotangent batch axes " + dims_str(gd) +
                                         " do not broadcast to the output");
  for (int a = 0; a < pb.dim; ++a)
    if (gd[nb + a] != pb.grid.n[a])
      return ffi::Error::InvalidArgument("voxax: cotangent shape " + dims_str(gd) +
                                         " does not match the grid");
  try {
    if (vertices.element_type() == ffi::DataType::F32)
      return backward_impl<float>(&pool, pb, gdim, vertices.typed_data<float>(),
                                  faces.typed_data<int32_t>(), cotangent.typed_data<float>(),
                                  out->typed_data<float>());
    return backward_impl<double>(&pool, pb, gdim, vertices.typed_data<double>(),
                                 faces.typed_data<int32_t>(), cotangent.typed_data<double>(),
                                 out->typed_data<double>());
  } catch (const std::bad_alloc&) {
    return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax: out of memory in the backward kernel");
  }
}

// The grid attributes shared by both handlers, in the order the handlers take them.
template <typename Binding>
auto with_grid(Binding binding) {
  return std::move(binding)
      .template Attr<double>("x0")
      .template Attr<double>("x1")
      .template Attr<int64_t>("nx")
      .template Attr<double>("y0")
      .template Attr<double>("y1")
      .template Attr<int64_t>("ny")
      .template Attr<double>("z0")
      .template Attr<double>("z1")
      .template Attr<int64_t>("nz");
}

}  // namespace
}  // namespace voxax

#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_forward, voxax::Forward,
                              voxax::with_grid(xla::ffi::Ffi::Bind()
                                                   .Ctx<xla::ffi::ThreadPool>()
                                                   .Arg<xla::ffi::AnyBuffer>()
                                                   .Arg<xla::ffi::AnyBuffer>()
                                                   .Ret<xla::ffi::AnyBuffer>()));

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_backward, voxax::Backward,
                              voxax::with_grid(xla::ffi::Ffi::Bind()
                                                   .Ctx<xla::ffi::ThreadPool>()
                                                   .Arg<xla::ffi::AnyBuffer>()
                                                   .Arg<xla::ffi::AnyBuffer>()
                                                   .Arg<xla::ffi::AnyBuffer>()
                                                   .Ret<xla::ffi::AnyBuffer>()));

#pragma GCC visibility pop

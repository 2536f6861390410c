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
#include "common/grid.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "voxelize/backward.h"
#include "voxelize/forward.h"

namespace voxax {
namespace {

struct GridAttributes {
  double x0, x1;
  int64_t nx;
  double y0, y1;
  int64_t ny;
  double z0, z1;
  int64_t nz;
};

struct Problem {
  GridSpec grid;
  Batch batch;
  int dim = 3;
  int64_t nv = 0, nf = 0;
  std::vector<int64_t> cotangent_batch;  // backward only: the cotangent's leading dims
};

// Ranks, dtypes and the grid attributes against the buffers' shapes. Reads no
// array data and allocates nothing sized by the attributes. `cotangent` is
// null for the forward.
ffi::Error check_shapes(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                        const ffi::AnyBuffer* cotangent, const ffi::AnyBuffer& out,
                        const GridAttributes& at, Problem* pb) {
  const auto vd = vertices.dimensions();
  const auto fd = faces.dimensions();
  const auto od = out.dimensions();
  if (vd.size() < 2)
    return ffi::Error::InvalidArgument("voxax: vertices must have shape (..., V, d), got " +
                                       dims_str(vd));
  if (fd.size() < 2)
    return ffi::Error::InvalidArgument("voxax: faces must have shape (..., F, d), got " +
                                       dims_str(fd));
  const int64_t d = vd[vd.size() - 1];
  if (d != 2 && d != 3)
    return ffi::Error::InvalidArgument("voxax: vertices must have 2 or 3 coordinates, got shape " +
                                       dims_str(vd));
  if (fd[fd.size() - 1] != d)
    return ffi::Error::InvalidArgument("voxax: faces " + dims_str(fd) + " must have " +
                                       std::to_string(d) + " indices per face for " +
                                       std::to_string(d) + "D vertices");
  const auto vt = vertices.element_type();
  if (vt != ffi::DataType::F32 && vt != ffi::DataType::F64)
    return ffi::Error::InvalidArgument("voxax: vertices must be float32 or float64");
  if (faces.element_type() != ffi::DataType::S32)
    return ffi::Error::InvalidArgument("voxax: faces must be int32");
  if (out.element_type() != vt)
    return ffi::Error::InvalidArgument("voxax: output dtype must match the vertices");
  if (cotangent && cotangent->element_type() != vt)
    return ffi::Error::InvalidArgument("voxax: cotangent dtype must match the vertices");
  pb->dim = static_cast<int>(d);
  pb->nv = vd[vd.size() - 2];
  pb->nf = fd[fd.size() - 2];
  if (pb->nv > INT32_MAX || pb->nf > INT32_MAX)
    return ffi::Error::InvalidArgument("voxax: at most 2^31 - 1 vertices and faces are supported");

  ffi::Error err =
      check_grid(pb->dim, at.x0, at.x1, at.nx, at.y0, at.y1, at.ny, at.z0, at.z1, at.nz, &pb->grid);
  if (err.failure()) return err;
  const size_t trailing = cotangent ? 3 : static_cast<size_t>(pb->dim);
  err = make_batch(vd, fd, od, trailing, &pb->batch);
  if (err.failure()) return err;
  const size_t nb = pb->batch.out.size();
  if (!cotangent) {
    for (int a = 0; a < pb->dim; ++a)
      if (od[nb + a] != pb->grid.n[a])
        return ffi::Error::InvalidArgument("voxax: output shape " + dims_str(od) +
                                           " does not match the grid");
    return ffi::Error::Success();
  }
  if (od[nb] != pb->nf || od[nb + 1] != pb->dim || od[nb + 2] != pb->dim)
    return ffi::Error::InvalidArgument(
        "voxax: backward output must have shape (..., F, d, d), got " + dims_str(od));
  const auto gd = cotangent->dimensions();
  if (gd.size() != nb + static_cast<size_t>(pb->dim))
    return ffi::Error::InvalidArgument("voxax: cotangent " + dims_str(gd) + " has the wrong rank");
  // The cotangent's batch axes broadcast like the inputs' (a vmap of a
  // gradient passes a size-1 axis when the cotangent does not vary).
  pb->cotangent_batch.assign(gd.begin(), gd.begin() + nb);
  for (size_t a = 0; a < nb; ++a)
    if (gd[a] != 1 && gd[a] != pb->batch.out[a])
      return ffi::Error::InvalidArgument("voxax: cotangent batch axes " + dims_str(gd) +
                                         " do not broadcast to the output");
  for (int a = 0; a < pb->dim; ++a)
    if (gd[nb + a] != pb->grid.n[a])
      return ffi::Error::InvalidArgument("voxax: cotangent shape " + dims_str(gd) +
                                         " does not match the grid");
  return ffi::Error::Success();
}

// Every vertex set finite and bounded, every face set in range.
ffi::Error check_values(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                        const Problem& pb) {
  const int64_t vcount = pb.nv * pb.dim, fcount = pb.nf * pb.dim;
  const bool f32 = vertices.element_type() == ffi::DataType::F32;
  for (int64_t b = 0; b < pb.batch.vertex_count(); ++b) {
    ffi::Error err = f32 ? check_vertices(vertices.typed_data<float>() + b * vcount, vcount, b)
                         : check_vertices(vertices.typed_data<double>() + b * vcount, vcount, b);
    if (err.failure()) return err;
  }
  for (int64_t b = 0; b < pb.batch.face_count(); ++b) {
    ffi::Error err = check_faces(faces.typed_data<int32_t>() + b * fcount, fcount, pb.nv, b);
    if (err.failure()) return err;
  }
  return ffi::Error::Success();
}

// Shapes, then the plane tables, then values.
ffi::Error prepare(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                   const ffi::AnyBuffer* cotangent, const ffi::AnyBuffer& out,
                   const GridAttributes& at, Problem* pb) {
  ffi::Error err = check_shapes(vertices, faces, cotangent, out, at, pb);
  if (err.failure()) return err;
  pb->grid.build_planes();
  return check_values(vertices, faces, *pb);
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
    const T* Gb = G + Batch::source(pb.batch.out, pb.cotangent_batch, b) * g.cell_count();
    T* ob = out + b * ostride;
    if (pb.dim == 3)
      backward_triangles_3d(g, Vb, Fb, Gb, t0, t1, ob);
    else
      backward_segments_2d(g, Vb, Fb, Gb, t0, t1, ob);
  });
}

ffi::Error Forward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                   ffi::Result<ffi::AnyBuffer> out, double x0, double x1, int64_t nx, double y0,
                   double y1, int64_t ny, double z0, double z1, int64_t nz) {
  return guarded("the forward kernel", [&]() {
    Problem pb;
    ffi::Error err =
        prepare(vertices, faces, nullptr, *out, {x0, x1, nx, y0, y1, ny, z0, z1, nz}, &pb);
    if (err.failure()) return err;
    if (vertices.element_type() == ffi::DataType::F32)
      forward_impl<float>(&pool, pb, vertices.typed_data<float>(), faces.typed_data<int32_t>(),
                          out->typed_data<float>());
    else
      forward_impl<double>(&pool, pb, vertices.typed_data<double>(), faces.typed_data<int32_t>(),
                           out->typed_data<double>());
    return ffi::Error::Success();
  });
}

ffi::Error Backward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                    ffi::AnyBuffer cotangent, ffi::Result<ffi::AnyBuffer> out, double x0, double x1,
                    int64_t nx, double y0, double y1, int64_t ny, double z0, double z1,
                    int64_t nz) {
  return guarded("the backward kernel", [&]() {
    Problem pb;
    ffi::Error err =
        prepare(vertices, faces, &cotangent, *out, {x0, x1, nx, y0, y1, ny, z0, z1, nz}, &pb);
    if (err.failure()) return err;
    if (vertices.element_type() == ffi::DataType::F32)
      backward_impl<float>(&pool, pb, vertices.typed_data<float>(), faces.typed_data<int32_t>(),
                           cotangent.typed_data<float>(), out->typed_data<float>());
    else
      backward_impl<double>(&pool, pb, vertices.typed_data<double>(), faces.typed_data<int32_t>(),
                            cotangent.typed_data<double>(), out->typed_data<double>());
    return ffi::Error::Success();
  });
}

}  // namespace
}  // namespace voxax

#pragma GCC visibility push(default)

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_forward, voxax::Forward,
                              voxax::with_grid_attributes(xla::ffi::Ffi::Bind()
                                                              .Ctx<xla::ffi::ThreadPool>()
                                                              .Arg<xla::ffi::AnyBuffer>()
                                                              .Arg<xla::ffi::AnyBuffer>()
                                                              .Ret<xla::ffi::AnyBuffer>()));

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_backward, voxax::Backward,
                              voxax::with_grid_attributes(xla::ffi::Ffi::Bind()
                                                              .Ctx<xla::ffi::ThreadPool>()
                                                              .Arg<xla::ffi::AnyBuffer>()
                                                              .Arg<xla::ffi::AnyBuffer>()
                                                              .Arg<xla::ffi::AnyBuffer>()
                                                              .Ret<xla::ffi::AnyBuffer>()));

#pragma GCC visibility pop

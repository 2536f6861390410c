// The input checks shared by the voxelization's FFI handlers (forward, backward,
// tangent): every handler takes a mesh (vertices (..., V, d), faces (..., F, d)
// int32), the grid attributes and an output with the mesh's batch axes, and checks
// them in this order before it allocates anything sized by the attributes: ranks and
// dtypes, the grid attributes, batch axes and the output's shape; then, after the
// plane tables are built, the values (finite, bounded vertices; face indices in
// range).
#pragma once

#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "common/batch.h"
#include "common/ffi_bind.h"
#include "common/grid.h"
#include "common/validate.h"
#include "xla/ffi/api/ffi.h"

namespace voxax {

struct GridAttributes {
  double x0, x1;
  int64_t nx;
  double y0, y1;
  int64_t ny;
  double z0, z1;
  int64_t nz;
  int64_t x_first, x_count;  // the window along x (x_count = 0: the whole axis)
};

struct Problem {
  GridSpec grid;
  Batch batch;
  int dim = 3;
  int64_t nv = 0, nf = 0;
  // The leading axes of the third input (the backward's cotangent, the tangent's corner
  // tangents): each 1 (broadcast) or the output's.
  std::vector<int64_t> extra_batch;
};

// Ranks, dtypes, counts, the grid attributes and the batch axes of the mesh against
// the output, whose trailing `trailing` axes (0: as many as the mesh's dimension d)
// follow its batch axes. Reads no array
// data and allocates nothing sized by the attributes.
inline ffi::Error check_mesh_shapes(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                                    const ffi::AnyBuffer& out, int trailing,
                                    const GridAttributes& at, Problem* pb) {
  const auto vd = vertices.dimensions();
  const auto fd = faces.dimensions();
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
  pb->dim = static_cast<int>(d);
  pb->nv = vd[vd.size() - 2];
  pb->nf = fd[fd.size() - 2];
  if (pb->nv > INT32_MAX || pb->nf > INT32_MAX)
    return ffi::Error::InvalidArgument("voxax: at most 2^31 - 1 vertices and faces are supported");
  ffi::Error err = check_grid(pb->dim, at.x0, at.x1, at.nx, at.y0, at.y1, at.ny, at.z0, at.z1,
                              at.nz, at.x_first, at.x_count, &pb->grid);
  if (err.failure()) return err;
  const size_t out_trailing = static_cast<size_t>(trailing > 0 ? trailing : pb->dim);
  return make_batch(vd, fd, out.dimensions(), out_trailing, &pb->batch);
}

// Whether axes [nb, nb + dim) of `shape` (the array called `what`) are the grid's.
inline ffi::Error check_grid_axes(ffi::Span<const int64_t> shape, size_t nb, const Problem& pb,
                                  const char* what) {
  for (int a = 0; a < pb.dim; ++a)
    if (shape[nb + a] != pb.grid.n[a])
      return ffi::Error::InvalidArgument(std::string("voxax: ") + what + " shape " +
                                         dims_str(shape) + " does not match the grid");
  return ffi::Error::Success();
}

// Records the batch axes of the third input, `shape` (called `what`), whose trailing
// `trailing` axes follow them: each must be 1 or the output's.
inline ffi::Error check_extra_batch(ffi::Span<const int64_t> shape, size_t trailing,
                                    const char* what, Problem* pb) {
  const size_t nb = pb->batch.out.size();
  if (shape.size() != nb + trailing)
    return ffi::Error::InvalidArgument(std::string("voxax: ") + what + " " + dims_str(shape) +
                                       " has the wrong rank");
  pb->extra_batch.assign(shape.begin(), shape.begin() + nb);
  for (size_t a = 0; a < nb; ++a)
    if (shape[a] != 1 && shape[a] != pb->batch.out[a])
      return ffi::Error::InvalidArgument(std::string("voxax: ") + what + " batch axes " +
                                         dims_str(shape) + " do not broadcast to the output");
  return ffi::Error::Success();
}

// Every vertex set finite and bounded, every face set in range.
inline ffi::Error check_mesh_values(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
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

// Calls fn(T()) with T the vertices' floating type (float or double).
template <typename Fn>
void with_float_type(const ffi::AnyBuffer& vertices, Fn&& fn) {
  if (vertices.element_type() == ffi::DataType::F32)
    fn(float());
  else
    fn(double());
}

// The FFI binding of a voxelization handler: the thread pool, the vertices, the faces,
// `kExtra` more buffers (the cotangent or the tangents), one result, the grid attributes.
template <int kExtra>
auto voxelize_binding() {
  return with_grid_attributes(buffers_binding<2 + kExtra, 1>());
}

}  // namespace voxax

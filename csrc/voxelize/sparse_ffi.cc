// XLA FFI handlers of the sparse voxelization (csrc/voxelize/sparse.h).
//
// voxax_sparse_forward(vertices (..., V, 3), faces (..., F, 3) int32)
//     -> cells (..., C, 3) int32, values (..., C), runs (..., R, 4) int32,
//        run_values (..., R), counts (..., 2) int32
//   The boundary cells (i, j, k) in ascending order with their values, the runs
//   (i, j, k_start, k_stop) of cells k_start <= k < k_stop holding run_values, in
//   ascending order, and how many of each there are; the rest of the C and R slots
//   (the capacities) are padding: cells (nx, ny, nz), runs (nx, ny, 0, 0), values 0.
//   Attribute `strict`: 1 makes more cells or runs than the capacities an error;
//   0 reports the counts only (the caller then runs again with room for them).
// voxax_sparse_backward(vertices, faces, cells, cotangent (..., C), counts)
//     -> corners (..., F, 3, 3): the corner gradients of sum(cotangent * values).
// voxax_sparse_tangent(vertices, faces, corner tangents (..., F, 3, 3), cells, counts)
//     -> dvalues (..., C): the directional derivative of the values.
// float32 or float64; the grid given by the attributes x0, ..., x_count. Leading axes
// are batch axes; each is 1 (broadcast) or the output's size.
//
// Every handler checks shapes, dtypes and the grid before it allocates anything sized
// by them, then the values (finite, bounded vertices; face indices in range; boundary
// cells in range, ascending, within the counts), inside `guarded`.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <map>
#include <string>
#include <utility>
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
#include "voxelize/sparse.h"
#include "voxelize/tangent.h"

namespace voxax {
namespace {

// Whether `shape` is (batch..., trailing...) with batch axes that are each 1 or the
// output's; records them in *dims.
ffi::Error check_broadcast(ffi::Span<const int64_t> shape, const Problem& pb,
                           std::vector<int64_t> trailing, const char* what,
                           std::vector<int64_t>* dims) {
  const size_t nb = pb.batch.out.size();
  bool ok = shape.size() == nb + trailing.size();
  for (size_t a = 0; ok && a < trailing.size(); ++a) ok = shape[nb + a] == trailing[a];
  for (size_t a = 0; ok && a < nb; ++a) ok = shape[a] == 1 || shape[a] == pb.batch.out[a];
  if (!ok) {
    std::string want = "(...";
    for (int64_t t : trailing) want += ", " + std::to_string(t);
    return ffi::Error::InvalidArgument(std::string("voxax: ") + what + " must have shape " + want +
                                       ") with the mesh's batch axes, got " + dims_str(shape));
  }
  dims->assign(shape.begin(), shape.begin() + nb);
  return ffi::Error::Success();
}

ffi::Error check_type(const ffi::AnyBuffer& a, ffi::DataType t, const char* what) {
  if (a.element_type() != t)
    return ffi::Error::InvalidArgument(
        std::string("voxax: ") + what +
        (t == ffi::DataType::S32 ? " must be int32" : " dtype must match the vertices"));
  return ffi::Error::Success();
}

// The mesh's shapes against `out` (whose `trailing` axes follow its batch axes), 3D only.
ffi::Error check_sparse_mesh(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                             const ffi::AnyBuffer& out, int trailing, const GridAttributes& at,
                             Problem* pb) {
  ffi::Error err = check_mesh_shapes(vertices, faces, out, trailing, at, pb);
  if (err.failure()) return err;
  if (pb->dim != 3)
    return ffi::Error::InvalidArgument("voxax: the sparse voxelization takes 3D meshes only");
  // Cells, run ends and the padding (n itself) are int32.
  for (int a = 0; a < 3; ++a)
    if (pb->grid.n[a] > INT32_MAX)
      return ffi::Error::InvalidArgument(
          "voxax: the sparse voxelization takes at most 2^31 - 1 cells per axis, got " +
          std::to_string(pb->grid.n[a]));
  return ffi::Error::Success();
}

// The boundary cells of every batch item: counts in [0, capacity], cells in the grid and
// strictly ascending.
ffi::Error check_cells(const int32_t* cells, const int32_t* counts, int64_t items, int64_t capacity,
                       const GridSpec& g) {
  for (int64_t b = 0; b < items; ++b) {
    const int64_t n = counts[2 * b];
    if (n < 0 || n > capacity)
      return ffi::Error::InvalidArgument("voxax: sparse grid count " + std::to_string(n) +
                                         " of batch item " + std::to_string(b) +
                                         " is outside [0, " + std::to_string(capacity) + "]");
    const int32_t* c = cells + 3 * capacity * b;
    for (int64_t q = 0; q < n; ++q) {
      const int32_t* p = c + 3 * q;
      for (int a = 0; a < 3; ++a)
        if (p[a] < 0 || p[a] >= g.n[a])
          return ffi::Error::InvalidArgument("voxax: sparse grid cell " + std::to_string(q) +
                                             " of batch item " + std::to_string(b) +
                                             " lies outside the grid");
      if (q > 0 && !SparseCells::less3(p - 3, p[0], p[1], p[2]))
        return ffi::Error::InvalidArgument("voxax: sparse grid cells of batch item " +
                                           std::to_string(b) + " are not in ascending order");
    }
  }
  return ffi::Error::Success();
}

// ---------------------------------------------------------------------------
// Forward

template <typename T>
ffi::Error forward_impl(ffi::ThreadPool* pool, const Problem& pb, bool strict, const T* V,
                        const int32_t* F, int64_t C, int64_t R, int32_t* cells, T* values,
                        int32_t* runs, T* run_values, int32_t* counts) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * 3, fstride = pb.nf * 3;
  const Tiling tl = make_tiling(g);
  const int64_t nx = g.n[0];
  std::vector<SparseRow<T>> rows(B * nx);
  {
    std::vector<Bins> bins(B), touch(B);
    for (int64_t b = 0; b < B; ++b) {
      const T* Vb = V + pb.batch.vsrc(b) * vstride;
      const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
      bin_triangles_3d(pool, g, tl, Vb, Fb, pb.nf, &bins[b]);
      bin_tangent_faces(pool, g, tl, 3, Vb, Fb, pb.nf, &touch[b]);
    }
    const int64_t tasks = B * tl.ntx;
    std::vector<SparseTileScratch> scratch(ParallelFor::workers(pool, tasks));
    ParallelFor::run(pool, tasks, [&](int64_t task, int worker) {
      const int64_t b = task / tl.ntx, ti = task % tl.ntx;
      sparse_tile_row(g, tl, ti, V + pb.batch.vsrc(b) * vstride, F + pb.batch.fsrc(b) * fstride,
                      bins[b], touch[b], scratch[worker], rows.data() + b * nx + ti * tl.tx);
    });
  }
  // Offsets of every row in its batch item's output, and the counts.
  std::vector<int64_t> cell_at(B * nx + 1, 0), run_at(B * nx + 1, 0);
  bool fits = true;
  std::string over;
  for (int64_t b = 0; b < B; ++b) {
    int64_t nc = 0, nr = 0;
    for (int64_t i = 0; i < nx; ++i) {
      cell_at[b * nx + i] = nc;
      run_at[b * nx + i] = nr;
      nc += static_cast<int64_t>(rows[b * nx + i].values.size());
      nr += static_cast<int64_t>(rows[b * nx + i].run_values.size());
    }
    if (nc > INT32_MAX || nr > INT32_MAX)
      return ffi::Error::InvalidArgument(
          "voxax: the sparse grid has more than 2^31 - 1 boundary cells or runs");
    counts[2 * b] = static_cast<int32_t>(nc);
    counts[2 * b + 1] = static_cast<int32_t>(nr);
    if ((nc > C || nr > R) && fits) {
      fits = false;
      over = "voxax: voxelize_sparse: batch item " + std::to_string(b) + " has " +
             std::to_string(nc) + " boundary cells and " + std::to_string(nr) +
             " runs, more than the capacity of " + std::to_string(C) + " cells and " +
             std::to_string(R) + " runs; pass a larger `capacity` (at least (" +
             std::to_string(nc) + ", " + std::to_string(nr) + "))";
    }
  }
  if (!fits && strict) return ffi::Error::InvalidArgument(over);
  const int32_t pad_cell[3] = {static_cast<int32_t>(g.n[0]), static_cast<int32_t>(g.n[1]),
                               static_cast<int32_t>(g.n[2])};
  const int32_t pad_run[4] = {pad_cell[0], pad_cell[1], 0, 0};
  // Rows are copied (and freed) in parallel; then the padding.
  ParallelFor::run(pool, B * nx, [&](int64_t task) {
    const int64_t b = task / nx;
    SparseRow<T>& row = rows[task];
    if (fits) {
      std::copy(row.cells.begin(), row.cells.end(), cells + 3 * (b * C + cell_at[task]));
      std::copy(row.values.begin(), row.values.end(), values + b * C + cell_at[task]);
      std::copy(row.runs.begin(), row.runs.end(), runs + 4 * (b * R + run_at[task]));
      std::copy(row.run_values.begin(), row.run_values.end(), run_values + b * R + run_at[task]);
    }
    row.clear();
  });
  for (int64_t b = 0; b < B; ++b) {
    const int64_t nc = fits ? counts[2 * b] : 0, nr = fits ? counts[2 * b + 1] : 0;
    for (int64_t q = nc; q < C; ++q) {
      std::copy(pad_cell, pad_cell + 3, cells + 3 * (b * C + q));
      values[b * C + q] = T(0);
    }
    for (int64_t q = nr; q < R; ++q) {
      std::copy(pad_run, pad_run + 4, runs + 4 * (b * R + q));
      run_values[b * R + q] = T(0);
    }
  }
  return ffi::Error::Success();
}

ffi::Error Forward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                   ffi::Result<ffi::AnyBuffer> cells, ffi::Result<ffi::AnyBuffer> values,
                   ffi::Result<ffi::AnyBuffer> runs, ffi::Result<ffi::AnyBuffer> run_values,
                   ffi::Result<ffi::AnyBuffer> counts, double x0, double x1, int64_t nx, double y0,
                   double y1, int64_t ny, double z0, double z1, int64_t nz, int64_t x_first,
                   int64_t x_count, int64_t strict) {
  return guarded("the sparse forward kernel", [&]() {
    Problem pb;
    ffi::Error err = check_sparse_mesh(vertices, faces, *values, 1,
                                       {x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count}, &pb);
    if (err.failure()) return err;
    const auto vt = vertices.element_type();
    const size_t nb = pb.batch.out.size();
    const int64_t C = values->dimensions()[nb];
    const auto rd = run_values->dimensions();
    if (rd.size() != nb + 1)
      return ffi::Error::InvalidArgument("voxax: run values have the wrong rank " + dims_str(rd));
    const int64_t R = rd[nb];
    std::vector<int64_t> dims;
    const std::vector<int64_t> full(pb.batch.out.begin(), pb.batch.out.end());
    struct Out {
      const ffi::AnyBuffer* buf;
      ffi::DataType type;
      std::vector<int64_t> trailing;
      const char* what;
    };
    const Out outs[] = {{&*cells, ffi::DataType::S32, {C, 3}, "cells"},
                        {&*runs, ffi::DataType::S32, {R, 4}, "runs"},
                        {&*run_values, vt, {R}, "run values"},
                        {&*counts, ffi::DataType::S32, {2}, "counts"}};
    for (const Out& o : outs) {
      err = check_type(*o.buf, o.type, o.what);
      if (err.failure()) return err;
      err = check_broadcast(o.buf->dimensions(), pb, o.trailing, o.what, &dims);
      if (err.failure()) return err;
      if (dims != full)
        return ffi::Error::InvalidArgument(std::string("voxax: ") + o.what +
                                           " must have the output's batch axes");
    }
    pb.grid.build_planes();
    err = check_mesh_values(vertices, faces, pb);
    if (err.failure()) return err;
    if (pb.batch.size() == 0) return ffi::Error::Success();
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      err = forward_impl<T>(&pool, pb, strict != 0, vertices.typed_data<T>(),
                            faces.typed_data<int32_t>(), C, R, cells->typed_data<int32_t>(),
                            values->typed_data<T>(), runs->typed_data<int32_t>(),
                            run_values->typed_data<T>(), counts->typed_data<int32_t>());
    });
    return err;
  });
}

// ---------------------------------------------------------------------------
// The derivatives: both take the boundary cells and counts of the forward.

struct SparseInputs {
  std::vector<int64_t> cell_batch, count_batch, extra_batch;
  int64_t capacity = 0;
};

// Checks cells (..., C, 3) int32, counts (..., 2) int32 and the third input `extra`
// (`what`, of the vertices' dtype, with `extra_trailing` axes after its batch axes), and
// the cells' values.
ffi::Error check_sparse_inputs(const ffi::AnyBuffer& vertices, const ffi::AnyBuffer& faces,
                               const ffi::AnyBuffer& cells, const ffi::AnyBuffer& counts,
                               const ffi::AnyBuffer& extra, std::vector<int64_t> extra_trailing,
                               const char* what, Problem* pb, SparseInputs* in) {
  const size_t nb = pb->batch.out.size();
  const auto cd = cells.dimensions();
  if (cd.size() != nb + 2)
    return ffi::Error::InvalidArgument("voxax: sparse grid cells " + dims_str(cd) +
                                       " have the wrong rank");
  in->capacity = cd[nb];
  ffi::Error err = check_type(cells, ffi::DataType::S32, "sparse grid cells");
  if (err.failure()) return err;
  err = check_broadcast(cd, *pb, {in->capacity, 3}, "sparse grid cells", &in->cell_batch);
  if (err.failure()) return err;
  err = check_type(counts, ffi::DataType::S32, "sparse grid counts");
  if (err.failure()) return err;
  err = check_broadcast(counts.dimensions(), *pb, {2}, "sparse grid counts", &in->count_batch);
  if (err.failure()) return err;
  if (in->count_batch != in->cell_batch)
    return ffi::Error::InvalidArgument("voxax: sparse grid cells and counts have other batch axes");
  err = check_type(extra, vertices.element_type(), what);
  if (err.failure()) return err;
  err = check_broadcast(extra.dimensions(), *pb, std::move(extra_trailing), what, &in->extra_batch);
  if (err.failure()) return err;
  pb->grid.build_planes();
  err = check_mesh_values(vertices, faces, *pb);
  if (err.failure()) return err;
  int64_t items = 1;
  for (int64_t n : in->cell_batch) items *= n;
  return check_cells(cells.typed_data<int32_t>(), counts.typed_data<int32_t>(), items, in->capacity,
                     pb->grid);
}

template <typename T>
void backward_impl(ffi::ThreadPool* pool, const Problem& pb, const SparseInputs& in, const T* V,
                   const int32_t* F, const int32_t* cells, const int32_t* counts, const T* G,
                   T* out) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * 3, fstride = pb.nf * 3, ostride = pb.nf * 9;
  const int64_t C = in.capacity;
  constexpr int64_t kChunk = 64;
  const int64_t chunks = (pb.nf + kChunk - 1) / kChunk;
  ParallelFor::run(pool, B * chunks, [&](int64_t task) {
    const int64_t b = task / chunks, c = task % chunks;
    const int64_t t0 = c * kChunk, t1 = std::min(pb.nf, t0 + kChunk);
    const int64_t cb = Batch::source(pb.batch.out, in.cell_batch, b);
    const SparseCells sc{cells + 3 * C * cb, counts[2 * cb]};
    const T* Gb = G + Batch::source(pb.batch.out, in.extra_batch, b) * C;
    backward_triangles_3d_by(
        g, V + pb.batch.vsrc(b) * vstride, F + pb.batch.fsrc(b) * fstride,
        [&](int64_t i, int64_t j) {
          const SparseCells::Column col = sc.column(i, j);
          return [col, Gb](int64_t k) {
            const int64_t s = col.slot(k);
            return s < 0 ? 0.0 : static_cast<double>(Gb[s]);
          };
        },
        t0, t1, out + b * ostride);
  });
}

ffi::Error Backward(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                    ffi::AnyBuffer cells, ffi::AnyBuffer cotangent, ffi::AnyBuffer counts,
                    ffi::Result<ffi::AnyBuffer> out, double x0, double x1, int64_t nx, double y0,
                    double y1, int64_t ny, double z0, double z1, int64_t nz, int64_t x_first,
                    int64_t x_count) {
  return guarded("the sparse backward kernel", [&]() {
    Problem pb;
    ffi::Error err = check_sparse_mesh(vertices, faces, *out, 3,
                                       {x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count}, &pb);
    if (err.failure()) return err;
    const auto od = out->dimensions();
    const size_t nb = pb.batch.out.size();
    if (od[nb] != pb.nf || od[nb + 1] != 3 || od[nb + 2] != 3)
      return ffi::Error::InvalidArgument(
          "voxax: sparse backward output must have shape (..., F, 3, 3), got " + dims_str(od));
    SparseInputs in;
    const auto cd = cells.dimensions();
    const int64_t C = cd.size() == nb + 2 ? cd[nb] : -1;
    err =
        check_sparse_inputs(vertices, faces, cells, counts, cotangent, {C}, "cotangent", &pb, &in);
    if (err.failure()) return err;
    if (pb.batch.size() == 0) return ffi::Error::Success();
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      backward_impl<T>(&pool, pb, in, vertices.typed_data<T>(), faces.typed_data<int32_t>(),
                       cells.typed_data<int32_t>(), counts.typed_data<int32_t>(),
                       cotangent.typed_data<T>(), out->typed_data<T>());
    });
    return ffi::Error::Success();
  });
}

template <typename T>
void tangent_impl(ffi::ThreadPool* pool, const Problem& pb, const SparseInputs& in, const T* V,
                  const int32_t* F, const T* TC, const int32_t* cells, const int32_t* counts,
                  T* out) {
  const GridSpec& g = pb.grid;
  const int64_t B = pb.batch.size();
  const int64_t vstride = pb.nv * 3, fstride = pb.nf * 3, tstride = pb.nf * 9;
  const int64_t C = in.capacity;
  const Tiling tl = make_tiling(g);
  const double inv_vol = 1.0 / g.cell_volume();
  // Bins depend on the vertices and faces only: one set per distinct pair.
  std::map<std::pair<int64_t, int64_t>, size_t> which;
  std::vector<size_t> bin_of(B);
  std::vector<Bins> bins;
  for (int64_t b = 0; b < B; ++b) {
    const auto key = std::make_pair(pb.batch.vsrc(b), pb.batch.fsrc(b));
    auto it = which.find(key);
    if (it == which.end()) {
      bins.emplace_back();
      bin_tangent_faces(pool, g, tl, 3, V + key.first * vstride, F + key.second * fstride, pb.nf,
                        &bins.back());
      it = which.emplace(key, bins.size() - 1).first;
    }
    bin_of[b] = it->second;
  }
  // Every cell lies in one tile, whose faces one thread adds in bin order.
  std::vector<double> acc(B * C, 0.0);
  const int64_t tiles = tl.count();
  ParallelFor::run(pool, B * tiles, [&](int64_t task) {
    const int64_t b = task / tiles, tile = task % tiles;
    const T* Vb = V + pb.batch.vsrc(b) * vstride;
    const int32_t* Fb = F + pb.batch.fsrc(b) * fstride;
    const T* Tb = TC + Batch::source(pb.batch.out, in.extra_batch, b) * tstride;
    const int64_t cb = Batch::source(pb.batch.out, in.cell_batch, b);
    const SparseCells sc{cells + 3 * C * cb, counts[2 * cb]};
    double* ab = acc.data() + b * C;
    const int64_t ti = tile / tl.nty, tj = tile % tl.nty;
    const int64_t ia = ti * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
    const int64_t ja = tj * tl.ty, jb = std::min(g.n[1], ja + tl.ty);
    const Bins& bn = bins[bin_of[b]];
    TriangleFrame frame;
    Poly<3> P;
    for (int64_t e = bn.start[tile]; e < bn.start[tile + 1]; ++e) {
      const int64_t t = bn.items[e];
      double c[3];
      if (!load_moving_triangle(Vb, Fb, Tb, t, &frame, &P, c)) continue;
      int64_t ci = -1, cj = -1;
      SparseCells::Column col{&sc, 0, 0, 0, 0};
      surface_pieces_in_tile(
          g, P, ia, ib, ja, jb, [&](int64_t i, int64_t j, int64_t k, const Poly<3>& Q) {
            if (i != ci || j != cj) {
              col = sc.column(i, j);
              ci = i;
              cj = j;
            }
            const int64_t s = col.slot(k);
            if (s < 0) return;
            double beta[3];
            frame.piece_integrals(Q, beta);
            ab[s] += inv_vol * (beta[0] * c[0] + beta[1] * c[1] + beta[2] * c[2]);
          });
    }
  });
  for (int64_t q = 0; q < B * C; ++q) out[q] = static_cast<T>(acc[q]);
}

template <typename T>
ffi::Error check_finite(const T* x, int64_t count, const char* what) {
  for (int64_t i = 0; i < count; ++i)
    if (!std::isfinite(static_cast<double>(x[i])))
      return ffi::Error::InvalidArgument(std::string("voxax: ") + what +
                                         " contain NaN or Inf (flat index " + std::to_string(i) +
                                         ")");
  return ffi::Error::Success();
}

ffi::Error Tangent(ffi::ThreadPool pool, ffi::AnyBuffer vertices, ffi::AnyBuffer faces,
                   ffi::AnyBuffer tangents, ffi::AnyBuffer cells, ffi::AnyBuffer counts,
                   ffi::Result<ffi::AnyBuffer> out, double x0, double x1, int64_t nx, double y0,
                   double y1, int64_t ny, double z0, double z1, int64_t nz, int64_t x_first,
                   int64_t x_count) {
  return guarded("the sparse tangent kernel", [&]() {
    Problem pb;
    ffi::Error err = check_sparse_mesh(vertices, faces, *out, 1,
                                       {x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count}, &pb);
    if (err.failure()) return err;
    const size_t nb = pb.batch.out.size();
    const auto cd = cells.dimensions();
    if (cd.size() != nb + 2 || cd[nb] != out->dimensions()[nb])
      return ffi::Error::InvalidArgument("voxax: sparse grid cells " + dims_str(cd) +
                                         " do not match the output " + dims_str(out->dimensions()));
    SparseInputs in;
    err = check_sparse_inputs(vertices, faces, cells, counts, tangents, {pb.nf, 3, 3},
                              "corner tangents", &pb, &in);
    if (err.failure()) return err;
    int64_t tcount = pb.nf * 9;
    for (int64_t n : in.extra_batch) tcount *= n;
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      err = check_finite(tangents.typed_data<T>(), tcount, "tangents");
    });
    if (err.failure()) return err;
    if (pb.batch.size() == 0) return ffi::Error::Success();
    with_float_type(vertices, [&](auto zero) {
      using T = decltype(zero);
      tangent_impl<T>(&pool, pb, in, vertices.typed_data<T>(), faces.typed_data<int32_t>(),
                      tangents.typed_data<T>(), cells.typed_data<int32_t>(),
                      counts.typed_data<int32_t>(), out->typed_data<T>());
    });
    return ffi::Error::Success();
  });
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_sparse_forward, Forward,
                  (with_grid_attributes(buffers_binding<2, 5>()).Attr<int64_t>("strict")))
VOXAX_FFI_HANDLER(voxax_sparse_backward, Backward, (with_grid_attributes(buffers_binding<5, 1>())))
VOXAX_FFI_HANDLER(voxax_sparse_tangent, Tangent, (with_grid_attributes(buffers_binding<5, 1>())))

}  // namespace voxax

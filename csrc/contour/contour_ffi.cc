// Marching cubes / squares: an XLA FFI handler with static capacities (the C API for
// exact-size eager results is in contour_host.cc).
//
// voxax_marching_cubes(values (..., *shape)) -> edges (..., VC, 2) int32,
//   faces (..., FC, dim) int32, counts (..., 2) int32
// with attributes level (double) and dim (int64, 2 or 3). counts holds the
// true vertex and face counts; padding is 0. A mesh that does not fit the
// capacities is an error that names the capacity it needs.

#include <atomic>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <new>
#include <string>
#include <thread>
#include <vector>

#include "common/batch.h"
#include "common/constants.h"
#include "common/errors.h"
#include "common/ffi_bind.h"
#include "common/grid.h"
#include "common/host_pool.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "contour/contour_checks.h"
#include "contour/marching_cubes.h"

namespace voxax {
namespace {

using contour::Counts;
using contour::Sampler;
using contour::Shape;

using contour::kInt32Max;

template <typename T>
int64_t first_non_finite(const T* v, int64_t n) {
  for (int64_t i = 0; i < n; ++i)
    if (!std::isfinite(static_cast<double>(v[i]))) return i;
  return -1;
}

using contour::shape_error;

template <typename T>
ffi::Error mc_impl(ffi::ThreadPool* pool, const Shape& sh, int64_t batch, const T* values,
                   double level, int32_t* edges, int64_t vcap, int32_t* faces, int64_t fcap,
                   int32_t* counts) {
  const int64_t cells = sh.cells();
  auto run = [&](int64_t n, auto&& body) {
    ParallelFor::run(pool, n, body);
    return true;
  };
  int64_t need_v = 0, need_f = 0;  // the largest counts of items that do not fit
  for (int64_t b = 0; b < batch; ++b) {
    const T* v = values + b * cells;
    const int64_t bad = first_non_finite(v, cells);
    if (bad >= 0)
      return ffi::Error::InvalidArgument(
          "voxax.isosurface: values contain NaN or Inf (batch item " + std::to_string(b) +
          ", flat index " + std::to_string(bad) + ")");
    Sampler<T> s{v, level};
    Counts cnt;
    if (!contour::count_pass(s, sh, run, &cnt))
      return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax.isosurface: out of memory");
    int32_t* eb = edges + b * vcap * 2;
    int32_t* fb = faces + b * fcap * sh.dim;
    std::fill(eb, eb + vcap * 2, 0);
    std::fill(fb, fb + fcap * sh.dim, 0);
    const int64_t nv = cnt.total_vertices(), nf = cnt.total_faces();
    counts[2 * b] = int32_t(std::min(nv, kInt32Max));
    counts[2 * b + 1] = int32_t(std::min(nf, kInt32Max));
    if (nv > vcap || nf > fcap) {  // reported once every item is counted
      need_v = std::max(need_v, nv);
      need_f = std::max(need_f, nf);
      continue;
    }
    if (!contour::fill_pass(s, sh, cnt, run, eb, vcap, fb, fcap))
      return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax.isosurface: out of memory");
  }
  if (need_v || need_f)
    return ffi::Error::InvalidArgument(
        "voxax.isosurface: the mesh needs capacity=(" + std::to_string(std::max(need_v, vcap)) +
        ", " + std::to_string(std::max(need_f, fcap)) + ") (vertices, faces) or more, got (" +
        std::to_string(vcap) + ", " + std::to_string(fcap) + ")");
  return ffi::Error::Success();
}

constexpr char kLevel[] = "level";
constexpr char kDim[] = "dim";

ffi::Error MarchingCubes(ffi::ThreadPool pool, ffi::AnyBuffer values,
                         ffi::Result<ffi::AnyBuffer> edges, ffi::Result<ffi::AnyBuffer> faces,
                         ffi::Result<ffi::AnyBuffer> counts, ffi::Attr<double, kLevel> level_attr,
                         ffi::Attr<int64_t, kDim> dim_attr) {
  const double level = *level_attr;
  const int64_t dim = *dim_attr;
  if (dim != 2 && dim != 3)
    return ffi::Error::InvalidArgument("voxax.isosurface: dim must be 2 or 3");
  if (!std::isfinite(level))
    return ffi::Error::InvalidArgument("voxax.isosurface: level must be finite");
  const auto vd = values.dimensions();
  const auto ed = edges->dimensions(), fd = faces->dimensions(), cd = counts->dimensions();
  if (vd.size() < size_t(dim))
    return ffi::Error::InvalidArgument("voxax.isosurface: values must have at least dim axes");
  const size_t nb = vd.size() - dim;
  if (ed.size() != nb + 2 || fd.size() != nb + 2 || cd.size() != nb + 1 || ed[nb + 1] != 2 ||
      fd[nb + 1] != dim || cd[nb] != 2)
    return ffi::Error::InvalidArgument("voxax.isosurface: output shapes do not match the values " +
                                       dims_str(vd));
  int64_t batch = 1;
  for (size_t a = 0; a < nb; ++a) {
    if (ed[a] != vd[a] || fd[a] != vd[a] || cd[a] != vd[a])
      return ffi::Error::InvalidArgument(
          "voxax.isosurface: output batch axes do not match the values");
    batch *= vd[a];
  }
  Shape sh;
  sh.dim = static_cast<int>(dim);
  for (int a = 0; a < dim; ++a) {
    sh.n[a] = vd[nb + a];
    if (sh.n[a] < 1) {
      batch = 0;  // empty grid: nothing to do
    }
  }
  if (batch > 0 && sh.cells() > kInt32Max) return ffi::Error::InvalidArgument(shape_error(sh));
  if (edges->element_type() != ffi::DataType::S32 || faces->element_type() != ffi::DataType::S32 ||
      counts->element_type() != ffi::DataType::S32)
    return ffi::Error::InvalidArgument("voxax.isosurface: outputs must be int32");
  const int64_t vcap = ed[nb], fcap = fd[nb];
  try {
    if (batch == 0) {
      std::fill(edges->typed_data<int32_t>(), edges->typed_data<int32_t>() + edges->element_count(),
                0);
      std::fill(faces->typed_data<int32_t>(), faces->typed_data<int32_t>() + faces->element_count(),
                0);
      std::fill(counts->typed_data<int32_t>(),
                counts->typed_data<int32_t>() + counts->element_count(), 0);
      return ffi::Error::Success();
    }
    switch (values.element_type()) {
      case ffi::DataType::F32:
        return mc_impl<float>(&pool, sh, batch, values.typed_data<float>(), level,
                              edges->typed_data<int32_t>(), vcap, faces->typed_data<int32_t>(),
                              fcap, counts->typed_data<int32_t>());
      case ffi::DataType::F64:
        return mc_impl<double>(&pool, sh, batch, values.typed_data<double>(), level,
                               edges->typed_data<int32_t>(), vcap, faces->typed_data<int32_t>(),
                               fcap, counts->typed_data<int32_t>());
      default:
        return ffi::Error::InvalidArgument("voxax.isosurface: values must be float32 or float64");
    }
  } catch (const std::bad_alloc&) {
    return ffi::Error(ffi::ErrorCode::kResourceExhausted, "voxax.isosurface: out of memory");
  } catch (const std::exception& e) {
    return ffi::Error(ffi::ErrorCode::kInternal, std::string("voxax.isosurface: ") + e.what());
  }
}

}  // namespace

VOXAX_FFI_HANDLER(voxax_marching_cubes, MarchingCubes)

}  // namespace voxax

// Marching cubes / squares: an XLA FFI handler with static capacities, and a
// C API (count pass, then fill pass) for exact-size eager results.
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
#include "common/grid.h"
#include "common/host_pool.h"
#include "common/parallel.h"
#include "common/validate.h"
#include "contour/marching_cubes.h"

namespace voxax {
namespace {

using contour::Counts;
using contour::Sampler;
using contour::Shape;

constexpr int64_t kInt32Max = 2147483647;

template <typename T>
int64_t first_non_finite(const T* v, int64_t n) {
  for (int64_t i = 0; i < n; ++i)
    if (!std::isfinite(static_cast<double>(v[i]))) return i;
  return -1;
}

std::string shape_error(const Shape& sh) {
  (void)sh;
  return "voxax.isosurface: the grid has more than 2^31 - 1 cells";
}

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

ffi::Error MarchingCubes(ffi::ThreadPool pool, ffi::AnyBuffer values,
                         ffi::Result<ffi::AnyBuffer> edges, ffi::Result<ffi::AnyBuffer> faces,
                         ffi::Result<ffi::AnyBuffer> counts, double level, int64_t dim) {
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

// -- the C API for eager, exact-size results
// -------------------------------------------

// Runs body(c), c in [0, n), on `threads` std::threads claiming indices in
// turn.
struct ThreadRun {
  int threads;
  template <typename Body>
  bool operator()(int64_t n, Body&& body) const {
    std::atomic<int64_t> next{0};
    std::atomic<bool> failed{false};
    auto work = [&]() {
      for (;;) {
        const int64_t i = next.fetch_add(1);
        if (i >= n) return;
        try {
          body(i);
        } catch (...) {
          failed.store(true);
        }
      }
    };
    const int64_t t = std::max<int64_t>(1, std::min<int64_t>(threads, n));
    std::vector<std::thread> pool;
    try {
      for (int64_t k = 1; k < t; ++k) pool.emplace_back(work);
    } catch (...) {
      failed.store(true);
    }
    work();
    for (auto& th : pool) th.join();
    return !failed.load();
  }
};

struct Context {
  Shape shape;
  const void* values = nullptr;
  int dtype = 0;  // 0: float32, 1: float64
  double level = 0;
  int threads = 1;
  Counts counts;
};

void set_error(char* buf, int64_t len, const std::string& msg) {
  if (!buf || len <= 0) return;
  std::snprintf(buf, static_cast<size_t>(len), "%s", msg.c_str());
}

}  // namespace
}  // namespace voxax

#pragma GCC visibility push(default)

extern "C" {

// Pass 1. Returns 0 on success and fills counts[0] = vertices, counts[1] =
// faces, range[0], range[1] = the smallest and largest sample, and *ctx; a
// non-zero status leaves an error message in err (NaN or infinite samples: 1).
int voxax_mc_count(const void* values, int dtype, int dim, const int64_t* shape, double level,
                   int threads, void** ctx, int64_t* counts, double* range, char* err,
                   int64_t errlen) {
  using namespace voxax;
  *ctx = nullptr;
  try {
    if (dim != 2 && dim != 3) {
      set_error(err, errlen, "voxax.isosurface: dim must be 2 or 3");
      return 1;
    }
    auto c = std::make_unique<Context>();
    c->shape.dim = dim;
    for (int a = 0; a < dim; ++a) {
      if (shape[a] < 1) {
        set_error(err, errlen, "voxax.isosurface: every grid axis needs at least one cell");
        return 1;
      }
      c->shape.n[a] = shape[a];
    }
    if (c->shape.cells() > kInt32Max) {
      set_error(err, errlen, shape_error(c->shape));
      return 1;
    }
    c->values = values;
    c->dtype = dtype;
    c->level = level;
    c->threads = spatial::resolve_threads(threads);  // 0: all cores
    ThreadRun run{c->threads};
    bool ok;
    if (dtype == 0) {
      contour::Sampler<float> s{static_cast<const float*>(values), level};
      ok = contour::count_pass(s, c->shape, run, &c->counts);
    } else {
      contour::Sampler<double> s{static_cast<const double*>(values), level};
      ok = contour::count_pass(s, c->shape, run, &c->counts);
    }
    if (!ok) {
      set_error(err, errlen, "voxax.isosurface: out of memory");
      return 2;
    }
    if (c->counts.non_finite) {
      set_error(err, errlen, "voxax.isosurface: `values` must be finite (they contain NaN or Inf)");
      return 1;
    }
    range[0] = c->counts.lo;
    range[1] = c->counts.hi;
    counts[0] = c->counts.total_vertices();
    counts[1] = c->counts.total_faces();
    if (counts[0] > kInt32Max || counts[1] > kInt32Max) {
      set_error(err, errlen, "voxax.isosurface: more than 2^31 - 1 vertices or faces");
      return 1;
    }
    *ctx = c.release();
    return 0;
  } catch (const std::bad_alloc&) {
    set_error(err, errlen, "voxax.isosurface: out of memory");
    return 2;
  } catch (const std::exception& e) {
    set_error(err, errlen, std::string("voxax.isosurface: ") + e.what());
    return 3;
  }
}

// Pass 2: edges (V, 2) and faces (F, dim) of exactly the counted sizes.
int voxax_mc_fill(void* ctx, int32_t* edges, int32_t* faces) {
  using namespace voxax;
  try {
    auto* c = static_cast<Context*>(ctx);
    ThreadRun run{c->threads};
    const int64_t nv = c->counts.total_vertices(), nf = c->counts.total_faces();
    if (c->dtype == 0) {
      contour::Sampler<float> s{static_cast<const float*>(c->values), c->level};
      return contour::fill_pass(s, c->shape, c->counts, run, edges, nv, faces, nf) ? 0 : 2;
    }
    contour::Sampler<double> s{static_cast<const double*>(c->values), c->level};
    return contour::fill_pass(s, c->shape, c->counts, run, edges, nv, faces, nf) ? 0 : 2;
  } catch (...) {
    return 2;
  }
}

// The number of vertices owned by x slice i (crossed edges whose lower cell
// lies in slice i) after pass 1; -1 when i is out of range.
int64_t voxax_mc_slice_vertices(const void* ctx, int64_t i) {
  const auto* c = static_cast<const voxax::Context*>(ctx);
  if (!c || i < 0 || i >= static_cast<int64_t>(c->counts.vertices.size())) return -1;
  return c->counts.vertices[static_cast<size_t>(i)];
}

void voxax_mc_release(void* ctx) { delete static_cast<voxax::Context*>(ctx); }

// Loops of the derived cube cases that found no valid triangulation (expected:
// 0).
int voxax_mc_table_failures() { return voxax::contour::cube_table().failures; }

}  // extern "C"

XLA_FFI_DEFINE_HANDLER_SYMBOL(voxax_marching_cubes, voxax::MarchingCubes,
                              xla::ffi::Ffi::Bind()
                                  .Ctx<xla::ffi::ThreadPool>()
                                  .Arg<xla::ffi::AnyBuffer>()
                                  .Ret<xla::ffi::AnyBuffer>()
                                  .Ret<xla::ffi::AnyBuffer>()
                                  .Ret<xla::ffi::AnyBuffer>()
                                  .Attr<double>("level")
                                  .Attr<int64_t>("dim"));

#pragma GCC visibility pop

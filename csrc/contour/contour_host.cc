// Marching cubes / squares as a C API for exact-size eager results: a count pass, then a
// fill pass (the XLA FFI handler with static capacities is in contour_ffi.cc).

#include <atomic>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <new>
#include <string>
#include <thread>
#include <vector>

#include "common/host_pool.h"
#include "contour/contour_checks.h"
#include "contour/marching_cubes.h"

namespace voxax {
namespace {

using contour::Counts;
using contour::kInt32Max;
using contour::Shape;
using contour::shape_error;

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

#pragma GCC visibility pop

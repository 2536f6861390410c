// Shared pieces of the voxax kernels: grid geometry, batch broadcasting and a
// deterministic parallel loop over XLA's intra-op thread pool.
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace voxax {

namespace ffi = xla::ffi;

// The largest coordinate magnitude the kernels accept: squared lengths of
// triangle normals (fourth powers of coordinates) stay finite in double.
constexpr double kMaxAbsCoordinate = 1e75;

// An axis-aligned regular grid of n[a] cells per axis. Plane i along axis a
// sits at lo[a] + i * h[a], and the last plane is exactly hi[a]; the Python
// Grid uses the same formula, so both sides agree bit for bit.
struct GridSpec {
  int dim = 3;
  double lo[3] = {0, 0, 0};
  double hi[3] = {1, 1, 1};
  double h[3] = {1, 1, 1};
  double inv_h[3] = {1, 1, 1};
  double slack[3] = {0, 0, 0};  // rounding allowance of span(), in cells
  int64_t n[3] = {1, 1, 1};
  std::vector<double> planes[3];  // planes[a][i] = plane(a, i), i in [0, n]

  double plane(int a, int64_t i) const { return planes[a][i]; }
  // A conservative cell range [c0, c1] covering the interval [mn, mx] along
  // axis a, clamped to the grid: it may include one extra cell on each side
  // when a bound lies within rounding distance of a plane, never one less.
  // Callers clip at the actual plane coordinates, so extra cells only cost an
  // empty piece. Returns false when the interval misses the grid.
  bool span(int a, double mn, double mx, int64_t* c0, int64_t* c1) const {
    if (mx < lo[a] || mn > hi[a]) return false;
    double u0 = (mn - lo[a]) * inv_h[a] - slack[a];
    double u1 = (mx - lo[a]) * inv_h[a] + slack[a];
    const double top = static_cast<double>(n[a] - 1);
    // Clamped to [0, n - 1], so truncation is the floor.
    *c0 = static_cast<int64_t>(std::min(std::max(u0, 0.0), top));
    *c1 = static_cast<int64_t>(std::min(std::max(u1, 0.0), top));
    return true;
  }
  int64_t column_count() const { return dim == 3 ? n[0] * n[1] : n[0]; }
  int64_t column_length() const { return dim == 3 ? n[2] : n[1]; }
  int64_t cell_count() const { return column_count() * column_length(); }
  double cell_volume() const { return dim == 3 ? h[0] * h[1] * h[2] : h[0] * h[1]; }
};

// Builds and checks a GridSpec from the handler's attributes.
inline ffi::Error make_grid(int dim, double x0, double x1, int64_t nx, double y0,
                            double y1, int64_t ny, double z0, double z1,
                            int64_t nz, GridSpec* g) {
  g->dim = dim;
  const double lo[3] = {x0, y0, z0}, hi[3] = {x1, y1, z1};
  const int64_t n[3] = {nx, ny, nz};
  for (int a = 0; a < dim; ++a) {
    if (n[a] < 1 || n[a] > (int64_t{1} << 31))
      return ffi::Error::InvalidArgument("voxax: grid shape must be in [1, 2^31] on every axis");
    if (!std::isfinite(lo[a]) || !std::isfinite(hi[a]) || !(hi[a] > lo[a]))
      return ffi::Error::InvalidArgument("voxax: grid corners must be finite with upper > lower");
    g->lo[a] = lo[a];
    g->hi[a] = hi[a];
    g->n[a] = n[a];
    g->h[a] = (hi[a] - lo[a]) / static_cast<double>(n[a]);
    g->inv_h[a] = 1.0 / g->h[a];
    g->slack[a] = 1e-12 * (1.0 + (std::fabs(lo[a]) + std::fabs(hi[a])) * g->inv_h[a]);
    g->planes[a].resize(n[a] + 1);
    for (int64_t i = 0; i < n[a]; ++i) g->planes[a][i] = lo[a] + static_cast<double>(i) * g->h[a];
    g->planes[a][n[a]] = hi[a];
    if (!(g->h[a] > 0) || !std::isfinite(g->h[a]) || !std::isfinite(g->inv_h[a]))
      return ffi::Error::InvalidArgument("voxax: grid cell size is not a positive finite number");
  }
  const double vol = g->cell_volume();
  if (!(vol >= 1e-300) || !(vol <= 1e300))
    return ffi::Error::InvalidArgument("voxax: grid cell volume must lie in [1e-300, 1e300]");
  return ffi::Error::Success();
}

// Leading (batch) axes of the arguments. Every argument carries the same
// number of leading axes; each is either 1 (broadcast) or the output's size.
struct Batch {
  std::vector<int64_t> out;   // output batch shape
  std::vector<int64_t> vdim;  // vertices' leading dims
  std::vector<int64_t> fdim;  // faces' leading dims
  int64_t size() const {
    int64_t s = 1;
    for (int64_t d : out) s *= d;
    return s;
  }
  int64_t vertex_count() const {
    int64_t s = 1;
    for (int64_t d : vdim) s *= d;
    return s;
  }
  int64_t face_count() const {
    int64_t s = 1;
    for (int64_t d : fdim) s *= d;
    return s;
  }
  // Flat index into an argument with leading dims `dims` for output batch item b.
  static int64_t source(const std::vector<int64_t>& out,
                        const std::vector<int64_t>& dims, int64_t b) {
    int64_t idx = 0, stride = 1;
    for (int64_t a = static_cast<int64_t>(out.size()) - 1; a >= 0; --a) {
      int64_t coord = b % out[a];
      b /= out[a];
      if (dims[a] != 1) idx += coord * stride;
      stride *= dims[a];
    }
    return idx;
  }
  int64_t vsrc(int64_t b) const { return source(out, vdim, b); }
  int64_t fsrc(int64_t b) const { return source(out, fdim, b); }
};

inline std::string dims_str(ffi::Span<const int64_t> d) {
  std::string s = "(";
  for (size_t i = 0; i < d.size(); ++i) s += (i ? ", " : "") + std::to_string(d[i]);
  return s + ")";
}

// Checks the leading axes of vertices (..., V, d), faces (..., F, k) and an
// array with `trailing` trailing axes whose batch shape must be the output's.
inline ffi::Error make_batch(ffi::Span<const int64_t> vd, ffi::Span<const int64_t> fd,
                             ffi::Span<const int64_t> od, size_t trailing, Batch* batch) {
  if (vd.size() < 2 || fd.size() < 2 || od.size() < trailing)
    return ffi::Error::InvalidArgument("voxax: vertices and faces need at least 2 axes");
  size_t nb = vd.size() - 2;
  if (fd.size() - 2 != nb || od.size() - trailing != nb)
    return ffi::Error::InvalidArgument(
        "voxax: vertices " + dims_str(vd) + ", faces " + dims_str(fd) + " and output " +
        dims_str(od) + " must have the same number of batch axes");
  batch->out.assign(od.begin(), od.begin() + nb);
  batch->vdim.assign(vd.begin(), vd.begin() + nb);
  batch->fdim.assign(fd.begin(), fd.begin() + nb);
  for (size_t a = 0; a < nb; ++a) {
    int64_t o = batch->out[a];
    bool vok = batch->vdim[a] == 1 || batch->vdim[a] == o;
    bool fok = batch->fdim[a] == 1 || batch->fdim[a] == o;
    if (!vok || !fok)
      return ffi::Error::InvalidArgument("voxax: batch axes of vertices " + dims_str(vd) +
                                         " and faces " + dims_str(fd) +
                                         " do not broadcast to " + dims_str(od));
  }
  return ffi::Error::Success();
}

// Runs body(i) for i in [0, n) on XLA's thread pool and the calling thread.
// Every index is processed exactly once; which thread runs it does not affect
// results because each index writes disjoint memory. Workers that start after
// all indices are claimed return without touching the caller's data, so the
// caller only waits for claimed work, never for a pool thread to become free.
class ParallelFor {
 public:
  template <typename Body>
  static bool run(ffi::ThreadPool* pool, int64_t n, Body&& body) {
    if (n <= 0) return true;
    int64_t threads = pool ? pool->num_threads() : 1;
    if (threads <= 1 || n == 1) {
      try {
        for (int64_t i = 0; i < n; ++i) body(i);
      } catch (...) {
        return false;
      }
      return true;
    }
    auto state = std::make_shared<State>();
    state->n = n;
    state->body = [&body](int64_t i) { body(i); };
    int64_t helpers = std::min<int64_t>(threads, n) - 1;
    for (int64_t t = 0; t < helpers; ++t) {
      pool->Schedule([state]() { work(*state); });
    }
    work(*state);
    std::unique_lock<std::mutex> lock(state->mutex);
    state->cv.wait(lock, [&] { return state->done.load() == state->n; });
    // Drop the reference to the caller's body before returning.
    state->body = nullptr;
    return !state->failed.load();
  }

 private:
  struct State {
    std::atomic<int64_t> next{0};
    std::atomic<int64_t> done{0};
    std::atomic<bool> failed{false};
    int64_t n = 0;
    std::function<void(int64_t)> body;
    std::mutex mutex;
    std::condition_variable cv;
  };
  static void work(State& s) {
    for (;;) {
      int64_t i = s.next.fetch_add(1);
      if (i >= s.n) return;
      try {
        s.body(i);
      } catch (...) {
        s.failed.store(true);
      }
      if (s.done.fetch_add(1) + 1 == s.n) {
        std::lock_guard<std::mutex> lock(s.mutex);
        s.cv.notify_all();
      }
    }
  }
};

}  // namespace voxax

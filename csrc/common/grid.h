// The regular grid the kernels work on, read from the handlers' attributes.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "common/constants.h"
#include "xla/ffi/api/ffi.h"

namespace voxax {

namespace ffi = xla::ffi;

// An axis-aligned regular grid of n[a] cells per axis. Plane i along axis a
// sits at lo[a] + i * h[a], and the last plane is exactly hi[a]; the Python
// Grid uses the same formula, so both sides agree bit for bit.
//
// Built in two steps so that nothing is allocated before the grid has been
// checked against the buffers: `check_grid` validates the attributes and
// fills in the scalars; after the caller has compared n with the shapes of
// the buffers, `build_planes` allocates the plane tables.
struct GridSpec {
  int dim = 3;
  double lo[3] = {0, 0, 0};
  double hi[3] = {1, 1, 1};
  double h[3] = {1, 1, 1};
  double inv_h[3] = {1, 1, 1};
  double slack[3] = {0, 0, 0};  // rounding allowance of span(), in cells
  int64_t n[3] = {1, 1, 1};
  // Along x the grid may be a window of a larger frame: cells [x_first, x_first + n[0]) of
  // a frame of x_frame_n cells from x_frame_lo to x_frame_hi, whose planes are the frame's
  // (so a slab of a grid holds the very planes of the whole grid, bit for bit).
  int64_t x_first = 0, x_frame_n = 1;
  double x_frame_lo = 0, x_frame_hi = 1;
  std::vector<double> planes[3];  // planes[a][i] = plane(a, i), i in [0, n]

  // Plane i along axis a (i may lie outside [0, n] along x, within the frame).
  double plane(int a, int64_t i) const { return a == 0 ? frame_plane(0, i) : planes[a][i]; }
  // How many cells lie from this grid's first cell to the end of the frame along a.
  int64_t cells_to_end(int a) const { return a == 0 ? x_frame_n - x_first : n[a]; }
  // The first cell, relative to this grid, that an interval starting at mn touches along
  // axis a, clamped to the frame rather than to the grid (it is negative when the
  // interval starts left of a window). Sweeps along x start there, so that every cell's
  // pieces are cut by the same sequence of planes whatever the window or the tile.
  int64_t first_cell(int a, double mn) const {
    if (a != 0) {
      int64_t c0, c1;
      span(a, mn, mn, &c0, &c1);
      return c0;
    }
    const double u0 = (mn - x_frame_lo) * inv_h[0] - slack[0];
    const double top = static_cast<double>(x_frame_n - 1);
    return static_cast<int64_t>(std::min(std::max(u0, 0.0), top)) - x_first;
  }
  // A conservative cell range [c0, c1] covering the interval [mn, mx] along
  // axis a, clamped to the grid: it may include one extra cell on each side
  // when a bound lies within rounding distance of a plane, never one less.
  // Callers clip at the actual plane coordinates, so extra cells only cost an
  // empty piece. Returns false when the interval misses the grid.
  bool span(int a, double mn, double mx, int64_t* c0, int64_t* c1) const {
    if (mx < lo[a] || mn > hi[a]) return false;
    if (a == 0 && (x_first != 0 || x_frame_n != n[0])) {
      // A window: the frame's cells, shifted and clamped to the window.
      const double top = static_cast<double>(x_frame_n - 1);
      const double u0 = (mn - x_frame_lo) * inv_h[0] - slack[0];
      const double u1 = (mx - x_frame_lo) * inv_h[0] + slack[0];
      const int64_t f0 = static_cast<int64_t>(std::min(std::max(u0, 0.0), top)) - x_first;
      const int64_t f1 = static_cast<int64_t>(std::min(std::max(u1, 0.0), top)) - x_first;
      *c0 = std::min(std::max<int64_t>(f0, 0), n[0] - 1);
      *c1 = std::min(std::max<int64_t>(f1, 0), n[0] - 1);
      return true;
    }
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

  // Allocates and fills the plane tables (n[a] + 1 entries per axis).
  void build_planes() {
    for (int a = 1; a < dim; ++a) {  // x planes are computed when asked (see plane)
      planes[a].resize(n[a] + 1);
      for (int64_t i = 0; i <= n[a]; ++i) planes[a][i] = frame_plane(a, i);
    }
  }

  // Plane i of this grid: lo + i * h, the last one exactly hi; along x, the frame's.
  double frame_plane(int a, int64_t i) const {
    if (a != 0) return i == n[a] ? hi[a] : lo[a] + static_cast<double>(i) * h[a];
    const int64_t k = x_first + i;
    return k == x_frame_n ? x_frame_hi : x_frame_lo + static_cast<double>(k) * h[0];
  }
};

// Checks the grid attributes of a `dim`-dimensional grid (z ignored in 2D) and
// fills in g's scalars. Allocates nothing.
//
// x_first, x_count: the window along x, cells [x_first, x_first + x_count) of the nx
// cells from x0 to x1 (x_count = 0: all of them).
inline ffi::Error check_grid(int dim, double x0, double x1, int64_t nx, double y0, double y1,
                             int64_t ny, double z0, double z1, int64_t nz, int64_t x_first,
                             int64_t x_count, GridSpec* g) {
  g->dim = dim;
  const double lo[3] = {x0, y0, z0}, hi[3] = {x1, y1, z1};
  const int64_t n[3] = {nx, ny, nz};
  for (int a = 0; a < dim; ++a) {
    if (n[a] < 1 || n[a] > kMaxCellsPerAxis)
      return ffi::Error::InvalidArgument(
          "voxax: grid shape must be in [1, 2^31] on every axis, got " + std::to_string(n[a]) +
          " cells along axis " + std::to_string(a));
    if (!std::isfinite(lo[a]) || !std::isfinite(hi[a]) || !(hi[a] > lo[a]))
      return ffi::Error::InvalidArgument("voxax: grid corners must be finite with upper > lower");
    g->lo[a] = lo[a];
    g->hi[a] = hi[a];
    g->n[a] = n[a];
    g->h[a] = (hi[a] - lo[a]) / static_cast<double>(n[a]);
    g->inv_h[a] = 1.0 / g->h[a];
    g->slack[a] = 1e-12 * (1.0 + (std::fabs(lo[a]) + std::fabs(hi[a])) * g->inv_h[a]);
    if (!(g->h[a] > 0) || !std::isfinite(g->h[a]) || !std::isfinite(g->inv_h[a]))
      return ffi::Error::InvalidArgument("voxax: grid cell size is not a positive finite number");
  }
  if (x_first < 0 || x_count < 0 || x_first > nx || x_count > nx - x_first ||
      (x_count == 0 && x_first != 0))
    return ffi::Error::InvalidArgument(
        "voxax: a grid window of " + std::to_string(x_count) + " cells from cell " +
        std::to_string(x_first) + " does not fit the " + std::to_string(nx) + " cells along x");
  g->x_first = x_first;
  g->x_frame_n = nx;
  g->x_frame_lo = x0;
  g->x_frame_hi = x1;
  if (x_count > 0) {
    g->n[0] = x_count;
    g->lo[0] = g->frame_plane(0, 0);
    g->hi[0] = g->frame_plane(0, x_count);
  }
  const double vol = g->cell_volume();
  if (!(vol >= kMinCellVolume) || !(vol <= kMaxCellVolume))
    return ffi::Error::InvalidArgument("voxax: grid cell volume must lie in [1e-300, 1e300]");
  return ffi::Error::Success();
}

// Adds the grid attributes x0, x1, nx, y0, y1, ny, z0, z1, nz, x_first, x_count (in this order)
// to a handler binding; the handler takes them in the same order.
template <typename Binding>
auto with_grid_attributes(Binding binding) {
  return std::move(binding)
      .template Attr<double>("x0")
      .template Attr<double>("x1")
      .template Attr<int64_t>("nx")
      .template Attr<double>("y0")
      .template Attr<double>("y1")
      .template Attr<int64_t>("ny")
      .template Attr<double>("z0")
      .template Attr<double>("z1")
      .template Attr<int64_t>("nz")
      .template Attr<int64_t>("x_first")
      .template Attr<int64_t>("x_count");
}

}  // namespace voxax

// The signed crossing counts of the winding numbers' rays, which all run along one fixed
// direction d: a tree over the triangles projected along d (class ColumnTree).
//
// make_ray's shear maps every ray along d onto a line x = X, y = Y in the sheared frame
// (X = x_kx - s_x x_kz, Y = x_ky - s_y x_kz, the depth Z = s_z x_kz, so that a point of a
// triangle at depth Z lies at t = Z - Z(p) along the ray from p), so a ray is a point query
// in 2D: the triangles it can cross are those whose projected box holds (X, Y) of p and
// whose largest depth is not behind p. Those candidates take ray_crossing (the watertight
// test of bvh_triangle.h, with its exact edge rules and its unclear cases), unchanged; the
// others are skipped where the query point lies outside their projected box (or behind
// their depth) by more than `margin` (1 + |s|) (twice that, far above the rounding of the
// projections): such a triangle is more than `margin` away from p in every coordinate of
// some axis, so ray_crossing would find a clear miss or a hit at t < -margin, or it would
// call p unclear only because p lies within `margin` of the triangle's box and plane, while
// it is more than `margin` away from the triangle itself (which the solid-angle sums near
// it do not need: they are smooth there). The build sorts the triangles by the Morton code
// of their projected centres and groups them four at a time into the leaves of an implicit
// balanced binary tree (a level's node j has the next level's nodes 2 j and 2 j + 1 as
// children); the tree does not depend on the points, and a point's sum on nothing but the
// point, so the counts are the same for any thread count.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "spatial/bvh_triangle.h"

namespace voxax {
namespace spatial {

class ColumnTree {
 public:
  static constexpr int32_t kLeaf = 4;

  // Triangles F (nf, 3) of vertices V, rays along d (no component zero); V and F validated
  // by the caller.
  void build(const double* V, const int32_t* F, int64_t nf, const double* d) {
    const double o[3] = {0, 0, 0};
    proto_ = make_ray(o, d, 0.0, std::numeric_limits<double>::infinity());
    const int kx = proto_.kx, ky = proto_.ky, kz = proto_.kz;
    const double sx = proto_.sx, sy = proto_.sy, sz = proto_.sz;
    const int64_t n = nf;
    levels_.clear();
    tris_.assign(9 * n, 0.0);
    extent_ = 0.0;
    if (n == 0) return;
    std::vector<Box> boxes(n);
    double clo[2] = {std::numeric_limits<double>::infinity(),
                     std::numeric_limits<double>::infinity()};
    double chi[2] = {-clo[0], -clo[1]};
    for (int64_t f = 0; f < n; ++f) {
      Box& b = boxes[f];
      for (int k = 0; k < 3; ++k) {
        const double* x = V + 3 * static_cast<int64_t>(F[3 * f + k]);
        const double X = x[kx] - sx * x[kz], Y = x[ky] - sy * x[kz], Z = sz * x[kz];
        b.lo[0] = std::min(b.lo[0], X);
        b.hi[0] = std::max(b.hi[0], X);
        b.lo[1] = std::min(b.lo[1], Y);
        b.hi[1] = std::max(b.hi[1], Y);
        b.zmax = std::max(b.zmax, Z);
        extent_ = std::max(extent_,
                           std::max(std::fabs(x[0]), std::max(std::fabs(x[1]), std::fabs(x[2]))));
      }
      for (int a = 0; a < 2; ++a) {
        const double c = 0.5 * b.lo[a] + 0.5 * b.hi[a];
        clo[a] = std::min(clo[a], c);
        chi[a] = std::max(chi[a], c);
      }
    }
    // Morton codes of the centres on a 2^16 x 2^16 grid over their box, ties by index
    std::vector<uint64_t> keys(n);
    double scale[2];
    for (int a = 0; a < 2; ++a) {
      const double w = chi[a] - clo[a];
      scale[a] = w > 0.0 && std::isfinite(65535.0 / w) ? 65535.0 / w : 0.0;
    }
    for (int64_t f = 0; f < n; ++f) {
      uint32_t q[2];
      for (int a = 0; a < 2; ++a) {
        const double c = 0.5 * boxes[f].lo[a] + 0.5 * boxes[f].hi[a];
        const double u = std::min(65535.0, std::max(0.0, (c - clo[a]) * scale[a]));
        q[a] = static_cast<uint32_t>(u);
      }
      keys[f] =
          static_cast<uint64_t>(spread(q[0]) | spread(q[1]) << 1) << 32 | static_cast<uint64_t>(f);
    }
    std::sort(keys.begin(), keys.end());
    // the leaves and the triangles in tree order
    std::vector<Box> level((n + kLeaf - 1) / kLeaf);
    for (int64_t i = 0; i < n; ++i) {
      const int64_t f = static_cast<int64_t>(keys[i] & 0xffffffffu);
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a)
          tris_[9 * i + 3 * k + a] = V[3 * static_cast<int64_t>(F[3 * f + k]) + a];
      level[i / kLeaf].grow(boxes[f]);
    }
    levels_.push_back(std::move(level));
    while (levels_.back().size() > 1) {
      const std::vector<Box>& below = levels_.back();
      std::vector<Box> up((below.size() + 1) / 2);
      for (size_t j = 0; j < below.size(); ++j) up[j / 2].grow(below[j]);
      levels_.push_back(std::move(up));
    }
    nt_ = n;
  }

  // The largest |coordinate| of the triangles' corners (0 for none).
  double extent() const { return extent_; }

  // The sum of ray_crossing over the triangles for the ray from p along d with tmin =
  // -margin (margin > 0), skipping those that cannot matter (see above); false (and *sum
  // left) where a crossing is unclear.
  bool crossings(const double* p, double margin, int64_t* sum) const {
    *sum = 0;
    if (levels_.empty()) return true;
    Ray ray = proto_;  // make_ray(p, d, -margin, inf): the shear depends on d alone
    for (int a = 0; a < 3; ++a) ray.org[a] = p[a];
    ray.tmin = -margin;
    const int kx = ray.kx, ky = ray.ky, kz = ray.kz;
    const double px = p[kx] - ray.sx * p[kz], py = p[ky] - ray.sy * p[kz];
    const double m2 = 2.0 * margin * (1.0 + std::fabs(ray.sx) + std::fabs(ray.sy));
    const double zmin = ray.sz * p[kz] - 2.0 * margin * (1.0 + std::fabs(ray.sz));
    const double xlo = px - m2, xhi = px + m2, ylo = py - m2, yhi = py + m2;
    auto meets = [&](const Box& b) {
      return b.lo[0] <= xhi && b.hi[0] >= xlo && b.lo[1] <= yhi && b.hi[1] >= ylo && b.zmax >= zmin;
    };
    const int top = static_cast<int>(levels_.size()) - 1;
    if (!meets(levels_[top][0])) return true;
    int64_t s = 0;
    struct Entry {
      int32_t level;
      int64_t index;
    };
    Entry stack[2 * 64];
    int sp = 0;
    stack[sp++] = {top, 0};
    while (sp > 0) {
      const Entry e = stack[--sp];
      if (e.level == 0) {
        const int64_t b = e.index * kLeaf, end = std::min(nt_, b + kLeaf);
        for (int64_t i = b; i < end; ++i) {
          const int c = ray_crossing(ray, &tris_[9 * i], margin);
          if (c == kUnclear) return false;
          s += c;
        }
        continue;
      }
      const std::vector<Box>& below = levels_[e.level - 1];
      const int64_t c0 = 2 * e.index, c1 = c0 + 1;
      if (c1 < static_cast<int64_t>(below.size()) && meets(below[c1]))
        stack[sp++] = {e.level - 1, c1};
      if (meets(below[c0])) stack[sp++] = {e.level - 1, c0};
    }
    *sum = s;
    return true;
  }

 private:
  // A projected box: [lo, hi] in X and Y, the largest depth Z.
  struct Box {
    double lo[2] = {std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity()};
    double hi[2] = {-std::numeric_limits<double>::infinity(),
                    -std::numeric_limits<double>::infinity()};
    double zmax = -std::numeric_limits<double>::infinity();
    void grow(const Box& b) {
      for (int a = 0; a < 2; ++a) {
        lo[a] = std::min(lo[a], b.lo[a]);
        hi[a] = std::max(hi[a], b.hi[a]);
      }
      zmax = std::max(zmax, b.zmax);
    }
  };
  // The bits of a 16-bit number spread to the even bits of a 32-bit one.
  static uint32_t spread(uint32_t x) {
    x &= 0xffffu;
    x = (x | x << 8) & 0x00ff00ffu;
    x = (x | x << 4) & 0x0f0f0f0fu;
    x = (x | x << 2) & 0x33333333u;
    x = (x | x << 1) & 0x55555555u;
    return x;
  }
  Ray proto_{};
  std::vector<std::vector<Box>> levels_;  // levels_[0]: the leaves; the last: the root
  std::vector<double> tris_;              // the corners in tree order, 9 per triangle
  int64_t nt_ = 0;
  double extent_ = 0.0;
};

}  // namespace spatial
}  // namespace voxax

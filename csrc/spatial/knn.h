// Exact k nearest neighbours in 3D with a uniform grid (counting-sorted cells), and a
// kd-tree for queries far from the data.
//
// The data points are binned into a grid sized for about two points per occupied
// cell (or another count: the kNN entry points ask for four when k > 3, so that the
// 3 x 3 x 3 block around a query more often holds its k nearest): first for points filling their
// bounding box, then refined while most cells are empty (points on a surface or a curve leave most
// of a volume grid empty, and large cells would make every query scan many points). A query first
// scans the 3 x 3 x 3 block of cells around its own as nine contiguous runs of points (the cells
// are stored in x-y-z order, so three cells along z are one run), then visits further Chebyshev
// rings while needed. It keeps the k best candidates ordered by (squared distance, index); it stops
// once the k-th candidate is strictly closer than the nearest point of space outside the rings
// searched (a conservative bound), so the result is the exact k smallest (distance, index) pairs,
// deterministic and independent of threads. Missing neighbours (k > N) are index
// -1 at distance +inf.
//
// Rings grow over empty cells one at a time, so a query far from the data (points on a
// surface, queries in the volume around it or outside the box) would visit many cells.
// With `far_index`, a query whose 3 x 3 x 3 block holds no point, that is not settled
// after kGridRings rings, or that lies beyond the box by more than a cell, is answered by
// a kd-tree instead (knn_tree.h, built on first need). Both searches return the same
// exact k smallest pairs, with the squared distances computed alike, so which one answers
// a query changes no bit of the result.
#pragma once

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <mutex>
#include <vector>

#include "spatial/knn_tree.h"

namespace voxax {
namespace spatial {

// The grid's points per cell for k neighbours in the kNN entry points (measured on 20k
// points on a surface: the same speed as two for k <= 3, faster for larger k).
inline double knn_points_per_cell(int64_t k) { return k > 3 ? 4.0 : 2.0; }

class PointGrid {
 public:
  // With `far_index`, the rings searched on the grid before a query goes to the kd-tree.
  static constexpr int64_t kGridRings = 3;

  // Bins the n points S (n, 3) (not while queries run) in cells for about `per_cell`
  // points each (where occupied); with `far_index`, queries far from the data use a
  // kd-tree (built by the first of them).
  void build(const double* S, int64_t n, bool far_index = false, double per_cell = 2.0) {
    pts_.assign(S, S + 3 * n);
    n_ = n;
    far_index_ = far_index;
    tree_built_.store(false);
    if (n == 0) return;
    for (int a = 0; a < 3; ++a) {
      lo_[a] = hi_[a] = S[a];
    }
    for (int64_t i = 1; i < n; ++i)
      for (int a = 0; a < 3; ++a) {
        lo_[a] = std::min(lo_[a], S[3 * i + a]);
        hi_[a] = std::max(hi_[a], S[3 * i + a]);
      }
    double ext[3], maxext = 0.0;
    for (int a = 0; a < 3; ++a) {
      ext[a] = hi_[a] - lo_[a];
      maxext = std::max(maxext, ext[a]);
    }
    if (!(maxext > 0.0)) maxext = 1.0;
    // Cell size for about per_cell points per cell over the box (flat boxes use the area).
    double h = maxext;
    {
      double vol = 1.0;
      int dims = 0;
      for (int a = 0; a < 3; ++a)
        if (ext[a] > 1e-12 * maxext) {
          vol *= ext[a];
          ++dims;
        }
      if (dims > 0) h = std::pow(per_cell * vol / static_cast<double>(n), 1.0 / dims);
      h = std::max(h, maxext / 1024.0);
    }
    // Bounded memory for any point distribution: at most this many cells.
    const int64_t cap = 16 * n + 4096;
    int64_t total = set_cells(ext, h);
    for (int attempt = 0; attempt < 200 && total > cap; ++attempt)
      total = set_cells(ext, h *= 1.25);
    // Refine while the occupied cells hold many more than per_cell points each (points on a
    // lower-dimensional set): the cell count then grows about like 1/h^2.
    std::vector<int64_t> cell(n);
    for (int refine = 0; refine < 6; ++refine) {
      std::vector<uint8_t> seen(static_cast<size_t>(total), 0);
      int64_t occupied = 0;
      for (int64_t i = 0; i < n; ++i) {
        const int64_t c = cell_of(S + 3 * i);
        occupied += seen[c] == 0;
        seen[c] = 1;
      }
      const double per = static_cast<double>(n) / static_cast<double>(occupied);
      if (per <= 1.5 * per_cell) break;
      const double hn = h * std::sqrt(per_cell / per);
      if (!(hn < h) || hn < maxext / 1024.0) break;
      double save[3] = {h_[0], h_[1], h_[2]};
      int64_t dsave[3] = {dim_[0], dim_[1], dim_[2]};
      const int64_t tn = set_cells(ext, hn);
      if (tn > cap) {  // keep the last size within the bound
        for (int a = 0; a < 3; ++a) {
          h_[a] = save[a];
          inv_h_[a] = 1.0 / h_[a];
          dim_[a] = dsave[a];
        }
        break;
      }
      h = hn;
      total = tn;
    }
    {
      const double side = static_cast<double>(kGridRings) * std::min(h_[0], std::min(h_[1], h_[2]));
      far_d2_ = side * side;
    }
    start_.assign(total + 1, 0);
    for (int64_t i = 0; i < n; ++i) {
      cell[i] = cell_of(S + 3 * i);
      start_[cell[i] + 1]++;
    }
    for (int64_t c = 0; c < total; ++c) start_[c + 1] += start_[c];
    order_.resize(n);
    std::vector<int64_t> fill(start_.begin(), start_.end() - 1);
    for (int64_t i = 0; i < n; ++i) order_[fill[cell[i]]++] = static_cast<int32_t>(i);
    // Coordinates in cell order, so that a cell's points are contiguous in memory.
    for (int64_t s = 0; s < n; ++s)
      for (int a = 0; a < 3; ++a) pts_[3 * s + a] = S[3 * static_cast<int64_t>(order_[s]) + a];
  }

  // The k nearest data points to q (k <= kMaxNeighbours), by (distance, index).
  void query(const double* q, int k, int32_t* idx, double* dist) const {
    switch (k) {  // the common k at compile time; the same pairs either way
      case 1:
        return query_k<1>(q, k, idx, dist);
      case 2:
        return query_k<2>(q, k, idx, dist);
      case 3:
        return query_k<3>(q, k, idx, dist);
      case 4:
        return query_k<4>(q, k, idx, dist);
      case 8:
        return query_k<8>(q, k, idx, dist);
      default:
        return query_k<0>(q, k, idx, dist);
    }
  }

  // Calls f(index, squared distance) for every data point within distance sqrt(r2) of q
  // (squared distance computed as in `query`, so the two agree bit for bit), in cell
  // order, until f returns false.
  template <typename F>
  void within(const double* q, double r2, F&& f) const {
    if (n_ == 0 || !(r2 >= 0.0)) return;
    // a slightly grown box: q +- r is rounded, the cells' binning is monotone
    const double r = std::sqrt(r2) * (1.0 + 1e-9) + 1e-300;
    int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      double p[3] = {q[0], q[1], q[2]};
      p[a] = q[a] - r;
      lo[a] = coord(p, a);
      p[a] = q[a] + r;
      hi[a] = coord(p, a);
    }
    for (int64_t i = lo[0]; i <= hi[0]; ++i)
      for (int64_t j = lo[1]; j <= hi[1]; ++j) {
        const int64_t row = (i * dim_[1] + j) * dim_[2];
        for (int64_t s = start_[row + lo[2]]; s < start_[row + hi[2] + 1]; ++s) {
          const double d2 = point_d2(&pts_[3 * static_cast<size_t>(s)], q);
          if (d2 <= r2 && !f(order_[s], d2)) return;
        }
      }
  }

 private:
  template <int K>
  void query_k(const double* q, int k, int32_t* idx, double* dist) const {
    NearestK<K> best(k);
    if (n_ > 0 && (beyond(q) || !grid_search(q, best))) {
      best = NearestK<K>(k);
      tree().search(q, best);
    }
    for (int j = 0; j < k; ++j) {
      idx[j] = best.idx[j];
      dist[j] = std::sqrt(best.d2[j]);
    }
  }

  // The grid search of `query` (n_ > 0): false (with `far_index`) when the query should go
  // to the kd-tree instead.
  template <class Best>
  bool grid_search(const double* q, Best& best) const {
    const int k = best.size();
    int64_t c[3];
    for (int a = 0; a < 3; ++a) c[a] = coord(q, a);
    const int64_t rmax = std::max(dim_[0], std::max(dim_[1], dim_[2]));
    // Rounding allowance of the cell boxes (binning rounds differently).
    const double tol = 1e-9 * (std::max(h_[0], std::max(h_[1], h_[2])) + std::fabs(q[0]) +
                               std::fabs(q[1]) + std::fabs(q[2]));
    // Offers the points in cell-order positions [b, e) to the candidate list. A block of
    // points is first filtered against the k-th candidate as it stands before the block,
    // without branches (the list only improves, so no point that could enter is left
    // out); the points kept are then offered in order.
    auto scan = [&](int64_t b, int64_t e) {
      constexpr int64_t kBlock = 16;
      double kept_d2[kBlock];
      int64_t kept[kBlock];
      for (int64_t s0 = b; s0 < e; s0 += kBlock) {
        const int64_t len = std::min(kBlock, e - s0);
        const double before = best.d2[k - 1];  // +inf while the list is not full
        int64_t n = 0;
        for (int64_t t = 0; t < len; ++t) {
          const double d2 = point_d2(&pts_[3 * static_cast<size_t>(s0 + t)], q);
          kept_d2[n] = d2;
          kept[n] = s0 + t;
          n += d2 <= before;
        }
        for (int64_t t = 0; t < n; ++t) {
          if (kept_d2[t] > best.d2[k - 1]) continue;
          best.offer(kept_d2[t], order_[kept[t]]);
        }
      }
    };
    // Squared distance from q to the (slightly grown) box of cells [lo, hi] (inclusive).
    auto box_d2 = [&](const int64_t* lo, const int64_t* hi) {
      double d2 = 0.0;
      for (int a = 0; a < 3; ++a) {
        const double l = lo_[a] + static_cast<double>(lo[a]) * h_[a] - tol;
        const double u = lo_[a] + static_cast<double>(hi[a] + 1) * h_[a] + tol;
        const double e = q[a] < l ? l - q[a] : (q[a] > u ? q[a] - u : 0.0);
        d2 += e * e;
      }
      return d2;
    };
    // Rings 0 and 1: nine runs of up to three cells along z, nearest rows first. A
    // row's box distance is a sum of per-axis terms: along x and y to the (grown)
    // cells c - 1, c, c + 1, along z to the run of cells k0..k1.
    {
      const int64_t k0 = std::max<int64_t>(0, c[2] - 1), k1 = std::min(dim_[2] - 1, c[2] + 1);
      auto axis_d2 = [&](int a, int64_t from, int64_t to) {
        const double l = lo_[a] + static_cast<double>(from) * h_[a] - tol;
        const double u = lo_[a] + static_cast<double>(to + 1) * h_[a] + tol;
        const double e = q[a] < l ? l - q[a] : (q[a] > u ? q[a] - u : 0.0);
        return e * e;
      };
      double ax[2][3];
      for (int a = 0; a < 2; ++a)
        for (int o = 0; o < 3; ++o) ax[a][o] = axis_d2(a, c[a] + o - 1, c[a] + o - 1);
      const double az = axis_d2(2, k0, k1);
      static constexpr int kOrder[9][2] = {{0, 0},   {-1, 0}, {1, 0},  {0, -1}, {0, 1},
                                           {-1, -1}, {-1, 1}, {1, -1}, {1, 1}};
      for (const auto& o : kOrder) {
        const int64_t i = c[0] + o[0], j = c[1] + o[1];
        if (i < 0 || i >= dim_[0] || j < 0 || j >= dim_[1]) continue;
        if (ax[0][o[0] + 1] + ax[1][o[1] + 1] + az > best.d2[k - 1]) continue;
        const int64_t row = (i * dim_[1] + j) * dim_[2];
        scan(start_[row + k0], start_[row + k1 + 1]);
      }
    }
    // No point in the 3 x 3 x 3 block, or the k-th farther than kGridRings cells: a query
    // far from the data, which rings would reach slowly.
    if (far_index_ && (best.have == 0 || (best.full() && best.d2[k - 1] > far_d2_))) return false;
    for (int64_t r = 1; r <= rmax; ++r) {
      if (far_index_ && r > kGridRings) return false;
      if (r >= 2) {
        for (int64_t i = c[0] - r; i <= c[0] + r; ++i) {
          if (i < 0 || i >= dim_[0]) continue;
          const bool ei = i == c[0] - r || i == c[0] + r;
          for (int64_t j = c[1] - r; j <= c[1] + r; ++j) {
            if (j < 0 || j >= dim_[1]) continue;
            const bool ej = ei || j == c[1] - r || j == c[1] + r;
            // Only the ring's shell: the k range is all of it on the faces, else its two ends.
            for (int64_t kk = c[2] - r; kk <= c[2] + r; kk += ej ? 1 : 2 * r) {
              if (kk < 0 || kk >= dim_[2]) continue;
              const int64_t cell = (i * dim_[1] + j) * dim_[2] + kk;
              if (start_[cell] == start_[cell + 1]) continue;
              if (best.full()) {
                // Skip cells whose (slightly grown) box is beyond the k-th candidate.
                const int64_t cc[3] = {i, j, kk};
                if (box_d2(cc, cc) > best.d2[k - 1]) continue;
              }
              scan(start_[cell], start_[cell + 1]);
            }
          }
        }
      }
      if (best.full()) {
        // Distance from q to the space outside the searched block of cells (sides
        // at the grid's boundary have no points beyond them).
        double gap = std::numeric_limits<double>::infinity();
        bool covers = true;
        for (int a = 0; a < 3; ++a) {
          if (c[a] - r > 0) {
            covers = false;
            gap = std::min(gap, q[a] - (lo_[a] + static_cast<double>(c[a] - r) * h_[a]));
          }
          if (c[a] + r < dim_[a] - 1) {
            covers = false;
            gap = std::min(gap, (lo_[a] + static_cast<double>(c[a] + r + 1) * h_[a]) - q[a]);
          }
        }
        if (covers) break;
        // Conservative: binning and this bound round differently.
        gap -= tol;
        if (gap > 0.0 && best.d2[k - 1] < gap * gap) break;
      }
    }
    return true;
  }

  std::vector<double> pts_;
  std::vector<int64_t> start_;
  std::vector<int32_t> order_;
  int64_t n_ = 0;
  double lo_[3] = {0, 0, 0}, hi_[3] = {0, 0, 0}, h_[3] = {1, 1, 1};
  double inv_h_[3] = {1, 1, 1};  // 1 / h_: binning multiplies (monotone, as dividing is)
  int64_t dim_[3] = {1, 1, 1};
  bool far_index_ = false;
  double far_d2_ = 0.0;  // (kGridRings times the smallest cell side)^2
  mutable std::mutex tree_mutex_;
  mutable std::atomic<bool> tree_built_{false};
  mutable PointTree tree_;

  // The kd-tree of the points, built by its first caller (queries run on many threads).
  const PointTree& tree() const {
    if (!tree_built_.load(std::memory_order_acquire)) {
      std::lock_guard<std::mutex> lock(tree_mutex_);
      if (!tree_built_.load(std::memory_order_relaxed)) {
        tree_.build(pts_.data(), order_.data(), n_);
        tree_built_.store(true, std::memory_order_release);
      }
    }
    return tree_;
  }
  // With `far_index`: a query beyond the box of cells by more than a cell along an axis.
  bool beyond(const double* q) const {
    if (!far_index_) return false;
    for (int a = 0; a < 3; ++a) {
      const double u = (q[a] - lo_[a]) * inv_h_[a];
      if (!(u >= -1.0) || !(u < static_cast<double>(dim_[a] + 1))) return true;
    }
    return false;
  }
  // Cells of side about h over the extents (at most 1024 along an axis); returns their count.
  int64_t set_cells(const double* ext, double h) {
    int64_t total = 1;
    for (int a = 0; a < 3; ++a) {
      dim_[a] = std::max<int64_t>(
          1, std::min<int64_t>(1024, static_cast<int64_t>(std::ceil(ext[a] / h))));
      h_[a] = ext[a] > 0.0 ? ext[a] / static_cast<double>(dim_[a]) : 1.0;
      inv_h_[a] = 1.0 / h_[a];
      total *= dim_[a];
    }
    return total;
  }
  int64_t coord(const double* p, int a) const {
    const double u = (p[a] - lo_[a]) * inv_h_[a];
    if (!(u > 0.0)) return 0;
    const double top = static_cast<double>(dim_[a] - 1);
    return static_cast<int64_t>(std::min(std::floor(u), top));
  }
  int64_t cell_of(const double* p) const {
    return (coord(p, 0) * dim_[1] + coord(p, 1)) * dim_[2] + coord(p, 2);
  }
};

// The order in which to answer m queries Q (m, 3) (finite): by buckets of a coarse grid
// over their box (x-major, about two queries per bucket, at most 64 per axis), by index
// within a bucket. Consecutive queries then touch the same cells and tree nodes; the
// answers do not depend on the order.
inline std::vector<int64_t> query_order(const double* Q, int64_t m) {
  std::vector<int64_t> order(static_cast<size_t>(m));
  if (m == 0) return order;
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = Q[a];
  for (int64_t i = 1; i < m; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], Q[3 * i + a]);
      hi[a] = std::max(hi[a], Q[3 * i + a]);
    }
  const int64_t b = std::max<int64_t>(
      1, std::min<int64_t>(64, static_cast<int64_t>(std::cbrt(static_cast<double>(m) / 2.0))));
  double scale[3];
  for (int a = 0; a < 3; ++a) {
    const double ext = hi[a] - lo[a];
    scale[a] = ext > 0.0 && std::isfinite(ext) ? static_cast<double>(b) / ext : 0.0;
  }
  auto key = [&](int64_t i) {
    int64_t c[3];
    for (int a = 0; a < 3; ++a) {
      const double u = (Q[3 * i + a] - lo[a]) * scale[a];
      c[a] = u > 0.0 ? std::min<int64_t>(b - 1, static_cast<int64_t>(u)) : 0;
    }
    return (c[0] * b + c[1]) * b + c[2];
  };
  std::vector<int64_t> start(static_cast<size_t>(b * b * b + 1), 0);
  for (int64_t i = 0; i < m; ++i) start[key(i) + 1]++;
  for (size_t c = 1; c < start.size(); ++c) start[c] += start[c - 1];
  for (int64_t i = 0; i < m; ++i) order[start[key(i)]++] = i;
  return order;
}

// Answers the queries order[b], ..., order[e - 1] of Q (m, 3) (k neighbours each, into
// idx and dist (m, k)). The order is spatially coherent but scattered in memory: each
// block of queries is first gathered into a local array (independent loads, which the
// processor overlaps), so that the searches do not wait on a cache miss for every query.
inline void query_run(const PointGrid& grid, const double* Q, const int64_t* order, int64_t b,
                      int64_t e, int k, int32_t* idx, double* dist) {
  constexpr int64_t kBlock = 64;
  double q[3 * kBlock];
  for (int64_t s0 = b; s0 < e; s0 += kBlock) {
    const int64_t len = std::min(kBlock, e - s0);
    for (int64_t t = 0; t < len; ++t)
      for (int a = 0; a < 3; ++a) q[3 * t + a] = Q[3 * order[s0 + t] + a];
    for (int64_t t = 0; t < len; ++t) {
      const int64_t i = order[s0 + t];
      grid.query(q + 3 * t, k, idx + int64_t{k} * i, dist + int64_t{k} * i);
    }
  }
}

}  // namespace spatial
}  // namespace voxax

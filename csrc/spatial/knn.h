// Exact k nearest neighbours in 3D with a uniform grid (counting-sorted cells).
//
// The data points are binned into a grid of about two points per cell over their
// bounding box. A query visits the cells in growing Chebyshev rings around its
// cell and keeps the k best candidates ordered by (squared distance, index); it
// stops once the k-th candidate is strictly closer than the nearest point of
// space outside the rings searched (a conservative bound), so the result is the
// exact k smallest (distance, index) pairs, deterministic and independent of
// threads. Missing neighbours (k > N) are index -1 at distance +inf.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace voxax {
namespace spatial {

constexpr int kMaxNeighbours = 32;

class PointGrid {
 public:
  void build(const double* S, int64_t n) {
    pts_.assign(S, S + 3 * n);
    n_ = n;
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
    // Cell size for about two points per cell over the box (flat boxes use the area).
    double h = maxext;
    {
      double vol = 1.0;
      int dims = 0;
      for (int a = 0; a < 3; ++a)
        if (ext[a] > 1e-12 * maxext) {
          vol *= ext[a];
          ++dims;
        }
      if (dims > 0) h = std::pow(2.0 * vol / static_cast<double>(n), 1.0 / dims);
      h = std::max(h, maxext / 1024.0);
    }
    int64_t total = 1;
    for (int attempt = 0; attempt < 200; ++attempt) {
      total = 1;
      for (int a = 0; a < 3; ++a) {
        dim_[a] = std::max<int64_t>(
            1, std::min<int64_t>(1024, static_cast<int64_t>(std::ceil(ext[a] / h))));
        h_[a] = ext[a] > 0.0 ? ext[a] / static_cast<double>(dim_[a]) : 1.0;
        total *= dim_[a];
      }
      if (total <= 4 * n + 64) break;  // bounded memory for any point distribution
      h *= 1.25;
    }
    start_.assign(total + 1, 0);
    std::vector<int64_t> cell(n);
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
    double bd[kMaxNeighbours];
    int32_t bi[kMaxNeighbours];
    int have = 0;
    for (int j = 0; j < k; ++j) {
      bd[j] = std::numeric_limits<double>::infinity();
      bi[j] = -1;
    }
    if (n_ > 0) {
      int64_t c[3];
      for (int a = 0; a < 3; ++a) c[a] = coord(q, a);
      const int64_t rmax = std::max(dim_[0], std::max(dim_[1], dim_[2]));
      // Rounding allowance of the cell boxes (binning rounds differently).
      const double tol = 1e-9 * (std::max(h_[0], std::max(h_[1], h_[2])) + std::fabs(q[0]) +
                                 std::fabs(q[1]) + std::fabs(q[2]));
      for (int64_t r = 0; r <= rmax; ++r) {
        for (int64_t i = c[0] - r; i <= c[0] + r; ++i) {
          if (i < 0 || i >= dim_[0]) continue;
          const bool ei = i == c[0] - r || i == c[0] + r;
          for (int64_t j = c[1] - r; j <= c[1] + r; ++j) {
            if (j < 0 || j >= dim_[1]) continue;
            const bool ej = ei || j == c[1] - r || j == c[1] + r;
            // Only the ring's shell: the k range is all of it on the faces, else its two ends.
            for (int64_t kk = c[2] - r; kk <= c[2] + r; kk += (ej || r == 0) ? 1 : 2 * r) {
              if (kk < 0 || kk >= dim_[2]) continue;
              const int64_t cell = (i * dim_[1] + j) * dim_[2] + kk;
              if (start_[cell] == start_[cell + 1]) continue;
              if (have == k) {
                // Skip cells whose (slightly grown) box is beyond the k-th candidate.
                const int64_t cc[3] = {i, j, kk};
                double d2 = 0.0;
                for (int a = 0; a < 3; ++a) {
                  const double lo = lo_[a] + static_cast<double>(cc[a]) * h_[a] - tol;
                  const double hi = lo_[a] + static_cast<double>(cc[a] + 1) * h_[a] + tol;
                  const double e = q[a] < lo ? lo - q[a] : (q[a] > hi ? q[a] - hi : 0.0);
                  d2 += e * e;
                }
                if (d2 > bd[k - 1]) continue;
              }
              for (int64_t s = start_[cell]; s < start_[cell + 1]; ++s) {
                const int32_t p = order_[s];
                const double* x = &pts_[3 * static_cast<size_t>(s)];
                const double dx = x[0] - q[0], dy = x[1] - q[1], dz = x[2] - q[2];
                const double d2 = dx * dx + dy * dy + dz * dz;
                if (have == k && !(d2 < bd[k - 1] || (d2 == bd[k - 1] && p < bi[k - 1]))) continue;
                int pos = have < k ? have++ : k - 1;
                while (pos > 0 && (d2 < bd[pos - 1] || (d2 == bd[pos - 1] && p < bi[pos - 1]))) {
                  bd[pos] = bd[pos - 1];
                  bi[pos] = bi[pos - 1];
                  --pos;
                }
                bd[pos] = d2;
                bi[pos] = p;
              }
            }
          }
        }
        if (have == k) {
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
          if (gap > 0.0 && bd[k - 1] < gap * gap) break;
        }
      }
    }
    for (int j = 0; j < k; ++j) {
      idx[j] = bi[j];
      dist[j] = std::sqrt(bd[j]);
    }
  }

 private:
  std::vector<double> pts_;
  std::vector<int64_t> start_;
  std::vector<int32_t> order_;
  int64_t n_ = 0;
  double lo_[3] = {0, 0, 0}, hi_[3] = {0, 0, 0}, h_[3] = {1, 1, 1};
  int64_t dim_[3] = {1, 1, 1};

  int64_t coord(const double* p, int a) const {
    const double u = (p[a] - lo_[a]) / h_[a];
    if (!(u > 0.0)) return 0;
    const double top = static_cast<double>(dim_[a] - 1);
    return static_cast<int64_t>(std::min(std::floor(u), top));
  }
  int64_t cell_of(const double* p) const {
    return (coord(p, 0) * dim_[1] + coord(p, 1)) * dim_[2] + coord(p, 2);
  }
};

}  // namespace spatial
}  // namespace voxax

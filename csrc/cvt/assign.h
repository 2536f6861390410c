// Nearest-seed assignment of weighted samples with their regions' moments (one CVT step's
// worth of work), warm-started from a previous assignment.
//
// Every sample x gets the seed nearest to it, ties by the smaller index: exactly what
// spatial::PointGrid::query gives for k = 1, bit for bit. A hint (any seed index per sample,
// e.g. the assignment of the previous step) only makes it faster: if the hinted seed a is
// at distance d from x, a seed b at most as far from x satisfies |s_b - s_a| <= 2 d (the
// triangle inequality). So each hinted seed gets the list of seeds within 2 d_max(a) of it
// (d_max(a): its farthest hinted sample), sorted by distance, and a sample scans its hinted
// seed's list up to 2 d (a few seeds when the hint is close), instead of the grid's 3 x 3 x 3
// cells. Samples without a valid hint, and those of seeds whose list would be long (a poor
// hint), use the grid search. Then, in sample order on one thread (deterministic for any
// thread count), the regions' weight, weighted first moment, sample count (weight > 0) and
// the energy sum_j w_j |x_j - s_a(j)|^2.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "common/constants.h"
#include "common/host_errors.h"
#include "cvt/assign_checks.h"
#include "spatial/knn.h"

namespace voxax {
namespace cvt {

constexpr int64_t kAssignChunk = 2048;
constexpr int kAssignMaxList = 32;  // longer lists fall back to the grid search

// `parallel(chunks, body)` runs body(c) for c in [0, chunks) (any order, any threads).
// S (n, 3) seeds, X (m, 3) samples, W (m,) weights, hint (m,) seed indices (out-of-range:
// none). Outputs: idx (m,), moments (n, 4) = [weight, weighted x, y, z], count (n,),
// *energy. The seeds and the counts are checked first (check_assign); the samples' and
// weights' checks are folded into the passes that read them (one pass over the samples
// fewer): on bad samples or weights it returns false with the message a check of them
// first would give (the first bad row), and no nearest-seed search sees a bad sample.
template <typename Parallel>
bool assign_moments(const double* S, int64_t n, const double* X, const double* W, int64_t m,
                    const int32_t* hint, int32_t* idx, double* moments, int32_t* count,
                    double* energy, Parallel&& parallel, std::string* msg) {
  if (!check_assign(S, n, m, msg)) return false;
  spatial::PointGrid grid;
  grid.build(S, n);
  auto d2_of = [](const double* s, const double* q) {
    const double dx = s[0] - q[0], dy = s[1] - q[1], dz = s[2] - q[2];
    return dx * dx + dy * dy + dz * dz;
  };
  const int64_t chunks = (m + kAssignChunk - 1) / kAssignChunk;
  // 1. the squared distance to the hinted seed (-1: no valid hint), and whether the
  // chunk's samples are finite and within the coordinate bound (NaN fails the comparison)
  std::vector<double> d2(static_cast<size_t>(m));
  std::vector<char> bad_chunk(static_cast<size_t>(chunks), 0);
  parallel(chunks, [&](int64_t c) {
    bool ok = true;
    const int64_t end = std::min(m, (c + 1) * kAssignChunk);
    for (int64_t q = c * kAssignChunk; q < end; ++q) {
      const double* x = X + 3 * q;
      ok &= (std::fabs(x[0]) <= kMaxAbsCoordinate) & (std::fabs(x[1]) <= kMaxAbsCoordinate) &
            (std::fabs(x[2]) <= kMaxAbsCoordinate);
      const int64_t h = hint[q];
      d2[q] = (h >= 0 && h < n) ? d2_of(S + 3 * h, x) : -1.0;
    }
    bad_chunk[c] = !ok;
  });
  if (std::find(bad_chunk.begin(), bad_chunk.end(), 1) != bad_chunk.end()) {
    check_host_coordinates(X, 3 * m, "samples", msg);  // the first bad row's message
    return false;
  }
  // 2. each seed's farthest hinted sample (a max: order-independent)
  std::vector<double> far(static_cast<size_t>(n), -1.0);
  for (int64_t q = 0; q < m; ++q)
    if (d2[q] >= 0.0) far[hint[q]] = std::max(far[hint[q]], d2[q]);
  // 3. per hinted seed, the other seeds within 2 d_max, nearest first (len -1: grid search);
  // each chunk of seeds keeps its lists in its own arrays (memory as long as the lists)
  constexpr int64_t kSeedChunk = 256;
  const int64_t seed_chunks = (n + kSeedChunk - 1) / kSeedChunk;
  std::vector<std::vector<int32_t>> list(static_cast<size_t>(seed_chunks));
  std::vector<std::vector<double>> ldist(static_cast<size_t>(seed_chunks));
  std::vector<int32_t> len(static_cast<size_t>(n), -1);
  std::vector<int32_t> at(static_cast<size_t>(n), 0);  // a list's start in its chunk's arrays
  parallel(seed_chunks, [&](int64_t c) {
    std::vector<std::pair<double, int32_t>> found;
    std::vector<int32_t>& li = list[c];
    std::vector<double>& ld = ldist[c];
    for (int64_t a = c * kSeedChunk; a < std::min(n, (c + 1) * kSeedChunk); ++a) {
      if (far[a] < 0.0) continue;
      // 4 d_max^2, grown for the rounding of the distances compared
      const double r2 = 4.0 * far[a] * (1.0 + 1e-9) + 1e-300;
      found.clear();
      bool overflow = false;
      grid.within(S + 3 * a, r2, [&](int32_t b, double d2ab) {
        if (b == a) return true;
        if (static_cast<int>(found.size()) == kAssignMaxList) {
          overflow = true;
          return false;
        }
        found.emplace_back(std::sqrt(d2ab), b);
        return true;
      });
      if (overflow) continue;
      std::sort(found.begin(), found.end());
      at[a] = static_cast<int32_t>(li.size());
      for (const auto& e : found) {
        ld.push_back(e.first);
        li.push_back(e.second);
      }
      len[a] = static_cast<int32_t>(found.size());
    }
  });
  // 4. the nearest seed of every sample (the distance to the hinted seed recomputed, not
  // read back: one array fewer in memory traffic)
  parallel(chunks, [&](int64_t c) {
    for (int64_t q = c * kAssignChunk; q < std::min(m, (c + 1) * kAssignChunk); ++q) {
      const double* x = X + 3 * q;
      const int64_t h = d2[q] >= 0.0 ? hint[q] : -1;
      if (h < 0 || len[h] < 0) {
        int32_t i;
        double d;
        grid.query(x, 1, &i, &d);
        idx[q] = i;
        continue;
      }
      double best = d2[q];
      int32_t bi = static_cast<int32_t>(h);
      // seeds farther than 2 |x - s_h| from s_h are farther from x than s_h (grown for rounding)
      const double reach = 2.0 * std::sqrt(best) * (1.0 + 1e-9) + 1e-300;
      const int32_t* li = list[h / kSeedChunk].data() + at[h];
      const double* ld = ldist[h / kSeedChunk].data() + at[h];
      for (int k = 0; k < len[h] && ld[k] <= reach; ++k) {
        const int32_t b = li[k];
        const double e = d2_of(S + 3 * static_cast<int64_t>(b), x);
        if (e < best || (e == best && b < bi)) {
          best = e;
          bi = b;
        }
      }
      idx[q] = bi;
    }
  });
  // 5. moments, counts and energy in sample order (each squared distance recomputed from
  // the seed found: the same bits as the search's), and the weights' check
  std::fill(moments, moments + 4 * n, 0.0);
  std::fill(count, count + n, 0);
  double e = 0.0;
  bool weights_ok = true;
  for (int64_t q = 0; q < m; ++q) {
    const int64_t a = idx[q];
    const double w = W[q];
    const double* x = X + 3 * q;
    weights_ok &= (w >= 0.0) & (w <= std::numeric_limits<double>::max());
    double* mo = moments + 4 * a;
    mo[0] += w;
    mo[1] += w * x[0];
    mo[2] += w * x[1];
    mo[3] += w * x[2];
    count[a] += w > 0.0;
    e += w * d2_of(S + 3 * a, x);
  }
  *energy = e;
  if (!weights_ok) return check_assign_weights(W, m, msg);
  return true;
}

}  // namespace cvt
}  // namespace voxax

// The column test of ray casts along many directions, a plain C ABI for ctypes.
//
//   voxax_column_test(P (n, 3) f64, ks (n,) i64, n, K, params (K, 15) f64, G, lims (K, G*G) f64,
//                     threads, out (n,) u8, err, errlen)
//
// For every point i and its direction k = ks[i]: the point in direction k's frame is
// `loc = P[i] @ M - c0` (M the 3 x 3 matrix whose columns are the frame's axes u, v, d,
// row-major in params[k, 0:9]; c0 = params[k, 9:12]); its cell in a G x G grid of width
// h = params[k, 14] over [-R, R]^2 (R = params[k, 13]) is (floor((x + R) / h),
// floor((y + R) / h)); out[i] = 1 where the point lies over the grid and
// `s * z < lims[k, cell]` (s = params[k, 12], +1 or -1), else 0. A ray from a point with
// out = 0 certainly misses the surface whose column depth bounds are `lims` (the caller
// builds them conservatively). Points with NaN coordinates get 0 (they cannot be cast).
// The result of each point depends on that point alone: the same for any thread count.

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "spatial/host_pool.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {
constexpr int kParams = 15;
constexpr int64_t kChunk = 4096;
}  // namespace

VOXAX_EXPORT int voxax_column_test(const double* P, const int64_t* ks, int64_t n, int64_t K,
                                   const double* params, int64_t G, const double* lims,
                                   int32_t threads, uint8_t* out, char* err, int64_t errlen) {
  return voxax::host_guarded("the column test", err, errlen, [&](std::string* msg) {
    if (n < 0 || K < 1) {
      *msg = "voxax: the column test needs n >= 0 points and K >= 1 directions";
      return false;
    }
    if (G < 1 || G > (int64_t{1} << 14)) {
      *msg = "voxax: the column grid's resolution must lie in [1, 16384]";
      return false;
    }
    std::vector<char> used(static_cast<size_t>(K), 0);
    for (int64_t i = 0; i < n; ++i) {
      if (ks[i] < 0 || ks[i] >= K) {
        *msg = "voxax: the column test's direction index " + std::to_string(ks[i]) + " of point " +
               std::to_string(i) + " is outside [0, " + std::to_string(K) + ")";
        return false;
      }
      used[ks[i]] = 1;
    }
    // only the directions in use need a frame (the others' rows may be unset)
    for (int64_t k = 0; k < K; ++k) {
      if (!used[k]) continue;
      const double* q = params + kParams * k;
      for (int a = 0; a < kParams; ++a)
        if (!std::isfinite(q[a])) {
          *msg = "voxax: the column test's frame parameters must be finite (direction " +
                 std::to_string(k) + ")";
          return false;
        }
      if (!(q[14] > 0.0) || !(q[13] > 0.0)) {
        *msg = "voxax: the column test's cell width and radius must be > 0 (direction " +
               std::to_string(k) + ")";
        return false;
      }
    }
    const double g = static_cast<double>(G);
    voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        const double* q = params + kParams * ks[i];
        const double* p = P + 3 * i;
        double loc[3];
        for (int c = 0; c < 3; ++c)
          loc[c] = p[0] * q[c] + p[1] * q[3 + c] + p[2] * q[6 + c] - q[9 + c];
        const double fi = (loc[0] + q[13]) / q[14];
        const double fj = (loc[1] + q[13]) / q[14];
        // written so that NaN fails every comparison
        if (!(fi >= 0.0 && fi < g && fj >= 0.0 && fj < g)) {
          out[i] = 0;
          continue;
        }
        const int64_t cell = static_cast<int64_t>(fi) * G + static_cast<int64_t>(fj);
        out[i] = q[12] * loc[2] < lims[ks[i] * G * G + cell] ? 1 : 0;
      }
    });
    return true;
  });
}

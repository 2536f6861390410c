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

#include <algorithm>
#include <climits>
#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "common/host_pool.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {
constexpr int kParams = 15;
constexpr int64_t kChunk = 4096;

// The cell of point p in the G x G grid of frame q when it lies over the grid and
// `s * z < lims[cell]` (s = q[12]), else -1. Written so that NaN fails every comparison.
int64_t column_cell(const double* p, const double* q, int64_t G, const double* lims) {
  double loc[3];
  for (int c = 0; c < 3; ++c) loc[c] = p[0] * q[c] + p[1] * q[3 + c] + p[2] * q[6 + c] - q[9 + c];
  const double g = static_cast<double>(G);
  const double fi = (loc[0] + q[13]) / q[14];
  const double fj = (loc[1] + q[13]) / q[14];
  if (!(fi >= 0.0 && fi < g && fj >= 0.0 && fj < g)) return -1;
  const int64_t cell = static_cast<int64_t>(fi) * G + static_cast<int64_t>(fj);
  return q[12] * loc[2] < lims[cell] ? cell : -1;
}
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
    voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i)
        out[i] = column_cell(P + 3 * i, params + kParams * ks[i], G, lims + ks[i] * G * G) >= 0;
    });
    return true;
  });
}

// Exact ray casts of the selection through per-line lists of triangles per column.
//
//   voxax_column_lists(V (nv, 3) f64, nv, F (nf, 3) i64, nf, L, frames (L, 15) f64, G, delta,
//                      fill, counts_or_offsets (L*G*G [+1]) i64, entries (ne) i32, ne,
//                      lo (L*G*G) f64, hi (L*G*G) f64, threads, err, errlen)
//
// For each line l (its frame as in the column test; the sign is not used) every triangle is
// listed in each cell of the G x G grid that the (x, y) bounding box of its corners,
// widened by `delta`, meets. With fill = 0 the call writes each cell's count into
// counts[l * G * G + cell]; with fill = 1 it takes their exclusive prefix sums (offsets,
// L * G * G + 1 of them, offsets[L * G * G] = ne) and writes the triangles of each cell in
// order of decreasing top depth (ties: ascending index) into entries[offsets[c]:offsets[c +
// 1]], and the least and largest depth of the listed triangles' corners (-+ delta; +inf /
// -inf for an empty cell) into lo and hi.
//
//   voxax_column_hits(P (n, 3) f64, ks (n,) i64, n, K, params (K, 15) f64, dirs (K, 3) f64,
//                     line_of (K,) i64, L, G, lims (K, G*G) f64, offsets (L*G*G+1) i64,
//                     entries (ne) i32, ne, T (nf, 9) f64, nf, t_min,
//                     threads, out (n,) u8, err, errlen)
//
// Whether the ray P[i] + t dirs[k] (k = ks[i]), t > t_min, meets a triangle: bit 0 of
// out[i]. A point that fails the column test (see above) is a miss without a look at a
// triangle; the others (bit 1 set) test the triangles listed in their cell of line
// line_of[k] (T: each triangle's three corners; dirs[k] must be the frame's third axis times
// its sign, the order of the lists). The test is watertight: the edge weight of edge (a, b)
// is d . ((a - p) x (b - p)), computed from the same differences in both triangles of the
// edge, so that they see exactly opposite values; a ray meets a triangle when its three
// weights have one sign (zero included) and a nonzero sum, at the parameter interpolated
// from the corners' parameters d . (v - p) with the weights (a triangle seen edge-on is
// never met, as in the BVH's test; a closed mesh's rays meet its neighbours). Every access
// to the lists is checked, and each result depends on its point alone.

namespace {

bool finite_frame(const double* q) {
  for (int a = 0; a < kParams; ++a)
    if (!std::isfinite(q[a])) return false;
  return q[13] > 0.0 && q[14] > 0.0;
}

// The cell range [i0, i1] x [j0, j1] of triangle t's widened bounding box in frame q.
void tri_cells(const double* V, const int64_t* F, int64_t t, const double* q, int64_t G,
               double delta, int64_t* r, double* zlo, double* zhi) {
  double lo[3] = {HUGE_VAL, HUGE_VAL, HUGE_VAL}, hi[3] = {-HUGE_VAL, -HUGE_VAL, -HUGE_VAL};
  for (int c = 0; c < 3; ++c) {
    const double* p = V + 3 * F[3 * t + c];
    for (int a = 0; a < 3; ++a) {
      const double x = p[0] * q[a] + p[1] * q[3 + a] + p[2] * q[6 + a] - q[9 + a];
      lo[a] = std::min(lo[a], x);
      hi[a] = std::max(hi[a], x);
    }
  }
  const double g = static_cast<double>(G - 1);
  auto cell = [&](double x) {
    const double f = std::floor((x + q[13]) / q[14]);
    return static_cast<int64_t>(std::min(std::max(f, 0.0), g));
  };
  r[0] = cell(lo[0] - delta);
  r[1] = cell(hi[0] + delta);
  r[2] = cell(lo[1] - delta);
  r[3] = cell(hi[1] + delta);
  *zlo = lo[2] - delta;
  *zhi = hi[2] + delta;
}

inline void sub3(const double* a, const double* b, double* o) {
  o[0] = a[0] - b[0];
  o[1] = a[1] - b[1];
  o[2] = a[2] - b[2];
}

inline double dot3(const double* a, const double* b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}

// d . (a x b)
inline double weight(const double* d, const double* a, const double* b) {
  return d[0] * (a[1] * b[2] - a[2] * b[1]) + d[1] * (a[2] * b[0] - a[0] * b[2]) +
         d[2] * (a[0] * b[1] - a[1] * b[0]);
}

// `*tmax`: the largest parameter of the triangle's corners along the ray.
bool ray_meets(const double* p, const double* d, const double* a, const double* b, const double* c,
               double t_min, double* tmax_out) {
  double pa[3], pb[3], pc[3];
  sub3(a, p, pa);
  sub3(b, p, pb);
  sub3(c, p, pc);
  const double ta = dot3(d, pa), tb = dot3(d, pb), tc = dot3(d, pc);
  const double tmax = std::max(ta, std::max(tb, tc));
  *tmax_out = tmax;
  if (!(tmax > t_min)) return false;
  const double wab = weight(d, pa, pb), wbc = weight(d, pb, pc), wca = weight(d, pc, pa);
  const bool pos = wab >= 0.0 && wbc >= 0.0 && wca >= 0.0;
  const bool neg = wab <= 0.0 && wbc <= 0.0 && wca <= 0.0;
  if (!pos && !neg) return false;
  const double w = wab + wbc + wca;
  if (w == 0.0) return false;  // seen edge-on (its neighbours of a closed mesh are not)
  return (wbc * ta + wca * tb + wab * tc) / w > t_min;
}

}  // namespace

VOXAX_EXPORT int voxax_column_lists(const double* V, int64_t nv, const int64_t* F, int64_t nf,
                                    int64_t L, const double* frames, int64_t G, double delta,
                                    int32_t fill, int64_t* counts, int32_t* entries, int64_t ne,
                                    double* lo, double* hi, int32_t threads, char* err,
                                    int64_t errlen) {
  return voxax::host_guarded("the column lists", err, errlen, [&](std::string* msg) {
    if (nv < 0 || nf < 0 || L < 0 || ne < 0 || nf > INT32_MAX) {
      *msg = "voxax: the column lists need nv, nf, L, ne >= 0 (and nf < 2^31)";
      return false;
    }
    if (G < 1 || G > (int64_t{1} << 14)) {
      *msg = "voxax: the column grid's resolution must lie in [1, 16384]";
      return false;
    }
    if (!(delta >= 0.0) || !std::isfinite(delta)) {
      *msg = "voxax: the column lists' margin must be finite and >= 0";
      return false;
    }
    for (int64_t i = 0; i < 3 * nf; ++i)
      if (F[i] < 0 || F[i] >= nv) {
        *msg = "voxax: the column lists' face " + std::to_string(i / 3) +
               " has a vertex index outside [0, " + std::to_string(nv) + ")";
        return false;
      }
    for (int64_t i = 0; i < 3 * nv; ++i)
      if (!std::isfinite(V[i])) {
        *msg = "voxax: the column lists' vertices must be finite";
        return false;
      }
    for (int64_t l = 0; l < L; ++l)
      if (!finite_frame(frames + kParams * l)) {
        *msg = "voxax: the column lists' frame " + std::to_string(l) +
               " must be finite, with radius and cell width > 0";
        return false;
      }
    const int64_t GG = G * G;
    if (fill) {
      if (counts[0] != 0 || counts[L * GG] != ne) {
        *msg = "voxax: the column lists' offsets must run from 0 to the entries' count";
        return false;
      }
      for (int64_t c = 0; c < L * GG; ++c)
        if (counts[c + 1] < counts[c]) {
          *msg = "voxax: the column lists' offsets must not decrease";
          return false;
        }
    }
    // one line per task: each writes only its own cells
    voxax::spatial::parallel_chunks(L, 1, threads, [&](int64_t, int64_t l, int64_t) {
      const double* q = frames + kParams * l;
      int64_t* base = counts + l * GG;
      std::vector<int64_t> at;
      std::vector<double> top;  // each triangle's top depth (fill)
      if (fill) {
        top.resize(static_cast<size_t>(nf));
        at.assign(base, base + GG);
        std::fill(lo + l * GG, lo + (l + 1) * GG, HUGE_VAL);
        std::fill(hi + l * GG, hi + (l + 1) * GG, -HUGE_VAL);
      } else {
        std::fill(base, base + GG, int64_t{0});
      }
      for (int64_t t = 0; t < nf; ++t) {
        int64_t r[4];
        double zlo, zhi;
        tri_cells(V, F, t, q, G, delta, r, &zlo, &zhi);
        if (fill) top[t] = zhi;
        for (int64_t i = r[0]; i <= r[1]; ++i)
          for (int64_t j = r[2]; j <= r[3]; ++j) {
            const int64_t c = i * G + j;
            if (!fill) {
              ++base[c];
              continue;
            }
            if (at[c] >= base[c + 1])
              throw voxax::InvalidInput("voxax: the column lists' offsets do not fit the faces");
            entries[at[c]++] = static_cast<int32_t>(t);
            lo[l * GG + c] = std::min(lo[l * GG + c], zlo);
            hi[l * GG + c] = std::max(hi[l * GG + c], zhi);
          }
      }
      if (!fill) return;
      // each cell's triangles from the highest top depth down (ties: ascending index): rays
      // along +d meet the likeliest first and stop at the first triangle wholly behind
      // them (rays along -d start from the end)
      for (int64_t c = 0; c < GG; ++c)
        std::sort(entries + base[c], entries + base[c + 1], [&](int32_t a, int32_t b) {
          return top[a] > top[b] || (top[a] == top[b] && a < b);
        });
    });
    return true;
  });
}

namespace {

// The tables of the column ray casts (see voxax_column_hits).
struct Casts {
  int64_t K, L, G;
  const double *params, *dirs;
  const int64_t* line_of;
  const double* lims;
  const int64_t* offsets;
  const int32_t* entries;
  int64_t ne;
  const double* T;
  int64_t nf;
  double t_min;

  // The checks of the tables that do not depend on the directions used.
  bool check(std::string* msg) const {
    if (K < 1 || L < 1 || ne < 0 || nf < 0) {
      *msg = "voxax: the column ray casts need K >= 1, L >= 1, ne, nf >= 0";
      return false;
    }
    if (G < 1 || G > (int64_t{1} << 14)) {
      *msg = "voxax: the column grid's resolution must lie in [1, 16384]";
      return false;
    }
    if (!std::isfinite(t_min)) {
      *msg = "voxax: the column ray casts' t_min must be finite";
      return false;
    }
    return true;
  }

  // The checks of direction k's rows.
  bool check_direction(int64_t k, std::string* msg) const {
    if (!finite_frame(params + kParams * k) || line_of[k] < 0 || line_of[k] >= L ||
        !(std::isfinite(dirs[3 * k]) && std::isfinite(dirs[3 * k + 1]) &&
          std::isfinite(dirs[3 * k + 2]))) {
      *msg = "voxax: the column ray casts' direction " + std::to_string(k) +
             " needs a finite frame and direction and a line in [0, " + std::to_string(L) + ")";
      return false;
    }
    return true;
  }

  // The cell of point p in direction k's grid when the ray may meet the surface by the
  // column test, else -1.
  int64_t column(const double* p, int64_t k) const {
    return column_cell(p, params + kParams * k, G, lims + k * G * G);
  }

  // Whether the ray from p along direction k meets a triangle listed over `cell`.
  bool scan(const double* p, int64_t k, int64_t cell) const {
    const int64_t c = line_of[k] * G * G + cell;
    const int64_t e0 = offsets[c], e1 = offsets[c + 1];
    if (e0 < 0 || e1 > ne || e0 > e1)
      throw voxax::InvalidInput("voxax: the column ray casts' offsets are out of range");
    const double* d = dirs + 3 * k;
    // along +d from the highest triangles (all after one wholly behind the ray, by a margin
    // far above rounding, are behind it too), along -d from the lowest
    const bool up = params[kParams * k + 12] > 0.0;
    const double behind = t_min - 1e-3 * std::fabs(t_min) - 1e-300;
    for (int64_t x = 0; x < e1 - e0; ++x) {
      const int64_t t = entries[up ? e0 + x : e1 - 1 - x];
      if (t < 0 || t >= nf)
        throw voxax::InvalidInput("voxax: the column ray casts' entries are out of range");
      const double* v = T + 9 * t;
      double tmax;
      if (ray_meets(p, d, v, v + 3, v + 6, t_min, &tmax)) return true;
      if (up && tmax < behind) return false;
    }
    return false;
  }

  // 0: a miss by the column test; 2: a miss after a look at the triangles; 3: a hit.
  uint8_t cast(const double* p, int64_t k) const {
    const int64_t cell = column(p, k);
    if (cell < 0) return 0;
    return scan(p, k, cell) ? 3 : 2;
  }
};

}  // namespace

#define VOXAX_CAST_ARGS                                                                          \
  int64_t K, const double *params, const double *dirs, const int64_t *line_of, int64_t L,        \
      int64_t G, const double *lims, const int64_t *offsets, const int32_t *entries, int64_t ne, \
      const double *T, int64_t nf, double t_min
#define VOXAX_CASTS \
  Casts { K, L, G, params, dirs, line_of, lims, offsets, entries, ne, T, nf, t_min }

VOXAX_EXPORT int voxax_column_hits(const double* P, const int64_t* ks, int64_t n, VOXAX_CAST_ARGS,
                                   int32_t threads, uint8_t* out, char* err, int64_t errlen) {
  return voxax::host_guarded("the column ray casts", err, errlen, [&](std::string* msg) {
    const Casts casts = VOXAX_CASTS;
    if (n < 0) {
      *msg = "voxax: the column ray casts need n >= 0 points";
      return false;
    }
    if (!casts.check(msg)) return false;
    std::vector<char> used(static_cast<size_t>(K), 0);
    for (int64_t i = 0; i < n; ++i) {
      if (ks[i] < 0 || ks[i] >= K) {
        *msg = "voxax: the column ray casts' direction index " + std::to_string(ks[i]) +
               " of point " + std::to_string(i) + " is outside [0, " + std::to_string(K) + ")";
        return false;
      }
      used[ks[i]] = 1;
    }
    for (int64_t k = 0; k < K; ++k)
      if (used[k] && !casts.check_direction(k, msg)) return false;
    voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) out[i] = casts.cast(P + 3 * i, ks[i]);
    });
    return true;
  });
}

// The ray casts of the selection's candidate floaters, a block at a time.
//
//   voxax_column_known(pairs (np, 2) i64, np, off (nb + 1,) i64, nb, R, nh, IN (nh, R) u8,
//                      gid (R,) i64, hk (nh,) i64, ghit (nh, cap) i8, cap, gn, gpts (gn, 3) f64,
//                      <the tables of voxax_column_hits>, threads, n_cast (1,) i64, err,
//                      errlen)
//
// For every pair (b, c): the rows r of block b (off[b] <= r < off[b + 1]) get in IN[c, r]
// the hit of the ray of registered point g = gid[r] along direction hk[c], from the registry
// ghit[c, g] (0 or 1), cast (and recorded there) when it holds -1. n_cast counts the
// casts that looked at triangles. Work items are (pair, block of rows): each writes only its
// own entries of IN, and of ghit as long as no two rows share a registered point (the
// caller's blocks are disjoint sets of samples), so the results do not depend on the thread
// count.
VOXAX_EXPORT int voxax_column_known(const int64_t* pairs, int64_t npairs, const int64_t* off,
                                    int64_t nb, int64_t R, int64_t nh, uint8_t* IN,
                                    const int64_t* gid, const int64_t* hk, int8_t* ghit,
                                    int64_t cap, int64_t gn, const double* gpts, VOXAX_CAST_ARGS,
                                    int32_t threads, int64_t* n_cast, char* err, int64_t errlen) {
  return voxax::host_guarded("the known ray casts", err, errlen, [&](std::string* msg) {
    const Casts casts = VOXAX_CASTS;
    if (npairs < 0 || nb < 0 || R < 0 || nh < 0 || cap < 0 || gn < 0 || gn > cap) {
      *msg = "voxax: the known ray casts need np, nb, R, nh >= 0 and 0 <= gn <= cap";
      return false;
    }
    if (!casts.check(msg)) return false;
    if (off[0] < 0 || off[nb] > R) {
      *msg = "voxax: the known ray casts' blocks must lie in [0, R)";
      return false;
    }
    for (int64_t b = 0; b < nb; ++b)
      if (off[b + 1] < off[b]) {
        *msg = "voxax: the known ray casts' block offsets must not decrease";
        return false;
      }
    for (int64_t j = 0; j < npairs; ++j) {
      const int64_t b = pairs[2 * j], c = pairs[2 * j + 1];
      if (b < 0 || b >= nb || c < 0 || c >= nh || hk[c] < 0 || hk[c] >= K) {
        *msg = "voxax: the known ray casts' pair " + std::to_string(j) +
               " names a block outside [0, nb), a column outside [0, nh) or a direction "
               "outside [0, K)";
        return false;
      }
      if (!casts.check_direction(hk[c], msg)) return false;
    }
    // work items: (pair, chunk of its block's rows)
    std::vector<int64_t> first(static_cast<size_t>(npairs + 1), 0);
    for (int64_t j = 0; j < npairs; ++j) {
      const int64_t rows = off[pairs[2 * j] + 1] - off[pairs[2 * j]];
      first[j + 1] = first[j] + (rows + kChunk - 1) / kChunk;
    }
    const int64_t items = first[npairs];
    std::vector<int64_t> counts(static_cast<size_t>(items), 0);
    voxax::spatial::parallel_chunks(items, 1, threads, [&](int64_t w, int64_t, int64_t) {
      const int64_t j = std::upper_bound(first.begin(), first.end(), w) - first.begin() - 1;
      const int64_t b = pairs[2 * j], c = pairs[2 * j + 1], k = hk[c];
      const int64_t r0 = off[b] + (w - first[j]) * kChunk, r1 = std::min(off[b + 1], r0 + kChunk);
      int64_t cast = 0;
      for (int64_t r = r0; r < r1; ++r) {
        const int64_t g = gid[r];
        if (g < 0 || g >= gn)
          throw voxax::InvalidInput("voxax: the known ray casts' row " + std::to_string(r) +
                                    " is not registered");
        int8_t h = ghit[c * cap + g];
        if (h < 0) {
          const uint8_t o = casts.cast(gpts + 3 * g, k);
          cast += o >> 1;
          h = static_cast<int8_t>(o & 1);
          ghit[c * cap + g] = h;
        }
        IN[c * R + r] = static_cast<uint8_t>(h == 1);
      }
      counts[w] = cast;
    });
    int64_t total = 0;
    for (int64_t x : counts) total += x;
    *n_cast = total;
    return true;
  });
}

// Which points lie inside height fields: the selection's filter of candidate floaters.
//
//   voxax_column_inside(P (n, 3) f64, n, blocks (nb, 4) i64, nb, <the tables of
//                       voxax_column_hits>, threads, out (n,) u8, n_cast (1,) i64, err, errlen)
//
// Block b = (start, end, k1, k2) asks, for the points start <= i < end, whether the rays
// along directions k1 and k2 (k2 = -1: k1 alone) both meet the surface: out[i] = 1 where
// they do (both column tests first, then k1's triangles, then k2's where k1 hits), 0
// elsewhere; points outside every block keep their
// value. n_cast counts the casts that looked at triangles. Work items are (block, chunk of
// its points); blocks must not overlap, so the results do not depend on the thread count.
VOXAX_EXPORT int voxax_column_inside(const double* P, int64_t n, const int64_t* blocks, int64_t nb,
                                     VOXAX_CAST_ARGS, int32_t threads, uint8_t* out,
                                     int64_t* n_cast, char* err, int64_t errlen) {
  return voxax::host_guarded("the height-field filter", err, errlen, [&](std::string* msg) {
    const Casts casts = VOXAX_CASTS;
    if (n < 0 || nb < 0) {
      *msg = "voxax: the height-field filter needs n, nb >= 0";
      return false;
    }
    if (!casts.check(msg)) return false;
    std::vector<std::pair<int64_t, int64_t>> spans;
    for (int64_t b = 0; b < nb; ++b) {
      const int64_t* q = blocks + 4 * b;
      if (q[0] < 0 || q[1] > n || q[0] > q[1] || q[2] < 0 || q[2] >= K || q[3] < -1 || q[3] >= K) {
        *msg = "voxax: the height-field filter's block " + std::to_string(b) +
               " needs 0 <= start <= end <= n and directions in [0, K) (the second may be -1)";
        return false;
      }
      if (!casts.check_direction(q[2], msg) || (q[3] >= 0 && !casts.check_direction(q[3], msg)))
        return false;
      if (q[1] > q[0]) spans.emplace_back(q[0], q[1]);
    }
    std::sort(spans.begin(), spans.end());
    for (size_t j = 1; j < spans.size(); ++j)
      if (spans[j].first < spans[j - 1].second) {
        *msg = "voxax: the height-field filter's blocks must not overlap";
        return false;
      }
    std::vector<int64_t> first(static_cast<size_t>(nb + 1), 0);
    for (int64_t b = 0; b < nb; ++b)
      first[b + 1] = first[b] + (blocks[4 * b + 1] - blocks[4 * b] + kChunk - 1) / kChunk;
    const int64_t items = first[nb];
    std::vector<int64_t> counts(static_cast<size_t>(items), 0);
    voxax::spatial::parallel_chunks(items, 1, threads, [&](int64_t w, int64_t, int64_t) {
      const int64_t b = std::upper_bound(first.begin(), first.end(), w) - first.begin() - 1;
      const int64_t* q = blocks + 4 * b;
      const int64_t i0 = q[0] + (w - first[b]) * kChunk, i1 = std::min(q[1], i0 + kChunk);
      int64_t cast = 0;
      for (int64_t i = i0; i < i1; ++i) {
        // both column tests before any look at the triangles
        const double* p = P + 3 * i;
        const int64_t c1 = casts.column(p, q[2]);
        const int64_t c2 = q[3] >= 0 ? casts.column(p, q[3]) : 0;
        bool in = c1 >= 0 && c2 >= 0;
        if (in) {
          ++cast;
          in = casts.scan(p, q[2], c1);
        }
        if (in && q[3] >= 0) {
          ++cast;
          in = casts.scan(p, q[3], c2);
        }
        out[i] = in ? 1 : 0;
      }
      counts[w] = cast;
    });
    int64_t total = 0;
    for (int64_t x : counts) total += x;
    *n_cast = total;
    return true;
  });
}

// The dense sums of the ESI selection's lower bounds (`voxax.esi._Dhf.children`), a plain C
// ABI for ctypes. Each entry point reads a node's rows and the children's columns and
// writes per-column sums; each sum is taken over its rows in one fixed order (the order
// given, or four interleaved partial sums), so the results are the same bits for any
// thread count.
//
//   voxax_bound_samples(rr (n,) i64, n, rows, nh, cur (n,) f64, Dr (rows, nh) f64,
//                       suf (rows, nh + 1) f64, Vr (rows, nh) u8, sufv (rows, nh + 1) u8,
//                       c0, nc, with_suf, C (n, nc) f64, Vn (n, nc) u8, cd (nc,) f64,
//                       vn (nc,) i64, vmax (nc,) i64, err, errlen)
//
// For the hidden surface samples rr of a node and the columns j = c0 + c (c < nc):
// C[i, c] = min(cur[i], Dr[rr[i], j]); cd[c] = sum_i C[i, c], or with with_suf
// sum_i min(C[i, c], suf[rr[i], j + 1]); Vn[i, c] = Vr[rr[i], j]; vn[c] = sum_i Vn[i, c];
// vmax[c] = sum_i (Vn[i, c] | sufv[rr[i], j + 1]).
//
//   voxax_bound_removals(IN (nh, R) u8, nh, R, rows (n,) i64, n, cols (nc,) i64, nc,
//                        col_of (n,) i64 or null, s3, wd (R,) f64, wt (R,) f64, threads,
//                        sums (3, nc) f64, Md (nh - s3, nc) f64, Mt (nh - s3, nc) f64,
//                        err, errlen)
//
// Row i counts in column c when IN[cols[c], rows[i]] != 0 (col_of null), or when
// col_of[i] == c (col_of ascending). sums[0 / 1 / 2][c] sums wd[row] / wt[row] / 1 over the rows
// counting in column c; Md[h - s3, c] (Mt) sums wd (wt) over the rows counting in column c with
// IN[h, row] == 0, for s3 <= h < nh and h > cols[c] (0 for h <= cols[c]). cols must be
// ascending.
//
//   voxax_bound_blocks(alive (R,) u8, R, off (nb + 1,) i64, nb, wd (R,) f64, wt (R,) f64,
//                      with_sums, out (3, nb) f64, err, errlen)
//
// out[0 / 1 / 2][b] = the sums of alive, alive * wd and alive * wt over the rows
// off[b] <= row < off[b + 1] of block b (the last two 0 without with_sums).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "common/host_pool.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {
// Below this much work (row x column pairs) one thread does it: starting threads costs more.
constexpr int64_t kThreadWork = int64_t{1} << 18;

// Rows set out at a time as a 0/1 matrix (32 x 80 doubles for the paper's 80 candidates: in
// the first-level cache).
constexpr int64_t kRowChunk = 32;

// AVX2 where the machine has it: the products below are of a weight and 0 or 1, exact, and
// each lane adds in the same order, so the vector code gives the same bits as the plain one.
#if defined(__GNUC__) && defined(__x86_64__) && defined(__linux__) && !defined(__SANITIZE_ADDRESS__)
#define VOXAX_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define VOXAX_CLONES
#endif

constexpr int64_t kLanes = 8;

// 1.0 where b, else 0.0, without a branch (the compilers turn `b ? 1.0 : 0.0` into one,
// mispredicted half the time on these flags).
inline double one_if(bool b) {
  const uint64_t bits = static_cast<uint64_t>(b) * uint64_t{0x3FF0000000000000};
  double d;
  std::memcpy(&d, &bits, sizeof d);
  return d;
}

// four doubles (GCC and Clang vector extensions: AVX registers in the AVX2 clone, pairs of
// SSE registers otherwise)
typedef double v4d __attribute__((vector_size(32)));

// For the rows at[0 .. rows) of A (ncp columns, 0 or 1; all rows 0 .. rows where at is
// null) and the column blocks of kLanes columns below lim: md[c] += aw[k] * A[at[k], c]
// and mt[c] += bw[k] * A[at[k], c], each column's sum in the order of the rows.
VOXAX_CLONES void add_rows(const double* A, int64_t ncp, const int32_t* at, const double* aw,
                           const double* bw, int64_t rows, int64_t lim, double* md, double* mt) {
  for (int64_t c0 = 0; c0 < lim; c0 += kLanes) {
    v4d x0, x1, y0, y1;  // (unaligned loads and stores through memcpy)
    std::memcpy(&x0, md + c0, sizeof x0);
    std::memcpy(&x1, md + c0 + 4, sizeof x1);
    std::memcpy(&y0, mt + c0, sizeof y0);
    std::memcpy(&y1, mt + c0 + 4, sizeof y1);
    for (int64_t k = 0; k < rows; ++k) {
      const double* a = A + (at ? at[k] : k) * ncp + c0;
      v4d a0, a1;
      std::memcpy(&a0, a, sizeof a0);
      std::memcpy(&a1, a + 4, sizeof a1);
      const double p = aw[k], q = bw[k];
      x0 += p * a0;
      x1 += p * a1;
      y0 += q * a0;
      y1 += q * a1;
    }
    std::memcpy(md + c0, &x0, sizeof x0);
    std::memcpy(md + c0 + 4, &x1, sizeof x1);
    std::memcpy(mt + c0, &y0, sizeof y0);
    std::memcpy(mt + c0 + 4, &y1, sizeof y1);
  }
}

bool indices_within(const int64_t* idx, int64_t n, int64_t hi, const char* what, std::string* msg) {
  for (int64_t i = 0; i < n; ++i)
    if (idx[i] < 0 || idx[i] >= hi) {
      *msg = std::string("voxax: ") + what + " " + std::to_string(idx[i]) + " (entry " +
             std::to_string(i) + ") is outside [0, " + std::to_string(hi) + ")";
      return false;
    }
  return true;
}

// The arguments of voxax_bound_removals (see the top of this file) and its stages.
struct Removals {
  const uint8_t* IN;
  int64_t nh, R;
  const int64_t* rows;
  int64_t n;
  const int64_t* cols;
  int64_t nc;
  const int64_t* col_of;
  int64_t s3;
  const double* wd;
  const double* wt;
  double* sums;
  double* Md;
  double* Mt;

  // The checks of the arguments; false with *msg set on bad input.
  bool valid(std::string* msg) const {
    if (nh < 0 || R < 0 || n < 0 || nc < 0 || s3 < 0 || s3 > nh) {
      *msg = "voxax: the bounds' removal sums need nh, R, n, nc >= 0 and 0 <= s3 <= nh";
      return false;
    }
    if (!indices_within(rows, n, R, "the bounds' removal row", msg) ||
        !indices_within(cols, nc, nh, "the bounds' removal column", msg))
      return false;
    for (int64_t c = 1; c < nc; ++c)
      if (cols[c] <= cols[c - 1]) {
        *msg = "voxax: the bounds' removal columns must be ascending";
        return false;
      }
    if (col_of && !indices_within(col_of, n, nc, "the bounds' removal column of a row", msg))
      return false;
    // finite weights: a 0 membership then adds exactly nothing (never inf * 0)
    for (int64_t i = 0; i < n; ++i)
      if (!std::isfinite(wd[rows[i]]) || !std::isfinite(wt[rows[i]])) {
        *msg = "voxax: the bounds' removal weights must be finite (row " + std::to_string(rows[i]) +
               ")";
        return false;
      }
    return true;
  }

  // With col_of: the sums and the removals of each row's one column (use: the threads).
  bool by_column(int use, std::string* msg) const {
    const int64_t nr3 = nh - s3;
    // one column per row (col_of ascending: each column's rows in one run): the sums,
    // then per column the removals along each h, in four interleaved partial sums
    for (int64_t i = 1; i < n; ++i)
      if (col_of[i] < col_of[i - 1]) {
        *msg = "voxax: the bounds' removal columns of the rows must be ascending";
        return false;
      }
    std::vector<int64_t> first(static_cast<size_t>(nc + 1), 0);
    for (int64_t i = 0; i < n; ++i) {
      const int64_t c = col_of[i];
      sums[c] += wd[rows[i]];
      sums[nc + c] += wt[rows[i]];
      sums[2 * nc + c] += 1.0;
      first[c + 1] = i + 1;
    }
    for (int64_t c = 1; c <= nc; ++c) first[c] = std::max(first[c], first[c - 1]);
    if (nr3 == 0) return true;
    voxax::spatial::parallel_chunks(nc, 1, use, [&](int64_t, int64_t c0, int64_t c1) {
      for (int64_t c = c0; c < c1; ++c)
        for (int64_t h = std::max(s3, cols[c] + 1); h < nh; ++h) {
          const uint8_t* in = IN + h * R;
          double x[4] = {0.0, 0.0, 0.0, 0.0}, y[4] = {0.0, 0.0, 0.0, 0.0};
          for (int64_t i = first[c]; i < first[c + 1]; ++i) {
            const int64_t row = rows[i];
            const double out = one_if(in[row] == 0);
            x[i & 3] += out * wd[row];
            y[i & 3] += out * wt[row];
          }
          Md[(h - s3) * nc + c] = (x[0] + x[1]) + (x[2] + x[3]);
          Mt[(h - s3) * nc + c] = (y[0] + y[1]) + (y[2] + y[3]);
        }
    });
    return true;
  }

  // Without col_of: the memberships gathered from IN, summed a chunk of rows at a time
  // (use: the threads).
  bool gathered(int use) const {
    const int64_t nr3 = nh - s3;
    // G[h - h0, i] = IN[h, rows[i]] for h0 = cols[0] <= h < nh, gathered one row of IN at a
    // time (an ascending sweep through it)
    const int64_t h0 = cols[0], ng = nh - h0;
    std::vector<uint8_t> G(static_cast<size_t>(ng * n));
    for (int64_t g = 0; g < ng; ++g) {
      const uint8_t* in = IN + (h0 + g) * R;
      uint8_t* o = G.data() + g * n;
      for (int64_t i = 0; i < n; ++i) o[i] = in[rows[i]] != 0;
    }
    std::vector<double> wdr(static_cast<size_t>(n)), wtr(static_cast<size_t>(n));
    for (int64_t i = 0; i < n; ++i) {
      wdr[i] = wd[rows[i]];
      wtr[i] = wt[rows[i]];
    }
    // the memberships of a chunk of rows as a 0/1 matrix (m, ncp), its columns padded to
    // whole lane blocks
    const int64_t ncp = (nc + kLanes - 1) / kLanes * kLanes;
    auto chunk_of = [&](int64_t i0, int64_t m, double* Ac) {
      std::fill(Ac, Ac + kRowChunk * ncp, 0.0);
      for (int64_t c = 0; c < nc; ++c) {
        const uint8_t* g = G.data() + (cols[c] - h0) * n + i0;
        for (int64_t i = 0; i < m; ++i) Ac[i * ncp + c] = one_if(g[i] != 0);
      }
    };
    {
      std::vector<double> Ac(static_cast<size_t>(kRowChunk * ncp));
      std::vector<double> s0(static_cast<size_t>(ncp), 0.0), s1(s0);
      for (int64_t i0 = 0; i0 < n; i0 += kRowChunk) {
        const int64_t m = std::min(kRowChunk, n - i0);
        chunk_of(i0, m, Ac.data());
        add_rows(Ac.data(), ncp, nullptr, wdr.data() + i0, wtr.data() + i0, m, nc, s0.data(),
                 s1.data());
      }
      for (int64_t c = 0; c < nc; ++c) {
        const uint8_t* g = G.data() + (cols[c] - h0) * n;  // the count: the row's 0/1 flags
        int64_t count = 0;
        for (int64_t i = 0; i < n; ++i) count += g[i];
        sums[c] = s0[c];
        sums[nc + c] = s1[c];
        sums[2 * nc + c] = static_cast<double>(count);
      }
    }
    if (nr3 == 0) return true;
    // row h - s3 of Md and Mt: the columns c < lim (cols[c] < h) only, the weights of the
    // rows that h leaves out (0 for the others), a chunk of rows at a time for every h of
    // the thread's share
    std::vector<double> MP(static_cast<size_t>(2 * nr3 * ncp), 0.0);
    // each thread a run of h of about equal work (the columns below h), so that each chunk
    // of rows is set out once per thread
    std::vector<int64_t> lims(static_cast<size_t>(nr3)), split(static_cast<size_t>(use) + 1, nr3);
    int64_t total = 0;
    for (int64_t j = 0; j < nr3; ++j) {
      lims[j] = std::lower_bound(cols, cols + nc, s3 + j) - cols;
      total += lims[j];
    }
    split[0] = 0;
    for (int t = 1; t < use; ++t) {
      int64_t acc = 0, j = 0;
      while (j < nr3 && acc * use < total * t) acc += lims[j++];
      split[t] = j;
    }
    voxax::spatial::parallel_chunks(use, 1, use, [&](int64_t t, int64_t, int64_t) {
      const int64_t j0 = split[t], j1 = std::max(split[t], split[t + 1]);
      if (j0 >= j1) return;
      std::vector<double> Ac(static_cast<size_t>(kRowChunk * ncp));
      double aw[kRowChunk], bw[kRowChunk];
      int32_t at[kRowChunk];
      for (int64_t i0 = 0; i0 < n; i0 += kRowChunk) {
        const int64_t m = std::min(kRowChunk, n - i0);
        chunk_of(i0, m, Ac.data());
        for (int64_t j = j0; j < j1; ++j) {
          const int64_t h = s3 + j, lim = lims[j];
          if (lim == 0) continue;  // (else h > cols[0] = h0: G holds its row)
          // the rows that h leaves out, listed without branches (the others would add 0)
          const uint8_t* g = G.data() + (h - h0) * n + i0;
          int64_t k = 0;
          for (int64_t i = 0; i < m; ++i) {
            at[k] = static_cast<int32_t>(i);
            aw[k] = wdr[i0 + i];
            bw[k] = wtr[i0 + i];
            k += g[i] == 0;
          }
          add_rows(Ac.data(), ncp, at, aw, bw, k, lim, MP.data() + j * ncp,
                   MP.data() + (nr3 + j) * ncp);
        }
      }
    });
    for (int64_t j = 0; j < nr3; ++j)
      for (int64_t c = 0; c < lims[j]; ++c) {
        Md[j * nc + c] = MP[j * ncp + c];
        Mt[j * nc + c] = MP[(nr3 + j) * ncp + c];
      }
    return true;
  }
};

}  // namespace

VOXAX_EXPORT int voxax_bound_samples(const int64_t* rr, int64_t n, int64_t rows, int64_t nh,
                                     const double* cur, const double* Dr, const double* suf,
                                     const uint8_t* Vr, const uint8_t* sufv, int64_t c0, int64_t nc,
                                     int32_t with_suf, double* C, uint8_t* Vn, double* cd,
                                     int64_t* vn, int64_t* vmax, char* err, int64_t errlen) {
  return voxax::host_guarded("the bounds' sample sums", err, errlen, [&](std::string* msg) {
    if (n < 0 || rows < 0 || nh < 0 || nc < 0 || c0 < 0 || c0 + nc > nh) {
      *msg =
          "voxax: the bounds' sample sums need n, rows, nh, nc >= 0 and 0 <= c0 <= c0 + nc <= nh";
      return false;
    }
    if (!indices_within(rr, n, rows, "the bounds' sample row", msg)) return false;
    if (n >= (int64_t{1} << 31)) {
      *msg = "voxax: the bounds' sample sums take fewer than 2^31 samples";
      return false;
    }
    std::fill(cd, cd + nc, 0.0);
    // the counts in 32 bits, which vectorise with the byte flags
    std::vector<int32_t> cv(static_cast<size_t>(nc), 0), cm(static_cast<size_t>(nc), 0);
    for (int64_t i = 0; i < n; ++i) {
      const int64_t q = rr[i];
      const double* d = Dr + q * nh + c0;
      const double* s = suf + q * (nh + 1) + c0 + 1;
      const uint8_t* v = Vr + q * nh + c0;
      const uint8_t* sv = sufv + q * (nh + 1) + c0 + 1;
      double* ci = C + i * nc;
      uint8_t* vi = Vn + i * nc;
      const double x = cur[i];
      for (int64_t c = 0; c < nc; ++c) ci[c] = std::min(x, d[c]);
      if (with_suf) {
        for (int64_t c = 0; c < nc; ++c) cd[c] += std::min(ci[c], s[c]);
      } else {
        for (int64_t c = 0; c < nc; ++c) cd[c] += ci[c];
      }
      for (int64_t c = 0; c < nc; ++c) {
        const uint8_t b = v[c] != 0;
        vi[c] = b;
        cv[c] += b;
        cm[c] += b | (sv[c] != 0);
      }
    }
    for (int64_t c = 0; c < nc; ++c) {
      vn[c] = cv[c];
      vmax[c] = cm[c];
    }
    return true;
  });
}

VOXAX_EXPORT int voxax_bound_removals(const uint8_t* IN, int64_t nh, int64_t R, const int64_t* rows,
                                      int64_t n, const int64_t* cols, int64_t nc,
                                      const int64_t* col_of, int64_t s3, const double* wd,
                                      const double* wt, int32_t threads, double* sums, double* Md,
                                      double* Mt, char* err, int64_t errlen) {
  return voxax::host_guarded("the bounds' removal sums", err, errlen, [&](std::string* msg) {
    const Removals r{IN, nh, R, rows, n, cols, nc, col_of, s3, wd, wt, sums, Md, Mt};
    if (!r.valid(msg)) return false;
    const int64_t nr3 = nh - s3;
    std::fill(sums, sums + 3 * nc, 0.0);
    std::fill(Md, Md + nr3 * nc, 0.0);
    std::fill(Mt, Mt + nr3 * nc, 0.0);
    if (nc == 0 || n == 0) return true;
    const int use = n * nc * std::max<int64_t>(nr3, 1) < kThreadWork
                        ? 1
                        : voxax::spatial::resolve_threads(threads);
    if (col_of) return r.by_column(use, msg);
    return r.gathered(use);
  });
}

VOXAX_EXPORT int voxax_bound_blocks(const uint8_t* alive, int64_t R, const int64_t* off, int64_t nb,
                                    const double* wd, const double* wt, int32_t with_sums,
                                    double* out, char* err, int64_t errlen) {
  return voxax::host_guarded("the bounds' block sums", err, errlen, [&](std::string* msg) {
    if (R < 0 || nb < 0) {
      *msg = "voxax: the bounds' block sums need R, nb >= 0";
      return false;
    }
    for (int64_t b = 0; b <= nb; ++b)
      if (off[b] < 0 || off[b] > R || (b > 0 && off[b] < off[b - 1])) {
        *msg = "voxax: the bounds' block offsets must be ascending within [0, R]";
        return false;
      }
    for (int64_t b = 0; b < nb; ++b) {
      int64_t cnt = 0;
      for (int64_t r = off[b]; r < off[b + 1]; ++r) cnt += alive[r] != 0;
      double sd = 0.0, st = 0.0;
      if (with_sums)
        for (int64_t r = off[b]; r < off[b + 1]; ++r) {
          const bool a = alive[r] != 0;
          sd += a ? wd[r] : 0.0;
          st += a ? wt[r] : 0.0;
        }
      out[b] = static_cast<double>(cnt);
      out[nb + b] = sd;
      out[2 * nb + b] = st;
    }
    return true;
  });
}

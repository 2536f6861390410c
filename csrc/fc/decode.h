// Faithful Contouring decoder: dual contouring of tokens.
//
// Every token row is a vertex (its anchor). Every lattice edge voted on by the rows of
// the 4 cells around it gives quads: in each cell, the rows with a non-zero sign on the
// edge, sorted by their anchors' coordinate along the edge (then by row), are paired
// across the 4 cells when every cell has the same number of them; otherwise the first
// row of each cell forms one quad. A cell whose rows all have sign 0 on the edge takes
// part with its first row and a vote of 0. The quad's orientation is the sign of the sum
// of its rows' votes (a majority vote), and it is split along one diagonal.
//
// Each edge is processed once, by its lowest voting row; rows are processed in fixed
// chunks whose outputs are concatenated in order, so the result does not depend on the
// thread count.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

namespace voxax {
namespace fc {

// Offsets of the 12 cell edges: edges 0-3 along x at (y, z) offsets (0,0), (1,0), (1,1),
// (0,1); 4-7 along y at (x, z) offsets; 8-11 along z at (x, y) offsets.
constexpr int kQuad[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};

inline void edge_offset(int e, int64_t o[3]) {
  const int a = e / 4;
  const int b = a == 0 ? 1 : 0, c = a == 2 ? 1 : 2;
  o[0] = o[1] = o[2] = 0;
  o[b] = kQuad[e % 4][0];
  o[c] = kQuad[e % 4][1];
}

struct DecodeInput {
  int64_t K = 0;
  const int64_t* index = nullptr;  // (K,) sorted
  const double* P = nullptr;       // (K, 3) anchors
  const double* N = nullptr;       // (K, 3) normals
  const int8_t* S = nullptr;       // (K, 12) signs
  int64_t n[3] = {1, 1, 1};
  int split = 0;  // 0 normal, 1 short, 2 none
};

// Rows [lo, hi) of cell c (empty when absent), by an exponential search from row `hint`:
// the cells around an edge lie near the hint's cell in the sorted index, so the search
// touches memory near the hint.
inline void rows_near(const DecodeInput& in, int64_t c, int64_t hint, int64_t* lo, int64_t* hi) {
  const int64_t* I = in.index;
  const int64_t K = in.K;
  int64_t a, b;  // lower_bound(c) lies in (a, b]
  if (I[hint] < c) {
    a = hint;
    int64_t step = 1;
    b = hint + 1;
    while (b < K && I[b] < c) {
      a = b;
      step *= 2;
      b = hint + step;
    }
    b = std::min(b, K);
  } else {
    b = hint;
    int64_t step = 1;
    a = hint - 1;
    while (a >= 0 && I[a] >= c) {
      b = a;
      step *= 2;
      a = hint - step;
    }
    a = std::max<int64_t>(a, -1);
  }
  const int64_t l = std::lower_bound(I + a + 1, I + b, c) - I;
  int64_t h = l;
  while (h < K && I[h] == c) ++h;
  *lo = l;
  *hi = h;
}

inline double tri_deviation(const DecodeInput& in, int64_t a, int64_t b, int64_t c) {
  const double* pa = in.P + 3 * a;
  const double* pb = in.P + 3 * b;
  const double* pc = in.P + 3 * c;
  double u[3], v[3];
  for (int k = 0; k < 3; ++k) {
    u[k] = pb[k] - pa[k];
    v[k] = pc[k] - pa[k];
  }
  double n[3] = {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
  const double len = std::sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2]);
  if (len > 0)
    for (int k = 0; k < 3; ++k) n[k] /= len;
  double dev = 0;
  for (int64_t r : {a, b, c}) {
    const double* m = in.N + 3 * r;
    dev += 1.0 - (n[0] * m[0] + n[1] * m[1] + n[2] * m[2]);
  }
  return dev;
}

inline void emit_quad(const DecodeInput& in, const int64_t q[4], std::vector<int64_t>* out) {
  const int64_t a = q[0], b = q[1], c = q[2], d = q[3];
  bool second = false;
  if (in.split == 0) {
    second = tri_deviation(in, a, b, d) + tri_deviation(in, b, c, d) <
             tri_deviation(in, a, b, c) + tri_deviation(in, a, c, d);
  } else if (in.split == 1) {
    double bd = 0, ac = 0;
    for (int k = 0; k < 3; ++k) {
      const double x = in.P[3 * b + k] - in.P[3 * d + k], y = in.P[3 * a + k] - in.P[3 * c + k];
      bd += x * x;
      ac += y * y;
    }
    second = bd < ac;
  }
  const int64_t t[6] = {a, b, c, a, c, d};
  const int64_t s[6] = {a, b, d, b, c, d};
  const int64_t* w = second ? s : t;
  out->insert(out->end(), w, w + 6);
}

// Triangles (as row triples) of the edges owned by rows [r0, r1).
inline void decode_rows(const DecodeInput& in, int64_t r0, int64_t r1, std::vector<int64_t>* out) {
  const int64_t ny = in.n[1], nz = in.n[2];
  std::vector<int64_t> L[4];
  for (int64_t r = r0; r < r1; ++r) {
    const int64_t c = in.index[r];
    const int64_t cell[3] = {c / (ny * nz), (c / nz) % ny, c % nz};
    for (int e = 0; e < 12; ++e) {
      if (in.S[12 * r + e] == 0) continue;
      const int a = e / 4;
      int64_t o[3];
      edge_offset(e, o);
      const int64_t node[3] = {cell[0] + o[0], cell[1] + o[1], cell[2] + o[2]};
      bool owner = true, complete = true;
      int64_t first[4];
      // Positions in increasing order of their cells' indices (0, 3, 1, 2), so that a row
      // that does not own the edge usually finds a lower voting row at the first lookup.
      static constexpr int kOrder[4] = {0, 3, 1, 2};
      for (int q = 0; q < 4; ++q) L[q].clear();
      for (int t = 0; t < 4 && complete && owner; ++t) {
        const int q = kOrder[t];
        // The cell at position q has this edge as its edge a * 4 + (q + 2) % 4.
        const int slot = a * 4 + (q + 2) % 4;
        int64_t qo[3];
        edge_offset(slot, qo);
        int64_t qc[3];
        for (int k = 0; k < 3; ++k) {
          qc[k] = node[k] - qo[k];
          if (qc[k] < 0 || qc[k] >= in.n[k]) complete = false;
        }
        if (!complete) break;
        int64_t lo, hi;
        rows_near(in, (qc[0] * ny + qc[1]) * nz + qc[2], r, &lo, &hi);
        if (lo == hi) {
          complete = false;
          break;
        }
        first[q] = lo;
        for (int64_t x = lo; x < hi; ++x)
          if (in.S[12 * x + slot] != 0) {
            if (x < r) {
              owner = false;
              break;
            }
            L[q].push_back(x);
          }
      }
      if (!complete || !owner) continue;
      size_t m = L[0].size();
      bool regular = true;
      for (int q = 0; q < 4; ++q) {
        std::sort(L[q].begin(), L[q].end(), [&](int64_t x, int64_t y) {
          const double dx = in.P[3 * x + a], dy = in.P[3 * y + a];
          return dx < dy || (dx == dy && x < y);
        });
        if (L[q].size() != m) regular = false;
      }
      if (!regular || m == 0) m = 1;
      for (size_t k = 0; k < m; ++k) {
        int64_t quad[4];
        int vote = 0;
        for (int q = 0; q < 4; ++q) {
          const int slot = a * 4 + (q + 2) % 4;
          if (regular && !L[q].empty()) {
            quad[q] = L[q][k];
          } else {
            quad[q] = L[q].empty() ? first[q] : L[q][0];
          }
          vote += in.S[12 * quad[q] + slot];
        }
        if (vote == 0) continue;
        // Counter-clockwise positions face +axis for x and z, -axis for y.
        if ((vote < 0) != (a == 1)) {
          std::swap(quad[0], quad[3]);
          std::swap(quad[1], quad[2]);
        }
        emit_quad(in, quad, out);
      }
    }
  }
}

}  // namespace fc
}  // namespace voxax

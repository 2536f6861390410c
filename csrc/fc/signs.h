// Faithful Contouring: the edge signs of one-anchor-per-cell tokens from the surface's
// crossings of the lattice edges.
//
// The crossings (edge id, +-1) are sorted by (edge id, crossing number); each edge's net
// flux is the sum of its crossings' signs. Every edge with a non-zero net flux writes it
// (clipped to [-127, 127]) into the 4 rows of the cells around it, found in the sorted
// row index by galloping searches (within one axis, edge ids are the C-order indices of
// their lower nodes, so the cells at each position around the edge come in increasing
// order). Cells around a signed edge that have no row are reported, each with the first
// crossing (in the sorted order) of the first edge that wants it. Edges are handled in
// fixed chunks and every (row, slot) belongs to exactly one edge, so the result does not
// depend on the thread count.
#pragma once

#include <algorithm>
#include <cstdint>
#include <utility>
#include <vector>

#include "fc/decode.h"

namespace voxax {
namespace fc {

// lower_bound(c) in the sorted I[0, K), searching forward from `from` (I[from - 1] < c).
inline int64_t gallop(const int64_t* I, int64_t K, int64_t from, int64_t c) {
  if (from >= K || I[from] >= c) return from;
  int64_t a = from, step = 1, b = from + 1;  // I[a] < c; lower_bound in (a, b]
  while (b < K && I[b] < c) {
    a = b;
    step *= 2;
    b = a + step;
  }
  b = std::min(b, K);
  return std::lower_bound(I + a + 1, I + b, c) - I;
}

struct Crossing {
  int64_t edge;
  int64_t id;
  int32_t sign;
};

// Sorted crossings: the net flux of every distinct edge and its first crossing.
struct EdgeNet {
  std::vector<int64_t> edge, first;
  std::vector<int64_t> net;
};

inline EdgeNet net_flux(const int64_t* edge, const int8_t* sign, int64_t C) {
  std::vector<Crossing> cr(C);
  for (int64_t c = 0; c < C; ++c) cr[c] = {edge[c], c, sign[c]};
  std::sort(cr.begin(), cr.end(), [](const Crossing& a, const Crossing& b) {
    return a.edge < b.edge || (a.edge == b.edge && a.id < b.id);
  });
  EdgeNet out;
  for (int64_t s = 0; s < C;) {
    int64_t e = s, net = 0;
    while (e < C && cr[e].edge == cr[s].edge) net += cr[e++].sign;
    if (net != 0) {
      out.edge.push_back(cr[s].edge);
      out.first.push_back(cr[s].id);
      out.net.push_back(net);
    }
    s = e;
  }
  return out;
}

// Writes the net signs of edges [e0, e1) of `en` into S (K, 12); appends (cell, crossing)
// for cells without a row to `missing`.
inline void scatter_signs(const EdgeNet& en, int64_t e0, int64_t e1, const int64_t* index,
                          int64_t K, const int64_t n[3], int8_t* S, std::vector<int64_t>* missing) {
  const int64_t s[3] = {n[0] + 1, n[1] + 1, n[2] + 1};
  const int64_t total = s[0] * s[1] * s[2];
  int64_t hint[4] = {-1, -1, -1, -1};
  int prev_axis = -1;
  for (int64_t r = e0; r < e1; ++r) {
    const int a = static_cast<int>(en.edge[r] / total);
    const int64_t lin = en.edge[r] % total;
    const int64_t node[3] = {lin / (s[1] * s[2]), (lin / s[2]) % s[1], lin % s[2]};
    if (a != prev_axis) {
      for (int q = 0; q < 4; ++q) hint[q] = -1;
      prev_axis = a;
    }
    const int64_t v = en.net[r];
    const int8_t val = static_cast<int8_t>(std::max<int64_t>(-127, std::min<int64_t>(127, v)));
    for (int q = 0; q < 4; ++q) {
      // The cell at position q has this edge as its edge a * 4 + (q + 2) % 4.
      const int slot = a * 4 + (q + 2) % 4;
      int64_t o[3];
      edge_offset(slot, o);
      bool inside = true;
      int64_t c = 0;
      for (int k = 0; k < 3; ++k) {
        const int64_t x = node[k] - o[k];
        inside = inside && x >= 0 && x < n[k];
        c = c * n[k] + x;
      }
      if (!inside) continue;
      const int64_t at = hint[q] < 0 ? std::lower_bound(index, index + K, c) - index
                                     : gallop(index, K, hint[q], c);
      hint[q] = at;
      if (at < K && index[at] == c) {
        S[12 * at + slot] = val;
      } else {
        missing->push_back(c);
        missing->push_back(en.first[r]);
      }
    }
  }
}

}  // namespace fc
}  // namespace voxax

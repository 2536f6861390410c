// Marching cubes (3D) and marching squares (2D) on samples at grid cell
// centres.
//
// Topology only: the kernels output, per vertex, the two flat cell indices of
// the crossed centre-to-centre grid edge (a < b), and faces as vertex indices;
// the vertex positions are interpolated by the caller (in JAX, so that they are
// differentiable in the samples).
//
// Conventions:
// - A sample g = f - level is "positive" when g >= 0 (ties count as positive),
//   so a crossed edge always joins a positive and a strictly negative sample.
// - One vertex per crossed grid edge. Vertices are numbered in increasing edge
//   id, edge id = 3 * (flat index of the lower cell) + axis (2D: 2 * ... +
//   axis).
// - Faces are listed cube by cube in C order (x slowest), in the order of the
//   cube's case entry. Triangles are oriented with their normals pointing
//   towards the positive side (increasing f).
// - The per-cube case handling is derived when first used (not copied from any
//   table) from a face-by-face rule: on every cube face the crossing points are
//   joined by segments, on ambiguous faces (diagonal corners of equal sign) by
//   the asymptotic decider, which sees only that face's four samples, so both
//   cubes sharing the face choose the same segments. The segments close into
//   loops on the cube's boundary; each loop is triangulated as a fan. The
//   result is a closed, 2-manifold, consistently oriented surface wherever the
//   level set does not reach the grid's boundary.
//
// Work is split into fixed chunks of x slices; every output position follows
// from prefix sums of per-slice counts, so the result does not depend on how
// chunks are assigned to threads.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <memory>
#include <utility>
#include <vector>

namespace voxax {
namespace contour {

// -- the cube and its case table
// -------------------------------------------------------

// Corner c of a cube has offsets (c & 1, (c >> 1) & 1, (c >> 2) & 1) along x,
// y, z. Edge e runs along axis e / 4 from corner edge_base(e) to edge_base(e) |
// (1 << axis).
inline int edge_axis(int e) { return e / 4; }
inline int edge_base(int e) {
  const int a = e / 4, r = e % 4, u = (a + 1) % 3, w = (a + 2) % 3;
  return ((r & 1) << u) | (((r >> 1) & 1) << w);
}
inline int edge_between(int c1, int c2) {
  const int diff = c1 ^ c2;
  const int a = diff == 1 ? 0 : diff == 2 ? 1 : 2;
  const int base = c1 & ~diff, u = (a + 1) % 3, w = (a + 2) % 3;
  return a * 4 + (((base >> u) & 1) | (((base >> w) & 1) << 1));
}
// The four corners of face f = 2 * axis + side, counter-clockwise seen from
// outside the cube.
inline void face_corners(int f, int q[4]) {
  const int a = f / 2, s = f % 2, u = (a + 1) % 3, w = (a + 2) % 3;
  static const int ccw[4][2] = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  for (int k = 0; k < 4; ++k) {
    const int kk = s ? k : (4 - k) % 4;  // reversed order on the lower side
    q[k] = (s << a) | (ccw[kk][0] << u) | (ccw[kk][1] << w);
  }
}

// Joins the crossings of one face (corners q in cyclic order, positive flags p)
// into directed segments next[from] = to. `connected` selects, on an ambiguous
// face, whether the positive corners are joined through the face centre.
// `edge_of(k)` gives the id of the edge between q[k] and q[k + 1].
template <typename EdgeOf>
inline void face_segments(const int q[4], const bool p[4], bool connected, EdgeOf edge_of,
                          int* next) {
  // Crossings in cyclic order: type A goes negative -> positive, type B the
  // reverse.
  int edge[4], type_a[4], m = 0;
  for (int k = 0; k < 4; ++k) {
    const bool p0 = p[k], p1 = p[(k + 1) % 4];
    if (p0 != p1) {
      edge[m] = edge_of(k);
      type_a[m] = p1 ? 1 : 0;
      ++m;
    }
  }
  (void)q;
  if (m == 0) return;
  // Segments run from a B crossing to an A crossing. Cutting off the positive
  // runs pairs each A with the following B; cutting off the negative runs
  // pairs each B with the following A.
  const bool cut_positive = (m == 2) ? true : !connected;
  for (int i = 0; i < m; ++i) {
    const int j = (i + 1) % m;
    if (cut_positive && type_a[i]) next[edge[j]] = edge[i];
    if (!cut_positive && !type_a[i]) next[edge[i]] = edge[j];
  }
}

struct CubeTable {
  // Index: config (bit c: corner c positive) | (decisions << 8), where bit f of
  // `decisions` says whether ambiguous face f joins its positive corners.
  static constexpr int kEntries = 256 * 64;
  static constexpr int kMaxTriangles = 12;
  uint8_t count[kEntries];
  uint8_t tri[kEntries][kMaxTriangles][3];
  uint8_t ambiguous[256];  // bit f: face f is ambiguous for this config
  int face_q[6][4];        // corners of each face, counter-clockwise from outside
  int failures = 0;        // loops without a valid triangulation (none expected)

  CubeTable() {
    for (int f = 0; f < 6; ++f) face_corners(f, face_q[f]);
    for (int cfg = 0; cfg < 256; ++cfg) {
      uint8_t amb = 0;
      for (int f = 0; f < 6; ++f) {
        bool p[4];
        for (int k = 0; k < 4; ++k) p[k] = (cfg >> face_q[f][k]) & 1;
        if (p[0] == p[2] && p[1] == p[3] && p[0] != p[1]) amb |= uint8_t(1 << f);
      }
      ambiguous[cfg] = amb;
      for (int dec = 0; dec < 64; ++dec) build(cfg, dec);
    }
  }

  void build(int cfg, int dec) {
    const int idx = cfg | (dec << 8);
    int next[12];
    for (int e = 0; e < 12; ++e) next[e] = -1;
    for (int f = 0; f < 6; ++f) {
      const int* q = face_q[f];
      bool p[4];
      for (int k = 0; k < 4; ++k) p[k] = (cfg >> q[k]) & 1;
      face_segments(
          q, p, (dec >> f) & 1, [&](int k) { return edge_between(q[k], q[(k + 1) % 4]); }, next);
    }
    int n = 0;
    bool seen[12] = {false};
    for (int e0 = 0; e0 < 12; ++e0) {
      if (next[e0] < 0 || seen[e0]) continue;
      int loop[12], len = 0;
      for (int e = e0; !seen[e]; e = next[e]) {
        seen[e] = true;
        loop[len++] = e;
      }
      int out[kMaxTriangles][3], m = 0;
      if (!triangulate(loop, len, next, forbidden_faces(cfg), out, &m)) ++failures;
      for (int t = 0; t < m; ++t, ++n)
        for (int v = 0; v < 3; ++v) tri[idx][n][v] = uint8_t(out[t][v]);
    }
    count[idx] = uint8_t(n);
  }

  // Diagonals this cube may not place within its ambiguous faces. On a face
  // with four crossings, the two loop segments leave four possible in-face
  // diagonals: two join crossings on neighbouring face edges, two join
  // crossings on opposite face edges. The cube below the face (the face is its
  // upper side) may use only the opposite-edge ones, the cube above only the
  // neighbouring-edge ones, so the two cubes never share a diagonal.
  // Bits 0-5: faces forbidding neighbouring-edge diagonals; bits 6-11: faces
  // forbidding opposite-edge diagonals.
  int forbidden_faces(int cfg) const {
    int mask = 0;
    for (int f = 0; f < 6; ++f) {
      if (!((ambiguous[cfg] >> f) & 1)) continue;
      mask |= (f % 2) ? 1 << f : 1 << (6 + f);
    }
    return mask;
  }

  // The cube faces edge e lies on, as a bit mask.
  static int faces_of_edge(int e) {
    const int a = edge_axis(e), base = edge_base(e);
    int mask = 0;
    for (int u = 0; u < 3; ++u)
      if (u != a) mask |= 1 << (2 * u + ((base >> u) & 1));
    return mask;
  }

  // Whether the segment x-y may be a triangle side: a side of the loop, a
  // diagonal between crossings that share no cube face, or an in-face diagonal
  // this cube is allowed (see forbidden_faces). An in-face diagonal (only
  // possible on an ambiguous face) used by both cubes sharing the face would
  // be a triangle side shared by four triangles.
  static bool side_ok(int x, int y, const int* next, int forbid) {
    if (next[x] == y || next[y] == x) return true;
    const int shared = faces_of_edge(x) & faces_of_edge(y);
    // Crossings on edges of different axes are neighbours on the face; on edges
    // of the same axis they sit on opposite sides of it.
    const int mask = edge_axis(x) != edge_axis(y) ? (forbid & 63) : (forbid >> 6);
    return !(shared & mask);
  }
  static bool tri_ok(int a, int b, int c, const int* next, int forbid) {
    return side_ok(a, b, next, forbid) && side_ok(b, c, next, forbid) &&
           side_ok(c, a, next, forbid);
  }

  // Triangulates a loop with only allowed sides; tries each fan apex first,
  // then any triangulation. Returns false when none exists.
  static bool triangulate(const int* loop, int len, const int* next, int forbid, int out[][3],
                          int* m) {
    for (int apex = 0; apex < len; ++apex) {
      int rot[12];
      for (int i = 0; i < len; ++i) rot[i] = loop[(apex + i) % len];
      bool ok = true;
      for (int i = 1; i + 1 < len && ok; ++i) ok = tri_ok(rot[0], rot[i], rot[i + 1], next, forbid);
      if (!ok) continue;
      for (int i = 1; i + 1 < len; ++i) {
        out[*m][0] = rot[0];
        out[*m][1] = rot[i];
        out[*m][2] = rot[i + 1];
        ++*m;
      }
      return true;
    }
    return split(loop, len, next, forbid, out, m);
  }

  static bool split(const int* poly, int len, const int* next, int forbid, int out[][3], int* m) {
    if (len < 3) return true;
    const int start = *m;
    for (int k = 2; k < len; ++k) {
      if (!tri_ok(poly[0], poly[1], poly[k], next, forbid)) continue;
      *m = start;
      out[*m][0] = poly[0];
      out[*m][1] = poly[1];
      out[*m][2] = poly[k];
      ++*m;
      int left[12], right[12], nl = 0, nr = 0;
      for (int i = 1; i <= k; ++i) left[nl++] = poly[i];
      for (int i = k; i < len; ++i) right[nr++] = poly[i];
      right[nr++] = poly[0];
      if (split(left, nl, next, forbid, out, m) && split(right, nr, next, forbid, out, m))
        return true;
    }
    *m = start;
    return false;
  }
};

inline const CubeTable& cube_table() {
  static const CubeTable* table = new CubeTable();  // built once, thread-safe
  return *table;
}

// Marching squares: corner c = (c & 1, c >> 1); square edges 0, 1 run along x
// (at y = 0, 1), edges 2, 3 along y (at x = 0, 1).
struct SquareTable {
  uint8_t count[32];
  uint8_t seg[32][2][2];
  SquareTable() {
    const int q[4] = {0, 1, 3, 2};  // counter-clockwise
    for (int cfg = 0; cfg < 16; ++cfg)
      for (int dec = 0; dec < 2; ++dec) {
        const int idx = cfg | (dec << 4);
        int next[4] = {-1, -1, -1, -1};
        bool p[4];
        for (int k = 0; k < 4; ++k) p[k] = (cfg >> q[k]) & 1;
        face_segments(
            q, p, dec,
            [&](int k) {
              const int c1 = q[k], c2 = q[(k + 1) % 4], diff = c1 ^ c2, base = c1 & ~diff;
              return diff == 1 ? (base >> 1) : 2 + (base & 1);
            },
            next);
        int n = 0;
        for (int e = 0; e < 4; ++e)
          if (next[e] >= 0) {
            // Reversed, so that loops run counter-clockwise around the negative
            // side.
            seg[idx][n][0] = uint8_t(next[e]);
            seg[idx][n][1] = uint8_t(e);
            ++n;
          }
        count[idx] = uint8_t(n);
      }
  }
};

inline const SquareTable& square_table() {
  static const SquareTable* table = new SquareTable();
  return *table;
}

// Whether the positive corners of an ambiguous face are joined through the
// face: the bilinear saddle value is >= level. With p1, p2 the positive and n1,
// n2 the negative diagonal (g = f - level), the saddle value is
// (p1 p2 - n1 n2) / (p1 + p2 - n1 - n2) and the denominator is positive.
// Both cubes sharing a face evaluate the same two products. The comparison is
// that of the exact products (scale-invariant): where a rounded product leaves
// the normal range (below about 1e-154 or above 1e154 per factor) the products
// are compared as mantissa and exponent; elsewhere the rounded products give
// the same answer.
inline bool face_connected(double p1, double p2, double n1, double n2) {
  const double a = p1 * p2, b = n1 * n2;
  const double lo = std::numeric_limits<double>::min();
  const double hi = std::numeric_limits<double>::max();
  if ((a >= lo || a == 0.0) && b >= lo && a <= hi && b <= hi) {
    // a == 0 only when p1 or p2 is 0 (b > 0: the negative samples are not 0)
    if (a != 0.0 || p1 == 0.0 || p2 == 0.0) return a >= b;
  }
  if (p1 == 0.0 || p2 == 0.0) return false;  // b > 0
  int e1, e2, e3, e4, ea, eb;
  double ma = std::frexp(std::frexp(p1, &e1) * std::frexp(p2, &e2), &ea);
  double mb = std::frexp(std::frexp(n1, &e3) * std::frexp(n2, &e4), &eb);
  ea += e1 + e2;
  eb += e3 + e4;
  return ea != eb ? ea > eb : ma >= mb;
}

// -- the sweep
// -------------------------------------------------------------------------

struct Shape {
  int dim = 3;
  int64_t n[3] = {1, 1, 1};
  int64_t slice() const { return dim == 3 ? n[1] * n[2] : n[1]; }
  int64_t cells() const { return n[0] * slice(); }
};

// Whether the grid has at least one cube (square): 2 cells on every axis.
inline bool has_cells(const Shape& s) {
  return s.n[0] > 1 && s.n[1] > 1 && (s.dim == 2 || s.n[2] > 1);
}

// Fixed chunking of the x slices: independent of the number of threads.
inline int64_t chunk_slices(const Shape& s) {
  const int64_t target = int64_t{1} << 20;  // cells per chunk, roughly
  return std::max<int64_t>(1, target / std::max<int64_t>(1, s.slice()));
}

template <typename T>
struct Sampler {
  const T* v;
  double level;
  double g(int64_t idx) const { return static_cast<double>(v[idx]) - level; }
};

// Per x slice i: the crossed edges whose lower cell lies in slice i, and the
// faces of the cubes (squares) between slices i and i + 1.
struct Counts {
  double lo = 0, hi = 0;             // the smallest and largest sample (after the count pass)
  bool non_finite = false;           // a sample is NaN or infinite
  std::unique_ptr<uint8_t[]> signs;  // 1 where g >= 0, per cell (after the count pass)
  std::vector<int64_t> vertices;     // per slice
  std::vector<int64_t> faces;        // per slice
  std::vector<int64_t> voff, foff;   // exclusive prefix sums, size n[0] + 1
  int64_t total_vertices() const { return voff.back(); }
  int64_t total_faces() const { return foff.back(); }
  void finish() {
    const size_t n = vertices.size();
    voff.assign(n + 1, 0);
    foff.assign(n + 1, 0);
    for (size_t i = 0; i < n; ++i) {
      voff[i + 1] = voff[i] + vertices[i];
      foff[i + 1] = foff[i] + faces[i];
    }
  }
};

// Signs of one slice: 1 where g >= 0.
template <typename T>
inline void slice_signs(const Sampler<T>& s, const Shape& sh, int64_t i, uint8_t* out) {
  const int64_t m = sh.slice(), base = i * m;
  const T* v = s.v + base;
  // (double)v - level >= 0 exactly when (double)v >= level; when the level is a
  // value of T the comparison can stay in T.
  const T lt = static_cast<T>(s.level);
  if (static_cast<double>(lt) == s.level) {
    for (int64_t c = 0; c < m; ++c) out[c] = v[c] >= lt;
  } else {
    const double level = s.level;
    for (int64_t c = 0; c < m; ++c) out[c] = static_cast<double>(v[c]) >= level;
  }
}

template <typename T>
inline int cube_index_of(const Sampler<T>& s, const Shape& sh, const CubeTable& tb, int64_t i,
                         int64_t j, int64_t k, int cfg);

// The range of the samples of a chunk, and whether one is NaN (a NaN is never
// selected by the comparisons; an infinity ends up in lo or hi).
struct Range {
  double lo = std::numeric_limits<double>::infinity();
  double hi = -std::numeric_limits<double>::infinity();
  bool nan = false;
};

template <typename T>
inline void slice_range(const Sampler<T>& s, const Shape& sh, int64_t i, Range* r) {
  const int64_t m = sh.slice();
  const T* v = s.v + i * m;
  T lo = std::numeric_limits<T>::infinity(), hi = -lo;
  unsigned nan = 0;
  for (int64_t c = 0; c < m; ++c) {
    const T x = v[c];
    lo = x < lo ? x : lo;
    hi = x > hi ? x : hi;
    nan |= unsigned(x != x);
  }
  r->lo = std::min(r->lo, double(lo));
  r->hi = std::max(r->hi, double(hi));
  r->nan = r->nan || nan;
}

// The table index of cube (i, j, k) given the signs of slices i and i + 1.
template <typename T>
inline int cube_index(const Sampler<T>& s, const Shape& sh, const CubeTable& tb, int64_t i,
                      int64_t j, int64_t k, const uint8_t* s0, const uint8_t* s1) {
  const int64_t nz = sh.n[2];
  const int64_t r0 = j * nz + k, r1 = r0 + nz;
  const int cfg = s0[r0] | (s1[r0] << 1) | (s0[r1] << 2) | (s1[r1] << 3) | (s0[r0 + 1] << 4) |
                  (s1[r0 + 1] << 5) | (s0[r1 + 1] << 6) | (s1[r1 + 1] << 7);
  return cube_index_of(s, sh, tb, i, j, k, cfg);
}

// The table index of cube (i, j, k) of sign configuration `cfg` (see
// row_configs): the configuration, with the decider's bits on ambiguous faces.
template <typename T>
inline int cube_index_of(const Sampler<T>& s, const Shape& sh, const CubeTable& tb, int64_t i,
                         int64_t j, int64_t k, int cfg) {
  const int64_t nz = sh.n[2];
  const int64_t r0 = j * nz + k;
  const int amb = tb.ambiguous[cfg];
  if (!amb) return cfg;
  int dec = 0;
  const int64_t m = sh.slice(), base = i * m + r0;
  for (int f = 0; f < 6; ++f) {
    if (!((amb >> f) & 1)) continue;
    const int* q = tb.face_q[f];
    double g[4];
    for (int t = 0; t < 4; ++t) {
      const int c = q[t];
      g[t] = s.g(base + (c & 1) * m + ((c >> 1) & 1) * nz + ((c >> 2) & 1));
    }
    // Corners q[0], q[2] share a sign, as do q[1], q[3].
    const bool even_positive = g[0] >= 0.0;
    const bool conn = even_positive ? face_connected(g[0], g[2], g[1], g[3])
                                    : face_connected(g[1], g[3], g[0], g[2]);
    if (conn) dec |= 1 << f;
  }
  return cfg | (dec << 8);
}

template <typename T>
inline int square_index(const Sampler<T>& s, const Shape& sh, int64_t i, int64_t j,
                        const uint8_t* s0, const uint8_t* s1) {
  const int cfg = s0[j] | (s1[j] << 1) | (s0[j + 1] << 2) | (s1[j + 1] << 3);
  if (cfg != 6 && cfg != 9) return cfg;
  const int64_t ny = sh.n[1], a = i * ny + j;
  const double g00 = s.g(a), g10 = s.g(a + ny), g01 = s.g(a + 1), g11 = s.g(a + ny + 1);
  // cfg 9: corners 0 and 3 ((0,0), (1,1)) positive; cfg 6: corners 1 and 2.
  const bool conn =
      cfg == 9 ? face_connected(g00, g11, g10, g01) : face_connected(g10, g01, g00, g11);
  return cfg | (conn ? 16 : 0);
}

// Whether any edge of a row of cells differs in sign: along the row (r0[k] vs
// r0[k + 1]) and to the rows given (null: none). Written for vectorization.
inline bool row_varies(const uint8_t* r0, int64_t len, const uint8_t* a, const uint8_t* b,
                       const uint8_t* c) {
  unsigned acc = 0;
  for (int64_t k = 0; k + 1 < len; ++k) acc |= unsigned(r0[k] ^ r0[k + 1]);
  if (a)
    for (int64_t k = 0; k < len; ++k) acc |= unsigned(r0[k] ^ a[k]);
  if (b)
    for (int64_t k = 0; k < len; ++k) acc |= unsigned(r0[k] ^ b[k]);
  if (c)
    for (int64_t k = 0; k < len; ++k) acc |= unsigned(r0[k] ^ c[k]);
  return acc != 0;
}

// The sign configurations of the cubes of one row (cube k joins cells k and
// k + 1 of rows a0, b0 of slice i and a1, b1 of slice i + 1; b = a + nz):
// out[k], k < len - 1, with bit c for corner c as in cube_index. Branch-free,
// written for vectorization.
inline void row_configs(const uint8_t* a0, const uint8_t* a1, int64_t len, int64_t nz,
                        uint8_t* out) {
  const uint8_t* b0 = a0 + nz;
  const uint8_t* b1 = a1 + nz;
  for (int64_t k = 0; k + 1 < len; ++k)
    out[k] = uint8_t(a0[k] | (a1[k] << 1) | (b0[k] << 2) | (b1[k] << 3) | (a0[k + 1] << 4) |
                     (a1[k + 1] << 5) | (b0[k + 1] << 6) | (b1[k + 1] << 7));
}

// Whether the 8 bytes at p are all 0 or all 255 (uniform cubes, or no crossed
// edge).
inline bool word_uniform(const uint8_t* p) {
  uint64_t w;
  std::memcpy(&w, p, 8);
  return w == 0 || w == ~uint64_t{0};
}

// Calls body(k) for every k < n with cfg[k] not 0 or 255 (a cube with a
// crossing), in increasing k; runs of uniform cubes are skipped 8 at a time.
template <typename Body>
inline void for_crossed(const uint8_t* cfg, int64_t n, Body&& body) {
  int64_t k = 0;
  for (; k + 8 <= n; k += 8) {
    if (word_uniform(cfg + k)) continue;
    for (int64_t t = k; t < k + 8; ++t)
      if (cfg[t] != 0 && cfg[t] != 255) body(t);
  }
  for (; k < n; ++k)
    if (cfg[k] != 0 && cfg[k] != 255) body(k);
}

// Crossed edges of one row counted without branches: along the row and to the
// rows given (null: none).
inline int64_t row_edge_count(const uint8_t* r, int64_t len, const uint8_t* rx, const uint8_t* ry) {
  uint32_t n = 0;
  for (int64_t k = 0; k + 1 < len; ++k) n += uint32_t(r[k] ^ r[k + 1]);
  if (rx)
    for (int64_t k = 0; k < len; ++k) n += uint32_t(r[k] ^ rx[k]);
  if (ry)
    for (int64_t k = 0; k < len; ++k) n += uint32_t(r[k] ^ ry[k]);
  return n;
}

// Crossed edges owned by slice i (its cells are their lower ends), counted or
// numbered. When `map` (size dim * slice) is given, map[dim * cell + axis]
// receives the vertex id of every crossed edge; other entries are not written.
// When `edges` is given, the crossed edges' cell pairs are written there too
// (ids below `vcap` only).
inline int64_t slice_edges(const Shape& sh, int64_t i, const uint8_t* s0, const uint8_t* s1,
                           int64_t first, int32_t* map, int32_t* edges = nullptr,
                           int64_t vcap = 0) {
  const bool has_next = i + 1 < sh.n[0];
  int64_t id = first;
  const int64_t m = sh.slice(), base = i * m;
  auto put = [&](int64_t vid, int64_t cell, int64_t stride) {
    if (edges && vid < vcap) {
      edges[2 * vid] = int32_t(cell);
      edges[2 * vid + 1] = int32_t(cell + stride);
    }
  };
  if (sh.dim == 3) {
    const int64_t ny = sh.n[1], nz = sh.n[2];
    std::vector<uint8_t> cross(map ? size_t(nz) : 0);
    for (int64_t j = 0; j < ny; ++j) {
      const int64_t c0 = j * nz;
      const uint8_t* r = s0 + c0;
      const uint8_t* rx = has_next ? s1 + c0 : nullptr;
      const uint8_t* ry = j + 1 < ny ? r + nz : nullptr;
      if (!map) {
        id += row_edge_count(r, nz, rx, ry);
        continue;
      }
      if (!row_varies(r, nz, rx, ry, nullptr)) continue;
      // Bits 0, 1, 2 of cross[k]: the edges along x, y, z from cell k cross.
      uint8_t* cr = cross.data();
      for (int64_t k = 0; k + 1 < nz; ++k) cr[k] = uint8_t((r[k] ^ r[k + 1]) << 2);
      cr[nz - 1] = 0;
      if (rx)
        for (int64_t k = 0; k < nz; ++k) cr[k] |= uint8_t(r[k] ^ rx[k]);
      if (ry)
        for (int64_t k = 0; k < nz; ++k) cr[k] |= uint8_t((r[k] ^ ry[k]) << 1);
      int64_t k = 0;
      auto cell_edges = [&](int64_t kk) {
        const int b = cr[kk];
        if (!b) return;
        const int cx = b & 1, cy = (b >> 1) & 1, cz = b >> 2;
        int32_t* mp = map + 3 * (c0 + kk);
        const int64_t cell = base + c0 + kk;
        if (cx) mp[0] = int32_t(id), put(id, cell, m);
        if (cy) mp[1] = int32_t(id + cx), put(id + cx, cell, nz);
        if (cz) mp[2] = int32_t(id + cx + cy), put(id + cx + cy, cell, 1);
        id += cx + cy + cz;
      };
      for (; k + 8 <= nz; k += 8) {
        uint64_t w;
        std::memcpy(&w, cr + k, 8);
        if (!w) continue;
        for (int64_t t = k; t < k + 8; ++t) cell_edges(t);
      }
      for (; k < nz; ++k) cell_edges(k);
    }
  } else {
    const int64_t ny = sh.n[1];
    if (!row_varies(s0, ny, has_next ? s1 : nullptr, nullptr, nullptr)) return 0;
    for (int64_t j = 0; j < ny; ++j) {
      const uint8_t a = s0[j];
      const bool cx = has_next && s1[j] != a;
      const bool cy = j + 1 < ny && s0[j + 1] != a;
      if (map) {
        if (cx) map[2 * j] = int32_t(id), put(id, base + j, m);
        if (cy) map[2 * j + 1] = int32_t(id + cx), put(id + cx, base + j, 1);
      }
      id += cx + cy;
    }
  }
  return id - first;
}

// Faces of the cubes between slices i and i + 1 (counted only).
template <typename T>
inline int64_t slab_face_count(const Sampler<T>& s, const Shape& sh, int64_t i, const uint8_t* s0,
                               const uint8_t* s1) {
  int64_t n = 0;
  if (sh.dim == 3) {
    const CubeTable& tb = cube_table();
    const int64_t ny = sh.n[1], nz = sh.n[2];
    std::vector<uint8_t> cfg(size_t(std::max<int64_t>(nz - 1, 1)));
    for (int64_t j = 0; j + 1 < ny; ++j) {
      const uint8_t* a0 = s0 + j * nz;
      const uint8_t* a1 = s1 + j * nz;
      if (!row_varies(a0, nz, a1, a0 + nz, a1 + nz)) continue;
      row_configs(a0, a1, nz, nz, cfg.data());
      for_crossed(cfg.data(), nz - 1, [&](int64_t k) {
        n += tb.count[cube_index_of(s, sh, tb, i, j, k, cfg[size_t(k)])];
      });
    }
  } else {
    const SquareTable& tb = square_table();
    for (int64_t j = 0; j + 1 < sh.n[1]; ++j) n += tb.count[square_index(s, sh, i, j, s0, s1)];
  }
  return n;
}

// Pass 1: per-slice counts. `run(n, body)` runs body(c) for c in [0, n).
template <typename T, typename Run>
bool count_pass(const Sampler<T>& s, const Shape& sh, Run&& run, Counts* out) {
  const int64_t nx = sh.n[0], m = sh.slice(), cs = chunk_slices(sh);
  const int64_t chunks = (nx + cs - 1) / cs;
  out->vertices.assign(nx, 0);
  out->faces.assign(nx, 0);
  if (!has_cells(sh)) {
    Range all;
    for (int64_t i = 0; i < nx; ++i) slice_range(s, sh, i, &all);
    out->lo = all.lo;
    out->hi = all.hi;
    out->non_finite = all.nan || !std::isfinite(all.lo) || !std::isfinite(all.hi);
    out->finish();
    return true;
  }
  std::vector<Range> ranges(size_t(std::max<int64_t>(chunks, 1)));
  // The signs of every slice, kept for the fill pass (one byte per cell).
  out->signs.reset(new uint8_t[size_t(nx * m)]);
  uint8_t* signs = out->signs.get();
  bool ok = run(chunks, [&](int64_t c) {
    const int64_t i1 = std::min(nx, (c + 1) * cs);
    for (int64_t i = c * cs; i < i1; ++i) {
      slice_signs(s, sh, i, signs + i * m);
      slice_range(s, sh, i, &ranges[size_t(c)]);
    }
  });
  ok = ok && run(chunks, [&](int64_t c) {
         const int64_t i1 = std::min(nx, (c + 1) * cs);
         for (int64_t i = c * cs; i < i1; ++i) {
           const bool has_next = i + 1 < nx;
           const uint8_t* a = signs + i * m;
           const uint8_t* b = has_next ? a + m : a;
           out->vertices[i] = slice_edges(sh, i, a, b, 0, nullptr);
           if (has_next) out->faces[i] = slab_face_count(s, sh, i, a, b);
         }
       });
  if (!ok) return false;
  Range all;
  for (const Range& r : ranges) {
    all.lo = std::min(all.lo, r.lo);
    all.hi = std::max(all.hi, r.hi);
    all.nan = all.nan || r.nan;
  }
  out->lo = all.lo;
  out->hi = all.hi;
  out->non_finite = all.nan || !std::isfinite(all.lo) || !std::isfinite(all.hi);
  out->finish();
  return true;
}

// Pass 2: writes the vertices' cell pairs (edges, (V, 2)) and the faces
// ((F, dim)). Entries at or beyond the capacities are not written.
template <typename T, typename Run>
bool fill_pass(const Sampler<T>& s, const Shape& sh, const Counts& cnt, Run&& run, int32_t* edges,
               int64_t vcap, int32_t* faces, int64_t fcap) {
  const int64_t nx = sh.n[0], m = sh.slice(), cs = chunk_slices(sh);
  const int64_t chunks = (nx + cs - 1) / cs;
  const int d = sh.dim;
  if (!has_cells(sh)) return true;
  return run(chunks, [&](int64_t c) {
    const int64_t i0 = c * cs, i1 = std::min(nx, i0 + cs);
    const uint8_t* signs = cnt.signs.get();
    const uint8_t* sa = signs + i0 * m;
    const uint8_t* sb = i0 + 1 < nx ? sa + m : sa;
    const uint8_t* sc = sb;
    // Map entries are written before they are read (crossed edges only).
    std::unique_ptr<int32_t[]> map_a(new int32_t[d * m]), map_b(new int32_t[d * m]);
    int32_t* ma = map_a.get();
    int32_t* mb = map_b.get();
    // Slice i's map needs the signs of slices i and i + 1.
    slice_edges(sh, i0, sa, sb, cnt.voff[i0], ma, edges, vcap);
    for (int64_t i = i0; i < i1; ++i) {
      const bool has_next = i + 1 < nx;
      if (!has_next) break;
      // Map of slice i + 1 (needs the signs of slice i + 2).
      sc = i + 2 < nx ? signs + (i + 2) * m : sb;
      // Slice i + 1's vertices are written by the chunk that owns the slice.
      slice_edges(sh, i + 1, sb, sc, cnt.voff[i + 1], mb, i + 1 < i1 ? edges : nullptr, vcap);
      // Faces of slab i.
      int64_t fid = cnt.foff[i];
      {
        if (d == 3) {
          const CubeTable& tb = cube_table();
          const int64_t ny = sh.n[1], nz = sh.n[2];
          std::vector<uint8_t> cfg(size_t(std::max<int64_t>(nz - 1, 1)));
          for (int64_t j = 0; j + 1 < ny; ++j) {
            const uint8_t* a0 = sa + j * nz;
            const uint8_t* a1 = sb + j * nz;
            if (!row_varies(a0, nz, a1, a0 + nz, a1 + nz)) continue;
            row_configs(a0, a1, nz, nz, cfg.data());
            for_crossed(cfg.data(), nz - 1, [&](int64_t k) {
              const int idx = cube_index_of(s, sh, tb, i, j, k, cfg[size_t(k)]);
              const int nt = tb.count[idx];
              for (int t = 0; t < nt; ++t, ++fid) {
                if (fid >= fcap) continue;
                for (int v = 0; v < 3; ++v) {
                  const int e = tb.tri[idx][t][v];
                  const int base = edge_base(e), axis = edge_axis(e);
                  const int64_t cell = (j + ((base >> 1) & 1)) * nz + k + ((base >> 2) & 1);
                  const int32_t* mp = (base & 1) ? mb : ma;
                  faces[3 * fid + v] = mp[3 * cell + axis];
                }
              }
            });
          }
        } else {
          const SquareTable& tb = square_table();
          for (int64_t j = 0; j + 1 < sh.n[1]; ++j) {
            const int idx = square_index(s, sh, i, j, sa, sb);
            const int ns = tb.count[idx];
            for (int t = 0; t < ns; ++t, ++fid) {
              if (fid >= fcap) continue;
              for (int v = 0; v < 2; ++v) {
                const int e = tb.seg[idx][t][v];
                // Edges 0, 1: along x at y = e; edges 2, 3: along y at x = e
                // - 2.
                const int axis = e < 2 ? 0 : 1;
                const int dx = e < 2 ? 0 : e - 2, dy = e < 2 ? e : 0;
                const int32_t* mp = dx ? mb : ma;
                faces[2 * fid + v] = mp[2 * (j + dy) + axis];
              }
            }
          }
        }
      }
      sa = sb;
      sb = sc;
      std::swap(ma, mb);
    }
  });
}

}  // namespace contour
}  // namespace voxax

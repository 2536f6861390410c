// Generalised winding numbers of a triangle mesh at points, in float64.
//
// The exact sum: w(p) = (1 / 4 pi) sum_t Omega_t(p), the signed solid angles of the
// triangles by the formula of Van Oosterom and Strackee (1983), added in face order; a
// point in the plane of a triangle (zero triple product) gets 0 from it, so points on a
// closed surface get the average of the two sides (1/2 on a face).
//
// Closed meshes: where every edge {i, j} is used as often from i to j as from j to i
// (the faces form a cycle: closed, or closed up to faces paired with their reverses),
// the solid-angle sum is the integer signed crossing count of any ray from p. One ray per
// point, through the tree of winding_rays.h (all rays run along one direction), gives it in
// O(log F); where that ray meets an edge or a vertex exactly, or p lies within rounding of a
// face it meets, the point falls back to the exact sum, so the result is always the
// solid-angle sum's value: the integer, or the half-integers of points on the surface.
//
// Open meshes with a small boundary: the boundary dS of the faces S (boundary_edges) is a
// 1-cycle, and a cap C over it (boundary_cap: dC = dS, built from the boundary's vertices)
// makes S - C a closed 2-cycle, whose solid-angle sum at p is the crossing count of one ray
// through S and C reversed; w_S(p) = w_{S-C}(p) + w_C(p), the second term the cap's sum
// (CapSum, exact) or its hierarchy's bounded expansion. C may cross S or itself: S - C is a
// cycle all the same. Points whose ray is unclear (on S or C, or meeting an edge) take the
// exact sum over S.
//
// Approximate, error-bounded evaluation (WindingTree::eval_approx), after Barill et al.
// (2018): a node's triangles seen from far away are replaced by the Taylor expansion, to
// third order, of the dipole kernel K(y) = y / |y|^3 about the node's centre c, whose
// coefficients are the exact moments of the triangles' area-weighted normals (order 0:
// their sum; 1 to 3: their moments with d = x - c, d (x) d, d (x) d (x) d, integrated
// exactly over each triangle). The remainder has a rigorous bound: with r = c - p,
// rho = |r|, every triangle point within R of c and q = R / rho < 1, the Legendre series
// of 1 / |r + d| gives the order-l term of K(r + d) as -grad_r of |d|^l P_l(cos) /
// rho^(l + 1), whose magnitude is at most (l + 1) |d|^l / rho^(l + 2) (in spherical
// coordinates about d, |grad|^2 rho^(2 l + 4) = (l + 1)^2 P_l^2 + (1 - x^2) P_l'^2, and
// P_l^2 + (1 - x^2) P_l'^2 / (l (l + 1)) <= 1 on [-1, 1]: by Legendre's equation its
// derivative is 2 x P_l'^2 / (l (l + 1)), so its maximum is at x = +-1, where it is 1).
// Truncated after order 3, a node's solid angle is therefore off by at most
//   sum_{l >= 4} (l + 1) int |d|^l dA / rho^(l + 2)
//     <= (5 mu4 + mu5 q (6 - 5 q) / (1 - q)^2) / rho^6,   mu_k >= int |d|^k dA,
// using int |d|^l dA <= R^(l - 5) mu5 for l >= 5; |d|^k is convex, so its mean over a
// triangle is at most the mean of its corners' values, which gives mu4 and mu5. A point's
// error budget 4 pi eps (in solid-angle units) is shared out during the traversal: a
// node may spend at most (budget left) * (its area) / (area not yet visited), so the
// spent bounds never add up to more than the budget. A node whose bound exceeds its share
// takes its exact boundary fan when the point is outside its box (unless descending looks
// cheaper: both children fit their shares, or the bound is not far above the share), else
// descends, down to the exact triangles of the leaves.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace voxax {
namespace spatial {

// Van Oosterom and Strackee's terms of the solid angle 2 atan2(num, den) of the triangle
// with corners p + a, p + b, p + c at p: num = a . (b x c), and den from the corners'
// lengths la, lb, lc. Every evaluation of the solid angle goes through these two, so all
// round the same.
inline double solid_angle_num(const double* a, const double* b, const double* c) {
  const double bc[3] = {b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2],
                        b[0] * c[1] - b[1] * c[0]};
  return a[0] * bc[0] + a[1] * bc[1] + a[2] * bc[2];
}
inline double solid_angle_den(const double* a, const double* b, const double* c, double la,
                              double lb, double lc) {
  return la * lb * lc + (a[0] * b[0] + a[1] * b[1] + a[2] * b[2]) * lc +
         (a[0] * c[0] + a[1] * c[1] + a[2] * c[2]) * lb +
         (b[0] * c[0] + b[1] * c[1] + b[2] * c[2]) * la;
}

// The signed solid angle of the triangle with corners p + a, p + b, p + c at p.
inline double solid_angle_of(const double* a, const double* b, const double* c) {
  const double la = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  const double lb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
  const double lc = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
  const double num = solid_angle_num(a, b, c);
  if (num == 0.0) return 0.0;
  return 2.0 * std::atan2(num, solid_angle_den(a, b, c, la, lb, lc));
}

// The signed solid angle of triangle (A, B, C) at p, in [-2 pi, 2 pi]. Where the corners
// lie so close to p that the cubic terms would underflow (a mesh at 1e-150 and below),
// the corners are first scaled to unit size (the solid angle does not depend on scale).
inline double solid_angle(const double* p, const double* A, const double* B, const double* C) {
  double a[3], b[3], c[3];
  double m = 0.0;
  for (int i = 0; i < 3; ++i) {
    a[i] = A[i] - p[i];
    b[i] = B[i] - p[i];
    c[i] = C[i] - p[i];
    m = std::max(m, std::max(std::fabs(a[i]), std::max(std::fabs(b[i]), std::fabs(c[i]))));
  }
  if (m < 1e-90 && m > 0.0)
    for (int i = 0; i < 3; ++i) {
      a[i] /= m;
      b[i] /= m;
      c[i] /= m;
    }
  return solid_angle_of(a, b, c);
}

// The exact sum at p over faces F (nf, 3) of vertices V.
inline double winding_sum(const double* p, const double* V, const int32_t* F, int64_t nf) {
  double s = 0.0;
  for (int64_t f = 0; f < nf; ++f)
    s += solid_angle(p, V + 3 * static_cast<int64_t>(F[3 * f]),
                     V + 3 * static_cast<int64_t>(F[3 * f + 1]),
                     V + 3 * static_cast<int64_t>(F[3 * f + 2]));
  return s / (4.0 * 3.14159265358979323846);
}

// Whether the faces form a cycle: every undirected edge used equally often in both
// directions (by vertex index; degenerate faces included, an edge {i, i} cancels itself).
inline bool faces_closed(const int32_t* F, int64_t nf) {
  std::vector<uint64_t> up, down;
  up.reserve(3 * nf);
  down.reserve(3 * nf);
  for (int64_t f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = static_cast<uint32_t>(F[3 * f + k]);
      const uint32_t j = static_cast<uint32_t>(F[3 * f + (k + 1) % 3]);
      if (i == j) continue;
      if (i < j)
        up.push_back(uint64_t{i} << 32 | j);
      else
        down.push_back(uint64_t{j} << 32 | i);
    }
  if (up.size() != down.size()) return false;
  std::sort(up.begin(), up.end());
  std::sort(down.begin(), down.end());
  return up == down;
}

// The boundary of faces F: the directed edges (i, j) whose uses from i to j outnumber those
// from j to i, with the excess as multiplicity, sorted by (i, j); empty where the faces form a
// cycle (edges {i, i} of degenerate faces cancel themselves). As a 1-chain it is a cycle:
// every vertex is left as often as it is entered, counted with multiplicity.
struct BoundaryEdge {
  int32_t i, j, mult;
};
inline std::vector<BoundaryEdge> boundary_edges(const int32_t* F, int64_t nf) {
  std::vector<uint64_t> keys;  // (lo << 32 | hi) << 1 | (1 where the use runs hi -> lo)
  keys.reserve(3 * nf);
  for (int64_t f = 0; f < nf; ++f)
    for (int k = 0; k < 3; ++k) {
      const uint32_t i = static_cast<uint32_t>(F[3 * f + k]);
      const uint32_t j = static_cast<uint32_t>(F[3 * f + (k + 1) % 3]);
      if (i == j) continue;
      const uint64_t lo = std::min(i, j), hi = std::max(i, j);
      keys.push_back((lo << 32 | hi) << 1 | (i > j ? 1 : 0));
    }
  std::sort(keys.begin(), keys.end());
  std::vector<BoundaryEdge> out;
  for (size_t a = 0; a < keys.size();) {
    size_t b = a;
    int64_t net = 0;
    while (b < keys.size() && keys[b] >> 1 == keys[a] >> 1) net += (keys[b++] & 1) ? -1 : 1;
    if (net != 0) {
      const int32_t lo = static_cast<int32_t>(keys[a] >> 33);
      const int32_t hi = static_cast<int32_t>((keys[a] >> 1) & 0xffffffff);
      out.push_back(net > 0 ? BoundaryEdge{lo, hi, static_cast<int32_t>(net)}
                            : BoundaryEdge{hi, lo, static_cast<int32_t>(-net)});
    }
    a = b;
  }
  std::sort(out.begin(), out.end(), [](const BoundaryEdge& x, const BoundaryEdge& y) {
    return x.i < y.i || (x.i == y.i && x.j < y.j);
  });
  return out;
}

// A cap of a boundary (a 1-cycle, as boundary_edges gives it): triangles C, appended to *cap
// as vertex triples, whose boundary is that cycle (dC = dS for the faces S it came from, so
// S - C is a closed 2-cycle). The cycle is split into closed walks (from the lowest unused
// edge, following unused edges, each walk ends where it first returns to its start; a walk
// may pass through a vertex more than once), and a walk w_0 .. w_{n-1} (w_n = w_0) is
// triangulated by halving its index range: the range [k, m] (m - k >= 2) gives the triangle
// (w_k, w_mid, w_m), mid = (k + m) / 2, and the ranges [k, mid] and [mid, m]. By induction the
// triangles of [k, m] have as boundary the walk from w_k to w_m plus the chord w_m -> w_k
// (the chords of the halves cancel against the triangle's sides), and the chord of [0, n] is
// the point w_0, so the walk's triangles have the walk as boundary. Triangles with a repeated
// vertex (a degenerate chord) have a zero boundary and zero solid angle and are left out.
// Unlike a fan from one vertex, the triangles are about as wide as their index range is long
// (small along the rim, few large ones inside), which suits the far-field hierarchy. Returns
// false (a walk that cannot close: not a cycle) or true.
inline bool boundary_cap(const std::vector<BoundaryEdge>& edges, std::vector<int32_t>* cap) {
  const size_t ne = edges.size();
  std::vector<int32_t> left(ne);  // the uses left of each edge
  int64_t uses = 0;
  for (size_t e = 0; e < ne; ++e) {
    left[e] = edges[e].mult;
    uses += edges[e].mult;
  }
  std::vector<size_t> next(ne);  // per edge: the first edge from its vertex i still unused
  for (size_t e = 0; e < ne; ++e) next[e] = e;
  std::vector<int32_t> walk;
  std::vector<std::array<int64_t, 2>> ranges;
  // the first edge from vertex v with uses left, or ne
  auto from = [&](int32_t v) -> size_t {
    size_t a = std::lower_bound(edges.begin(), edges.end(), v,
                                [](const BoundaryEdge& x, int32_t u) { return x.i < u; }) -
               edges.begin();
    if (a == ne || edges[a].i != v) return ne;
    size_t b = next[a];
    while (b < ne && edges[b].i == v && left[b] == 0) ++b;
    next[a] = b;
    return b < ne && edges[b].i == v ? b : ne;
  };
  for (size_t s = 0; s < ne; ++s) {
    while (left[s] > 0) {
      walk.clear();
      const int32_t start = edges[s].i;
      size_t e = s;
      while (true) {
        --left[e];
        walk.push_back(edges[e].i);
        const int32_t v = edges[e].j;
        if (v == start) break;
        e = from(v);
        if (e == ne || static_cast<int64_t>(walk.size()) > uses) return false;
      }
      const int64_t n = static_cast<int64_t>(walk.size());
      ranges.clear();
      ranges.push_back({0, n});
      while (!ranges.empty()) {
        const auto r = ranges.back();
        ranges.pop_back();
        if (r[1] - r[0] < 2) continue;
        const int64_t mid = r[0] + (r[1] - r[0]) / 2;
        const int32_t a = walk[r[0]], b = walk[mid], c = walk[r[1] % n];
        if (a != b && b != c && c != a) {
          cap->push_back(a);
          cap->push_back(b);
          cap->push_back(c);
        }
        ranges.push_back({mid, r[1]});
        ranges.push_back({r[0], mid});
      }
    }
  }
  return true;
}

// The exact solid-angle sum of a fixed set of triangles (a cap: triangles over few vertices,
// each vertex shared by several) at points: per point, every vertex's offset u = x - p and
// length |u| are computed once, then each triangle's Van Oosterom-Strackee terms num and den
// from them, and the half-angles atan2(num, den) are added as the argument of a product of
// the complex numbers 1 + i num / den over runs whose |num| / den add up to at most 1.5
// (as in WindingTree::fan_angle; exact up to rounding, and the product's magnitude stays
// below exp(1.5^2 / 2)), so that most triangles cost no square root and no atan2. Triangles with
// num == 0 count 0, as in solid_angle; those whose corners all lie within 1e-90 of p take
// solid_angle (which rescales them).
class CapSum {
 public:
  void build(const double* V, const std::vector<int32_t>& tris) {
    std::vector<int32_t> ids(tris);
    std::sort(ids.begin(), ids.end());
    ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
    const size_t nv = ids.size();
    x_.resize(3 * nv);
    for (size_t k = 0; k < nv; ++k)
      for (int a = 0; a < 3; ++a) x_[3 * k + a] = V[3 * static_cast<int64_t>(ids[k]) + a];
    local_.resize(tris.size());
    for (size_t t = 0; t < tris.size(); ++t)
      local_[t] =
          static_cast<int32_t>(std::lower_bound(ids.begin(), ids.end(), tris[t]) - ids.begin());
  }
  size_t vertex_count() const { return x_.size() / 3; }

  // The sum of the triangles' solid angles at p; `work` holds 4 doubles per vertex.
  double eval(const double* p, double* work) const {
    const size_t nv = x_.size() / 3;
    double* u = work;
    double* l = work + 3 * nv;
    for (size_t k = 0; k < nv; ++k) {
      const double a = x_[3 * k] - p[0], b = x_[3 * k + 1] - p[1], c = x_[3 * k + 2] - p[2];
      u[3 * k] = a;
      u[3 * k + 1] = b;
      u[3 * k + 2] = c;
      l[k] = std::sqrt(a * a + b * b + c * c);
    }
    double s = 0.0, zr = 1.0, zi = 0.0, t = 0.0;
    for (size_t f = 0; f + 2 < local_.size(); f += 3) {
      const int32_t i = local_[f], j = local_[f + 1], k = local_[f + 2];
      const double* a = u + 3 * i;
      const double* b = u + 3 * j;
      const double* c = u + 3 * k;
      const double la = l[i], lb = l[j], lc = l[k];
      if (std::max(la, std::max(lb, lc)) < 1e-90) {
        s += solid_angle(p, x_.data() + 3 * i, x_.data() + 3 * j, x_.data() + 3 * k);
        continue;
      }
      const double num = solid_angle_num(a, b, c);
      if (num == 0.0) continue;
      const double den = solid_angle_den(a, b, c, la, lb, lc);
      if (!(den > 0.0)) {
        s += 2.0 * std::atan2(num, den);
        continue;
      }
      const double x = num / den;
      if (t > 0.0 && t + std::fabs(x) > 1.5) {
        s += 2.0 * std::atan2(zi, zr);
        zr = 1.0;
        zi = 0.0;
        t = 0.0;
      }
      // z (1 + i x): no division on the chain, and |z|^2 <= exp(sum x^2) stays small
      const double nr = zr - zi * x, ni = zi + zr * x;
      zr = nr;
      zi = ni;
      t += std::fabs(x);
    }
    if (t > 0.0) s += 2.0 * std::atan2(zi, zr);
    return s;
  }

 private:
  std::vector<double> x_;       // the vertices' coordinates
  std::vector<int32_t> local_;  // the triangles' corners, as indices into x_
};

// A hierarchy for the winding numbers of any mesh (open, or a soup), exact up to rounding
// (Jacobson et al. 2013): each node keeps the boundary of its triangles (the edges whose
// uses in the two directions do not cancel, with their net multiplicity). For a point p
// outside a node's box, the node's patch S and the fan C from one of its vertices over its
// boundary form a closed chain S - C inside the box, whose winding number at p is 0: so
// w_S(p) = w_C(p), a sum over the boundary edges only. Nodes whose boundary has fewer edges
// than triangles are evaluated that way from outside their box; points inside a box
// descend into it, down to the triangles' own solid angles at the leaves.
class WindingTree {
 public:
  static constexpr int32_t kLeaf = 8;

  void build(const double* V, const int32_t* F, int64_t nf) {
    V_ = V;
    F_ = F;
    const int32_t n = static_cast<int32_t>(nf);
    order_.resize(n);
    for (int32_t i = 0; i < n; ++i) order_[i] = i;
    nodes_.clear();
    edges_.clear();
    if (n == 0) return;
    std::vector<std::array<double, 3>> cent(n);
    for (int32_t f = 0; f < n; ++f)
      for (int a = 0; a < 3; ++a)
        cent[f][a] = (corner(f, 0)[a] + corner(f, 1)[a] + corner(f, 2)[a]) / 3.0;
    nodes_.push_back(Node{});
    struct Task {
      int32_t node, b, e;
    };
    std::vector<Task> stack{{0, 0, n}};
    std::vector<std::array<int64_t, 2>> keys;  // (undirected edge, +-1) of a node's triangles
    while (!stack.empty()) {
      const Task t = stack.back();
      stack.pop_back();
      Node node;
      node.first = t.b;
      node.count = t.e - t.b;
      for (int32_t i = t.b; i < t.e; ++i)
        for (int k = 0; k < 3; ++k) {
          const double* x = corner(order_[i], k);
          for (int a = 0; a < 3; ++a) {
            node.lo[a] = std::min(node.lo[a], x[a]);
            node.hi[a] = std::max(node.hi[a], x[a]);
          }
        }
      const double* c0 = corner(order_[t.b], 0);
      for (int a = 0; a < 3; ++a) node.c[a] = c0[a];
      // the boundary: directed edges with non-zero net use
      keys.clear();
      for (int32_t i = t.b; i < t.e; ++i)
        for (int k = 0; k < 3; ++k) {
          const int64_t u = F_[3 * int64_t(order_[i]) + k],
                        w = F_[3 * int64_t(order_[i]) + (k + 1) % 3];
          if (u == w) continue;
          keys.push_back({std::min(u, w) << 32 | std::max(u, w), u < w ? 1 : -1});
        }
      std::sort(keys.begin(), keys.end());
      node.edge_begin = static_cast<int64_t>(edges_.size());
      for (size_t j = 0; j < keys.size();) {
        size_t m = j;
        int64_t net = 0;
        while (m < keys.size() && keys[m][0] == keys[j][0]) net += keys[m++][1];
        if (net != 0) {
          const int32_t lo = static_cast<int32_t>(keys[j][0] >> 32);
          const int32_t hi = static_cast<int32_t>(keys[j][0] & 0xffffffff);
          edges_.push_back(Edge{net > 0 ? lo : hi, net > 0 ? hi : lo,
                                static_cast<int32_t>(net > 0 ? net : -net)});
        }
        j = m;
      }
      node.edge_end = static_cast<int64_t>(edges_.size());
      if (node.edge_end - node.edge_begin >= node.count) {  // no cheaper than the triangles
        edges_.resize(node.edge_begin);
        node.edge_begin = node.edge_end = -1;
      }
      if (node.count > kLeaf) {
        int axis = 0;
        for (int a = 1; a < 3; ++a)
          if (node.hi[a] - node.lo[a] > node.hi[axis] - node.lo[axis]) axis = a;
        const int32_t mid = t.b + node.count / 2;
        std::nth_element(order_.begin() + t.b, order_.begin() + mid, order_.begin() + t.e,
                         [&](int32_t x, int32_t y) {
                           return cent[x][axis] < cent[y][axis] ||
                                  (cent[x][axis] == cent[y][axis] && x < y);
                         });
        node.left = static_cast<int32_t>(nodes_.size());
        nodes_.push_back(Node{});
        nodes_.push_back(Node{});
        stack.push_back({node.left + 1, mid, t.e});
        stack.push_back({node.left, t.b, mid});
      }
      nodes_[t.node] = node;
    }
  }

  // The winding number at p (the solid-angle sum over the triangles, up to rounding).
  double eval(const double* p) const {
    if (nodes_.empty()) return 0.0;
    const double scale = std::max(std::fabs(p[0]), std::max(std::fabs(p[1]), std::fabs(p[2])));
    double s = 0.0;
    int32_t stack[128];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
      const Node& nd = nodes_[stack[--sp]];
      if (nd.edge_begin >= 0 && outside(nd, p, 1e-9 * (scale + nd.extent()))) {
        for (int64_t j = nd.edge_begin; j < nd.edge_end; ++j) {
          const Edge& e = edges_[j];
          s += e.mult * solid_angle(p, nd.c, V_ + 3 * int64_t(e.i), V_ + 3 * int64_t(e.j));
        }
        continue;
      }
      if (nd.left < 0 || sp + 2 > 128) {
        for (int32_t i = nd.first; i < nd.first + nd.count; ++i)
          s += solid_angle(p, corner(order_[i], 0), corner(order_[i], 1), corner(order_[i], 2));
        continue;
      }
      stack[sp++] = nd.left + 1;
      stack[sp++] = nd.left;
    }
    return s / (4.0 * 3.14159265358979323846);
  }

  // The nodes' far-field moments, for eval_approx (after build). A node whose box is a
  // point (or below the normal range) gets none and is never expanded.
  void build_moments() {
    moments_.assign(nodes_.size(), Moments{});
    if (nodes_.empty()) return;
    const int32_t n = static_cast<int32_t>(order_.size());
    // every triangle's area in units of the root's size (for the budget's shares)
    std::vector<double> area(n, 0.0);
    {
      const Node& root = nodes_[0];
      double c[3], h;
      if (frame(root, c, &h))
        for (int32_t f = 0; f < n; ++f) {
          double d[3][3];
          for (int k = 0; k < 3; ++k)
            for (int a = 0; a < 3; ++a) d[k][a] = (corner(f, k)[a] - c[a]) * (1.0 / h);
          double nn[3];
          half_cross(d, nn);
          area[f] = norm3(nn);
        }
    }
    for (size_t k = 0; k < nodes_.size(); ++k) {
      const Node& nd = nodes_[k];
      Moments& m = moments_[k];
      for (int32_t i = nd.first; i < nd.first + nd.count; ++i) m.area += area[order_[i]];
      double c[3], h;
      if (!frame(nd, c, &h)) continue;
      const double ih = 1.0 / h;
      // the centre: the triangles' area-weighted centroid (the box's centre if no area)
      double g[3] = {0, 0, 0}, wsum = 0.0;
      for (int32_t i = nd.first; i < nd.first + nd.count; ++i) {
        double d[3][3];
        for (int j = 0; j < 3; ++j)
          for (int a = 0; a < 3; ++a) d[j][a] = (corner(order_[i], j)[a] - c[a]) * ih;
        double nn[3];
        half_cross(d, nn);
        const double w = norm3(nn);
        wsum += w;
        for (int a = 0; a < 3; ++a) g[a] += w * (d[0][a] + d[1][a] + d[2][a]) / 3.0;
      }
      if (wsum > 0.0)
        for (int a = 0; a < 3; ++a) c[a] += h * (g[a] / wsum);
      double r2 = 0.0;  // the farthest vertex from c, in units of h
      for (int32_t i = nd.first; i < nd.first + nd.count; ++i)
        for (int j = 0; j < 3; ++j) {
          double d2 = 0.0;
          for (int a = 0; a < 3; ++a) {
            const double x = (corner(order_[i], j)[a] - c[a]) * ih;
            d2 += x * x;
          }
          r2 = std::max(r2, d2);
        }
      const double rn = std::sqrt(r2);
      if (!(rn > 0.0)) continue;
      const double irn = ih / rn;
      for (int a = 0; a < 3; ++a) m.c[a] = c[a];
      m.R = h * rn;
      for (int32_t i = nd.first; i < nd.first + nd.count; ++i) {
        double d[3][3];  // the corners relative to c, in units of R
        for (int j = 0; j < 3; ++j)
          for (int a = 0; a < 3; ++a) d[j][a] = (corner(order_[i], j)[a] - c[a]) * irn;
        double nn[3];  // the area-weighted normal
        half_cross(d, nn);
        const double at = norm3(nn);
        m.A += at;
        // |d|^4 and |d|^5 are convex: their means over a triangle are at most the means
        // over its corners
        double l4 = 0.0, l5 = 0.0;
        for (int j = 0; j < 3; ++j) {
          const double l2 = d[j][0] * d[j][0] + d[j][1] * d[j][1] + d[j][2] * d[j][2];
          l4 += l2 * l2;
          l5 += l2 * l2 * std::sqrt(l2);
        }
        m.mu4 += at * l4 / 3.0;
        m.mu5 += at * l5 / 3.0;
        double s[3];
        for (int a = 0; a < 3; ++a) s[a] = d[0][a] + d[1][a] + d[2][a];
        // int_t d_j d_k dA = (area / 12) (sum of the corners' d_j d_k + s_j s_k)
        double S[6];
        int idx = 0;
        for (int a = 0; a < 3; ++a)
          for (int b = a; b < 3; ++b, ++idx)
            S[idx] =
                (d[0][a] * d[0][b] + d[1][a] * d[1][b] + d[2][a] * d[2][b] + s[a] * s[b]) / 12.0;
        for (int a = 0; a < 3; ++a) {
          m.N[a] += nn[a];
          for (int b = 0; b < 3; ++b) m.M1[3 * a + b] += nn[a] * s[b] / 3.0;
          for (int j = 0; j < 6; ++j) m.M2[6 * a + j] += nn[a] * S[j];
        }
        // int_t d_j d_k d_l dA = (area / 60) (s_j s_k s_l + sum over the corners v of
        // v_j v_k s_l + v_j s_k v_l + s_j v_k v_l + 2 v_j v_k v_l)
        idx = 0;
        double T[10];
        for (int a = 0; a < 3; ++a)
          for (int b = a; b < 3; ++b)
            for (int e = b; e < 3; ++e, ++idx) {
              double t = s[a] * s[b] * s[e];
              for (int j = 0; j < 3; ++j)
                t += d[j][a] * d[j][b] * s[e] + d[j][a] * s[b] * d[j][e] +
                     s[a] * d[j][b] * d[j][e] + 2.0 * d[j][a] * d[j][b] * d[j][e];
              T[idx] = t / 60.0;
            }
        for (int a = 0; a < 3; ++a)
          for (int j = 0; j < 10; ++j) m.M3[10 * a + j] += nn[a] * T[j];
      }
    }
  }

  // The winding number at p within eps of the solid-angle sum (plus rounding), for
  // eps >= 0 (after build_moments). 0: the same value as eval.
  double eval_approx(const double* p, double eps) const {
    if (nodes_.empty()) return 0.0;
    const double scale = std::max(std::fabs(p[0]), std::max(std::fabs(p[1]), std::fabs(p[2])));
    double budget = 4.0 * 3.14159265358979323846 * eps;  // in solid-angle units
    double area_left = moments_[0].area;
    double s = 0.0;
    int32_t stack[128];
    int sp = 0;
    stack[sp++] = 0;
    while (sp > 0) {
      const int32_t id = stack[--sp];
      const Node& nd = nodes_[id];
      const Moments& m = moments_[id];
      double u[3], q, bound, ratio;
      if (admissible(m, p, budget, area_left, u, &q, &bound, &ratio)) {
        s += expansion(m, u, q);
        budget -= bound;
        area_left -= m.area;
        continue;
      }
      if (nd.edge_begin >= 0 &&
          (nd.left < 0 || nd.edge_end - nd.edge_begin <= 2 ||
           !(descend_cost(ratio) < double(nd.edge_end - nd.edge_begin) ||
             children_expand(nd.left, p, budget, area_left))) &&
          outside(nd, p, 1e-9 * (scale + nd.extent()))) {
        s += fan_angle(nd.c, nd.edge_begin, nd.edge_end, p);
        area_left -= m.area;
        continue;
      }
      if (nd.left < 0 || sp + 2 > 128) {
        for (int32_t i = nd.first; i < nd.first + nd.count; ++i)
          s += solid_angle(p, corner(order_[i], 0), corner(order_[i], 1), corner(order_[i], 2));
        area_left -= m.area;
        continue;
      }
      // the farther child first (last on the stack): it spends little of its share and
      // leaves the rest to the nearer one (a fixed order for a given point: deterministic)
      const bool swap = dist2(moments_[nd.left].c, p) > dist2(moments_[nd.left + 1].c, p);
      stack[sp++] = swap ? nd.left + 1 : nd.left;
      stack[sp++] = swap ? nd.left : nd.left + 1;
    }
    return s / (4.0 * 3.14159265358979323846);
  }
  // The solid angle of the fan from c over edges [b, e) at p: the sum of 2 atan2(num, den)
  // over its triangles, with one atan2 for each run of triangles whose half-angles add up
  // to less than 1.5 in magnitude (bounded by sum |num| / den where den > 0): the
  // product of the complex numbers den + i num has their sum as its argument, exactly
  // (up to rounding) while that sum stays in (-pi, pi).
  double fan_angle(const double* c, int64_t b, int64_t e, const double* p) const {
    double a[3];
    double m = 0.0;
    for (int k = 0; k < 3; ++k) {
      a[k] = c[k] - p[k];
      m = std::max(m, std::fabs(a[k]));
    }
    double s = 0.0;
    if (m < 1e-80) {  // tiny: the scaled solid angles
      for (int64_t j = b; j < e; ++j)
        s += edges_[j].mult *
             solid_angle(p, c, V_ + 3 * int64_t(edges_[j].i), V_ + 3 * int64_t(edges_[j].j));
      return s;
    }
    const double la = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
    double zr = 1.0, zi = 0.0, t = 0.0;
    for (int64_t j = b; j < e; ++j) {
      const Edge& ed = edges_[j];
      const double* B = V_ + 3 * int64_t(ed.i);
      const double* C = V_ + 3 * int64_t(ed.j);
      const double u[3] = {B[0] - p[0], B[1] - p[1], B[2] - p[2]};
      const double w[3] = {C[0] - p[0], C[1] - p[1], C[2] - p[2]};
      const double lb = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
      const double lc = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
      const double num = solid_angle_num(a, u, w);
      if (num == 0.0) continue;
      const double den = solid_angle_den(a, u, w, la, lb, lc);
      if (!(den > 0.0) || ed.mult != 1) {
        s += ed.mult * 2.0 * std::atan2(num, den);
        continue;
      }
      const double x = std::fabs(num) / den;
      if (t > 0.0 && t + x > 1.5) {
        s += 2.0 * std::atan2(zi, zr);
        zr = 1.0;
        zi = 0.0;
        t = 0.0;
      }
      const double nr = zr * den - zi * num, ni = zr * num + zi * den;
      const double k = 1.0 / std::max(std::fabs(nr), std::fabs(ni));
      zr = nr * k;
      zi = ni * k;
      t += x;
    }
    if (t > 0.0) s += 2.0 * std::atan2(zi, zr);
    return s;
  }
  static double dist2(const double* a, const double* b) {
    return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
           (a[2] - b[2]) * (a[2] - b[2]);
  }

 private:
  // A node's far field: its centre c (the triangles' area-weighted centroid), the radius R
  // of its corners about c and, in units of R (so that neither tiny nor huge meshes under-
  // or overflow), the total absolute area A, bounds mu4, mu5 on int |d|^4, |d|^5 dA and the
  // moments of the area-weighted normals n: N_i = sum n_i, M1_ij = int n_i d_j, M2_ijk =
  // int n_i d_j d_k, M3_ijkl = int n_i d_j d_k d_l (d = x - c; jk, jkl packed sorted);
  // `area` is the node's area in units of the root's size, for the budget's shares.
  struct Moments {
    double c[3] = {0, 0, 0};
    double R = 0.0, A = 0.0, mu4 = 0.0, mu5 = 0.0, area = 0.0;
    double N[3] = {0, 0, 0};
    double M1[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    double M2[18] = {0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0};
    double M3[30] = {};
  };

  // Whether node m's expansion at p is within its share of the budget; then u (the unit
  // vector from p to the centre), q = R / rho and the bound.
  static bool admissible(const Moments& m, const double* p, double budget, double area_left,
                         double* u, double* q, double* bound, double* ratio = nullptr) {
    if (ratio) *ratio = std::numeric_limits<double>::infinity();
    if (!(m.R > 0.0 && budget > 0.0)) return false;
    double big = 0.0;
    for (int a = 0; a < 3; ++a) {
      u[a] = m.c[a] - p[a];
      big = std::max(big, std::fabs(u[a]));
    }
    if (!(big > 0.0)) return false;
    for (int a = 0; a < 3; ++a) u[a] /= big;
    const double len = norm3(u);
    *q = m.R / big / len;
    if (!(*q < 1.0)) return false;
    *bound = remainder(m, *q);
    const double share = m.area >= area_left ? budget : budget * (m.area / area_left);
    if (ratio && share > 0.0) *ratio = *bound / share;
    if (!(*bound <= share)) return false;
    for (int a = 0; a < 3; ++a) u[a] /= len;
    return true;
  }
  // About what descending into a node costs (in solid angles) where its bound is `ratio`
  // times its share: its descendants' bounds fall as their radius^6 (q^6), their shares
  // only as their area, so the number of them needed grows as a power of ratio (the
  // constant and the power tuned on open meshes). Only a choice of work: the values stay
  // within the bound either way.
  static double descend_cost(double ratio) {
    return ratio < 1e30 ? 8.0 * std::cbrt(ratio * ratio) : ratio;
  }
  // Whether both children of an inner node would take their expansions at p (cheaper than
  // the node's boundary fan of more than two edges), with the budget as it stands.
  bool children_expand(int32_t left, const double* p, double budget, double area_left) const {
    if (left < 0) return false;
    double u[3], q, b0, b1;
    if (!admissible(moments_[left], p, budget, area_left, u, &q, &b0)) return false;
    return admissible(moments_[left + 1], p, budget - b0, area_left - moments_[left].area, u, &q,
                      &b1);
  }

  // The bound on the error of a node's expansion at a point at distance R / q from its
  // centre: sum_{l >= 4} (l + 1) int |d|^l dA / rho^(l + 2), with int |d|^l dA <= R^(l - 5)
  // mu5 for l >= 5 (in units of R: q^6 (5 mu4 + q mu5 sum_j (j + 6) q^j)).
  static double remainder(const Moments& m, double q) {
    const double q2 = q * q;
    return q2 * q2 * q2 * (5.0 * m.mu4 + q * m.mu5 * (6.0 - 5.0 * q) / ((1.0 - q) * (1.0 - q)));
  }

  // The third-order expansion of a node's solid angle at a point at distance R / q from
  // its centre, u the unit vector from the point to the centre: sum of the orders
  // N.K + M1:grad K + M2:grad^2 K / 2 + M3:grad^3 K / 6 of K(y) = y / |y|^3 at y = u R / q.
  static double expansion(const Moments& m, const double* u, double q) {
    const double o0 = m.N[0] * u[0] + m.N[1] * u[1] + m.N[2] * u[2];
    double tr = m.M1[0] + m.M1[4] + m.M1[8], uMu = 0.0;
    for (int a = 0; a < 3; ++a)
      for (int b = 0; b < 3; ++b) uMu += u[a] * m.M1[3 * a + b] * u[b];
    const double o1 = tr - 3.0 * uMu;
    // packed index of (j, k), j <= k: 00 01 02 11 12 22
    static constexpr int kSym[3][3] = {{0, 1, 2}, {1, 3, 4}, {2, 4, 5}};
    double t1 = 0.0, t2 = 0.0, t3 = 0.0;
    for (int i = 0; i < 3; ++i) {
      const double* S = m.M2 + 6 * i;
      double Su = 0.0, uSu = 0.0;
      for (int j = 0; j < 3; ++j) {
        double row = 0.0;
        for (int k = 0; k < 3; ++k) row += S[kSym[j][k]] * u[k];
        uSu += u[j] * row;
        if (j == i) Su = row;
      }
      t1 += Su;                           // sum_i M2_iik u_k
      t2 += u[i] * (S[0] + S[3] + S[5]);  // sum_i u_i M2_ijj
      t3 += u[i] * uSu;                   // M2_ijk u_i u_j u_k
    }
    const double o2 = 0.5 * (15.0 * t3 - 3.0 * (2.0 * t1 + t2));
    // order 3: M3_ijkl d^3 K_i / 6 = -M3_ijkl T_ijkl / 6, T the fourth derivatives of
    // 1 / |y|: (105 u_i u_j u_k u_l - 15 (delta u u, 6 terms) + 3 (delta delta, 3 terms))
    static constexpr int kSym3[3][3][3] = {{{0, 1, 2}, {1, 3, 4}, {2, 4, 5}},
                                           {{1, 3, 4}, {3, 6, 7}, {4, 7, 8}},
                                           {{2, 4, 5}, {4, 7, 8}, {5, 8, 9}}};
    double W = 0.0, X = 0.0, Y = 0.0, Z = 0.0;
    for (int i = 0; i < 3; ++i) {
      const double* M = m.M3 + 10 * i;
      double b[3], tr[3];
      for (int j = 0; j < 3; ++j) {
        double bj = 0.0;
        for (int k = 0; k < 3; ++k) {
          double a = 0.0;
          for (int l = 0; l < 3; ++l) a += M[kSym3[j][k][l]] * u[l];
          bj += a * u[k];
        }
        b[j] = bj;                                                          // M3_i(j, u, u)
        tr[j] = M[kSym3[0][0][j]] + M[kSym3[1][1][j]] + M[kSym3[2][2][j]];  // M3_i(k, k, j)
      }
      W += u[i] * (b[0] * u[0] + b[1] * u[1] + b[2] * u[2]);
      X += b[i];
      Y += u[i] * (tr[0] * u[0] + tr[1] * u[1] + tr[2] * u[2]);
      Z += tr[i];
    }
    const double o3 = (-105.0 * W + 45.0 * (X + Y) - 9.0 * Z) / 6.0;
    return (q * q) * (o0 + q * (o1 + q * (o2 + q * o3)));
  }
  static double norm3(const double* x) {
    return std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
  }
  static void half_cross(const double (*d)[3], double* nn) {
    double e1[3], e2[3];
    for (int a = 0; a < 3; ++a) {
      e1[a] = d[1][a] - d[0][a];
      e2[a] = d[2][a] - d[0][a];
    }
    nn[0] = 0.5 * (e1[1] * e2[2] - e1[2] * e2[1]);
    nn[1] = 0.5 * (e1[2] * e2[0] - e1[0] * e2[2]);
    nn[2] = 0.5 * (e1[0] * e2[1] - e1[1] * e2[0]);
  }
  struct Node {
    double lo[3] = {std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity(),
                    std::numeric_limits<double>::infinity()};
    double hi[3] = {-std::numeric_limits<double>::infinity(),
                    -std::numeric_limits<double>::infinity(),
                    -std::numeric_limits<double>::infinity()};
    double c[3] = {0, 0, 0};  // the fan's centre: a vertex of the patch
    int32_t first = 0, count = 0, left = -1;
    int64_t edge_begin = -1, edge_end = -1;
    double extent() const {
      double m = 0.0;
      for (int a = 0; a < 3; ++a) m = std::max(m, std::max(std::fabs(lo[a]), std::fabs(hi[a])));
      return m;
    }
  };
  struct Edge {
    int32_t i, j, mult;
  };
  std::vector<Moments> moments_;
  // The centre of a node's box and its largest half-extent h; false where h is zero or
  // below the normal range.
  static bool frame(const Node& nd, double* c, double* h) {
    double e = 0.0;
    for (int a = 0; a < 3; ++a) {
      c[a] = 0.5 * nd.lo[a] + 0.5 * nd.hi[a];
      e = std::max(e, 0.5 * nd.hi[a] - 0.5 * nd.lo[a]);
    }
    *h = e;
    return e >= std::numeric_limits<double>::min() && std::isfinite(e);
  }
  const double* corner(int32_t f, int k) const { return V_ + 3 * int64_t(F_[3 * int64_t(f) + k]); }
  static bool outside(const Node& nd, const double* p, double margin) {
    for (int a = 0; a < 3; ++a)
      if (p[a] < nd.lo[a] - margin || p[a] > nd.hi[a] + margin) return true;
    return false;
  }
  const double* V_ = nullptr;
  const int32_t* F_ = nullptr;
  std::vector<int32_t> order_;
  std::vector<Node> nodes_;
  std::vector<Edge> edges_;
};

}  // namespace spatial
}  // namespace voxax

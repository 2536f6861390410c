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
// point, through the BVH, gives it in O(log F); where that ray meets an edge or a vertex
// exactly, or p lies within rounding of a face it meets, the point falls back to the
// exact sum, so the result is always the solid-angle sum's value: the integer, or the
// half-integers of points on the surface.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

namespace voxax {
namespace spatial {

// The signed solid angle of triangle (A, B, C) at p, in [-2 pi, 2 pi].
inline double solid_angle(const double* p, const double* A, const double* B, const double* C) {
  double a[3], b[3], c[3];
  for (int i = 0; i < 3; ++i) {
    a[i] = A[i] - p[i];
    b[i] = B[i] - p[i];
    c[i] = C[i] - p[i];
  }
  const double la = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  const double lb = std::sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2]);
  const double lc = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
  const double bc[3] = {b[1] * c[2] - b[2] * c[1], b[2] * c[0] - b[0] * c[2],
                        b[0] * c[1] - b[1] * c[0]};
  const double num = a[0] * bc[0] + a[1] * bc[1] + a[2] * bc[2];
  if (num == 0.0) return 0.0;
  const double ab = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
  const double ac = a[0] * c[0] + a[1] * c[1] + a[2] * c[2];
  const double bcd = b[0] * c[0] + b[1] * c[1] + b[2] * c[2];
  const double den = la * lb * lc + ab * lc + ac * lb + bcd * la;
  return 2.0 * std::atan2(num, den);
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

 private:
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

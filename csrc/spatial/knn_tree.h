// The k best candidates of a nearest-neighbour search, and a kd-tree over points for
// queries far from the data.
//
// `Nearest` keeps the k best (squared distance, index) pairs offered to it, in that
// order; a pair replaces the k-th when it is strictly smaller. Every search offers each
// point with its squared distance computed the same way, `dx * dx + dy * dy + dz * dz`
// with `dx = x - q` (so all searches agree bit for bit), and skips only points that cannot
// be among the k best, so the result is the exact k smallest pairs whatever the search.
//
// `PointTree` is a kd-tree of median splits (along the widest axis of a node's points,
// ties of a coordinate by index) with the bounding box of its points and their smallest
// index in every node. A query visits the nearer child first and skips a node whose box is
// farther than the k-th candidate, or exactly as far with no smaller index inside. The box
// distance needs no rounding allowance: it is the same sum of squares over per-axis gaps
// `lo - q` or `q - hi`, each at most the gap `x - q` of any point inside as computed
// (rounding is monotone), so it never exceeds the computed distance of a point inside.
#pragma once

#include <algorithm>
#include <cstdint>
#include <limits>
#include <vector>

namespace voxax {
namespace spatial {

constexpr int kMaxNeighbours = 32;

// K > 0: the k = K best, K known at compile time (the loops unroll); K == 0: k given at
// run time, up to kMaxNeighbours. Both keep the same pairs.
template <int K>
struct NearestK {
  static constexpr int kCap = K > 0 ? K : kMaxNeighbours;
  double d2[kCap];
  int32_t idx[kCap];
  int k;
  int have = 0;

  explicit NearestK(int k_) : k(K > 0 ? K : k_) {
    for (int j = 0; j < size(); ++j) {
      d2[j] = std::numeric_limits<double>::infinity();
      idx[j] = -1;
    }
  }
  int size() const { return K > 0 ? K : k; }
  bool full() const { return have == size(); }
  // Whether a point at squared distance at least `lower` with index at least `min_index`
  // could enter the list.
  bool may_enter(double lower, int32_t min_index) const {
    const int n = size();
    return have < n || lower < d2[n - 1] || (lower == d2[n - 1] && min_index < idx[n - 1]);
  }
  void offer(double dd, int32_t p) {
    const int n = size();
    if (have == n && !(dd < d2[n - 1] || (dd == d2[n - 1] && p < idx[n - 1]))) return;
    int pos = have < n ? have++ : n - 1;
    // the list is ordered, so the pairs after (dd, p) are those farther than dd, then
    // before them those as far with a larger index (ties are rare: one comparison mostly)
    while (pos > 0 && dd < d2[pos - 1]) {
      d2[pos] = d2[pos - 1];
      idx[pos] = idx[pos - 1];
      --pos;
    }
    while (pos > 0 && dd == d2[pos - 1] && p < idx[pos - 1]) {
      d2[pos] = d2[pos - 1];
      idx[pos] = idx[pos - 1];
      --pos;
    }
    d2[pos] = dd;
    idx[pos] = p;
  }
};

using Nearest = NearestK<0>;

inline double point_d2(const double* x, const double* q) {
  const double dx = x[0] - q[0], dy = x[1] - q[1], dz = x[2] - q[2];
  return dx * dx + dy * dy + dz * dz;
}

class PointTree {
 public:
  static constexpr int64_t kLeaf = 8;

  // The n points S (n, 3) with their indices `index` (n,) (the tree does not depend on
  // the order in which they come).
  void build(const double* S, const int32_t* index, int64_t n) {
    nodes_.clear();
    std::vector<Item> items(static_cast<size_t>(n));
    for (int64_t p = 0; p < n; ++p) {
      for (int a = 0; a < 3; ++a) items[p].x[a] = S[3 * p + a];
      items[p].index = index[p];
    }
    if (n > 0) {
      nodes_.reserve(static_cast<size_t>(2 * (n / kLeaf) + 2));
      build_node(items.data(), 0, n);
    }
    pts_.resize(static_cast<size_t>(3 * n));
    order_.resize(static_cast<size_t>(n));
    for (int64_t s = 0; s < n; ++s) {
      for (int a = 0; a < 3; ++a) pts_[3 * s + a] = items[s].x[a];
      order_[s] = items[s].index;
    }
  }

  // Offers to `best` every point that can be among its k best for the query q.
  template <class Best>
  void search(const double* q, Best& best) const {
    if (nodes_.empty()) return;
    struct Entry {
      double d2;
      int32_t node;
    };
    Entry stack[kMaxDepth + 2];
    int top = 0;
    stack[top++] = {box_d2(nodes_[0], q), 0};
    while (top > 0) {
      const Entry e = stack[--top];
      int32_t at = e.node;
      if (!best.may_enter(e.d2, nodes_[at].min_index)) continue;
      bool live = true;
      while (nodes_[at].right >= 0) {
        const int32_t l = at + 1, r = nodes_[at].right;
        const double dl = box_d2(nodes_[l], q), dr = box_d2(nodes_[r], q);
        // the nearer child now (the left, with the smaller indices, on a tie), the other later
        const bool right_first = dr < dl;
        const int32_t nr = right_first ? r : l, fr = right_first ? l : r;
        const double dn = right_first ? dr : dl, df = right_first ? dl : dr;
        if (best.may_enter(df, nodes_[fr].min_index)) stack[top++] = {df, fr};
        if (!best.may_enter(dn, nodes_[nr].min_index)) {
          live = false;
          break;
        }
        at = nr;
      }
      if (!live) continue;
      const Node& leaf = nodes_[at];
      for (int32_t s = leaf.begin; s < leaf.end; ++s)
        best.offer(point_d2(&pts_[3 * static_cast<size_t>(s)], q), order_[s]);
    }
  }

 private:
  // Median splits of at most 2^31 points into leaves of kLeaf halve the count each level.
  static constexpr int kMaxDepth = 40;

  struct Node {
    double lo[3], hi[3];  // the box of the node's points
    int32_t begin, end;   // its points, positions in tree order
    int32_t right;        // the right child (the left one is the next node); -1 for a leaf
    int32_t min_index;    // the smallest index of its points
  };

  std::vector<Node> nodes_;
  std::vector<double> pts_;
  std::vector<int32_t> order_;

  static double box_d2(const Node& nd, const double* q) {
    double d2 = 0.0;
    for (int a = 0; a < 3; ++a) {
      const double g =
          q[a] < nd.lo[a] ? nd.lo[a] - q[a] : (q[a] > nd.hi[a] ? q[a] - nd.hi[a] : 0.0);
      d2 += g * g;
    }
    return d2;
  }

  struct Item {
    double x[3];
    int32_t index;
  };

  void build_node(Item* items, int64_t b, int64_t e) {
    const size_t id = nodes_.size();
    nodes_.emplace_back();
    Node nd;
    nd.begin = static_cast<int32_t>(b);
    nd.end = static_cast<int32_t>(e);
    nd.right = -1;
    nd.min_index = items[b].index;
    for (int a = 0; a < 3; ++a) nd.lo[a] = nd.hi[a] = items[b].x[a];
    for (int64_t s = b + 1; s < e; ++s) {
      nd.min_index = std::min(nd.min_index, items[s].index);
      for (int a = 0; a < 3; ++a) {
        nd.lo[a] = std::min(nd.lo[a], items[s].x[a]);
        nd.hi[a] = std::max(nd.hi[a], items[s].x[a]);
      }
    }
    if (e - b > kLeaf) {
      int axis = 0;
      for (int a = 1; a < 3; ++a)
        if (nd.hi[a] - nd.lo[a] > nd.hi[axis] - nd.lo[axis]) axis = a;
      const int64_t m = b + (e - b) / 2;
      // (coordinate, index) is a total order, so each half holds one definite set of points
      std::nth_element(items + b, items + m, items + e, [axis](const Item& u, const Item& v) {
        return u.x[axis] < v.x[axis] || (u.x[axis] == v.x[axis] && u.index < v.index);
      });
      build_node(items, b, m);
      nd.right = static_cast<int32_t>(nodes_.size());
      build_node(items, m, e);
    }
    nodes_[id] = nd;
  }
};

}  // namespace spatial
}  // namespace voxax

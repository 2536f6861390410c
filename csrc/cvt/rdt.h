// Restricted Delaunay triangles read off surface samples ("fragments") and seeds.
//
// Every fragment x reports the seeds near a Voronoi vertex: of its four nearest seeds
// s1..s4 (distances d1 <= ... <= d4), the triangles {s1, sj, sk} whose farthest seed is
// within `tau` of d1 are candidates. A candidate's score at x is its spread (farthest
// distance minus d1) minus its margin (the distance of the nearest seed outside it minus
// its farthest distance): a fragment on the Voronoi vertex of a restricted Delaunay
// triangle has spread 0 and a positive margin (an empty ball), so true triangles score
// below the other triangles of nearly co-spherical seeds. Triangles without s1 are never
// proposed (s1 would lie inside their ball). Each candidate keeps its best score and the
// sum of its witnesses' normals, which orients it.
//
// The triangles are then taken greedily by (score, seeds): a triangle is accepted when
// none of its three directed edges is used yet, so every edge has at most two incident
// triangles, with opposite directions (the mesh stays an oriented pseudo-manifold and
// overlapping triangles of co-spherical seeds are never both taken). Holes left by
// co-spherical configurations (boundary loops of up to `max_hole` edges) are then
// fanned from the vertex that maximises the worst triangle quality. Finally every edge-
// connected component is flipped when most of its witness normals disagree with it.
//
// Everything but the nearest-seed search runs on one thread over sorted data, so the
// result does not depend on the thread count.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <stdexcept>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "common/host_pool.h"
#include "spatial/knn.h"

namespace voxax {
namespace cvt {

struct RdtStats {
  int64_t candidates = 0;  // distinct candidate triangles
  int64_t greedy = 0;      // triangles taken from candidates
  int64_t filled = 0;      // triangles added to fill holes
  int64_t flipped = 0;     // triangles flipped by the component vote
  int64_t boundary = 0;    // directed edges without a twin at the end
  int64_t components = 0;  // edge-connected components
};

struct Candidate {
  uint64_t key;  // three sorted seed ids, 21 bits each
  double score;
  double n[3];
};

inline uint64_t tri_key(int32_t a, int32_t b, int32_t c) {
  int32_t t[3] = {a, b, c};
  std::sort(t, t + 3);
  return (static_cast<uint64_t>(t[0]) << 42) | (static_cast<uint64_t>(t[1]) << 21) |
         static_cast<uint64_t>(t[2]);
}

inline uint64_t dir_key(int32_t a, int32_t b) {
  return (static_cast<uint64_t>(static_cast<uint32_t>(a)) << 32) | static_cast<uint32_t>(b);
}

inline double tri_quality(const double* S, int32_t a, int32_t b, int32_t c) {
  const double* p[3] = {S + 3 * a, S + 3 * b, S + 3 * c};
  double e[3], cr[3];
  for (int i = 0; i < 3; ++i) {
    const double* u = p[i];
    const double* v = p[(i + 1) % 3];
    e[i] = std::sqrt((u[0] - v[0]) * (u[0] - v[0]) + (u[1] - v[1]) * (u[1] - v[1]) +
                     (u[2] - v[2]) * (u[2] - v[2]));
  }
  const double ux = p[1][0] - p[0][0], uy = p[1][1] - p[0][1], uz = p[1][2] - p[0][2];
  const double vx = p[2][0] - p[0][0], vy = p[2][1] - p[0][1], vz = p[2][2] - p[0][2];
  cr[0] = uy * vz - uz * vy;
  cr[1] = uz * vx - ux * vz;
  cr[2] = ux * vy - uy * vx;
  const double area = 0.5 * std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
  const double half = 0.5 * (e[0] + e[1] + e[2]);
  const double emax = std::max(e[0], std::max(e[1], e[2]));
  if (!(half > 0.0) || !(emax > 0.0)) return 0.0;
  return (6.0 / std::sqrt(3.0)) * area / (half * emax);
}

inline double oriented(const double* S, int32_t a, int32_t b, int32_t c, const double* n) {
  const double* p = S + 3 * a;
  const double* q = S + 3 * b;
  const double* r = S + 3 * c;
  const double ux = q[0] - p[0], uy = q[1] - p[1], uz = q[2] - p[2];
  const double vx = r[0] - p[0], vy = r[1] - p[1], vz = r[2] - p[2];
  return (uy * vz - uz * vy) * n[0] + (uz * vx - ux * vz) * n[1] + (ux * vy - uy * vx) * n[2];
}

class Rdt {
 public:
  // S: (ns, 3) seeds; X, N: (np, 3) fragments and unit normals.
  void run(const double* S, int64_t ns, const double* X, const double* N, int64_t np, double tau,
           int max_hole, int threads) {
    S_ = S;
    ns_ = ns;
    spatial::PointGrid grid;
    grid.build(S, ns);
    const int k = static_cast<int>(std::min<int64_t>(4, ns));
    constexpr int64_t kChunk = 4096;
    const int64_t chunks = (np + kChunk - 1) / kChunk;
    std::vector<std::vector<Candidate>> per(static_cast<size_t>(chunks));
    spatial::parallel_chunks(np, kChunk, threads, [&](int64_t c, int64_t b, int64_t e) {
      std::vector<Candidate>& out = per[static_cast<size_t>(c)];
      int32_t idx[spatial::kMaxNeighbours];
      double dist[spatial::kMaxNeighbours];
      for (int64_t i = b; i < e; ++i) {
        grid.query(X + 3 * i, k, idx, dist);
        if (k < 3) continue;
        const int a = 0;  // triangles with the nearest seed only
        for (int bb = a + 1; bb < k; ++bb)
          for (int cc = bb + 1; cc < k; ++cc) {
            const double spread = dist[cc] - dist[0];
            if (!(spread <= tau)) continue;
            // the margin of the first seed outside the triple (none: k == 3)
            int outside = -1;
            for (int o = 0; o < k && outside < 0; ++o)
              if (o != a && o != bb && o != cc) outside = o;
            const double margin = outside >= 0 ? dist[outside] - dist[cc] : tau;
            const double score = spread - margin;
            Candidate cand;
            cand.key = tri_key(idx[a], idx[bb], idx[cc]);
            cand.score = score;
            for (int j = 0; j < 3; ++j) cand.n[j] = N[3 * i + j];
            out.push_back(cand);
          }
      }
      reduce(&out);  // neighbouring fragments report the same triangles: a chunk's are few
    });
    std::vector<Candidate> all;
    size_t total = 0;
    for (const auto& v : per) total += v.size();
    all.reserve(total);
    for (auto& v : per) all.insert(all.end(), v.begin(), v.end());
    per.clear();
    std::vector<Candidate> uniq = std::move(all);
    reduce(&uniq);
    stats.candidates = static_cast<int64_t>(uniq.size());
    std::sort(uniq.begin(), uniq.end(), [](const Candidate& a, const Candidate& b) {
      return a.score < b.score || (a.score == b.score && a.key < b.key);
    });
    // Greedy acceptance on free directed edges.
    used_.reserve(uniq.size() * 2);
    for (const Candidate& c : uniq) {
      int32_t a = static_cast<int32_t>(c.key >> 42);
      int32_t b = static_cast<int32_t>((c.key >> 21) & 0x1fffff);
      int32_t d = static_cast<int32_t>(c.key & 0x1fffff);
      const double o = oriented(S, a, b, d, c.n);
      if (o == 0.0) continue;
      if (o < 0.0) std::swap(b, d);
      if (try_add(a, b, d)) {
        normals_.push_back({c.n[0], c.n[1], c.n[2]});
        ++stats.greedy;
      }
    }
    for (int round = 0; round < 4; ++round)
      if (fill_holes(max_hole) == 0) break;
    vote();
    count_boundary();
  }

  std::vector<std::array<int32_t, 3>> faces;
  RdtStats stats;

 private:
  const double* S_ = nullptr;
  int64_t ns_ = 0;
  std::unordered_set<uint64_t> used_;
  std::unordered_set<uint64_t> tris_;
  std::vector<std::array<double, 3>> normals_;

  // Sorts candidates by (key, score) and keeps one per triangle: its best score and the
  // sum of the normals (summed in that order: deterministic, as the chunks are fixed).
  static void reduce(std::vector<Candidate>* c) {
    std::sort(c->begin(), c->end(), [](const Candidate& a, const Candidate& b) {
      return a.key < b.key || (a.key == b.key && a.score < b.score);
    });
    size_t out = 0;
    for (size_t i = 0; i < c->size();) {
      Candidate r = (*c)[i];
      size_t j = i + 1;
      for (; j < c->size() && (*c)[j].key == r.key; ++j)
        for (int t = 0; t < 3; ++t) r.n[t] += (*c)[j].n[t];
      (*c)[out++] = r;
      i = j;
    }
    c->resize(out);
  }

  bool try_add(int32_t a, int32_t b, int32_t c) {
    const uint64_t e0 = dir_key(a, b), e1 = dir_key(b, c), e2 = dir_key(c, a);
    if (used_.count(e0) || used_.count(e1) || used_.count(e2)) return false;
    if (!tris_.insert(tri_key(a, b, c)).second) return false;
    used_.insert(e0);
    used_.insert(e1);
    used_.insert(e2);
    faces.push_back({a, b, c});
    return true;
  }

  // Boundary half-edges u->v (no v->u): a hole is traced along the reversed edges.
  int64_t fill_holes(int max_hole) {
    std::vector<std::pair<int32_t, int32_t>> rev;  // v -> u for every boundary edge u -> v
    for (const auto& f : faces)
      for (int i = 0; i < 3; ++i) {
        const int32_t u = f[i], v = f[(i + 1) % 3];
        if (!used_.count(dir_key(v, u))) rev.push_back({v, u});
      }
    std::sort(rev.begin(), rev.end());
    // next[v] = w when the reversed boundary edge out of v is unique.
    std::unordered_map<int32_t, int32_t> next;
    std::unordered_set<int32_t> multi;
    for (size_t i = 0; i < rev.size(); ++i) {
      if ((i > 0 && rev[i - 1].first == rev[i].first) ||
          (i + 1 < rev.size() && rev[i + 1].first == rev[i].first))
        multi.insert(rev[i].first);
      else
        next[rev[i].first] = rev[i].second;
    }
    std::unordered_set<int32_t> seen;
    int64_t added = 0;
    for (const auto& e : rev) {
      const int32_t start = e.first;
      if (multi.count(start) || seen.count(start)) continue;
      std::vector<int32_t> loop;
      int32_t v = start;
      bool closed = false;
      for (int step = 0; step <= max_hole; ++step) {
        if (multi.count(v) || !next.count(v)) break;
        loop.push_back(v);
        v = next[v];
        if (v == start) {
          closed = true;
          break;
        }
      }
      for (int32_t u : loop) seen.insert(u);
      if (!closed || loop.size() < 3 || static_cast<int>(loop.size()) > max_hole) continue;
      // distinct vertices only
      std::vector<int32_t> sorted = loop;
      std::sort(sorted.begin(), sorted.end());
      if (std::adjacent_find(sorted.begin(), sorted.end()) != sorted.end()) continue;
      added += fan(loop);
    }
    stats.filled += added;
    return added;
  }

  // Fans the loop (in fill orientation) from its best vertex; returns triangles added.
  int64_t fan(const std::vector<int32_t>& loop) {
    const int m = static_cast<int>(loop.size());
    int best = -1;
    double best_q = -1.0;
    for (int r = 0; r < m; ++r) {
      double q = 2.0;
      bool ok = true;
      for (int i = 1; i + 1 < m && ok; ++i) {
        const int32_t a = loop[r], b = loop[(r + i) % m], c = loop[(r + i + 1) % m];
        q = std::min(q, tri_quality(S_, a, b, c));
        // diagonals must be new edges
        if (i >= 2 && (used_.count(dir_key(a, b)) || used_.count(dir_key(b, a)))) ok = false;
      }
      if (ok && q > best_q) {
        best_q = q;
        best = r;
      }
    }
    if (best < 0) return 0;
    int64_t added = 0;
    for (int i = 1; i + 1 < m; ++i) {
      const int32_t a = loop[best], b = loop[(best + i) % m], c = loop[(best + i + 1) % m];
      if (try_add(a, b, c)) {
        normals_.push_back({0.0, 0.0, 0.0});
        ++added;
      }
    }
    return added;
  }

  // Per edge-connected component: flip when the witness normals mostly disagree.
  void vote() {
    const int64_t nf = static_cast<int64_t>(faces.size());
    std::vector<int64_t> parent(nf);
    std::iota(parent.begin(), parent.end(), 0);
    auto find = [&](int64_t x) {
      while (parent[x] != x) {
        parent[x] = parent[parent[x]];
        x = parent[x];
      }
      return x;
    };
    std::unordered_map<uint64_t, int64_t> owner;
    owner.reserve(nf * 3);
    for (int64_t f = 0; f < nf; ++f)
      for (int i = 0; i < 3; ++i) owner[dir_key(faces[f][i], faces[f][(i + 1) % 3])] = f;
    for (int64_t f = 0; f < nf; ++f)
      for (int i = 0; i < 3; ++i) {
        auto it = owner.find(dir_key(faces[f][(i + 1) % 3], faces[f][i]));
        if (it != owner.end()) {
          const int64_t a = find(f), b = find(it->second);
          if (a != b) parent[std::max(a, b)] = std::min(a, b);
        }
      }
    std::vector<double> votes(nf, 0.0);
    int64_t comps = 0;
    for (int64_t f = 0; f < nf; ++f) {
      const int64_t r = find(f);
      if (r == f) ++comps;
      const double o = oriented(S_, faces[f][0], faces[f][1], faces[f][2], normals_[f].data());
      votes[r] += o > 0 ? 1.0 : (o < 0 ? -1.0 : 0.0);
    }
    stats.components = comps;
    for (int64_t f = 0; f < nf; ++f)
      if (votes[find(f)] < 0.0) {
        std::swap(faces[f][1], faces[f][2]);
        ++stats.flipped;
      }
  }

  void count_boundary() {
    std::unordered_set<uint64_t> d;
    for (const auto& f : faces)
      for (int i = 0; i < 3; ++i) d.insert(dir_key(f[i], f[(i + 1) % 3]));
    int64_t b = 0;
    for (const auto& f : faces)
      for (int i = 0; i < 3; ++i)
        if (!d.count(dir_key(f[(i + 1) % 3], f[i]))) ++b;
    stats.boundary = b;
  }
};

}  // namespace cvt
}  // namespace voxax

// Exact triangle-triangle intersection search: every pair of faces of one mesh (or of two
// meshes) whose closed triangles intersect, with adjacency rules for faces that share
// vertices. A host entry point called through ctypes (the output size is data dependent).
//
// C interface:
//   voxax_intersections(va, nva, fa, nfa, vb, nvb, fb, nfb, threads, &handle, err, errlen)
//     (threads <= 0: every core)
//     -> number of pairs (>= 0), or -1 with a message in err. vb == nullptr: self test.
//   voxax_intersections_copy(handle, out)  writes the (K, 2) int64 pairs, sorted.
//   voxax_intersections_free(handle)
//
// Candidates come from a sparse uniform grid over the faces' float64 bounding boxes (a pair
// is examined in exactly one cell: the first cell both boxes cover); the pairs of every chunk
// of cells are collected separately and the result is sorted, so the output does not
// depend on the thread count.

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "common/host_pool.h"
#include "intersect/tritri.h"

namespace voxax {
namespace intersect {

// Coordinates must be 0 or of magnitude in [kMinAbs, kMaxAbs] for the predicates to be
// exact (see predicates.h); kMaxAbs matches MAX_ABS_COORDINATE of the Python side.
constexpr double kMinAbs = 1e-50;
constexpr double kMaxAbs = 1e75;

struct Mesh {
  const double* v = nullptr;
  const int32_t* f = nullptr;
  int64_t nv = 0, nf = 0;
};

struct Box {
  double lo[3], hi[3];
};

struct Result {
  std::vector<int64_t> pairs;  // flattened (K, 2)
};

std::string check(const Mesh& m, const char* name) {
  if (m.nv < 0 || m.nf < 0) return std::string(name) + ": negative sizes";
  if (m.nv > INT32_MAX || m.nf > INT32_MAX)
    return std::string(name) + ": at most 2^31 - 1 vertices and faces are supported";
  if ((m.nv > 0 && m.v == nullptr) || (m.nf > 0 && m.f == nullptr))
    return std::string(name) + ": missing data";
  for (int64_t i = 0; i < 3 * m.nv; ++i) {
    const double x = m.v[i];
    if (!std::isfinite(x))
      return std::string(name) + ": vertex " + std::to_string(i / 3) +
             " has a NaN or Inf coordinate";
    const double a = std::fabs(x);
    if (a != 0.0 && (a < kMinAbs || a > kMaxAbs))
      return std::string(name) + ": vertex " + std::to_string(i / 3) +
             " has a coordinate of magnitude outside [1e-50, 1e75] (other than 0); the exact "
             "test needs coordinates in that range (rescale the mesh)";
  }
  for (int64_t i = 0; i < 3 * m.nf; ++i) {
    const int32_t k = m.f[i];
    if (k < 0 || k >= m.nv)
      return std::string(name) + ": face " + std::to_string(i / 3) + " refers to vertex " +
             std::to_string(k) + ", outside [0, " + std::to_string(m.nv) + ")";
  }
  return "";
}

struct Face {
  const double* p[3];
  int32_t idx[3];
  bool degenerate;  // geometrically (collinear corners) or by repeated indices
};

Face face_of(const Mesh& m, int64_t i) {
  Face fc;
  for (int k = 0; k < 3; ++k) {
    fc.idx[k] = m.f[3 * i + k];
    fc.p[k] = m.v + 3 * static_cast<int64_t>(fc.idx[k]);
  }
  fc.degenerate = fc.idx[0] == fc.idx[1] || fc.idx[1] == fc.idx[2] || fc.idx[0] == fc.idx[2] ||
                  tritri::degenerate(fc.p[0], fc.p[1], fc.p[2]);
  return fc;
}

// The verdict for two faces of one mesh, with the adjacency rules.
bool self_pair(const Face& a, const Face& b) {
  int shared = 0;
  int sa[3], sb[3];  // positions of the shared vertices in a and b
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      if (a.idx[i] == b.idx[j]) {
        bool seen = false;
        for (int s = 0; s < shared; ++s) seen |= a.idx[sa[s]] == a.idx[i];
        if (!seen) {
          sa[shared] = i;
          sb[shared] = j;
          ++shared;
        }
      }
  if (shared == 0) return tritri::triangles(a.p, b.p);
  if (a.degenerate || b.degenerate) return false;
  if (shared == 3) return true;  // the same triangle twice
  if (shared == 2) {
    const int oa = 3 - sa[0] - sa[1], ob = 3 - sb[0] - sb[1];
    return tritri::fold_across_edge(a.p[sa[0]], a.p[sa[1]], a.p[oa], b.p[ob]);
  }
  const double* s = a.p[sa[0]];
  const double* a1 = a.p[(sa[0] + 1) % 3];
  const double* a2 = a.p[(sa[0] + 2) % 3];
  const double* b1 = b.p[(sb[0] + 1) % 3];
  const double* b2 = b.p[(sb[0] + 2) % 3];
  return tritri::meet_beyond_vertex(s, a1, a2, b1, b2);
}

Box box_of(const Face& f) {
  Box b;
  for (int k = 0; k < 3; ++k) {
    b.lo[k] = std::min({f.p[0][k], f.p[1][k], f.p[2][k]});
    b.hi[k] = std::max({f.p[0][k], f.p[1][k], f.p[2][k]});
  }
  return b;
}

inline bool boxes_overlap(const Box& a, const Box& b) {
  for (int k = 0; k < 3; ++k)
    if (a.hi[k] < b.lo[k] || b.hi[k] < a.lo[k]) return false;
  return true;
}

// Runs body(begin, end) over fixed slices of [0, n) on up to `threads` threads (each
// index written by exactly one slice, so results do not depend on the thread count).
template <class Body>
void parallel_ranges(int64_t n, int threads, Body body) {
  const int64_t slices = std::max<int64_t>(1, std::min<int64_t>(threads, n / 4096));
  if (slices == 1) {
    body(0, n);
    return;
  }
  std::vector<std::thread> pool;
  std::atomic<bool> failed{false};
  for (int64_t t = 1; t < slices; ++t)
    pool.emplace_back([&, t]() {
      try {
        body(n * t / slices, n * (t + 1) / slices);
      } catch (...) {
        failed.store(true);
      }
    });
  try {
    body(0, n / slices);
  } catch (...) {
    failed.store(true);
  }
  for (auto& th : pool) th.join();
  if (failed.load()) throw std::bad_alloc();
}

// Stable LSD radix sort of (key, face) entries by key, keys in [0, limit): the same order
// as sorting the pairs, since the entries arrive in increasing face order.
void radix_sort(std::vector<std::pair<int64_t, int32_t>>* entries, int64_t limit) {
  std::vector<std::pair<int64_t, int32_t>> tmp(entries->size());
  int bits = 0;
  while (bits < 63 && (int64_t{1} << bits) < limit) ++bits;
  for (int shift = 0; shift < bits; shift += 16) {
    std::vector<size_t> count(65537, 0);
    for (const auto& e : *entries) ++count[((e.first >> shift) & 0xFFFF) + 1];
    for (size_t d = 0; d < 65536; ++d) count[d + 1] += count[d];
    for (const auto& e : *entries) tmp[count[(e.first >> shift) & 0xFFFF]++] = e;
    entries->swap(tmp);
  }
}

// A sparse grid over the union of the boxes, cell size twice the mean box size: the
// (cell, face) entries sorted by cell; only occupied cells exist.
struct Cells {
  int64_t dims[3];
  std::vector<int64_t> cmin, cmax;  // per face and axis, the first and last cell of its box
  std::vector<std::pair<int64_t, int32_t>> entries;
  std::vector<int64_t> start;  // first entry of every occupied cell, then the end

  void build(const std::vector<Box>& boxes) {
    const int64_t n = static_cast<int64_t>(boxes.size());
    double lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
      lo[k] = INFINITY;
      hi[k] = -INFINITY;
    }
    double mean_extent = 0.0;
    for (const Box& b : boxes)
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(lo[k], b.lo[k]);
        hi[k] = std::max(hi[k], b.hi[k]);
      }
    for (const Box& b : boxes)
      mean_extent += std::max({b.hi[0] - b.lo[0], b.hi[1] - b.lo[1], b.hi[2] - b.lo[2]}) / n;
    const double span = std::max({hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]});
    double h = std::max(2.0 * mean_extent, span / 1048576.0);  // fastest in tests: 2x
    if (!(h > 0.0)) h = 1.0;                                   // every face is one point
    double inv[3];
    cmin.assign(3 * n, 0);
    cmax.assign(3 * n, 0);
    for (;;) {
      for (int k = 0; k < 3; ++k) {
        dims[k] = std::max<int64_t>(
            1, static_cast<int64_t>(std::min((hi[k] - lo[k]) / h, 1048575.0)) + 1);
        inv[k] = hi[k] > lo[k] ? dims[k] / (hi[k] - lo[k]) : 0.0;
      }
      auto cell = [&](double x, int k) {
        double c = std::floor((x - lo[k]) * inv[k]);
        if (!(c >= 0.0)) c = 0.0;
        if (c > static_cast<double>(dims[k] - 1)) c = static_cast<double>(dims[k] - 1);
        return static_cast<int64_t>(c);
      };
      double total = 0.0;
      for (int64_t i = 0; i < n; ++i) {
        double count = 1.0;
        for (int k = 0; k < 3; ++k) {
          cmin[3 * i + k] = cell(boxes[i].lo[k], k);
          cmax[3 * i + k] = cell(boxes[i].hi[k], k);
          count *= static_cast<double>(cmax[3 * i + k] - cmin[3 * i + k] + 1);
        }
        total += count;
      }
      if (total <= 32.0 * static_cast<double>(n) + 1024.0) break;
      h *= 2.0;  // a few huge faces: coarser cells
    }
    entries.reserve(static_cast<size_t>(n) * 4);
    for (int64_t i = 0; i < n; ++i)
      for (int64_t x = cmin[3 * i]; x <= cmax[3 * i]; ++x)
        for (int64_t y = cmin[3 * i + 1]; y <= cmax[3 * i + 1]; ++y)
          for (int64_t z = cmin[3 * i + 2]; z <= cmax[3 * i + 2]; ++z)
            entries.emplace_back((x * dims[1] + y) * dims[2] + z, static_cast<int32_t>(i));
    radix_sort(&entries, dims[0] * dims[1] * dims[2]);
    for (size_t e = 0; e < entries.size(); ++e)
      if (e == 0 || entries[e].first != entries[e - 1].first)
        start.push_back(static_cast<int64_t>(e));
    start.push_back(static_cast<int64_t>(entries.size()));
  }
};

void run(const Mesh& A, const Mesh* B, int threads, Result* out) {
  const bool self = B == nullptr;
  const int64_t na = A.nf, nb = self ? 0 : B->nf;
  const int64_t n = na + nb;
  out->pairs.clear();
  if (na == 0 || (!self && nb == 0)) return;
  std::vector<Face> faces(n);
  std::vector<Box> boxes(n);
  parallel_ranges(n, threads, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      faces[i] = i < na ? face_of(A, i) : face_of(*B, i - na);
      boxes[i] = box_of(faces[i]);
    }
  });
  Cells cells;
  cells.build(boxes);
  const int64_t* dims = cells.dims;
  const std::vector<int64_t>& cmin = cells.cmin;
  const std::vector<std::pair<int64_t, int32_t>>& entries = cells.entries;
  const std::vector<int64_t>& start = cells.start;
  const int64_t ncells = static_cast<int64_t>(start.size()) - 1;

  // Each cell's candidate pairs; a pair is examined only in the first cell both cover.
  auto examine_cell = [&](int64_t c, std::vector<int64_t>* found) {
    const int64_t key = entries[start[c]].first;
    const int64_t z = key % dims[2], y = (key / dims[2]) % dims[1], x = key / (dims[1] * dims[2]);
    const int64_t b0 = start[c], b1 = start[c + 1];
    for (int64_t s = b0; s < b1; ++s) {
      const int64_t i = entries[s].second;
      if (!self && i >= na) continue;
      for (int64_t t = self ? s + 1 : b0; t < b1; ++t) {
        const int64_t j = entries[t].second;
        if (!self && j < na) continue;
        if (std::max(cmin[3 * i], cmin[3 * j]) != x ||
            std::max(cmin[3 * i + 1], cmin[3 * j + 1]) != y ||
            std::max(cmin[3 * i + 2], cmin[3 * j + 2]) != z)
          continue;
        if (!boxes_overlap(boxes[i], boxes[j])) continue;
        const bool hit =
            self ? self_pair(faces[i], faces[j]) : tritri::triangles(faces[i].p, faces[j].p);
        if (hit) {
          found->push_back(i);  // entries of a cell are in increasing face order: i < j
          found->push_back(self ? j : j - na);
        }
      }
    }
  };

  const int64_t chunk = 256;
  const int64_t nchunks = (ncells + chunk - 1) / chunk;
  std::vector<std::vector<int64_t>> found(nchunks);
  std::atomic<int64_t> next{0};
  std::atomic<bool> failed{false};
  auto worker = [&]() {
    try {
      for (;;) {
        const int64_t k = next.fetch_add(1);
        if (k >= nchunks || failed.load()) return;
        for (int64_t c = k * chunk; c < std::min(ncells, (k + 1) * chunk); ++c)
          examine_cell(c, &found[k]);
      }
    } catch (...) {
      failed.store(true);
    }
  };
  const int nthreads = static_cast<int>(std::max<int64_t>(1, std::min<int64_t>(threads, nchunks)));
  std::vector<std::thread> pool;
  for (int t = 1; t < nthreads; ++t) pool.emplace_back(worker);
  worker();
  for (auto& th : pool) th.join();
  if (failed.load()) throw std::bad_alloc();
  size_t total = 0;
  for (const auto& f : found) total += f.size();
  std::vector<std::pair<int64_t, int64_t>> pairs;
  pairs.reserve(total / 2);
  for (const auto& f : found)
    for (size_t s = 0; s < f.size(); s += 2) pairs.emplace_back(f[s], f[s + 1]);
  std::sort(pairs.begin(), pairs.end());
  out->pairs.resize(2 * pairs.size());
  for (size_t s = 0; s < pairs.size(); ++s) {
    out->pairs[2 * s] = pairs[s].first;
    out->pairs[2 * s + 1] = pairs[s].second;
  }
}

void set_error(char* err, int64_t errlen, const std::string& msg) {
  if (err == nullptr || errlen <= 0) return;
  const size_t n = std::min<size_t>(msg.size(), static_cast<size_t>(errlen - 1));
  std::memcpy(err, msg.data(), n);
  err[n] = '\0';
}

}  // namespace intersect
}  // namespace voxax

extern "C" {

__attribute__((visibility("default"))) int64_t voxax_intersections(
    const double* va, int64_t nva, const int32_t* fa, int64_t nfa, const double* vb, int64_t nvb,
    const int32_t* fb, int64_t nfb, int64_t threads, void** handle, char* err, int64_t errlen) {
  using namespace voxax::intersect;
  if (handle == nullptr) {
    set_error(err, errlen, "voxax.intersections: no output handle");
    return -1;
  }
  *handle = nullptr;
  try {
    Mesh a{va, fa, nva, nfa};
    std::string msg = check(a, "voxax.intersections: mesh");
    Mesh b{vb, fb, nvb, nfb};
    const bool two = vb != nullptr || fb != nullptr;
    if (msg.empty() && two) msg = check(b, "voxax.intersections: other");
    if (!msg.empty()) {
      set_error(err, errlen, msg);
      return -1;
    }
    Result* r = new Result();
    try {
      // threads <= 0: every core (the one rule of the host entry points)
      run(a, two ? &b : nullptr,
          voxax::spatial::resolve_threads(static_cast<int>(std::min<int64_t>(threads, 256))), r);
    } catch (...) {
      delete r;
      throw;
    }
    *handle = r;
    return static_cast<int64_t>(r->pairs.size() / 2);
  } catch (const std::bad_alloc&) {
    set_error(err, errlen, "voxax.intersections: out of memory");
  } catch (const std::exception& e) {
    set_error(err, errlen, std::string("voxax.intersections: ") + e.what());
  } catch (...) {
    set_error(err, errlen, "voxax.intersections: unknown error");
  }
  return -1;
}

__attribute__((visibility("default"))) void voxax_intersections_copy(void* handle, int64_t* out) {
  if (handle == nullptr || out == nullptr) return;
  const auto* r = static_cast<voxax::intersect::Result*>(handle);
  std::copy(r->pairs.begin(), r->pairs.end(), out);
}

__attribute__((visibility("default"))) void voxax_intersections_free(void* handle) {
  delete static_cast<voxax::intersect::Result*>(handle);
}

}  // extern "C"

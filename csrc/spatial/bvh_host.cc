// Eager host entry points of the BVH, a plain C ABI for ctypes (which releases
// the GIL while they run). Every function validates its input, catches every
// exception and reports failures as a non-zero status with a message in `err`.
//
//   voxax_bvh_build(V (nv, 3) f64, nv, F (nf, 3) i32, nf, &handle, err, errlen)
//   voxax_bvh_free(handle)
//   voxax_bvh_stats(handle, out[2]): node count, face count
//   voxax_bvh_float_records(handle): the first hits' float records (0: none, float64 only)
//   voxax_bvh_ray_avx2(handle): 1 where first hits take the AVX2 traversal, else 0
//   voxax_bvh_closest(handle, P (n, 3), n, max_dist, threads, dist, face, bary (n, 3),
//   point (n, 3), err, errlen)  (max_dist: inf, or no farther; see Bvh::closest)
//   voxax_bvh_first_hit(handle, O (n, 3), D (n, 3), n, tmin, tmax, any, threads,
//                       t, face, bary (n, 3), sign, err, errlen)
//   voxax_bvh_all_hits(handle, O, D, n, tmin, tmax, threads, counts (n,), &hits, err, errlen)
//   voxax_hits_copy(hits, t, face, bary, sign); voxax_hits_free(hits)

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <limits>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include "common/host_errors.h"
#include "common/host_pool.h"
#include "spatial/bvh.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {

using voxax::spatial::Bvh;
using voxax::spatial::RayHit;

constexpr int64_t kChunk = 256;  // queries per task: fixed, so results do not depend on threads

// The Morton keys of n >= 1 points over their bounding box, `bits` (at most 10) per axis.
std::vector<uint32_t> morton_keys(const double* X, int64_t n, int bits) {
  double lo[3] = {X[0], X[1], X[2]}, hi[3] = {X[0], X[1], X[2]};
  for (int64_t i = 1; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], X[3 * i + a]);
      hi[a] = std::max(hi[a], X[3 * i + a]);
    }
  auto spread = [](uint32_t x) {  // 10 bits -> every third bit
    x &= 0x3ff;
    x = (x | x << 16) & 0x030000ffu;
    x = (x | x << 8) & 0x0300f00fu;
    x = (x | x << 4) & 0x030c30c3u;
    x = (x | x << 2) & 0x09249249u;
    return x;
  };
  const double top = static_cast<double>((1 << bits) - 1);
  double scale[3];
  for (int a = 0; a < 3; ++a) scale[a] = hi[a] > lo[a] ? top / (hi[a] - lo[a]) : 0.0;
  std::vector<uint32_t> key(n);
  for (int64_t i = 0; i < n; ++i) {
    uint32_t k = 0;
    for (int a = 0; a < 3; ++a) {
      const double u = std::min(top, std::max(0.0, (X[3 * i + a] - lo[a]) * scale[a]));
      k |= spread(static_cast<uint32_t>(u)) << a;
    }
    key[i] = k;
  }
  return key;
}

// The order of closest-point queries: sorted along a Morton curve over their bounding box
// (10 bits per axis; ties by index), so that consecutive queries are close in space.
// Results are written back by index, and each query's answer does not depend on the order.
// A stable radix sort (three passes of 10 bits) keeps this serial step at a few per cent
// of the queries' time.
std::vector<int64_t> spatial_order(const double* X, int64_t n) {
  std::vector<int64_t> order(n);
  for (int64_t i = 0; i < n; ++i) order[i] = i;
  if (n < 2) return order;
  std::vector<uint32_t> key = morton_keys(X, n, 10);
  std::vector<int64_t> tmp(n);
  std::vector<uint32_t> tmp_key(n);
  std::vector<int64_t> count(1025);
  for (int shift = 0; shift < 30; shift += 10) {
    std::fill(count.begin(), count.end(), 0);
    for (int64_t j = 0; j < n; ++j) ++count[((key[j] >> shift) & 1023u) + 1];
    for (int b = 0; b < 1024; ++b) count[b + 1] += count[b];
    for (int64_t j = 0; j < n; ++j) {
      const int64_t at = count[(key[j] >> shift) & 1023u]++;
      tmp[at] = order[j];
      tmp_key[at] = key[j];
    }
    order.swap(tmp);
    key.swap(tmp_key);
  }
  return order;
}

struct Hits {
  std::vector<RayHit> hits;
};

bool check_rays(const double* O, const double* D, int64_t n, double tmin, double tmax,
                std::string* msg) {
  if (!voxax::check_host_coordinates(O, 3 * n, "ray origins", msg)) return false;
  if (!voxax::check_host_coordinates(D, 3 * n, "ray directions", msg)) return false;
  for (int64_t i = 0; i < n; ++i) {
    const double* d = D + 3 * i;
    if (d[0] == 0.0 && d[1] == 0.0 && d[2] == 0.0) {
      *msg = "voxax: ray direction " + std::to_string(i) + " is zero";
      return false;
    }
  }
  if (std::isnan(tmin) || std::isnan(tmax) || !(tmin <= tmax)) {
    *msg = "voxax: the ray interval needs tmin <= tmax (no NaN)";
    return false;
  }
  return true;
}

}  // namespace

VOXAX_EXPORT int voxax_bvh_build(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                                 void** handle, char* err, int64_t errlen) {
  *handle = nullptr;
  return voxax::host_guarded("the BVH", err, errlen, [&](std::string* msg) {
    if (nv < 0 || nf < 0 || nf > INT32_MAX / 2) {
      *msg = "voxax: the BVH takes at most 2^30 faces";
      return false;
    }
    if (!voxax::check_host_coordinates(V, 3 * nv, "vertices", msg) ||
        !voxax::check_coordinate_scale(V, 3 * nv, "vertices", msg))
      return false;
    if (!voxax::check_host_faces(F, nf, nv, msg)) return false;
    auto bvh = std::make_unique<Bvh>();  // freed if the build throws
    bvh->build(V, F, nf);
    *handle = bvh.release();
    return true;
  });
}

VOXAX_EXPORT void voxax_bvh_free(void* handle) { delete static_cast<Bvh*>(handle); }

VOXAX_EXPORT void voxax_bvh_stats(void* handle, int64_t* out) {
  const Bvh* bvh = static_cast<const Bvh*>(handle);
  out[0] = bvh ? bvh->node_count() : 0;
  out[1] = bvh ? bvh->face_count() : 0;
}

VOXAX_EXPORT int64_t voxax_bvh_float_records(void* handle) {
  const Bvh* bvh = static_cast<const Bvh*>(handle);
  return bvh ? bvh->float_record_count() : 0;
}

VOXAX_EXPORT int32_t voxax_bvh_ray_avx2(void* handle) {
  const Bvh* bvh = static_cast<const Bvh*>(handle);
  return bvh && bvh->ray_avx2() ? 1 : 0;
}

VOXAX_EXPORT int voxax_bvh_closest(void* handle, const double* P, int64_t n, double max_dist,
                                   int32_t threads, double* dist, int32_t* face, double* bary,
                                   double* point, char* err, int64_t errlen) {
  return voxax::host_guarded("the BVH", err, errlen, [&](std::string* msg) {
    const Bvh* bvh = static_cast<const Bvh*>(handle);
    if (!bvh) {
      *msg = "voxax: the BVH has been freed";
      return false;
    }
    if (!voxax::check_host_coordinates(P, 3 * n, "points", msg)) return false;
    if (!(max_dist >= 0.0)) {
      *msg = "voxax: the closest points' max_distance must be >= 0";
      return false;
    }
    // the squared bound, rounded up so that no point within max_dist is lost
    const double cap2 =
        std::isinf(max_dist) ? max_dist : std::nextafter(max_dist * max_dist, HUGE_VAL);
    const std::vector<int64_t> order = spatial_order(P, n);
    voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      int32_t hint = -1;
      for (int64_t j = b; j < e; ++j) {
        const int64_t i = order[j];
        const auto r = bvh->closest(P + 3 * i, hint, cap2);
        if (r.slot >= 0) hint = r.slot;
        dist[i] = std::sqrt(r.dist2);
        face[i] = r.face;
        for (int a = 0; a < 3; ++a) {
          bary[3 * i + a] = r.bary[a];
          point[3 * i + a] = r.point[a];
        }
      }
    });
    return true;
  });
}

VOXAX_EXPORT int voxax_bvh_first_hit(void* handle, const double* O, const double* D, int64_t n,
                                     double tmin, double tmax, int32_t any, int32_t threads,
                                     double* t, int32_t* face, double* bary, int8_t* sign,
                                     char* err, int64_t errlen) {
  return voxax::host_guarded("the BVH", err, errlen, [&](std::string* msg) {
    const Bvh* bvh = static_cast<const Bvh*>(handle);
    if (!bvh) {
      *msg = "voxax: the BVH has been freed";
      return false;
    }
    if (!check_rays(O, D, n, tmin, tmax, msg)) return false;
    // Rays in their own order, several traced at once (Bvh::first_hits); each result is
    // written where its ray was read.
    voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      bvh->first_hits(
          b, e, any != 0,
          [&](int64_t j) { return voxax::spatial::make_ray(O + 3 * j, D + 3 * j, tmin, tmax); },
          [&](int64_t j, bool found, const RayHit& h) {
            voxax::spatial::store_hit(found, h, j, t, face, bary, sign);
          });
    });
    return true;
  });
}

VOXAX_EXPORT int voxax_bvh_all_hits(void* handle, const double* O, const double* D, int64_t n,
                                    double tmin, double tmax, int32_t threads, int64_t* counts,
                                    void** out, char* err, int64_t errlen) {
  *out = nullptr;
  return voxax::host_guarded("the BVH", err, errlen, [&](std::string* msg) {
    const Bvh* bvh = static_cast<const Bvh*>(handle);
    if (!bvh) {
      *msg = "voxax: the BVH has been freed";
      return false;
    }
    if (!check_rays(O, D, n, tmin, tmax, msg)) return false;
    const int64_t chunks = (n + kChunk - 1) / kChunk;
    std::vector<std::vector<RayHit>> parts(chunks);
    voxax::spatial::parallel_chunks(n, kChunk, threads, [&](int64_t c, int64_t b, int64_t e) {
      for (int64_t i = b; i < e; ++i) {
        const size_t before = parts[c].size();
        const auto ray = voxax::spatial::make_ray(O + 3 * i, D + 3 * i, tmin, tmax);
        bvh->all_hits(ray, &parts[c]);
        counts[i] = static_cast<int64_t>(parts[c].size() - before);
      }
    });
    auto hits = std::make_unique<Hits>();  // freed if a copy throws
    size_t total = 0;
    for (const auto& p : parts) total += p.size();
    hits->hits.reserve(total);
    for (auto& p : parts) {
      hits->hits.insert(hits->hits.end(), p.begin(), p.end());
      std::vector<RayHit>().swap(p);
    }
    *out = hits.release();
    return true;
  });
}

VOXAX_EXPORT int64_t voxax_hits_size(void* hits) {
  return hits ? static_cast<int64_t>(static_cast<Hits*>(hits)->hits.size()) : 0;
}

VOXAX_EXPORT void voxax_hits_copy(void* hits, double* t, int32_t* face, double* bary,
                                  int8_t* sign) {
  if (!hits) return;
  const auto& h = static_cast<Hits*>(hits)->hits;
  for (size_t i = 0; i < h.size(); ++i) {
    t[i] = h[i].t;
    face[i] = h[i].face;
    sign[i] = h[i].sign;
    for (int a = 0; a < 3; ++a) bary[3 * i + a] = h[i].bary[a];
  }
}

VOXAX_EXPORT void voxax_hits_free(void* hits) { delete static_cast<Hits*>(hits); }

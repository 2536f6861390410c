// Eager host entry points of the line crossings (dexels), a plain C ABI for ctypes
// (which releases the GIL while they run). Every function validates its input, catches
// every exception and reports failures as a non-zero status with a message in `err`.
//
//   voxax_line_crossings(V (nv, 3) f64, nv, F (nf, 3) i32, nf, axis, L0 (n0,), n0,
//                        L1 (n1,), n1, threads, &handle, err, errlen)
//     L0, L1: strictly increasing line coordinates on the two axes other than `axis`, in
//     increasing axis order; line (i0, i1) has index i0 * n1 + i1.
//   voxax_crossings_size(handle) -> number of crossings
//   voxax_crossings_copy(handle, offsets (n0 * n1 + 1,) i64, depth f64, sign i8, face i32)
//   voxax_crossings_free(handle)

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

#include "common/constants.h"
#include "common/host_errors.h"
#include "common/host_pool.h"
#include "raster/line_crossings.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {

using voxax::raster::Crossing;

// Coordinates must be 0 or of magnitude in [kMinAbs, kMaxAbsCoordinate] for the exact
// predicates (see intersect/predicates.h).
constexpr double kMinAbs = 1e-50;
constexpr int64_t kFaceChunk = 2048;  // faces per task: fixed, so results do not depend on threads
constexpr int64_t kLineChunk = 4096;  // lines per sorting task
constexpr int64_t kMaxLines = int64_t{1} << 36;

struct Crossings {
  std::vector<int64_t> offsets;
  std::vector<Crossing> items;
};

bool check_value(double x, const char* what, int64_t row, std::string* msg) {
  const double m = std::fabs(x);
  if (!std::isfinite(x)) {
    *msg = std::string("voxax: ") + what + " contain NaN or Inf (row " + std::to_string(row) + ")";
    return false;
  }
  if (m != 0.0 && (m < kMinAbs || m > voxax::kMaxAbsCoordinate)) {
    *msg = std::string("voxax: ") + what +
           " have a coordinate of magnitude outside [1e-50, 1e75] " + "other than 0 (row " +
           std::to_string(row) + "); the exact test needs that range";
    return false;
  }
  return true;
}

bool check_lines(const double* L, int64_t n, const char* what, std::string* msg) {
  if (n < 0) {
    *msg = std::string("voxax: negative number of ") + what;
    return false;
  }
  for (int64_t i = 0; i < n; ++i) {
    if (!check_value(L[i], what, i, msg)) return false;
    if (i > 0 && !(L[i] > L[i - 1])) {
      *msg = std::string("voxax: ") + what + " must be strictly increasing (at " +
             std::to_string(i) + ")";
      return false;
    }
  }
  return true;
}

// The crossings of faces [begin, end) with every line, appended to `out`.
void cross_faces(const double* V, const int32_t* F, int64_t begin, int64_t end, int axis,
                 const double* L0, int64_t n0, const double* L1, int64_t n1,
                 std::vector<Crossing>* out) {
  // u, v: the two other axes in cyclic order after `axis`, so that the orientation of the
  // projection is the sign of the normal's component along `axis`.
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  const bool u_first = u < v;  // whether u is the first of the two in increasing axis order
  const double* Lu = u_first ? L0 : L1;
  const double* Lv = u_first ? L1 : L0;
  const int64_t nu = u_first ? n0 : n1, nv = u_first ? n1 : n0;
  const voxax::raster::LineSearch su(Lu, nu), sv(Lv, nv);
  for (int64_t f = begin; f < end; ++f) {
    double p[3][2], z[3];
    for (int c = 0; c < 3; ++c) {
      const double* x = V + 3 * static_cast<int64_t>(F[3 * f + c]);
      p[c][0] = x[u];
      p[c][1] = x[v];
      z[c] = x[axis];
    }
    // Lines on the bounding box's border may be crossed (the perturbation decides).
    // Small faces between the lines (most faces of a fine mesh) stop at the first test.
    const double umin = std::min({p[0][0], p[1][0], p[2][0]});
    const double umax = std::max({p[0][0], p[1][0], p[2][0]});
    const int64_t iu0 = su.lower(umin), iu1 = su.upper(umax);
    if (iu0 >= iu1) continue;
    const double vmin = std::min({p[0][1], p[1][1], p[2][1]});
    const double vmax = std::max({p[0][1], p[1][1], p[2][1]});
    const int64_t iv0 = sv.lower(vmin), iv1 = sv.upper(vmax);
    if (iv0 >= iv1) continue;
    const int orientation = voxax::exact::orient2d(p[0], p[1], p[2]);
    if (orientation == 0) continue;
    const double zmin = std::min({z[0], z[1], z[2]}), zmax = std::max({z[0], z[1], z[2]});
    for (int64_t iu = iu0; iu < iu1; ++iu) {
      for (int64_t iv = iv0; iv < iv1; ++iv) {
        const double q[2] = {Lu[iu], Lv[iv]};
        double depth = 0.0;
        const int s = voxax::raster::cross_triangle(p, z, orientation, q, u_first, &depth);
        if (s == 0) continue;
        const int64_t line = u_first ? iu * nv + iv : iv * nu + iu;
        out->push_back({std::min(zmax, std::max(zmin, depth)), line, static_cast<int32_t>(f),
                        static_cast<int8_t>(s)});
      }
    }
  }
}

}  // namespace

VOXAX_EXPORT int voxax_line_crossings(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                                      int32_t axis, const double* L0, int64_t n0, const double* L1,
                                      int64_t n1, int32_t threads, void** handle, char* err,
                                      int64_t errlen) {
  *handle = nullptr;
  return voxax::host_guarded("line_crossings", err, errlen, [&](std::string* msg) {
    if (axis < 0 || axis > 2) {
      *msg = "voxax: line_crossings: axis must be 0, 1 or 2, got " + std::to_string(axis);
      return false;
    }
    if (nv < 0 || nf < 0 || nf > std::numeric_limits<int32_t>::max()) {
      *msg = "voxax: line_crossings: negative vertex or face count, or more than 2^31 - 1 faces";
      return false;
    }
    for (int64_t i = 0; i < 3 * nv; ++i)
      if (!check_value(V[i], "vertices", i / 3, msg)) return false;
    if (!voxax::check_host_faces(F, nf, nv, msg)) return false;
    if (n0 < 0 || n1 < 0) {
      *msg = "voxax: negative number of line coordinates";
      return false;
    }
    if (n0 > 0 && n1 > kMaxLines / n0) {
      *msg = "voxax: line_crossings takes at most 2^36 lines";
      return false;
    }
    if (!check_lines(L0, n0, "line coordinates", msg)) return false;
    if (!check_lines(L1, n1, "line coordinates", msg)) return false;
    const int64_t lines = n0 * n1;
    const int64_t chunks = (nf + kFaceChunk - 1) / kFaceChunk;
    std::vector<std::vector<Crossing>> parts(chunks);
    voxax::spatial::parallel_chunks(nf, kFaceChunk, threads, [&](int64_t c, int64_t b, int64_t e) {
      cross_faces(V, F, b, e, axis, L0, n0, L1, n1, &parts[c]);
    });
    auto out = std::make_unique<Crossings>();  // freed if a step throws
    // A counting sort by line (stable, in face order), then each line's crossings by
    // depth and face: a total order, the same for any thread count.
    out->offsets.assign(lines + 1, 0);
    size_t total = 0;
    for (const auto& part : parts) {
      total += part.size();
      for (const Crossing& x : part) ++out->offsets[x.line + 1];
    }
    for (int64_t l = 0; l < lines; ++l) out->offsets[l + 1] += out->offsets[l];
    out->items.resize(total);
    std::vector<int64_t> cursor(out->offsets.begin(), out->offsets.end() - 1);
    for (auto& part : parts) {
      for (const Crossing& x : part) out->items[cursor[x.line]++] = x;
      std::vector<Crossing>().swap(part);
    }
    voxax::spatial::parallel_chunks(lines, kLineChunk, threads, [&](int64_t, int64_t b, int64_t e) {
      for (int64_t l = b; l < e; ++l) {
        auto first = out->items.begin() + out->offsets[l];
        auto last = out->items.begin() + out->offsets[l + 1];
        if (last - first > 1) std::sort(first, last, voxax::raster::crossing_less);
      }
    });
    *handle = out.release();
    return true;
  });
}

VOXAX_EXPORT int64_t voxax_crossings_size(void* handle) {
  return handle ? static_cast<int64_t>(static_cast<Crossings*>(handle)->items.size()) : 0;
}

VOXAX_EXPORT void voxax_crossings_copy(void* handle, int64_t* offsets, double* depth, int8_t* sign,
                                       int32_t* face) {
  if (!handle) return;
  const auto* c = static_cast<const Crossings*>(handle);
  std::copy(c->offsets.begin(), c->offsets.end(), offsets);
  for (size_t i = 0; i < c->items.size(); ++i) {
    depth[i] = c->items[i].depth;
    sign[i] = c->items[i].sign;
    face[i] = c->items[i].face;
  }
}

VOXAX_EXPORT void voxax_crossings_free(void* handle) { delete static_cast<Crossings*>(handle); }

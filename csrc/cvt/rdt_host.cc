// Eager host entry points of the restricted Delaunay extraction, a plain C ABI for
// ctypes (which releases the GIL while they run). Every function validates its input,
// catches every exception and reports failures as a non-zero status with a message.
//
//   voxax_rdt_run(S (ns, 3), ns, X (np, 3), np, N (nn, 3), nn, tau, max_hole, threads,
//                 &handle, err, errlen)   (nn must equal np: one normal per fragment)
//   voxax_rdt_size(handle) -> number of faces
//   voxax_rdt_copy(handle, faces (nf, 3) i32, stats (6,) i64)
//   voxax_rdt_free(handle)

#include <cmath>
#include <cstdint>
#include <memory>
#include <string>

#include "common/host_errors.h"
#include "cvt/rdt.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

VOXAX_EXPORT int voxax_rdt_run(const double* S, int64_t ns, const double* X, int64_t np,
                               const double* N, int64_t nn, double tau, int32_t max_hole,
                               int32_t threads, void** handle, char* err, int64_t errlen) {
  *handle = nullptr;
  return voxax::host_guarded("the RDT", err, errlen, [&](std::string* msg) {
    if (ns < 3) {
      *msg = "voxax: the RDT needs at least 3 seeds";
      return false;
    }
    if (ns >= (int64_t{1} << 21)) {
      *msg = "voxax: the RDT takes fewer than 2^21 seeds";
      return false;
    }
    if (np < 1) {
      *msg = "voxax: the RDT needs fragments (empty surface)";
      return false;
    }
    if (nn != np) {
      *msg = "voxax: the RDT needs one normal per fragment (" + std::to_string(np) +
             " fragments, " + std::to_string(nn) + " normals)";
      return false;
    }
    if (!(tau >= 0.0) || !std::isfinite(tau)) {
      *msg = "voxax: the RDT tolerance must be finite and >= 0";
      return false;
    }
    if (max_hole < 3 || max_hole > 64) {
      *msg = "voxax: max_hole must lie in [3, 64]";
      return false;
    }
    if (!voxax::check_host_coordinates(S, 3 * ns, "seeds", msg)) return false;
    if (!voxax::check_host_coordinates(X, 3 * np, "fragments", msg)) return false;
    if (!voxax::check_host_coordinates(N, 3 * np, "normals", msg)) return false;
    auto rdt = std::make_unique<voxax::cvt::Rdt>();
    rdt->run(S, ns, X, N, np, tau, max_hole, threads);
    *handle = rdt.release();
    return true;
  });
}

VOXAX_EXPORT int64_t voxax_rdt_size(void* handle) {
  const auto* r = static_cast<const voxax::cvt::Rdt*>(handle);
  return r ? static_cast<int64_t>(r->faces.size()) : 0;
}

VOXAX_EXPORT void voxax_rdt_copy(void* handle, int32_t* faces, int64_t* stats) {
  const auto* r = static_cast<const voxax::cvt::Rdt*>(handle);
  if (!r) return;
  for (size_t f = 0; f < r->faces.size(); ++f)
    for (int i = 0; i < 3; ++i) faces[3 * f + i] = r->faces[f][i];
  const auto& s = r->stats;
  const int64_t v[6] = {s.candidates, s.greedy, s.filled, s.flipped, s.boundary, s.components};
  for (int i = 0; i < 6; ++i) stats[i] = v[i];
}

VOXAX_EXPORT void voxax_rdt_free(void* handle) { delete static_cast<voxax::cvt::Rdt*>(handle); }

// Eager host entry points of the Faithful Contouring encoder, a plain C ABI for
// ctypes (which releases the GIL while they run). Every function validates its
// input, catches every exception and reports failures as a non-zero status with
// a message in `err`.
//
//   voxax_fc_encode(V (nv, 3) f64, nv, F (nf, 3) i32, nf, open (nf,) u8 or null (bit k: edge k
//                   of the face is an open boundary), box[6] (lower, upper), shape[3],
//                   params[3] (lambda_n, lambda_d, weight_power), flags, joined (J,) i64
//                   sorted or null, J, threads, &handle, sizes[3] (rows, faces, pieces), err,
//                   errlen)
//       joined: cells that get one anchor for all their pieces even with components
//       flags: 1 clamp, 2 components, 4 record faces per row, 8 pieces only, 16 find the
//       open boundary edges here (instead of `open`)
//   voxax_fc_rows(handle, index (K,) i64, component (K,) i32, offset (K, 3), normal (K, 3),
//                 area (K,), clamped (K,) i32, face_count (K,) i64, faces (sum,) i32)
//   voxax_fc_pieces(handle, cell (P,) i64, face (P,) i32, area (P,), centroid (P, 3))
//   voxax_fc_free(handle)
//   voxax_fc_decode, voxax_fc_node_side, voxax_fc_signs: see below

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "common/constants.h"
#include "common/grid.h"
#include "common/host_errors.h"
#include "common/host_pool.h"
#include "fc/decode.h"
#include "fc/encode.h"
#include "fc/signs.h"
#include "intersect/predicates.h"

#define VOXAX_EXPORT extern "C" __attribute__((visibility("default")))

namespace {

using voxax::fc::Rows;

// The rows of an encoding, as the slabs made them (concatenated in slab order).
struct Encoded {
  std::vector<Rows> parts;
};

// Copies the concatenation of field `member` of every part to `out` (when not null).
template <typename T>
void copy_parts(const Encoded& e, std::vector<T> Rows::* member, T* out) {
  if (!out) return;
  for (const auto& p : e.parts) out = std::copy((p.*member).begin(), (p.*member).end(), out);
}

// Stores the message of a rejected input for `host_guarded` and returns false.
struct Reject {
  std::string* msg;
  bool operator()(std::string m) const {
    *msg = std::move(m);
    return false;
  }
};

// The checks of the mesh: sizes, finite vertices, face indices in range.
bool check_mesh(const double* V, int64_t nv, const int32_t* F, int64_t nf, const Reject& fail) {
  if (nv < 0 || nf < 0 || nv > INT32_MAX || nf > INT32_MAX)
    return fail("voxax: fc.encode takes at most 2^31 - 1 vertices and faces");
  if ((nv > 0 && !V) || (nf > 0 && !F)) return fail("voxax: fc.encode got a null mesh array");
  for (int64_t i = 0; i < 3 * nv; ++i)
    if (!std::isfinite(V[i]) || std::fabs(V[i]) > voxax::kMaxAbsCoordinate)
      return fail(
          "voxax: fc.encode: vertices contain NaN, Inf or a coordinate beyond 1e75 "
          "(row " +
          std::to_string(i / 3) + ")");
  for (int64_t i = 0; i < 3 * nf; ++i)
    if (F[i] < 0 || F[i] >= nv)
      return fail("voxax: fc.encode: face index " + std::to_string(F[i]) + " is out of range [0, " +
                  std::to_string(nv) + ") (face " + std::to_string(i / 3) + ")");
  return true;
}

// Reads params (lambda_n, lambda_d, weight_power) and the flags 1, 2, 4 into *prm.
bool read_params(const double* params, int32_t flags, voxax::fc::Params* prm, const Reject& fail) {
  prm->lambda_n = params[0];
  prm->lambda_d = params[1];
  prm->power = params[2];
  if (!(prm->lambda_n >= 0) || !std::isfinite(prm->lambda_n))
    return fail("voxax: fc.encode: lambda_n must be >= 0 and finite");
  if (!(prm->lambda_d > 0) || !std::isfinite(prm->lambda_d))
    return fail("voxax: fc.encode: lambda_d must be > 0 and finite");
  if (!(prm->power >= 0) || !(prm->power <= 16))
    return fail("voxax: fc.encode: weight_power must lie in [0, 16]");
  if (flags < 0 || flags > 31) return fail("voxax: fc.encode: bad flags");
  prm->clamp = (flags & 1) != 0;
  prm->components = (flags & 2) != 0;
  prm->faces = (flags & 4) != 0;
  return true;
}

}  // namespace

VOXAX_EXPORT int voxax_fc_encode(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                                 const uint8_t* open, const double* box, const int64_t* shape,
                                 const double* params, int32_t flags, const int64_t* joined,
                                 int64_t njoined, int32_t threads, void** handle, int64_t* sizes,
                                 char* err, int64_t errlen) {
  if (handle) *handle = nullptr;
  const double t_start = voxax::fc::thread_seconds();
  const bool profile = std::getenv("VOXAX_FC_PROFILE") != nullptr;
  auto since = [&]() { return voxax::fc::thread_seconds() - t_start; };
  return voxax::host_guarded("fc.encode", err, errlen, [&](std::string* msg) {
    const Reject fail{msg};
    if (!handle || !sizes || !box || !shape || !params)
      return fail("voxax: fc.encode got a null argument");
    if (!check_mesh(V, nv, F, nf, fail)) return false;
    voxax::GridSpec g;
    const voxax::ffi::Error ge = voxax::check_grid(3, box[0], box[3], shape[0], box[1], box[4],
                                                   shape[1], box[2], box[5], shape[2], 0, 0, &g);
    if (ge.failure()) return fail(ge.message());
    voxax::fc::Params prm;
    if (!read_params(params, flags, &prm, fail)) return false;
    const double t_checked = since();
    std::vector<uint8_t> open_bits;
    if (flags & 16) {
      open_bits = voxax::fc::open_edges(F, nf);
      // A closed mesh has no boundary lines: the solves need not look for them.
      const bool any = std::any_of(open_bits.begin(), open_bits.end(), [](uint8_t b) { return b; });
      prm.open = any ? open_bits.data() : nullptr;
    } else {
      prm.open = open;
    }
    if (njoined < 0 || (njoined > 0 && !joined))
      return fail("voxax: fc.encode got a bad list of joined cells");
    for (int64_t r = 1; r < njoined; ++r)
      if (joined[r] <= joined[r - 1])
        return fail("voxax: fc.encode: joined cells must be sorted and unique");
    prm.joined = joined;
    prm.njoined = njoined;
    const bool pieces_only = (flags & 8) != 0;
    g.build_planes();

    // Slabs of whole x-columns; their width depends on the grid only.
    voxax::Tiling tl;
    tl.tx = std::max<int64_t>(1, (g.n[0] + 127) / 128);
    tl.ty = g.n[1];
    tl.ntx = (g.n[0] + tl.tx - 1) / tl.tx;
    tl.nty = 1;
    voxax::Bins bins;
    voxax::bin_faces(
        nullptr, tl, nf,
        [&](int64_t t, int32_t* r) {
          const double x[3] = {V[3 * int64_t(F[3 * t])], V[3 * int64_t(F[3 * t + 1])],
                               V[3 * int64_t(F[3 * t + 2])]};
          const double lo = std::min({x[0], x[1], x[2]}), hi = std::max({x[0], x[1], x[2]});
          int64_t i0, i1;
          if (!g.span(0, lo, hi, &i0, &i1)) return false;
          r[0] = static_cast<int32_t>(i0 / tl.tx);
          r[1] = static_cast<int32_t>(i1 / tl.tx);
          r[2] = 0;
          r[3] = 0;
          return true;
        },
        &bins);
    const double t_binned = since();
    const int64_t slabs = tl.ntx;
    std::vector<Rows> parts(slabs);
    // VOXAX_FC_PROFILE=1 prints the times of the encoder's stages.
    std::vector<double> seconds(profile ? 3 * slabs : 0, 0.0);
    const auto t_bins = std::chrono::steady_clock::now();
    voxax::spatial::parallel_chunks(slabs, 1, threads, [&](int64_t s, int64_t, int64_t) {
      const int64_t ia = s * tl.tx, ib = std::min(g.n[0], ia + tl.tx);
      voxax::fc::encode_slab(g, prm, V, F, bins, s, ia, ib, pieces_only, &parts[s],
                             profile ? &seconds[3 * s] : nullptr);
    });
    if (profile) {
      double sum[3] = {0, 0, 0};
      for (int64_t s = 0; s < slabs; ++s)
        for (int k = 0; k < 3; ++k) sum[k] += seconds[3 * s + k];
      std::fprintf(stderr,
                   "fc.encode: slabs %.3f s wall; thread CPU s: clip %.3f, sort %.3f, solve %.3f\n",
                   std::chrono::duration<double>(std::chrono::steady_clock::now() - t_bins).count(),
                   sum[0], sum[1], sum[2]);
    }
    // The slabs' rows stay where they are: the copy functions concatenate them in slab
    // order.
    auto rows = std::make_unique<Encoded>();
    rows->parts.swap(parts);
    int64_t k = 0, nfaces = 0, npieces = 0;
    for (const auto& p : rows->parts) {
      k += static_cast<int64_t>(p.index.size());
      nfaces += static_cast<int64_t>(p.faces.size());
      npieces += static_cast<int64_t>(p.p_cell.size());
    }
    if (profile)
      std::fprintf(stderr,
                   "fc.encode: thread CPU s: checks %.3f, open edges + bins %.3f, total %.3f\n",
                   t_checked, t_binned - t_checked, since());
    sizes[0] = k;
    sizes[1] = nfaces;
    sizes[2] = npieces;
    *handle = rows.release();
    return true;
  });
}

VOXAX_EXPORT void voxax_fc_rows(void* handle, int64_t* index, int32_t* component, double* offset,
                                double* normal, double* area, int32_t* clamped, int64_t* face_count,
                                int32_t* faces) {
  const Encoded* e = static_cast<const Encoded*>(handle);
  if (!e) return;
  copy_parts(*e, &Rows::index, index);
  copy_parts(*e, &Rows::component, component);
  copy_parts(*e, &Rows::offset, offset);
  copy_parts(*e, &Rows::normal, normal);
  copy_parts(*e, &Rows::area, area);
  copy_parts(*e, &Rows::clamped, clamped);
  bool counted = true;
  for (const auto& p : e->parts) counted = counted && p.face_count.size() == p.index.size();
  if (counted) copy_parts(*e, &Rows::face_count, face_count);
  copy_parts(*e, &Rows::faces, faces);
}

VOXAX_EXPORT void voxax_fc_pieces(void* handle, int64_t* cell, int32_t* face, double* area,
                                  double* centroid) {
  const Encoded* e = static_cast<const Encoded*>(handle);
  if (!e) return;
  copy_parts(*e, &Rows::p_cell, cell);
  copy_parts(*e, &Rows::p_face, face);
  copy_parts(*e, &Rows::p_area, area);
  copy_parts(*e, &Rows::p_centroid, centroid);
}

VOXAX_EXPORT void voxax_fc_free(void* handle) { delete static_cast<Encoded*>(handle); }

// voxax_fc_decode(index (K,) i64, P (K, 3), N (K, 3), S (K, 12) i8, K, shape[3], split, threads,
//                 &handle, &count, err, errlen): triangles as row triples; copy with
//                 voxax_fc_triangles(handle, out (T, 3) i64), free with voxax_fc_free_triangles.
VOXAX_EXPORT int voxax_fc_decode(const int64_t* index, const double* P, const double* N,
                                 const int8_t* S, int64_t K, const int64_t* shape, int32_t split,
                                 int32_t threads, void** handle, int64_t* count, char* err,
                                 int64_t errlen) {
  if (handle) *handle = nullptr;
  return voxax::host_guarded("fc.decode", err, errlen, [&](std::string* msg) {
    const Reject fail{msg};
    if (!handle || !count || !shape || K < 0 || (K > 0 && (!index || !P || !N || !S)))
      return fail("voxax: fc.decode got a null argument");
    if (split < 0 || split > 2) return fail("voxax: fc.decode: bad split mode");
    voxax::fc::DecodeInput in;
    in.K = K;
    in.index = index;
    in.P = P;
    in.N = N;
    in.S = S;
    in.split = split;
    for (int a = 0; a < 3; ++a) {
      if (shape[a] < 1 || shape[a] > voxax::kMaxCellsPerAxis)
        return fail("voxax: fc.decode: bad grid shape");
      in.n[a] = shape[a];
    }
    const double cells = double(in.n[0]) * double(in.n[1]) * double(in.n[2]);
    if (!(cells < 9.2e18)) return fail("voxax: fc.decode: the grid is too large");
    const int64_t total = in.n[0] * in.n[1] * in.n[2];
    for (int64_t r = 0; r < K; ++r) {
      if (index[r] < 0 || index[r] >= total)
        return fail("voxax: fc.decode: cell index out of range (row " + std::to_string(r) + ")");
      if (r > 0 && index[r] < index[r - 1])
        return fail("voxax: fc.decode: rows must be sorted by cell index");
    }
    for (int64_t i = 0; i < 3 * K; ++i) {
      if (!std::isfinite(P[i]) || !std::isfinite(N[i]))
        return fail("voxax: fc.decode: anchors and normals must be finite");
      if (std::fabs(P[i]) > voxax::kMaxAbsCoordinate)
        return fail("voxax: fc.decode: anchors must have magnitudes <= 1e75 (row " +
                    std::to_string(i / 3) + ")");
    }
    for (int64_t i = 0; i < 12 * K; ++i)
      if (S[i] < -127)
        return fail("voxax: fc.decode: edge signs must lie in [-127, 127] (row " +
                    std::to_string(i / 12) + ")");
    constexpr int64_t kChunk = 4096;
    const int64_t chunks = (K + kChunk - 1) / kChunk;
    std::vector<std::vector<int64_t>> parts(chunks);
    voxax::spatial::parallel_chunks(K, kChunk, threads, [&](int64_t c, int64_t b, int64_t e) {
      voxax::fc::decode_rows(in, b, e, &parts[c]);
    });
    auto out = std::make_unique<std::vector<int64_t>>();
    size_t n = 0;
    for (const auto& p : parts) n += p.size();
    out->reserve(n);
    for (auto& p : parts) {
      out->insert(out->end(), p.begin(), p.end());
      std::vector<int64_t>().swap(p);
    }
    *count = static_cast<int64_t>(out->size() / 3);
    *handle = out.release();
    return true;
  });
}

VOXAX_EXPORT void voxax_fc_triangles(void* handle, int64_t* out) {
  const auto* t = static_cast<const std::vector<int64_t>*>(handle);
  if (t && out) std::copy(t->begin(), t->end(), out);
}

VOXAX_EXPORT void voxax_fc_free_triangles(void* handle) {
  delete static_cast<std::vector<int64_t>*>(handle);
}

// voxax_fc_node_side(V (nv, 3), nv, F (nf, 3), nf, m, faces (m,), nodes (m, 3), axis (m,),
//                    out (m,) i8, err, errlen): for the crossing of face faces[i] with the line
// along axis[i] through nodes[i], +1 when the crossing lies above the node along the axis,
// -1 below, decided exactly (orientation predicates) with the node moved to
// node + (e_x, e_y, e_z), e_x >> e_y >> e_z > 0 (the perturbation of the lines' tie rule).
VOXAX_EXPORT int voxax_fc_node_side(const double* V, int64_t nv, const int32_t* F, int64_t nf,
                                    int64_t m, const int32_t* faces, const double* nodes,
                                    const int32_t* axis, int8_t* out, char* err, int64_t errlen) {
  return voxax::host_guarded("fc.node_side", err, errlen, [&](std::string* msg) {
    const Reject fail{msg};
    if (nv < 0 || nf < 0 || m < 0 || (m > 0 && (!faces || !nodes || !axis || !out)) ||
        (nf > 0 && !F) || (nv > 0 && !V))
      return fail("voxax: fc.node_side got a bad argument");
    for (int64_t i = 0; i < m; ++i) {
      if (faces[i] < 0 || faces[i] >= nf || axis[i] < 0 || axis[i] > 2)
        return fail("voxax: fc.node_side: face or axis out of range");
      for (int c = 0; c < 3; ++c) {
        const int32_t v = F[3 * int64_t(faces[i]) + c];
        if (v < 0 || v >= nv) return fail("voxax: fc.node_side: vertex out of range");
      }
    }
    for (int64_t i = 0; i < m; ++i) {
      const int32_t* f = F + 3 * int64_t(faces[i]);
      const double* a = V + 3 * int64_t(f[0]);
      const double* b = V + 3 * int64_t(f[1]);
      const double* c = V + 3 * int64_t(f[2]);
      const double* d = nodes + 3 * i;
      // Signs of the normal's components, exactly: n_x is orient2d of the (y, z)
      // projections, n_y of (z, x), n_z of (x, y).
      int ns[3];
      for (int k = 0; k < 3; ++k) {
        const int u = (k + 1) % 3, w = (k + 2) % 3;
        const double pa[2] = {a[u], a[w]}, pb[2] = {b[u], b[w]}, pc[2] = {c[u], c[w]};
        ns[k] = voxax::exact::orient2d(pa, pb, pc);
      }
      // sign(n . (d - a)) = -orient3d(a, b, c, d); on the plane, n . e decides.
      int s = -voxax::exact::orient3d(a, b, c, d);
      for (int k = 0; k < 3 && s == 0; ++k) s = ns[k];
      const int na = ns[axis[i]];
      // The crossing lies below the node (t* < d_a) when n . (d - a) and n_a agree.
      out[i] = static_cast<int8_t>(s * na > 0 ? -1 : (s * na < 0 ? 1 : 0));
    }
    return true;
  });
}

// voxax_fc_signs(index (K,) i64 sorted, K, shape[3], edge (C,) i64, sign (C,) i8, C, threads,
//                S (K, 12) i8 (zeros), &handle, &count, err, errlen): writes the net sign of
//                every crossed edge into the rows of its 4 cells; the cells without a row come
//                back as `count` (cell, crossing) pairs, sorted by cell, one per cell (copy with
//                voxax_fc_triangles(handle, out (count, 2) i64), free with
//                voxax_fc_free_triangles).
VOXAX_EXPORT int voxax_fc_signs(const int64_t* index, int64_t K, const int64_t* shape,
                                const int64_t* edge, const int8_t* sign, int64_t C, int32_t threads,
                                int8_t* S, void** handle, int64_t* count, char* err,
                                int64_t errlen) {
  if (handle) *handle = nullptr;
  return voxax::host_guarded("fc.signs", err, errlen, [&](std::string* msg) {
    const Reject fail{msg};
    if (!handle || !count || !shape || K < 0 || C < 0 || (K > 0 && (!index || !S)) ||
        (C > 0 && (!edge || !sign)))
      return fail("voxax: fc.signs got a null argument");
    int64_t n[3];
    for (int a = 0; a < 3; ++a) {
      if (shape[a] < 1 || shape[a] > voxax::kMaxCellsPerAxis)
        return fail("voxax: fc.signs: bad grid shape");
      n[a] = shape[a];
    }
    const int64_t edges = 3 * (n[0] + 1) * (n[1] + 1) * (n[2] + 1);
    for (int64_t c = 0; c < C; ++c)
      if (edge[c] < 0 || edge[c] >= edges) return fail("voxax: fc.signs: edge id out of range");
    const int64_t total = n[0] * n[1] * n[2];
    for (int64_t r = 0; r < K; ++r)
      if (index[r] < 0 || index[r] >= total || (r > 0 && index[r] < index[r - 1]))
        return fail("voxax: fc.signs: rows must be sorted cell indices");
    const voxax::fc::EdgeNet en = voxax::fc::net_flux(edge, sign, C);
    const int64_t E = static_cast<int64_t>(en.edge.size());
    constexpr int64_t kChunk = 1 << 16;
    std::vector<std::vector<int64_t>> parts((E + kChunk - 1) / kChunk);
    voxax::spatial::parallel_chunks(E, kChunk, threads, [&](int64_t c, int64_t b, int64_t e) {
      voxax::fc::scatter_signs(en, b, e, index, K, n, S, &parts[c]);
    });
    std::vector<std::pair<int64_t, int64_t>> miss;  // (cell, order of appearance)
    std::vector<int64_t> src;
    for (const auto& p : parts)
      for (size_t i = 0; i < p.size(); i += 2) {
        miss.emplace_back(p[i], static_cast<int64_t>(src.size()));
        src.push_back(p[i + 1]);
      }
    std::sort(miss.begin(), miss.end());
    auto out = std::make_unique<std::vector<int64_t>>();
    for (size_t i = 0; i < miss.size(); ++i) {
      if (i > 0 && miss[i].first == miss[i - 1].first) continue;
      out->push_back(miss[i].first);
      out->push_back(src[miss[i].second]);
    }
    *count = static_cast<int64_t>(out->size() / 2);
    *handle = out.release();
    return true;
  });
}

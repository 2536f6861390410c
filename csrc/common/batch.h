// Leading (batch) axes of the kernels' arguments and their broadcasting.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace voxax {

namespace ffi = xla::ffi;

// Every argument carries the same number of leading axes; each is either 1
// (broadcast) or the output's size.
struct Batch {
  std::vector<int64_t> out;   // output batch shape
  std::vector<int64_t> vdim;  // vertices' leading dims
  std::vector<int64_t> fdim;  // faces' leading dims
  int64_t size() const { return product(out); }
  int64_t vertex_count() const { return product(vdim); }
  int64_t face_count() const { return product(fdim); }
  // Flat index into an argument with leading dims `dims` for output batch item b.
  static int64_t source(const std::vector<int64_t>& out, const std::vector<int64_t>& dims,
                        int64_t b) {
    int64_t idx = 0, stride = 1;
    for (int64_t a = static_cast<int64_t>(out.size()) - 1; a >= 0; --a) {
      int64_t coord = b % out[a];
      b /= out[a];
      if (dims[a] != 1) idx += coord * stride;
      stride *= dims[a];
    }
    return idx;
  }
  int64_t vsrc(int64_t b) const { return source(out, vdim, b); }
  int64_t fsrc(int64_t b) const { return source(out, fdim, b); }

 private:
  static int64_t product(const std::vector<int64_t>& dims) {
    int64_t s = 1;
    for (int64_t d : dims) s *= d;
    return s;
  }
};

// "(2, 3, 4)" for messages.
inline std::string dims_str(ffi::Span<const int64_t> d) {
  std::string s = "(";
  for (size_t i = 0; i < d.size(); ++i) s += (i ? ", " : "") + std::to_string(d[i]);
  return s + ")";
}

// Checks the leading axes of vertices (..., V, d), faces (..., F, k) and an
// array with `trailing` trailing axes whose batch shape must be the output's.
inline ffi::Error make_batch(ffi::Span<const int64_t> vd, ffi::Span<const int64_t> fd,
                             ffi::Span<const int64_t> od, size_t trailing, Batch* batch) {
  if (vd.size() < 2 || fd.size() < 2)
    return ffi::Error::InvalidArgument("voxax: vertices and faces need at least 2 axes");
  if (od.size() < trailing)
    return ffi::Error::InvalidArgument("voxax: output " + dims_str(od) + " has fewer than " +
                                       std::to_string(trailing) + " axes");
  size_t nb = vd.size() - 2;
  if (fd.size() - 2 != nb || od.size() - trailing != nb)
    return ffi::Error::InvalidArgument("voxax: vertices " + dims_str(vd) + ", faces " +
                                       dims_str(fd) + " and output " + dims_str(od) +
                                       " must have the same number of batch axes");
  batch->out.assign(od.begin(), od.begin() + nb);
  batch->vdim.assign(vd.begin(), vd.begin() + nb);
  batch->fdim.assign(fd.begin(), fd.begin() + nb);
  for (size_t a = 0; a < nb; ++a) {
    int64_t o = batch->out[a];
    bool vok = batch->vdim[a] == 1 || batch->vdim[a] == o;
    bool fok = batch->fdim[a] == 1 || batch->fdim[a] == o;
    if (!vok || !fok)
      return ffi::Error::InvalidArgument("voxax: batch axes of vertices " + dims_str(vd) +
                                         " and faces " + dims_str(fd) + " do not broadcast to " +
                                         dims_str(od));
  }
  return ffi::Error::Success();
}

}  // namespace voxax

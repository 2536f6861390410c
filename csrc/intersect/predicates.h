// Exact orientation predicates on float64 inputs.
//
// orient2d / orient3d return the exact sign (-1, 0, +1) of the usual determinants. A
// floating-point evaluation with a forward error bound decides almost every call; when the
// bound cannot certify the sign, the determinant is recomputed exactly with floating-point
// expansions (sums of non-overlapping doubles, built with error-free two-sum and
// fma-based two-product), whose sign is the sign of the largest component.
//
// Exactness needs every intermediate product to stay clear of underflow and overflow: the
// callers accept coordinates that are 0 or of magnitude in [MIN_ABS, MAX_ABS] (see
// intersect.cc), for which every expansion component is a multiple of 2^-654 and below
// 2^760.

#pragma once

#include <cmath>
#include <vector>

namespace voxax {
namespace exact {

// a + b = s + e exactly (round to nearest).
inline void two_sum(double a, double b, double* s, double* e) {
  const double x = a + b;
  const double bv = x - a;
  const double av = x - bv;
  *s = x;
  *e = (a - av) + (b - bv);
}

// a * b = p + e exactly (no underflow, no overflow).
inline void two_product(double a, double b, double* p, double* e) {
  const double x = a * b;
  *p = x;
  *e = std::fma(a, b, -x);
}

// A non-overlapping expansion, components in increasing magnitude, no zeros.
using Expansion = std::vector<double>;

// e += b (Shewchuk's grow-expansion with zero elimination).
inline void grow(Expansion* e, double b) {
  if (b == 0.0) return;
  double q = b;
  size_t out = 0;
  for (size_t i = 0; i < e->size(); ++i) {
    double s, h;
    two_sum(q, (*e)[i], &s, &h);
    q = s;
    if (h != 0.0) (*e)[out++] = h;
  }
  e->resize(out);
  if (q != 0.0) e->push_back(q);
}

inline Expansion difference(double a, double b) {
  Expansion e;
  grow(&e, a);
  grow(&e, -b);
  return e;
}

inline Expansion product(const Expansion& a, const Expansion& b) {
  Expansion r;
  for (double x : a)
    for (double y : b) {
      double p, q;
      two_product(x, y, &p, &q);
      grow(&r, q);
      grow(&r, p);
    }
  return r;
}

inline void add(Expansion* r, const Expansion& a, double sign) {
  for (double x : a) grow(r, sign * x);
}

inline int sign(const Expansion& e) {
  if (e.empty()) return 0;
  return e.back() > 0 ? 1 : -1;
}

// Exact sign of | bx-ax  by-ay ; cx-ax  cy-ay |.
inline int orient2d_exact(const double* a, const double* b, const double* c) {
  const Expansion bx = difference(b[0], a[0]), by = difference(b[1], a[1]);
  const Expansion cx = difference(c[0], a[0]), cy = difference(c[1], a[1]);
  Expansion r = product(bx, cy);
  add(&r, product(by, cx), -1.0);
  return sign(r);
}

// Exact sign of det[a-d; b-d; c-d].
inline int orient3d_exact(const double* a, const double* b, const double* c, const double* d) {
  Expansion ad[3], bd[3], cd[3];
  for (int k = 0; k < 3; ++k) {
    ad[k] = difference(a[k], d[k]);
    bd[k] = difference(b[k], d[k]);
    cd[k] = difference(c[k], d[k]);
  }
  Expansion r;
  // ad . (bd x cd)
  for (int k = 0; k < 3; ++k) {
    const int k1 = (k + 1) % 3, k2 = (k + 2) % 3;
    Expansion cross = product(bd[k1], cd[k2]);
    add(&cross, product(bd[k2], cd[k1]), -1.0);
    add(&r, product(ad[k], cross), 1.0);
  }
  return sign(r);
}

// Relative error bounds of the plain evaluations below (with margin over the classical
// (3 + 16 u) u and (7 + 56 u) u, u = 2^-53).
constexpr double kOrient2dBound = 4.0e-16;
constexpr double kOrient3dBound = 8.0e-16;

// Sign of orient2d of 2D points (pointers to 2 doubles).
inline int orient2d(const double* a, const double* b, const double* c) {
  const double l = (b[0] - a[0]) * (c[1] - a[1]);
  const double r = (b[1] - a[1]) * (c[0] - a[0]);
  const double det = l - r;
  const double bound = kOrient2dBound * (std::fabs(l) + std::fabs(r));
  if (det > bound) return 1;
  if (-det > bound) return -1;
  return orient2d_exact(a, b, c);
}

// Sign of det[a-d; b-d; c-d] (positive when d lies below the plane of a, b, c seen with
// a, b, c counter-clockwise).
inline int orient3d(const double* a, const double* b, const double* c, const double* d) {
  const double adx = a[0] - d[0], ady = a[1] - d[1], adz = a[2] - d[2];
  const double bdx = b[0] - d[0], bdy = b[1] - d[1], bdz = b[2] - d[2];
  const double cdx = c[0] - d[0], cdy = c[1] - d[1], cdz = c[2] - d[2];
  const double bc = bdy * cdz - bdz * cdy, ca = cdy * adz - cdz * ady, ab = ady * bdz - adz * bdy;
  const double det = adx * bc + bdx * ca + cdx * ab;
  const double perm = (std::fabs(bdy * cdz) + std::fabs(bdz * cdy)) * std::fabs(adx) +
                      (std::fabs(cdy * adz) + std::fabs(cdz * ady)) * std::fabs(bdx) +
                      (std::fabs(ady * bdz) + std::fabs(adz * bdy)) * std::fabs(cdx);
  const double bound = kOrient3dBound * perm;
  if (det > bound) return 1;
  if (-det > bound) return -1;
  return orient3d_exact(a, b, c, d);
}

}  // namespace exact
}  // namespace voxax

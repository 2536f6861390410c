"""Closed parametric 2D curves as differentiable polylines, and Monte Carlo voxelization
of the exact curves.

The constructors here return a [`Curve`][voxax.curves.Curve]: polyline `vertices (V, 2)`
(a JAX array, a differentiable function of the parameters) and `faces (V, 2)` (a NumPy
ring of counter-clockwise segments). `jax.grad` of any energy of
`voxax.voxelize(*curve, grid)` flows to the curve's parameters by plain composition:

```python
>>> grid = voxax.Grid.cube(64, dim=2)
>>> area = lambda r: voxax.voxelize(*circle((0.0, 0.0), r, 128), grid).sum() * grid.voxel_volume
>>> round(float(jax.grad(area)(0.5)), 6)    # n sin(2 pi / n) r for the 128-gon, ~ 2 pi r
3.140331

```

The polyline is a *polygonal approximation* of the curve: the voxelization, and its
gradient, are those of the inscribed polygon (for a circle of n segments the area is
`n/2 r^2 sin(2 pi / n)`, relative error ~ (2 pi / n)^2 / 6). Use enough segments for the
grid (a few per voxel along the curve).

For the exact curve, [`voxelize_curve_mc`][voxax.curves.voxelize_curve_mc] follows the
paper's Fig. 2: its gradient samples points on the exact curve (any differentiable
`curve(params, t)`), and its forward takes winding numbers of a fine polyline.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from . import _validate
from ._grid import Grid
from ._voxelize import filters as _filters

__all__ = [
    "Curve",
    "circle",
    "bezier_closed",
    "circle_point",
    "bezier_point",
    "polyline",
    "voxelize_curve_mc",
]


class Curve(NamedTuple):
    """A closed polyline: `vertices (V, 2)` float, `faces (V, 2)` int (CCW segments).

    Unpacks like a mesh: `voxax.voxelize(*curve, grid)`.
    """

    vertices: jax.Array
    faces: np.ndarray


def _ring(n: int) -> np.ndarray:
    i = np.arange(n, dtype=np.int32)
    return np.stack([i, (i + 1) % n], axis=1)


def _float(where: str, name: str, x, d: int | None = None):
    """`x (..., d)` as a float JAX array: a real dtype (never bool, complex or strings) and,
    when concrete, finite values of magnitude <= 1e75 (`_validate.coordinates`)."""
    x = jnp.asarray(_validate.coordinates(where, name, x, d))
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(jnp.result_type(float))


def _parameters(where: str, t, dtype):
    """The curve parameters `t`: real (never bool, complex or strings), finite when concrete."""
    t = _validate.typed_array(where, "t", t, "fiu", "real numbers")
    if _validate.is_concrete(t) and np.size(t) and not np.all(np.isfinite(np.asarray(t))):
        raise ValueError(f"{where}: `t` must be finite (it contains NaN or Inf)")
    return jnp.asarray(t, dtype)


# -- point evaluators: curve(params, t), t in [0, 1) ------------------------------------------


def circle_point(params, t):
    """Points of the circle `params = (cx, cy, r)` at parameters `t` in [0, 1) (CCW).

    **Returns:** `t.shape + (2,)`.
    """
    where = "voxax.curves.circle_point"
    params = _float(where, "params", params)
    if params.shape != (3,):
        raise ValueError(f"{where}: `params` must be (cx, cy, r), shape (3,), got {tuple(params.shape)}")
    t = _parameters(where, t, params.dtype)
    a = 2 * jnp.pi * t
    return params[:2] + params[2] * jnp.stack([jnp.cos(a), jnp.sin(a)], axis=-1)


def bezier_point(control_points, t):
    """Points of the closed cubic Bezier spline `control_points (3K, 2)` at `t` in [0, 1).

    Segment k (of K, covering `t in [k/K, (k+1)/K)`) has control points
    `P[3k], P[3k+1], P[3k+2], P[3k+3 mod 3K]`: it starts at the anchor `P[3k]` and ends at
    the next anchor. The spline is C0 (and C1 where each anchor lies midway between its
    neighbouring handles).

    **Returns:** `t.shape + (2,)`.
    """
    where = "voxax.curves.bezier_point"
    P = _float(where, "control_points", control_points, 2)
    n = P.shape[0]
    if P.ndim != 2 or n % 3 != 0 or n == 0:
        raise ValueError(f"{where}: `control_points` must have shape (3K, 2), got {tuple(P.shape)}")
    K = n // 3
    t = _parameters(where, t, P.dtype)
    s = jnp.mod(t, 1.0) * K
    k = jnp.clip(jnp.floor(s), 0, K - 1).astype(jnp.int32)
    u = (s - k)[..., None]
    p0, p1, p2, p3 = P[3 * k], P[3 * k + 1], P[3 * k + 2], P[(3 * k + 3) % n]
    return (1 - u) ** 3 * p0 + 3 * (1 - u) ** 2 * u * p1 + 3 * (1 - u) * u**2 * p2 + u**3 * p3


def polyline(curve: Callable, params, n: int) -> Curve:
    """The closed polyline through `curve(params, j / n)`, j = 0 .. n-1."""
    return _polyline("voxax.curves.polyline", curve, params, n)


def _polyline(where: str, curve: Callable, params, n) -> Curve:
    if not callable(curve):
        raise TypeError(f"{where}: `curve` must be a function curve(params, t), got {type(curve).__name__}")
    n = _validate.positive_int(where, "n", n, minimum=3, bytes_each=256.0)
    t = jnp.arange(n) / n
    return Curve(curve(params, t), _ring(n))


# -- polygonal curves --------------------------------------------------------------------------


def circle(center, radius, n: int = 64) -> Curve:
    """A circle as the inscribed regular n-gon, counter-clockwise, differentiable in
    `center (2,)` and `radius`.

    Vertex j is `center + radius * (cos(2 pi j / n), sin(2 pi j / n))`. The polygon's
    area is `n/2 radius^2 sin(2 pi / n)` (slightly less than pi r^2).

    **Returns:** [`Curve`][voxax.curves.Curve] with `vertices (n, 2)`, `faces (n, 2)`.
    """
    where = "voxax.curves.circle"
    c = _float(where, "center", center, 2)
    if c.shape != (2,):
        raise ValueError(f"{where}: `center` must have shape (2,), got {tuple(c.shape)}")
    if _validate.is_concrete(radius):
        if isinstance(radius, (bool, np.bool_, str, bytes, complex)) or np.ndim(radius) != 0:
            raise TypeError(f"{where}: `radius` must be a real number, got {type(radius).__name__}")
        _validate.positive_float(where, "radius", radius)
    r = jnp.asarray(radius, c.dtype)
    return _polyline(where, circle_point, jnp.concatenate([c, r[None]]), n)


def bezier_closed(control_points, samples_per_segment: int = 16) -> Curve:
    """A closed cubic Bezier spline as a polyline, differentiable in `control_points`.

    `control_points (3K, 2)`: see [`bezier_point`][voxax.curves.bezier_point]. Each of the
    K segments is sampled at `samples_per_segment` uniform parameter values (the anchors
    are vertices), giving `K * samples_per_segment` vertices. Orient the control polygon
    counter-clockwise for outward normals.

    **Returns:** [`Curve`][voxax.curves.Curve].
    """
    where = "voxax.curves.bezier_closed"
    P = _float(where, "control_points", control_points, 2)
    if P.ndim != 2 or P.shape[0] % 3 != 0 or P.shape[0] == 0:
        raise ValueError(f"{where}: `control_points` must have shape (3K, 2), got {tuple(P.shape)}")
    spp = _validate.positive_int(where, "samples_per_segment", samples_per_segment)
    K = P.shape[0] // 3
    if K * spp < 3:
        raise ValueError(f"{where}: `samples_per_segment` must give at least 3 vertices in total, got {K} x {spp}")
    # Bernstein weights (spp, 4) at u = j / spp, applied to every segment: (K, spp, 2).
    u = np.arange(spp) / spp
    B = np.stack([(1 - u) ** 3, 3 * (1 - u) ** 2 * u, 3 * (1 - u) * u**2, u**3], axis=1)
    idx = (3 * np.arange(K)[:, None] + np.arange(4)[None, :]) % P.shape[0]  # (K, 4)
    verts = jnp.einsum("sj,kjd->ksd", jnp.asarray(B, P.dtype), P[idx]).reshape(K * spp, 2)
    return Curve(verts, _ring(K * spp))


# -- Monte Carlo voxelization of the exact curve ----------------------------------------------


def _curve_forward(curve, params, key, st, segments):
    verts = curve(params, jnp.arange(segments, dtype=params.dtype) / segments)
    return _filters.mc_forward(verts, jnp.asarray(_ring(segments)), key, st)


def _curve_backward(curve, params, key, g, st, n):
    # d W[b] / d theta = integral over the curve of k(x - c_b) (d x / d theta . n) dl
    #                  = integral_0^1 k(x(t) - c_b) (d x / d theta . rot(x'(t))) dt,
    # with rot(x') = (x'_y, -x'_x) = |x'| n for a counter-clockwise curve.
    dtype = params.dtype
    bkey = jax.random.fold_in(key, 1)
    t = (jnp.arange(n, dtype=dtype) + jax.random.uniform(bkey, (n,), dtype)) / n
    x, dx = jax.jvp(lambda s: curve(params, s), (t,), (jnp.ones_like(t),))
    G = _filters.kernel_gather(g.astype(dtype), x, st)  # (n,)
    cot = G[:, None] * jnp.stack([dx[:, 1], -dx[:, 0]], axis=-1) / n
    _, pullback = jax.vjp(lambda p: curve(p, t), params)
    return pullback(cot.astype(x.dtype))[0]


@functools.partial(jax.custom_vjp, nondiff_argnums=(0, 3, 4, 5))
def _curve_mc(curve, params, key, st, segments, curve_samples):
    return _curve_forward(curve, params, key, st, segments)


def _curve_mc_fwd(curve, params, key, st, segments, curve_samples):
    return _curve_forward(curve, params, key, st, segments), (params, key)


def _curve_mc_bwd(curve, st, segments, curve_samples, res, g):
    params, key = res
    return _curve_backward(curve, params, key, g, st, curve_samples), None


_curve_mc.defvjp(_curve_mc_fwd, _curve_mc_bwd)


@functools.partial(jax.jit, static_argnums=(0, 3, 4, 5))
def _curve_mc_jit(curve, params, key, st, segments, curve_samples):
    return _curve_mc(curve, params, key, st, segments, curve_samples)


def voxelize_curve_mc(
    curve: Callable,
    params,
    grid: Grid,
    kernel,
    key,
    *,
    samples: int = 64,
    curve_samples: int = 4096,
    segments: int = 1024,
    strata: int | None = None,
) -> jax.Array:
    """Monte Carlo voxelization of an exact closed curve, differentiable in its parameters.

    `curve(params, t)` maps `t` in [0, 1) (any shape) to points `t.shape + (2,)` of a
    closed, counter-clockwise curve (e.g. [`circle_point`][voxax.curves.circle_point] or
    [`bezier_point`][voxax.curves.bezier_point]); it must be differentiable in `params`
    and in `t`, and hashable (a module-level function, not a fresh lambda per call, to
    reuse compilations).

    - Forward: as [`voxax.voxelize_mc`][voxax.voxelize_mc], with the winding number
      of the polyline through `segments` points of the curve (a polygonal approximation
      of the forward only: error ~ 1 / segments^2).
    - Backward (`jax.custom_vjp`): the transport-theorem integral (paper Eq. 14) over the
      *exact* curve, `dL/dtheta = integral_0^1 g(x(t)) (dx/dtheta . rot(x'(t))) dt`, with
      `rot(x') = (x'_y, -x'_x)` (= speed times outward normal) and
      `g(x) = sum_b (dL/dW_b) k(x - c_b)`, estimated from `curve_samples` stratified values
      of t. Unbiased for the exact curve's gradient.

    Runs in JAX. The same key gives the same bits.

    **Arguments:**

    - `curve`: the point function; `params`: its float parameters (a single array).
    - `grid`: a 2D `voxax.Grid`; `kernel`: a [`Kernel`][voxax.Kernel] such as `voxax.Box` or `voxax.Gaussian`; `key`: a PRNG key.
    - `samples`, `strata`: forward samples per voxel and strata per axis (see `voxelize_mc`).
    - `curve_samples`: samples along the curve for the backward.
    - `segments`: polyline segments for the forward.

    **Returns:** `grid.shape` array.
    """
    where = "voxax.curves.voxelize_curve_mc"
    _validate.grid(where, grid, dim=2)
    st = _filters.mc_settings(grid, kernel, samples, strata, 1, where)
    if not callable(curve):
        raise TypeError(f"{where}: `curve` must be a function curve(params, t), got {type(curve).__name__}")
    params = _float(where, "params", params)
    key = _validate.jax_key(where, key)
    segments = _validate.positive_int(where, "segments", segments, minimum=3)
    curve_samples = _validate.positive_int(where, "curve_samples", curve_samples)
    return _curve_mc_jit(curve, params, key, st, segments, curve_samples)

"""Other filters: Monte Carlo voxelization with general kernels, and integer box filters.

`voxax.voxelize` computes the winding number averaged over each voxel (a box filter one
voxel wide) in closed form. This module handles other kernels k:

    W[b] = integral of k(x - c_b) w(x) dx          (c_b the centre of voxel b)

- [`voxelize_mc`][voxax.voxelize_mc] estimates W by Monte Carlo for a [`Box`][voxax.Box]
  of any width or a truncated [`Gaussian`][voxax.Gaussian], with the gradient
  estimated by sampling the surface (Sec. 3.2 of the paper), as a `jax.custom_vjp`.
- [`box_filter`][voxax.box_filter] is the exact alternative for boxes an odd whole
  number of voxels wide: the one-voxel result convolved with a discrete box (Sec. 3.3, "Box
  filters of different sizes"), differentiated by JAX itself.

The Monte Carlo kernels run in JAX (`jax.lax.map` over chunks), not in the C++ kernels.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate
from .._constants import MAX_ABS_COORDINATE, PAIR_BUDGET
from .._grid import Grid
from .._spatial.winding import winding_flat

__all__ = ["Kernel", "Box", "Gaussian", "voxelize_mc", "voxelize_mc_tangent", "box_filter"]


# -- kernels ----------------------------------------------------------------------------------


@runtime_checkable
class Kernel(Protocol):
    """The filter-kernel protocol of [`voxelize_mc`][voxax.voxelize_mc].

    A kernel is any hashable object (a frozen dataclass, say) with:

    - `support`: a float, or one float per grid axis: the half-width of the kernel's
      support in voxels. The kernel must vanish outside the box `|t_a| <= support[a]`.
    - `weight(t)`: the kernel's density at offsets `t` `(..., d)` from a voxel centre,
      measured in voxels (`t = (x - c) / spacing`), returning `(...)`. It must be a JAX
      function of `t` and integrate to 1 over the support (in voxel units), so that a
      region of winding number 1 gives `W = 1`.

    and optionally:

    - `sample(u)`: maps uniform numbers `u` `(..., d)` in `[0, 1)` to offsets `(..., d)`
      distributed with density `weight` (exact importance sampling, like `Box` and
      `Gaussian` do). Without it `voxelize_mc` samples the support box uniformly and
      weights every sample by `weight(t) * volume(support)`, which is also unbiased.

    The offsets are in voxels per axis, so a kernel scales with the grid's spacing (and
    becomes anisotropic in space on a grid with anisotropic cells).

    **Example:** a separable Epanechnikov kernel of radius 1.5 voxels:

    ```python
    >>> @dataclasses.dataclass(frozen=True)
    ... class Epanechnikov:
    ...     radius: float = 1.5
    ...     @property
    ...     def support(self):
    ...         return self.radius
    ...     def weight(self, t):
    ...         u = t / self.radius
    ...         return jnp.prod(jnp.where(jnp.abs(u) <= 1, 0.75 * (1 - u * u) / self.radius, 0.0), axis=-1)
    >>> isinstance(Epanechnikov(), voxax.Kernel)
    True
    ```
    """

    @property
    def support(self) -> float | tuple[float, ...]: ...

    def weight(self, t: jax.Array) -> jax.Array: ...


@dataclasses.dataclass(frozen=True)
class Box:
    """A box kernel, constant on `|x_a - c_a| <= radius * spacing_a` on every axis.

    `radius` is in voxels: the half-width of the box. `Box(0.5)` is the one-voxel box of
    `voxax.voxelize`; `Box(1.5)` is three voxels wide (the paper's Fig. 2). The kernel is
    normalized to integrate to 1. Implements the [`Kernel`][voxax.Kernel] protocol.
    """

    radius: float = 0.5

    def __post_init__(self):
        r = _validate.positive_float("voxax.Box", "radius", self.radius)
        object.__setattr__(self, "radius", r)

    @property
    def reach(self) -> float:
        """Half-width of the support, in voxels."""
        return self.radius

    @property
    def support(self) -> float:
        """Half-width of the support, in voxels (the `Kernel` protocol)."""
        return self.radius

    def weight(self, t):
        """`1 / (2 radius)^d` on the box `|t_a| <= radius`, 0 outside (`t` in voxels)."""
        r = self.radius
        inside = jnp.all(jnp.abs(t) <= r, axis=-1)
        return jnp.where(inside, (2 * r) ** -t.shape[-1], 0.0).astype(t.dtype)

    def sample(self, u):
        """Uniform `u` in `[0, 1)^d` -> offsets uniform on the box (in voxels)."""
        return (2 * u - 1) * self.radius


@dataclasses.dataclass(frozen=True)
class Gaussian:
    """A Gaussian kernel with standard deviation `sigma` voxels, truncated at `truncate` sigma.

    On every axis a the kernel is `exp(-x_a^2 / (2 s_a^2))` with `s_a = sigma * spacing_a`,
    restricted to `|x_a| <= truncate * s_a` (a box support, default 3 sigma) and
    renormalized so that it integrates to 1 over that support (the truncated mass,
    `1 - erf(truncate / sqrt 2)` per axis, 0.27% at 3 sigma, is *not* lost but spread over
    the support). A smoothed winding number of a shape is thus the product over axes of
    truncated-normal probabilities for an axis-aligned box. Implements the
    [`Kernel`][voxax.Kernel] protocol.
    """

    sigma: float = 1.0
    truncate: float = 3.0

    def __post_init__(self):
        s = _validate.positive_float("voxax.Gaussian", "sigma", self.sigma)
        t = _validate.positive_float("voxax.Gaussian", "truncate", self.truncate)
        object.__setattr__(self, "sigma", s)
        object.__setattr__(self, "truncate", t)

    @property
    def reach(self) -> float:
        """Half-width of the support, in voxels."""
        return self.sigma * self.truncate

    @property
    def support(self) -> float:
        """Half-width of the support, in voxels (the `Kernel` protocol)."""
        return self.reach

    @property
    def _mass(self) -> float:
        return math.erf(self.truncate / math.sqrt(2.0))

    def weight(self, t):
        """The truncated, renormalized product of normal densities at `t` (in voxels)."""
        z = t / self.sigma
        per_axis = jnp.exp(-0.5 * z * z) / (self.sigma * math.sqrt(2 * math.pi) * self._mass)
        inside = jnp.abs(t) <= self.reach
        return jnp.prod(jnp.where(inside, per_axis, 0.0), axis=-1)

    def sample(self, u):
        """Inverse CDF of the truncated normal: `u` in `[0, 1)^d` -> offsets (in voxels)."""
        z = jax.scipy.special.erfinv((2 * u - 1) * self._mass)
        return jnp.clip(self.sigma * math.sqrt(2.0) * z, -self.reach, self.reach)


def _support(where: str, kernel, d: int) -> tuple[float, ...]:
    """The kernel's support half-widths per axis, checked."""
    s = kernel.support
    values = (s,) * d if np.ndim(s) == 0 else tuple(s)
    try:
        values = tuple(float(v) for v in values)
    except (TypeError, ValueError):
        raise TypeError(f"{where}: `kernel.support` must be a number or {d} numbers, got {s!r}") from None
    if len(values) != d or not all(math.isfinite(v) and v > 0 for v in values):
        raise ValueError(f"{where}: `kernel.support` must be {d} positive finite half-widths (voxels), got {s!r}")
    return values


def _check_kernel(where: str, kernel, d: int) -> tuple[float, ...]:
    if not isinstance(kernel, Kernel):
        raise TypeError(
            f"{where}: `kernel` must implement the voxax.Kernel protocol (a `support` half-width and a "
            f"`weight(t)` method), e.g. voxax.Box or voxax.Gaussian; got {type(kernel).__name__}"
        )
    try:
        hash(kernel)
    except TypeError:
        raise TypeError(f"{where}: `kernel` must be hashable (e.g. a frozen dataclass), got {type(kernel).__name__}") from None
    return _support(where, kernel, d)


# -- static settings --------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class MCSettings:
    """Static settings of a Monte Carlo voxelization (a static argument under `jax.jit`)."""

    grid: Grid
    kernel: Kernel
    support: tuple  # per-axis half-widths of the kernel's support, in voxels
    strata: int  # strata per axis in the kernel's support
    per_stratum: int  # samples per stratum
    surface_samples: int  # per face (a square number for triangles)

    @property
    def samples(self) -> int:
        return self.per_stratum * self.strata**self.grid.dim


def _int_root(n: int, d: int) -> int:
    m = max(1, int(round(n ** (1.0 / d))))
    while m**d > n:
        m -= 1
    while (m + 1) ** d <= n:
        m += 1
    return max(m, 1)


# -- forward: stratified samples of w around each voxel centre --------------------------------


def _unravel(flat, shape):
    idx = []
    for n in reversed(shape):
        idx.append(flat % n)
        flat = flat // n
    return jnp.stack(idx[::-1], axis=-1)


def mc_forward(vertices, faces, key, st: MCSettings):
    """Monte Carlo estimate of the filtered winding numbers of one mesh (the forward pass)."""
    grid, kernel = st.grid, st.kernel
    d = grid.dim
    dtype = vertices.dtype
    S = st.samples
    n_vox = grid.size
    n_faces = faces.shape[0]
    m = st.strata
    # Stratum corners in the unit cube, each repeated per_stratum times: (S, d).
    cells = np.indices((m,) * d).reshape(d, -1).T
    cells = np.repeat(cells, st.per_stratum, axis=0).astype(np.float64)
    cells = jnp.asarray(cells, dtype)
    lower = jnp.asarray(grid.lower, dtype)
    h = jnp.asarray(grid.spacing, dtype)
    fkey = jax.random.fold_in(key, 0)

    voxels_per_chunk = max(1, min(n_vox, PAIR_BUDGET // max(1, S * n_faces)))
    inner = max(1, min(voxels_per_chunk * S, PAIR_BUDGET // max(1, n_faces)))
    n_chunks = -(-n_vox // voxels_per_chunk)

    sample = getattr(kernel, "sample", None)
    support = jnp.asarray(st.support, dtype)
    box_volume = float(np.prod([2 * r for r in st.support]))

    def one_voxel_offsets(b):
        u = jax.random.uniform(jax.random.fold_in(fkey, b), (S, d), dtype)
        u = (cells + u) / m
        if sample is not None:  # samples distributed like the kernel
            return jnp.asarray(sample(u), dtype), jnp.ones((S,), dtype)
        t = (2 * u - 1) * support  # uniform on the support, weighted by the kernel
        return t, jnp.asarray(kernel.weight(t), dtype) * box_volume

    def chunk(idx):
        valid = idx < n_vox
        idx = jnp.where(valid, idx, 0)
        centres = lower + (_unravel(idx, grid.shape).astype(dtype) + 0.5) * h  # (C, d)
        t, factor = jax.vmap(one_voxel_offsets)(idx)  # (C, S, d), (C, S)
        pts = (centres[:, None, :] + t * h).reshape(-1, d)
        w = winding_flat(vertices, faces, pts, inner).reshape(idx.shape[0], S)
        return jnp.mean(w * factor, axis=1)

    idx = jnp.arange(n_chunks * voxels_per_chunk, dtype=jnp.int32).reshape(n_chunks, voxels_per_chunk)
    values = jax.lax.map(chunk, idx).reshape(-1)[:n_vox]
    return values.reshape(grid.shape)


# -- backward: samples on the faces, kernel-weighted cotangent gathered from nearby voxels ----


def _stencil(st: MCSettings):
    """Per axis, how many voxel centres can lie within the kernel's support of a point."""
    return tuple(int(math.floor(2 * r)) + 1 for r in st.support)


def _stencil_weights(x, st: MCSettings):
    """The voxels within the kernel's support of points `x` (..., d) and their kernel values.

    Returns flat voxel indices and weights `k(x - c_b)` (in world units, the kernel's
    voxel-unit density divided by the cell volume), both `(..., K)` (K the stencil size);
    entries for voxels out of reach or outside the grid have weight 0.
    """
    grid, kernel = st.grid, st.kernel
    d = grid.dim
    dtype = x.dtype
    lead = x.shape[:-1]
    sizes = _stencil(st)
    flat = jnp.zeros(lead + (1,) * d, jnp.int32)
    ok = jnp.ones(lead + (1,) * d, bool)
    offsets = []
    stride = 1
    for a in reversed(range(d)):
        h, r = grid.spacing[a], st.support[a]
        u = (x[..., a] - grid.lower[a]) / h - 0.5  # continuous centre index
        start = jnp.ceil(u - r)
        b = start[..., None] + jnp.arange(sizes[a], dtype=dtype)  # (..., k_a) voxel indices
        t = u[..., None] - b  # offsets in voxels
        valid = (jnp.abs(t) <= r) & (b >= 0) & (b < grid.shape[a])
        bi = jnp.clip(b, 0, grid.shape[a] - 1).astype(jnp.int32)
        shape = lead + tuple(sizes[a] if c == a else 1 for c in range(d))
        flat = flat + bi.reshape(shape) * stride
        ok = ok & valid.reshape(shape)
        offsets.insert(0, t.reshape(shape))
        stride *= grid.shape[a]
    full = lead + sizes
    t_all = jnp.stack([jnp.broadcast_to(t, full) for t in offsets], axis=-1)  # (..., k_0..k_{d-1}, d)
    weight = jnp.asarray(kernel.weight(t_all), dtype) / grid.voxel_volume
    weight = jnp.where(jnp.broadcast_to(ok, full), weight, 0)
    K = int(np.prod(sizes))
    return jnp.broadcast_to(flat, full).reshape(lead + (K,)), weight.reshape(lead + (K,))


def kernel_gather(g, x, st: MCSettings):
    """G(x) = sum_b g[b] k(x - c_b) for points `x` (..., d): the kernel-weighted cotangent."""
    flat, weight = _stencil_weights(x, st)
    return jnp.sum(g.reshape(-1)[flat] * weight, axis=-1)


def _face_samples(key, f, n, d, dtype):
    """Stratified uniform barycentric coordinates (n, d) on a segment (d=2) or triangle (d=3)."""
    k = jax.random.fold_in(key, f)
    if d == 2:
        t = (jnp.arange(n, dtype=dtype) + jax.random.uniform(k, (n,), dtype)) / n
        return jnp.stack([1 - t, t], axis=-1)
    m = _int_root(n, 2)
    ij = np.indices((m, m)).reshape(2, -1).T.astype(np.float64)
    u = (jnp.asarray(ij, dtype) + jax.random.uniform(k, (m * m, 2), dtype)) / m
    # The area-preserving square-to-triangle map keeps the strata equal in area.
    s = jnp.sqrt(u[:, 0])
    return jnp.stack([1 - s, s * (1 - u[:, 1]), s * u[:, 1]], axis=-1)


def _area_normal(corners):
    """Area times unit outward normal of faces (..., d, d)."""
    if corners.shape[-1] == 2:
        e = corners[..., 1, :] - corners[..., 0, :]
        return jnp.stack([e[..., 1], -e[..., 0]], axis=-1)
    n = jnp.cross(corners[..., 1, :] - corners[..., 0, :], corners[..., 2, :] - corners[..., 0, :])
    return 0.5 * n


def _face_chunks(n_faces: int, S: int, K: int):
    per_chunk = max(1, min(n_faces, PAIR_BUDGET // max(1, S * K)))
    n_chunks = -(-n_faces // per_chunk)
    return jnp.arange(n_chunks * per_chunk, dtype=jnp.int32).reshape(n_chunks, per_chunk)


def _surface_samples(vertices, faces, fidx, key, S):
    """Samples on the faces `fidx` (C,): barycentrics (C, S, d), points (C, S, d) and the
    faces' area normals (C, d), zeroed for padding indices (>= F)."""
    d = vertices.shape[-1]
    dtype = vertices.dtype
    n_faces = faces.shape[0]
    valid = fidx < n_faces
    fi = jnp.where(valid, fidx, 0)
    corners = vertices[faces[fi]]  # (C, d, d)
    beta = jax.vmap(lambda f: _face_samples(key, f, S, d, dtype))(fi)  # (C, S, d)
    x = jnp.einsum("csm,cmk->csk", beta, corners)
    an = _area_normal(corners) * valid[:, None].astype(dtype)  # (C, d)
    return fi, beta, x, an


def _backward(vertices, faces, key, g, st: MCSettings):
    grid = st.grid
    d = grid.dim
    S = st.surface_samples
    bkey = jax.random.fold_in(key, 1)
    g = g.astype(vertices.dtype)

    def chunk(fidx):
        _, beta, x, an = _surface_samples(vertices, faces, fidx, bkey, S)
        G = kernel_gather(g, x, st)  # (C, S)
        wsum = jnp.einsum("cs,csm->cm", G, beta) / S  # (C, d corners)
        return wsum[:, :, None] * an[:, None, :]  # (C, d corners, d)

    fidx = _face_chunks(faces.shape[0], S, int(np.prod(_stencil(st))))
    corner_grads = jax.lax.map(chunk, fidx).reshape(-1, d, d)[: faces.shape[0]]
    return jnp.zeros_like(vertices).at[faces].add(corner_grads)


def _tangent(vertices, faces, key, tangent, st: MCSettings):
    grid = st.grid
    S = st.surface_samples
    bkey = jax.random.fold_in(key, 1)
    tangent = tangent.astype(vertices.dtype)

    def step(acc, fidx):
        fi, beta, x, an = _surface_samples(vertices, faces, fidx, bkey, S)
        # Normal speed times area at every sample: sum_m beta_m (dv_m . area n).
        speed = jnp.einsum("cmk,ck->cm", tangent[faces[fi]], an)  # (C, d corners)
        vn = jnp.einsum("csm,cm->cs", beta, speed) / S  # (C, S)
        flat, weight = _stencil_weights(x, st)  # (C, S, K)
        acc = acc.at[flat.reshape(-1)].add((weight * vn[..., None]).reshape(-1))
        return acc, None

    fidx = _face_chunks(faces.shape[0], S, int(np.prod(_stencil(st))))
    out, _ = jax.lax.scan(step, jnp.zeros(grid.size, vertices.dtype), fidx)
    return out.reshape(grid.shape)


@functools.partial(jax.custom_vjp, nondiff_argnums=(3,))
def _mc(vertices, faces, key, st):
    return mc_forward(vertices, faces, key, st)


def _mc_fwd(vertices, faces, key, st):
    return mc_forward(vertices, faces, key, st), (vertices, faces, key)


def _mc_bwd(st, res, g):
    vertices, faces, key = res
    return _backward(vertices, faces, key, g, st), None, None


_mc.defvjp(_mc_fwd, _mc_bwd)


def _grid_signature(grid: Grid) -> str:
    return "(" + ",".join(f"g{a}" for a in range(grid.dim)) + ")"


@functools.partial(jax.jit, static_argnums=(3,))
def _mc_jit(vertices, faces, key, st):
    # Leading axes of vertices and faces broadcast; every item shares the key.
    fn = jnp.vectorize(lambda v, f: _mc(v, f, key, st), signature="(n,d),(m,k)->" + _grid_signature(st.grid))
    return fn(vertices, faces)


def mc_settings(grid, kernel, samples, strata, surface_samples, where="voxax.voxelize_mc") -> MCSettings:
    """Checks the grid, kernel and sample counts; returns the static `MCSettings`."""
    grid = _validate.grid(where, grid)
    d = grid.dim
    support = _check_kernel(where, kernel, d)
    samples = _validate.positive_int(where, "samples", samples)
    surface_samples = _validate.positive_int(where, "surface_samples", surface_samples)
    m = _int_root(samples, d) if strata is None else _validate.positive_int(where, "strata", strata)
    per = -(-samples // m**d)
    _validate.check_allocation(where, 16.0 * d * per * float(m) ** d, f"a table of {per * m**d} samples", "use fewer samples")
    if d == 3:
        r = _int_root(surface_samples, 2)
        if r * r < surface_samples:
            r += 1
        surface_samples = r * r
    return MCSettings(grid, kernel, support, m, per, surface_samples)


def _mesh_in(where, vertices, faces, grid):
    vertices, faces = _validate.mesh(where, vertices, faces, dim=grid.dim, batch=True)
    # concrete values are checked above; traced ones by the value-check kernel (NaN, Inf, > 1e75)
    vertices = _validate.finite_values(where, "vertices", jnp.asarray(vertices), MAX_ABS_COORDINATE)
    return vertices, jnp.asarray(np.asarray(faces, np.int32) if _validate.is_concrete(faces) else faces, jnp.int32)


def voxelize_mc(
    vertices,
    faces=None,
    grid: Grid | None = None,
    kernel: Kernel | None = None,
    key=None,
    *,
    samples: int = 64,
    surface_samples: int = 64,
    strata: int | None = None,
) -> jax.Array:
    """Voxelizes with a general kernel by Monte Carlo: `W[b] = integral k(x - c_b) w(x) dx`.

    **Forward.** Around every voxel centre c_b, `samples` points x_s are drawn from the
    kernel itself (uniform on the box; the truncated normal by its inverse CDF), stratified:
    the kernel's support is split into `strata^d` equal cells in the kernel's own measure
    (by default as many as `samples` allows, one sample each) with equally many samples
    per cell, and `W[b] = mean_s w(x_s)` with w the exact generalised winding number
    ([`voxax.winding_number`][voxax.winding_number]). The samples of different voxels are
    independent. w is evaluated everywhere, also outside the grid: the shape need not lie
    inside it. The estimate is unbiased; its error decreases like 1/sqrt(samples) with a
    fixed number of strata (e.g. `strata=1`, plain Monte Carlo) and faster with the default
    full stratification.

    **Backward** (a `jax.custom_vjp`). By the transport theorem (the paper's Eq. 14),
    `dW[b]/dv_m = integral over the surface of k(x - c_b) beta_m(x) n(x) dA`, with beta_m
    the barycentric coordinate of vertex m and n the unit outward normal. It is estimated
    with `surface_samples` stratified uniform samples x_s on every face f:
    `dL/dv_m += sum_s g(x_s) beta_m(x_s) area_f n_f / surface_samples`, where
    `g(x) = sum_b (dL/dW[b]) k(x - c_b)` gathers the incoming cotangent from the voxels
    within the kernel's reach of x (voxels outside the grid contribute nothing). This is an
    unbiased estimate of the exact gradient of W — it is *not* the derivative of the
    forward estimate, which is piecewise constant in the vertices.

    Both passes run in JAX (`jax.lax.map` over chunks of voxels resp. faces, memory
    bounded), not in the C++ kernels: the forward costs O(voxels x samples x faces).
    The same key gives the same bits; forward and backward use independent streams
    derived from it (`fold_in(key, 0)`, `fold_in(key, 1)`). Works under `jax.jit`,
    `jax.grad` and `jax.vmap`; leading axes of `vertices` and `faces` are batch axes that
    broadcast against each other, as for `voxax.voxelize`, and every item shares the key
    (common random numbers).

    **Arguments:**

    - `vertices`: `(..., V, d)` float32 or float64; `faces`: `(..., F, d)` int,
      outward-oriented triangles (3D) or segments (2D), as for `voxax.voxelize` (or a
      mesh object in their place: `voxelize_mc(mesh, grid, kernel, key)`).
    - `grid`: the `voxax.Grid`.
    - `kernel`: any [`Kernel`][voxax.Kernel]: `voxax.Box(radius)`,
      `voxax.Gaussian(sigma, truncate=3)` (sizes in voxels) or your own.
    - `key`: a JAX PRNG key (`jax.random.key(0)` or `jax.random.PRNGKey(0)`) or an int
      (`jax.random.key(int)`).
    - `samples`: samples per voxel for the forward; rounded up to a multiple of `strata^d`.
    - `surface_samples`: samples per face for the backward (rounded up to a square in 3D).
    - `strata`: strata per axis; by default the largest m with `m^d <= samples`.

    **Returns:**

    `(..., *grid.shape)` array of the vertices' dtype.

    **Example:**

    ```python
    >>> square = voxax.data.polygon_square()       # [-0.5, 0.5]^2
    >>> grid = voxax.Grid.cube(16, dim=2)
    >>> W = voxelize_mc(square.vertices, square.faces, grid, Gaussian(1.0), jax.random.key(0))
    >>> W.shape, round(float(W[8, 8]), 6), round(float(W[0, 0]), 6)
    ((16, 16), 1.0, 0.0)

    ```
    """
    where = "voxax.voxelize_mc"
    vertices, faces, (grid, kernel, key) = _validate.unpack_mesh(where, vertices, faces, grid, kernel, key)
    st = mc_settings(grid, kernel, samples, strata, surface_samples)
    vertices, faces = _mesh_in(where, vertices, faces, st.grid)
    key = _validate.jax_key(where, key)
    return _mc_jit(vertices, faces, key, st)


@functools.partial(jax.jit, static_argnums=(4,))
def _tangent_jit(vertices, faces, key, tangent, st):
    sig = "(n,d),(m,k),(n,d)->" + _grid_signature(st.grid)
    return jnp.vectorize(lambda v, f, t: _tangent(v, f, key, t, st), signature=sig)(vertices, faces, tangent)


def voxelize_mc_tangent(
    vertices,
    faces=None,
    grid: Grid | None = None,
    kernel: Kernel | None = None,
    key=None,
    tangent=None,
    *,
    surface_samples: int = 64,
) -> jax.Array:
    """The directional derivative of `voxelize_mc` along a vertex displacement, by splatting.

    Estimates `dW/de` for `vertices + e * tangent` at `e = 0`, i.e. for every voxel b
    `integral over the surface of k(x - c_b) (dx/de . n) dA`, by splatting the normal
    speed of the surface samples, weighted by the kernel, into the voxels within reach:
    `dW[b] += k(x_s - c_b) * (sum_m beta_m(x_s) tangent_m) . (area_f n_f) / surface_samples`.
    It draws the same surface samples as `voxelize_mc`'s backward for the same key and
    settings, so it is exactly the adjoint of that VJP:
    `sum(g * voxelize_mc_tangent(..., t, ...)) == sum(vjp(g) * t)` up to rounding.
    `voxelize_mc` itself only supports reverse mode (it is a `jax.custom_vjp`); this is
    the cheap way to get a whole grid of derivatives with respect to one parameter
    (one pass instead of one VJP per voxel). Runs in JAX.

    **Arguments:**

    - `vertices`: `(..., V, d)`, `faces`: `(..., F, d)` (or a mesh object in their place),
      `grid`, `kernel`, `key`: as for `voxelize_mc`.
    - `tangent`: `(..., V, d)` float, the vertex velocities `dv/de`; its leading axes
      broadcast with those of `vertices` and `faces`.
    - `surface_samples`: samples per face (rounded up to a square in 3D).

    **Returns:** `(..., *grid.shape)` array.
    """
    where = "voxax.voxelize_mc_tangent"
    vertices, faces, (grid, kernel, key, tangent) = _validate.unpack_mesh(
        where, vertices, faces, grid, kernel, key, tangent
    )
    st = mc_settings(grid, kernel, 1, None, surface_samples, where)
    vertices, faces = _mesh_in(where, vertices, faces, st.grid)
    if tangent is None:
        raise TypeError(f"{where}: missing `tangent`")
    tangent = jnp.asarray(tangent, vertices.dtype)
    if tangent.ndim < 2 or tangent.shape[-2:] != vertices.shape[-2:]:
        raise ValueError(
            f"{where}: `tangent` must have the shape (..., V, d) of `vertices`, "
            f"got {tuple(tangent.shape)} and {tuple(vertices.shape)}"
        )
    return _tangent_jit(vertices, faces, _validate.jax_key(where, key), tangent, st)


# -- integer box filters by discrete convolution ----------------------------------------------


def box_filter(W, factor: int, *, dim: int | None = None) -> jax.Array:
    """Box-filters a one-voxel voxelization by a box `factor` voxels wide (a discrete convolution).

    `out[i] = (1 / factor^d) * sum of W over the factor^d voxels around i`, computed with
    `jax.lax.reduce_window` (differentiable by JAX). Because `W = voxax.voxelize(...)` is
    already the average of the winding number over each voxel, for an *odd* factor this is
    exactly the winding number averaged over a box `factor` voxels wide centred on voxel
    i's centre — `voxelize_mc(..., Box(radius=factor / 2))` without the noise. For an
    *even* factor the window covers voxels `i - factor/2 + 1 ... i + factor/2` per axis
    (JAX's 'SAME' convention), i.e. the box is centred on the upper corner of voxel i,
    half a voxel off its centre.

    Boundary: outside the grid W is taken to be 0 (zero padding), i.e. the shape is
    assumed empty outside the grid. The result is exact (and `sum(out) == sum(W)`, the
    volume identity) when the shape keeps `(factor - 1) / 2` voxels away from the border;
    otherwise voxels near the border miss the parts of the box outside the grid.

    **Arguments:**

    - `W`: `(..., *grid.shape)` float array (leading axes are batch axes).
    - `factor`: int >= 1, the width of the box in voxels.
    - `dim`: the number of grid axes (the trailing axes of W); by default `W.ndim`, which
      must then be 2 or 3 (pass `dim` for batched grids).

    **Returns:**

    An array of W's shape and dtype.
    """
    W = jnp.asarray(_validate.typed_array("voxax.box_filter", "W", W, "f", "a float array"))
    s = _validate.positive_int("voxax.box_filter", "factor", factor)
    if dim is None:
        if W.ndim not in (2, 3):
            raise ValueError(f"voxax.box_filter: cannot tell the grid axes of a {W.ndim}-D array; pass dim=2 or dim=3")
        dim = W.ndim
    if dim not in (2, 3) or W.ndim < dim:
        raise ValueError(f"voxax.box_filter: dim must be 2 or 3 and at most W.ndim, got dim={dim}, W.ndim={W.ndim}")
    widest = max(W.shape[W.ndim - dim:], default=0)
    if s > 2 * widest + 1:  # a wider box covers the whole grid from every voxel: only its cost grows
        raise ValueError(f"voxax.box_filter: `factor` must be at most 2 * {widest} + 1 (twice the largest grid axis, "
                         f"plus one), got {s}")
    if s == 1:
        return W
    nb = W.ndim - dim
    window = (1,) * nb + (s,) * dim
    padding = ((0, 0),) * nb + (((s - 1) // 2, s // 2),) * dim
    out = jax.lax.reduce_window(W, jnp.array(0, W.dtype), jax.lax.add, window, (1,) * W.ndim, padding)
    return out / (s**dim)

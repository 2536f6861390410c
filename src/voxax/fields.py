"""Implicit fields in JAX: analytic signed distances, classic implicit surfaces, CSG and
small neural fields.

Every field is a pure function of points: `points (..., d)` float -> values `(...)`, with
its parameters as keyword arguments. All of them work under `jax.jit`, `jax.grad` and
`jax.vmap`, in float32 and float64. The sign convention is **negative inside, positive
outside**, and the surface is the zero level set.

Signed distance functions (`|grad f| = 1` almost everywhere, `f` is the exact distance to
the surface, negative inside): [`sphere`][voxax.fields.sphere], [`box`][voxax.fields.box],
[`torus`][voxax.fields.torus]. Implicit surfaces that are *not* distances (their gradient
norm varies): [`gyroid`][voxax.fields.gyroid], [`chebyshev`][voxax.fields.chebyshev] (the
octic with Euler characteristic -160) and [`blob`][voxax.fields.blob].

CSG on field values: [`union`][voxax.fields.union] (min),
[`intersection`][voxax.fields.intersection] (max), [`difference`][voxax.fields.difference]
(`max(a, -b)`) and [`smooth_union`][voxax.fields.smooth_union]. The sharp operations keep
the sign (inside/outside) exact; their values are exact distances outside a union and
inside an intersection, and lower bounds elsewhere (they stay 1-Lipschitz). Transforms of
field functions: [`translated`][voxax.fields.translated], [`scaled`][voxax.fields.scaled].

Neural fields (equinox modules): [`Siren`][voxax.fields.Siren] (sine activations with the
SIREN initialisation, for 3D fields and 2D height fields) and
[`DeepSDF`][voxax.fields.DeepSDF] (an auto-decoder: per-shape latent codes and an MLP), with
[`deepsdf_loss`][voxax.fields.deepsdf_loss].

>>> import jax.numpy as jnp
>>> from voxax import fields
>>> p = jnp.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
>>> fields.sphere(p, radius=0.5).tolist()
[-0.5, 0.5]
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import _validate

__all__ = [
    "DeepSDF",
    "Siren",
    "blob",
    "box",
    "chebyshev",
    "chebyshev_polynomial",
    "deepsdf_loss",
    "difference",
    "gyroid",
    "intersection",
    "scaled",
    "smooth_union",
    "sphere",
    "torus",
    "translated",
    "union",
]


def _points(where: str, points, dim: int | None = None, name: str = "points"):
    """`points (..., d)` as a float JAX array, checked through `_validate.coordinates` for
    their dtype and shape: real (float or integer), never bool, complex or strings. Their
    values are not checked (a field is a pure function: NaN in, NaN out)."""
    p = _validate.coordinates(where, name, points, dim, finite=False)
    p = jnp.asarray(p)
    if not jnp.issubdtype(p.dtype, jnp.floating):
        p = p.astype(jnp.result_type(float))
    return p


def _vector(where: str, x, d: int, name: str, dtype):
    if isinstance(x, (bool, str, bytes, complex)) or (hasattr(x, "dtype") and np.dtype(x.dtype).kind not in "fiu"):
        raise TypeError(f"{where}: `{name}` must be a real number or vector, got {getattr(x, 'dtype', type(x).__name__)}")
    v = jnp.asarray(x, dtype=dtype)
    if v.ndim == 0:
        v = jnp.broadcast_to(v, (d,))
    if v.shape[-1] != d:
        raise ValueError(f"{where}: `{name}` must have {d} components to match the points, got shape {v.shape}")
    return v


def _safe_norm(x, axis=-1):
    """Euclidean norm with a zero (finite) gradient at the origin."""
    sq = jnp.sum(x * x, axis=axis)
    pos = sq > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, sq, 1)), 0)


# -- signed distance functions -------------------------------------------------------------


def sphere(points, radius=1.0, center=0.0):
    """Signed distance to a sphere (a circle for 2D points): `|p - center| - radius`.

    **Arguments:**

    - `points`: `(..., d)` float, any `d`.
    - `radius`: scalar (may be a traced value, so it can be optimised).
    - `center`: `(d,)` or a scalar broadcast to every axis.

    **Returns:** `(...)` signed distances, negative inside.

    >>> import jax.numpy as jnp
    >>> float(sphere(jnp.array([0.0, 3.0, 4.0]), radius=2.0))
    3.0
    """
    p = _points("voxax.fields.sphere", points)
    _validate.real_value("voxax.fields.sphere", "radius", radius, "fiu", sequences=False)
    c = _vector("voxax.fields.sphere", center, p.shape[-1], "center", p.dtype)
    return _safe_norm(p - c) - radius


def box(points, half_extents=0.5, center=0.0):
    """Exact signed distance to an axis-aligned box (a rectangle in 2D).

    With `q = |p - center| - half_extents` (componentwise), the distance is
    `|max(q, 0)| + min(max_i q_i, 0)`: the Euclidean distance to the box outside, minus
    the distance to the nearest face inside.

    **Arguments:**

    - `points`: `(..., d)` float.
    - `half_extents`: `(d,)` or scalar, the half side lengths (all > 0).
    - `center`: `(d,)` or scalar.

    **Returns:** `(...)` signed distances, negative inside.

    >>> import jax.numpy as jnp
    >>> box(jnp.array([[0.0, 0.0, 0.0], [2.0, 2.0, 0.0]]), half_extents=1.0).tolist()
    [-1.0, 1.4142135623730951]
    """
    p = _points("voxax.fields.box", points)
    d = p.shape[-1]
    q = jnp.abs(p - _vector("voxax.fields.box", center, d, "center", p.dtype)) - _vector(
        "voxax.fields.box", half_extents, d, "half_extents", p.dtype
    )
    outside = _safe_norm(jnp.maximum(q, 0))
    inside = jnp.minimum(jnp.max(q, axis=-1), 0)
    return outside + inside


_AXES = {"x": 0, "y": 1, "z": 2}


def torus(points, major_radius=0.5, minor_radius=0.2, center=0.0, axis="z"):
    """Signed distance to a torus: `|(|p_plane| - R, p_axis)| - r`.

    **Arguments:**

    - `points`: `(..., 3)` float.
    - `major_radius`: `R`, the radius of the centre circle.
    - `minor_radius`: `r`, the radius of the tube (`0 < r < R` for a ring torus).
    - `center`: `(3,)` or scalar.
    - `axis`: `"x"`, `"y"` or `"z"`, the symmetry axis.

    **Returns:** `(...)` signed distances, negative inside.

    >>> import jax.numpy as jnp
    >>> round(float(torus(jnp.array([0.5, 0.0, 0.0]))), 12)
    -0.2
    """
    p = _points("voxax.fields.torus", points, 3)
    _validate.real_value("voxax.fields.torus", "major_radius", major_radius, "fiu", sequences=False)
    _validate.real_value("voxax.fields.torus", "minor_radius", minor_radius, "fiu", sequences=False)
    if axis not in _AXES:
        raise ValueError(f"voxax.fields.torus: `axis` must be 'x', 'y' or 'z', got {axis!r}")
    p = p - _vector("voxax.fields.torus", center, 3, "center", p.dtype)
    a = _AXES[axis]
    plane = [i for i in range(3) if i != a]
    ring = _safe_norm(p[..., plane]) - major_radius
    return _safe_norm(jnp.stack([ring, p[..., a]], axis=-1)) - minor_radius


# -- implicit surfaces (not distances) -----------------------------------------------------


def gyroid(points, period=1.0, level=0.0):
    """The gyroid `sin x cos y + sin y cos z + sin z cos x - level`, `x = 2 pi p_x / period`.

    Not a distance: `|grad f|` varies (it is at most `3 * 2 pi / period`, so the field is
    Lipschitz with that constant). A triply periodic minimal-like surface; `level` shifts
    the sheet (`|level| < 1.5` for a connected surface).

    **Arguments:**

    - `points`: `(..., 3)` float.
    - `period`: the spatial period along each axis.
    - `level`: the iso-value subtracted from the field.

    **Returns:** `(...)` values, zero on the surface.

    >>> import jax.numpy as jnp
    >>> float(gyroid(jnp.zeros(3)))
    0.0
    """
    _validate.real_value("voxax.fields.gyroid", "period", period, "fiu", sequences=False)
    _validate.real_value("voxax.fields.gyroid", "level", level, "fiu", sequences=False)
    if _validate.is_concrete(period) and not np.all(np.asarray(period) != 0):
        raise ValueError("voxax.fields.gyroid: `period` must be non-zero")
    p = _points("voxax.fields.gyroid", points, 3) * (2 * math.pi / period)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return (
        jnp.sin(x) * jnp.cos(y)
        + jnp.sin(y) * jnp.cos(z)
        + jnp.sin(z) * jnp.cos(x)
        - level
    )


def chebyshev_polynomial(x, degree: int):
    """The Chebyshev polynomial of the first kind `T_n(x)`, by the three-term recurrence.

    `T_0 = 1`, `T_1 = x`, `T_{n+1} = 2 x T_n - T_{n-1}`; `T_n(cos t) = cos(n t)`.

    **Arguments:**

    - `x`: array of any shape.
    - `degree`: `n >= 0` (a Python int).

    **Returns:** `T_n(x)`, same shape as `x`.

    >>> import jax.numpy as jnp
    >>> chebyshev_polynomial(jnp.array([0.5, 1.0]), 8).tolist()  # 128x^8 - 256x^6 + 160x^4 - 32x^2 + 1
    [-0.5, 1.0]
    """
    degree = _validate.positive_int("voxax.fields.chebyshev_polynomial", "degree", degree, minimum=0, maximum=10_000)
    x = jnp.asarray(x)
    prev, cur = jnp.ones_like(x), x
    if degree == 0:
        return prev
    for _ in range(degree - 1):
        prev, cur = cur, 2 * x * cur - prev
    return cur


def chebyshev(points, degree: int = 8, level=0.0):
    """The Chebyshev ("Chmutov") surface `T_n(x) + T_n(y) + T_n(z) = level`.

    The field is `sum_i T_n(p_i) - level`, negative inside. With the default `degree=8`
    and `level=0` it is the octic surface used to benchmark CVT meshing: it lies in
    `[-a, a]^3` with `T_8(a) = 2`, `a = cosh(arccosh(2) / 8) = 1.01358` (since `T_8 >= -1`
    on every axis), and has Euler characteristic -160. The
    printed formula in that paper (`T(x) = 2x^2 (3 - 4x^2) ... = 1.6`) is garbled; read
    with `T_6` it falls apart into 27 separate blobs, so `T_8` with level 0 is the surface
    meant. Not a distance.

    **Arguments:**

    - `points`: `(..., d)` float (usually `d = 3`).
    - `degree`: the polynomial degree `n` (a Python int).
    - `level`: the iso-value.

    **Returns:** `(...)` values.

    >>> import jax.numpy as jnp
    >>> float(chebyshev(jnp.zeros(3)))  # T_8(0) = 1 on each axis
    3.0
    """
    p = _points("voxax.fields.chebyshev", points)
    _validate.real_value("voxax.fields.chebyshev", "level", level, "fiu", sequences=False)
    return jnp.sum(chebyshev_polynomial(p, degree), axis=-1) - level


def blob(points):
    """The non-algebraic surface `x^2 + y^2 + z^2 + sin 4x - cos 4y + sin 4z = 0`.

    The smooth blob the CVT meshing paper shows in its implicit-surface figure (and
    remeshes with 7,890 seeds). Negative inside (the origin has value -1). Not a distance.

    **Arguments:**

    - `points`: `(..., 3)` float.

    **Returns:** `(...)` values.

    >>> import jax.numpy as jnp
    >>> float(blob(jnp.zeros(3)))
    -1.0
    """
    p = _points("voxax.fields.blob", points, 3)
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return x * x + y * y + z * z + jnp.sin(4 * x) - jnp.cos(4 * y) + jnp.sin(4 * z)


# -- CSG -----------------------------------------------------------------------------------


def _fold(name: str, op, values):
    """Combines two or more fields' values pointwise with `op`, left to right."""
    if len(values) < 2:
        raise ValueError(f"voxax.fields.{name}: `values` must hold at least two fields")
    out = values[0]
    for v in values[1:]:
        out = op(out, v)
    return out


def union(*values):
    """Union of solids given by field values: the pointwise minimum.

    **Arguments:** two or more arrays of field values (broadcastable).

    **Returns:** `min(a, b, ...)`.

    >>> import jax.numpy as jnp
    >>> union(jnp.array(1.0), jnp.array(-2.0)).item()
    -2.0
    """
    return _fold("union", jnp.minimum, values)


def intersection(*values):
    """Intersection of solids given by field values: the pointwise maximum.

    >>> import jax.numpy as jnp
    >>> intersection(jnp.array(1.0), jnp.array(-2.0)).item()
    1.0
    """
    return _fold("intersection", jnp.maximum, values)


def difference(a, b):
    """The solid `a` minus the solid `b`: `max(a, -b)`.

    >>> import jax.numpy as jnp
    >>> difference(jnp.array(-1.0), jnp.array(-0.5)).item()  # inside both: removed
    0.5
    """
    return jnp.maximum(a, -b)


def smooth_union(a, b, k=0.1):
    """A smooth union (polynomial smooth minimum) of width `k > 0`.

    `h = clip(0.5 + 0.5 (b - a) / k, 0, 1)`, value `b (1 - h) + a h - k h (1 - h)`. It
    equals `min(a, b)` wherever `|a - b| >= k` and lies below it (by at most `k / 4`)
    elsewhere, blending the two surfaces with a fillet.

    >>> import jax.numpy as jnp
    >>> smooth_union(jnp.array(0.0), jnp.array(1.0), k=0.5).item()
    0.0
    """
    h = jnp.clip(0.5 + 0.5 * (b - a) / k, 0.0, 1.0)
    return b * (1 - h) + a * h - k * h * (1 - h)


def translated(field: Callable, offset) -> Callable:
    """The field moved by `offset`: `p -> field(p - offset)`.

    >>> import jax.numpy as jnp
    >>> f = translated(sphere, jnp.array([1.0, 0.0, 0.0]))
    >>> float(f(jnp.array([1.0, 0.0, 0.0])))
    -1.0
    """

    def moved(points, *args, **kwargs):
        p = _points("voxax.fields.translated", points)
        return field(p - jnp.asarray(offset, dtype=p.dtype), *args, **kwargs)

    return moved


def scaled(field: Callable, factor) -> Callable:
    """The field scaled uniformly by `factor > 0`: `p -> factor * field(p / factor)`.

    The outer factor keeps a signed distance function a signed distance function.

    >>> import jax.numpy as jnp
    >>> float(scaled(sphere, 2.0)(jnp.array([3.0, 0.0, 0.0])))
    1.0
    """

    def grown(points, *args, **kwargs):
        p = _points("voxax.fields.scaled", points)
        return factor * field(p / factor, *args, **kwargs)

    return grown


# -- neural fields ---------------------------------------------------------------------------


def _uniform(key, shape, bound, dtype):
    return jax.random.uniform(key, shape, dtype=dtype, minval=-bound, maxval=bound)


class Siren(eqx.Module):
    """A SIREN: an MLP with sine activations, `sin(omega_0 (W x + b))`, and a linear output.

    Initialisation as in Sitzmann et al. (2020): first-layer weights uniform in
    `[-1/n_in, 1/n_in]`, hidden-layer weights uniform in
    `[-sqrt(6/n_in)/omega_0, sqrt(6/n_in)/omega_0]` (so every sine sees pre-activations of
    unit standard deviation and its outputs stay arcsine-distributed in depth), biases
    uniform in `[-1/sqrt(n_in), 1/sqrt(n_in)]`; the output layer uses the hidden-layer
    bound. `omega_0 = 30` by default (the first layer multiplies by `first_omega_0`).

    `in_size=3, out_size=1` gives a 3D scalar field; `in_size=2, out_size=1` a height field
    `z = h(x, y)`. Call it on points `(..., in_size)`; the result is `(...)` when
    `out_size == 1` and `(..., out_size)` otherwise.

    **Arguments:**

    - `in_size`, `out_size`: input and output dimensions.
    - `width`: hidden width; `depth`: number of hidden (sine) layers, >= 1.
    - `key`: a `jax.random` key.
    - `omega_0`, `first_omega_0`: frequency factors (30 and 30 by default).
    - `dtype`: parameter dtype (defaults to JAX's default float).

    >>> import jax
    >>> net = Siren(2, 1, width=16, depth=2, key=jax.random.key(0))
    >>> net(jax.numpy.zeros((5, 2))).shape
    (5,)
    """

    weights: list
    biases: list
    omega_0: float = eqx.field(static=True)
    first_omega_0: float = eqx.field(static=True)
    in_size: int = eqx.field(static=True)
    out_size: int = eqx.field(static=True)

    def __init__(
        self,
        in_size: int = 3,
        out_size: int = 1,
        width: int = 64,
        depth: int = 3,
        *,
        key,
        omega_0: float = 30.0,
        first_omega_0: float = 30.0,
        dtype=None,
    ):
        where = "voxax.fields.Siren"
        in_size, out_size, width, depth = (_validate.positive_int(where, name, value) for name, value in (
            ("in_size", in_size), ("out_size", out_size), ("width", width), ("depth", depth)))
        _validate.check_allocation(where, 8.0 * depth * (width + 1) * float(width + in_size + out_size),
                                   f"a Siren of depth {depth} and width {width}", "pass a smaller `depth` or `width`")
        key = _validate.key(where, key)
        omega_0 = _validate.positive_float(where, "omega_0", omega_0)
        first_omega_0 = _validate.positive_float(where, "first_omega_0", first_omega_0)
        dtype = jnp.result_type(float) if dtype is None else _validate.float_dtype(where, dtype)
        sizes = [in_size] + [width] * depth + [out_size]
        keys = jax.random.split(key, 2 * (len(sizes) - 1))
        weights, biases = [], []
        for i, (n_in, n_out) in enumerate(itertools.pairwise(sizes)):
            bound = 1.0 / n_in if i == 0 else math.sqrt(6.0 / n_in) / omega_0
            weights.append(_uniform(keys[2 * i], (n_out, n_in), bound, dtype))
            biases.append(
                _uniform(keys[2 * i + 1], (n_out,), 1.0 / math.sqrt(n_in), dtype)
            )
        self.weights, self.biases = weights, biases
        self.omega_0, self.first_omega_0 = float(omega_0), float(first_omega_0)
        self.in_size, self.out_size = int(in_size), int(out_size)

    def hidden(self, x):
        """The activations of every sine layer for one point `x (in_size,)` (a list)."""
        acts = []
        for i, (w, b) in enumerate(zip(self.weights[:-1], self.biases[:-1])):
            omega = self.first_omega_0 if i == 0 else self.omega_0
            x = jnp.sin(omega * (w @ x + b))
            acts.append(x)
        return acts

    def _single(self, x):
        h = self.hidden(x)[-1]
        y = self.weights[-1] @ h + self.biases[-1]
        return y[0] if self.out_size == 1 else y

    def __call__(self, points):
        p = _points("voxax.fields.Siren", points, self.in_size)
        lead = p.shape[:-1]
        flat = p.reshape(-1, self.in_size)
        out = jax.vmap(self._single)(flat)
        return out.reshape(lead + out.shape[1:])


class DeepSDF(eqx.Module):
    """A DeepSDF auto-decoder: one latent code per training shape and an MLP `f(z, x)`.

    The decoder follows Park et al. (2019) in small: `depth` fully connected ReLU layers
    of `width` units on the concatenation `[z, x]`, the input concatenated again to the
    activations entering layer `skip` (the paper: 8 layers of 512, skip at 4), and a
    `tanh` output (the training targets are clamped to `[-clamp, clamp]` inside
    `tanh`'s range). Latent codes start from `N(0, code_std^2)` (the paper: 0.01). Weight
    normalisation and dropout are left out (they change training, not the model).

    `model(points, index)` evaluates shape `index` (an int or an int array broadcast with
    the points' leading axes); `model.decode(latent, points)` evaluates any code, e.g. an
    interpolated or optimised one.

    **Arguments:**

    - `n_shapes`: number of latent codes; `latent_size`: their length.
    - `width`, `depth`, `skip`: decoder width, number of hidden layers, and the layer that
      receives the skip connection (`None` for none).
    - `key`: a `jax.random` key; `code_std`: the codes' initial standard deviation.
    - `dim`: point dimension (3).

    >>> import jax
    >>> net = DeepSDF(n_shapes=2, latent_size=8, width=32, depth=4, skip=2, key=jax.random.key(0))
    >>> net(jax.numpy.zeros((7, 3)), 1).shape
    (7,)
    """

    codes: jax.Array
    layers: list
    output: eqx.nn.Linear
    skip: int | None = eqx.field(static=True)
    dim: int = eqx.field(static=True)

    def __init__(
        self,
        n_shapes: int,
        latent_size: int = 64,
        width: int = 128,
        depth: int = 4,
        skip: int | None = 2,
        *,
        key,
        code_std: float = 0.01,
        dim: int = 3,
        dtype=None,
    ):
        where = "voxax.fields.DeepSDF"
        n_shapes, width, depth = (_validate.positive_int(where, name, value) for name, value in (
            ("n_shapes", n_shapes), ("width", width), ("depth", depth)))
        latent_size = _validate.positive_int(where, "latent_size", latent_size, minimum=0)
        dim = _validate.positive_int(where, "dim", dim)
        _validate.check_allocation(where, 8.0 * (n_shapes * float(latent_size) + depth * (width + 1) *
                                                 float(width + latent_size + dim)),
                                   f"a DeepSDF of {n_shapes} shapes, depth {depth} and width {width}",
                                   "pass smaller sizes")
        if skip is not None:
            skip = _validate.positive_int(where, "skip", skip)
            if skip >= depth:
                raise ValueError(f"{where}: `skip` must lie in [1, depth) = [1, {depth}), or be None; got {skip}")
        key = _validate.key(where, key)
        code_std = _validate.positive_float(where, "code_std", code_std, allow_zero=True)
        dtype = jnp.result_type(float) if dtype is None else _validate.float_dtype(where, dtype)
        kc, *kl = jax.random.split(key, depth + 2)
        self.codes = code_std * jax.random.normal(
            kc, (n_shapes, latent_size), dtype=dtype
        )
        n_in = latent_size + dim
        layers = []
        size = n_in
        for i in range(depth):
            if skip is not None and i == skip:
                size += n_in
            layers.append(eqx.nn.Linear(size, width, key=kl[i], dtype=dtype))
            size = width
        self.layers = layers
        self.output = eqx.nn.Linear(width, 1, key=kl[depth], dtype=dtype)
        self.skip, self.dim = skip, int(dim)

    @property
    def latent_size(self) -> int:
        """Length of each latent code."""
        return int(self.codes.shape[1])

    def _single(self, z, x):
        inp = jnp.concatenate([z, x])
        h = inp
        for i, layer in enumerate(self.layers):
            if self.skip is not None and i == self.skip:
                h = jnp.concatenate([h, inp])
            h = jax.nn.relu(layer(h))
        return jnp.tanh(self.output(h)[0])

    def decode(self, latent, points):
        """The field of latent code `latent (latent_size,)` (or `(..., latent_size)`,
        broadcast with the points' leading axes) at `points (..., dim)` -> `(...)`."""
        p = _points("voxax.fields.DeepSDF", points, self.dim)
        z = jnp.asarray(latent, dtype=p.dtype)
        if z.shape[-1:] != (self.latent_size,):
            raise ValueError(
                f"voxax.fields.DeepSDF.decode: `latent` must have shape (..., {self.latent_size}), got {z.shape}"
            )
        lead = jnp.broadcast_shapes(p.shape[:-1], z.shape[:-1])
        p = jnp.broadcast_to(p, lead + (self.dim,)).reshape(-1, self.dim)
        z = jnp.broadcast_to(z, lead + (self.latent_size,)).reshape(
            -1, self.latent_size
        )
        return jax.vmap(self._single)(z, p).reshape(lead)

    def __call__(self, points, index=0):
        """The field of training shape(s) `index` at `points (..., dim)` -> `(...)`."""
        _shape_index("voxax.fields.DeepSDF", index, self.codes.shape[0])
        return self.decode(self.codes[jnp.asarray(index)], points)


def _shape_index(where: str, index, n: int) -> None:
    """Checks the shape indices `index` (an int or an int array) of a DeepSDF with `n`
    codes: integers, and in `[0, n)` when concrete (JAX would clamp them silently)."""
    if isinstance(index, (bool, np.bool_)) or (hasattr(index, "dtype") and np.dtype(index.dtype).kind not in "iu"):
        raise TypeError(f"{where}: `index` must be an int or an int array, got {getattr(index, 'dtype', 'bool')}")
    if not hasattr(index, "dtype") and not isinstance(index, (int, np.integer)):
        index = _validate.typed_array(where, "index", index, "iu", "an int or an int array")
    if _validate.is_concrete(index) and np.size(index):
        a = np.asarray(index)
        if a.min() < 0 or a.max() >= n:
            raise ValueError(f"{where}: `index` must lie in [0, {n}) (the model's shapes), got [{a.min()}, {a.max()}]")


def deepsdf_loss(
    model: DeepSDF,
    points,
    sdf,
    index=0,
    *,
    clamp: float = 0.1,
    code_sigma: float = 1e-2,
):
    """The DeepSDF training loss: clamped L1 plus the latent-code prior.

    `mean |clamp_d(f(z_i, x)) - clamp_d(s)| + (1 / sigma^2) * mean_i |z_i|^2 / n` where
    `clamp_d(t) = min(d, max(-d, t))` with `d = clamp` (the paper: 0.1) and the code prior
    of weight `1/sigma^2`, scaled here by the number of samples so that both terms are
    means. Codes are regularised only for the shapes in `index`.

    **Arguments:**

    - `model`: a `DeepSDF`.
    - `points`: `(..., 3)` sample points; `sdf`: `(...)` target signed distances.
    - `index`: int or int array (broadcast with the points' leading axes).
    - `clamp`, `code_sigma`: the clamp distance and the prior's standard deviation.

    **Returns:** scalar loss.
    """
    where = "voxax.fields.deepsdf_loss"
    if not isinstance(model, DeepSDF):
        raise TypeError(f"{where}: `model` must be a voxax.fields.DeepSDF, got {type(model).__name__}")
    p = _points(where, _validate.coordinates(where, "points", points, model.dim), model.dim)
    sdf = _validate.typed_array(where, "sdf", sdf, "fiu")
    if tuple(sdf.shape) != tuple(p.shape[:-1]):
        raise ValueError(f"{where}: `sdf` must have one value per point, shape {tuple(p.shape[:-1])}, got "
                         f"{tuple(sdf.shape)}")
    if _validate.is_concrete(sdf) and np.size(sdf) and not np.all(np.isfinite(np.asarray(sdf))):
        raise ValueError(f"{where}: `sdf` must be finite (it contains NaN or Inf)")
    _shape_index(where, index, model.codes.shape[0])
    clamp = _validate.positive_float(where, "clamp", clamp)
    code_sigma = _validate.positive_float(where, "code_sigma", code_sigma)
    pred = model(p, index)
    s = jnp.asarray(sdf, dtype=pred.dtype)
    data = jnp.mean(jnp.abs(jnp.clip(pred, -clamp, clamp) - jnp.clip(s, -clamp, clamp)))
    codes = model.codes[jnp.asarray(index)]
    prior = jnp.mean(jnp.sum(codes * codes, axis=-1)) / code_sigma**2
    return data + prior / max(int(jnp.size(pred)), 1)

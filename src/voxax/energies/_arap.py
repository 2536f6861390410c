"""As-rigid-as-possible (ARAP) energy with spokes-and-rims cells and cotangent weights."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from .. import _validate

__all__ = ["cotangent_weights", "arap_rotations", "arap"]

# Edge k of a triangle is the one opposite corner k: it runs from corner k+1 to corner k+2.
# (NumPy, not jnp: nothing may start the XLA backend at import.)
_NEXT = np.array([1, 2, 0])
_PREV = np.array([2, 0, 1])


def _check_mesh(vertices, faces, name):
    _validate.mesh(f"voxax.energies.{name}", vertices, faces, batch=True, faces_dim=3, finite=False)


def _batch(fn, signature, *args):
    """Applies the one-mesh `fn` over the broadcast leading axes of `args`."""
    return jnp.vectorize(fn, signature=signature)(*args)


def _as_float(x):
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    return x


def _edges(vertices, faces):
    """`(F, 3, d)` edge vectors; edge k runs from corner k+1 to corner k+2."""
    corners = vertices[faces]  # (F, 3, d)
    return corners[:, _PREV] - corners[:, _NEXT]


@_validate.checked_jit("voxax.energies.cotangent_weights", static_argnames=("min_weight", "max_weight"))
def cotangent_weights(vertices, faces, min_weight: float = 1e-4, max_weight: float = 1e4):
    """Per-triangle cotangent weights of a mesh, robust to obtuse and degenerate triangles.

    `weights[f, k] = cot(angle at corner k of face f) / 2`, the weight of the edge opposite
    corner k (from corner k+1 to corner k+2). Summing the weights of the (up to) two faces
    that share an edge gives the classic cotangent-Laplacian weight `(cot a + cot b) / 2`.
    Negative (obtuse angles) and tiny weights are clamped up to `min_weight` (so that the
    ARAP energy stays a sum of non-negative terms), huge ones (near-degenerate triangles)
    down to `max_weight`; degenerate triangles (zero area, repeated vertices) give finite
    weights, never NaN or inf.

    **Arguments:**

    - `vertices`: `(..., V, 3)` float vertex positions.
    - `faces`: `(..., F, 3)` int triangles.
    - `min_weight`, `max_weight`: the clamp range (applied to `cot / 2`).

    **Returns:**

    `(..., F, 3)` float weights (leading axes: the broadcast batch axes of the inputs).

    **Example:**

    ```python
    >>> m = voxax.data.get("icosphere")
    >>> w = voxax.energies.cotangent_weights(m.vertices, m.faces)   # (F, 3)
    ```
    """
    vertices = _as_float(vertices)
    faces = jnp.asarray(faces)
    _check_mesh(vertices, faces, "cotangent_weights")
    one = functools.partial(_cotangent_weights, min_weight=min_weight, max_weight=max_weight)
    return _batch(one, "(v,d),(f,k)->(f,k)", vertices, faces)


def _cotangent_weights(vertices, faces, min_weight, max_weight):
    corners = vertices[faces]  # (F, 3, d)
    u = corners[:, _NEXT] - corners  # from corner k to corner k+1
    v = corners[:, _PREV] - corners  # from corner k to corner k+2
    dot = jnp.sum(u * v, axis=-1)
    if vertices.shape[-1] == 3:
        cross = jnp.linalg.norm(jnp.cross(u, v), axis=-1)
    else:
        cross = jnp.abs(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])
    tiny = jnp.finfo(vertices.dtype).tiny
    # Guard the denominator relative to the edge lengths, so that degenerate triangles
    # give large (then clamped) weights rather than inf/NaN.
    scale = jnp.sum(u * u, axis=-1) + jnp.sum(v * v, axis=-1)
    denom = jnp.maximum(cross, 1e-12 * scale + tiny)
    w = 0.5 * dot / denom
    return jnp.clip(w, min_weight, max_weight)


def _covariances(vertices, rest_vertices, faces, weights):
    """`(V, 3, 3)` spokes-and-rims covariances `S_i = sum w e_rest e_cur^T`."""
    e_rest = _edges(rest_vertices, faces)  # (F, 3, 3)
    e_cur = _edges(vertices, faces)
    M = jnp.einsum("fe,fea,feb->fab", weights, e_rest, e_cur)  # per face
    d = vertices.shape[-1]
    S = jnp.zeros((vertices.shape[0], d, d), vertices.dtype)
    return S.at[faces].add(jnp.broadcast_to(M[:, None], (faces.shape[0], 3, d, d)))


@_validate.checked_jit("voxax.energies.arap_rotations", static_argnames=())
def arap_rotations(vertices, rest_vertices, faces, weights=None):
    """The best-fitting rotation of every vertex cell (spokes and rims), by SVD.

    For vertex i, `S_i = sum_e w_e e_rest e_cur^T` over every edge e of every face that
    contains i (the cell's spokes and rims); with `S_i = U diag(s) V^T`,
    `R_i = V U^T`, with the sign of the last column of `U` flipped when `det(V U^T) < 0`,
    so `R_i` is a proper rotation that maps rest edges onto current edges as well as
    possible. The result is wrapped in `jax.lax.stop_gradient`.

    **Arguments:**

    - `vertices`: `(..., V, 3)` current vertex positions.
    - `rest_vertices`: `(..., V, 3)` rest positions.
    - `faces`: `(..., F, 3)` int triangles.
    - `weights`: optional `(F, 3)` edge weights (default: `cotangent_weights(rest_vertices, faces)`).

    **Returns:**

    `(..., V, 3, 3)` rotations (identity-like but arbitrary for vertices in no face).

    **Example:**

    ```python
    >>> m = voxax.data.icosphere(1)
    >>> R = voxax.energies.arap_rotations(m.vertices * 2.0, m.vertices, m.faces)   # (V, 3, 3)
    >>> R.shape, bool(jnp.allclose(R, jnp.eye(3), atol=1e-9))   # scaling rotates nothing
    ((42, 3, 3), True)
    ```
    """
    vertices = _as_float(vertices)
    rest_vertices = _as_float(rest_vertices).astype(vertices.dtype)
    faces = jnp.asarray(faces)
    _check_mesh(vertices, faces, "arap_rotations")
    if rest_vertices.shape[-2:] != vertices.shape[-2:]:
        raise ValueError(f"voxax.energies.arap_rotations: `rest_vertices` {rest_vertices.shape} and `vertices` {vertices.shape} differ in shape")
    if weights is None:
        weights = cotangent_weights(rest_vertices, faces)
    weights = jnp.asarray(weights, vertices.dtype)
    return _batch(_arap_rotations, "(v,d),(v,d),(f,k),(f,k)->(v,d,d)", vertices, rest_vertices, faces, weights)


def _arap_rotations(vertices, rest_vertices, faces, weights):
    vertices = jax.lax.stop_gradient(vertices)
    rest_vertices = jax.lax.stop_gradient(rest_vertices)
    weights = jax.lax.stop_gradient(jnp.asarray(weights, vertices.dtype))
    S = _covariances(vertices, rest_vertices, faces, weights)
    U, _, Vt = jnp.linalg.svd(S)
    V_ = jnp.swapaxes(Vt, -1, -2)
    R = V_ @ jnp.swapaxes(U, -1, -2)
    det = jnp.linalg.det(R)
    U = U.at[..., -1].multiply(jnp.where(det < 0, -1.0, 1.0)[..., None].astype(U.dtype))
    R = V_ @ jnp.swapaxes(U, -1, -2)
    # Cells without faces have S = 0: any rotation will do; avoid NaN from odd SVDs.
    eye = jnp.eye(vertices.shape[-1], dtype=vertices.dtype)
    R = jnp.where(jnp.all(jnp.isfinite(R), axis=(-1, -2), keepdims=True), R, eye)
    return jax.lax.stop_gradient(R)


@_validate.checked_jit("voxax.energies.arap", static_argnames=("normalize",))
def arap(vertices, rest_vertices, faces, weights=None, *, rotations=None, normalize: bool = True):
    """The as-rigid-as-possible deformation energy (spokes and rims, cotangent weights).

    `E = sum_i sum_{e in cell(i)} w_e |e_cur - R_i e_rest|^2`, where the cell of vertex i
    holds every edge of every face containing i (so each edge of a face counts once for
    each of the face's three corners; Chao et al. 2010), `w_e` are the rest shape's
    cotangent weights (`cotangent_weights`, computed per face and clamped to be positive)
    and `R_i` the best rotations (`arap_rotations`), held fixed under differentiation
    (`stop_gradient`). Since the `R_i` minimize the energy, the gradient with fixed
    rotations *is* the gradient of the minimized energy (the envelope theorem).

    With `normalize=True` (the default) the sum is divided by the total rest area, which
    makes the energy dimensionless and independent of the mesh's scale and (roughly) of
    its resolution: it is about three times the area-averaged squared strain. With
    `normalize=False` it is the raw sum (units of length^2).

    It is zero exactly for rigid motions (rotation + translation) of the rest shape and
    positive otherwise (stretching, bending, shearing).

    **Arguments:**

    - `vertices`: `(..., V, 3)` float, the deformed positions (differentiated).
    - `rest_vertices`: `(..., V, 3)` float, the rest positions.
    - `faces`: `(..., F, 3)` int triangles.
    - `weights`: optional `(F, 3)` edge weights (default: cotangent weights of the rest
      shape). Precompute them once with `cotangent_weights` in a loop if you like.
    - `rotations`: optional `(V, 3, 3)` fixed rotations (default: `arap_rotations`).
    - `normalize`: divide by the total rest area (default) or not.

    **Returns:**

    A scalar per mesh: leading axes of `vertices`, `rest_vertices`, `faces` (and of
    `weights`, `rotations`) are batch axes that broadcast against each other, so
    `(B, V, 3)` vertices give `(B,)` energies; `jax.vmap` works too.

    **Example:**

    ```python
    >>> m = voxax.data.get("torus")
    >>> e = voxax.energies.arap(m.vertices * 1.1, m.vertices, m.faces)   # > 0: scaling
    >>> bool(e > 0)
    True
    >>> g = jax.grad(voxax.energies.arap)(jnp.asarray(m.vertices * 1.1), m.vertices, m.faces)
    >>> g.shape == m.vertices.shape
    True
    ```
    """
    vertices = _as_float(vertices)
    rest_vertices = _as_float(rest_vertices).astype(vertices.dtype)
    faces = jnp.asarray(faces)
    _check_mesh(vertices, faces, "arap")
    if rest_vertices.shape[-2:] != vertices.shape[-2:]:
        raise ValueError(f"voxax.energies.arap: `rest_vertices` {rest_vertices.shape} and `vertices` {vertices.shape} differ in shape")
    if weights is None:
        weights = cotangent_weights(rest_vertices, faces)
    weights = jnp.asarray(weights, vertices.dtype)
    if weights.shape[-2:] != faces.shape[-2:]:
        raise ValueError(f"voxax.energies.arap: `weights` must have shape {faces.shape} (one per face edge), got {weights.shape}")
    if rotations is None:
        rotations = arap_rotations(vertices, rest_vertices, faces, weights)
    rotations = jax.lax.stop_gradient(jnp.asarray(rotations, vertices.dtype))
    one = functools.partial(_arap, normalize=normalize)
    sig = "(v,d),(v,d),(f,k),(f,k),(v,d,d)->()"
    return _batch(one, sig, vertices, rest_vertices, faces, weights, rotations)


def _arap(vertices, rest_vertices, faces, weights, rotations, normalize):
    e_rest = _edges(rest_vertices, faces)  # (F, 3 edges, d)
    e_cur = _edges(vertices, faces)
    R = rotations[faces]  # (F, 3 corners, d, d)
    r = e_cur[:, None, :, :] - jnp.einsum("fcab,feb->fcea", R, e_rest)  # (F, corner, edge, d)
    E = jnp.sum(weights[:, None, :] * jnp.sum(r * r, axis=-1))
    if normalize:
        corners = rest_vertices[faces]
        a, b = corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]
        if vertices.shape[-1] == 3:
            area = 0.5 * jnp.sum(jnp.linalg.norm(jnp.cross(a, b), axis=-1))
        else:
            area = 0.5 * jnp.sum(jnp.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]))
        E = E / jnp.maximum(jax.lax.stop_gradient(area), jnp.finfo(vertices.dtype).tiny)
    return E

"""Energies on voxel grids (the output of `voxax.voxelize`): pure JAX."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

from .. import _validate


def _grid(where: str, W, name: str = "W", rank: int = 3, mean: bool = False):
    """`W` as a float JAX array of at least `rank` axes, real (bools and integers become
    floats; complex numbers and strings are refused) and finite (checked eagerly, and
    by the value-check kernel under a trace: `_validate.finite_values`). Its last `rank`
    axes (the grid's) hold at least one cell each; with `mean` (an energy that is a mean
    over all of `W`'s values) `W` must not be empty at all."""
    W = _validate.typed_array(where, name, W, "fiub")
    W = jnp.asarray(W)
    if not jnp.issubdtype(W.dtype, jnp.floating):
        W = W.astype(jnp.result_type(float))
    if W.ndim < rank:
        raise ValueError(f"{where}: `{name}` must be a grid with at least {rank} axes (..., nx, ny, nz), got shape "
                         f"{W.shape}")
    if 0 in W.shape[W.ndim - rank:]:
        raise ValueError(f"{where}: `{name}` must have at least one cell along each grid axis, got shape {W.shape}")
    if mean and W.size == 0:
        raise ValueError(f"{where}: `{name}` must not be empty (the energy is a mean over its cells)")
    return _validate.finite_values(where, name, W)


@_validate.checked_jit("voxax.energies.mellowmax", static_argnames=("axis",), positive=("w",))
def mellowmax(x, w: float = 1000.0, axis: int = -1):
    r"""A smooth maximum: the mellowmax operator of Asadi and Littman (2017).

    `mellowmax(x) = log(mean(exp(w * x))) / w`, evaluated stably as
    `m + (logsumexp(w * (x - m)) - log N) / w` with `m` the maximum along `axis`.
    It lies between the mean and the maximum, and tends to the maximum as `w -> inf`
    (it undershoots it by at most `log(N) / w`). Its gradient is the softmax of
    `w * x` along `axis`: ties share the gradient equally. (The value does not depend on
    the shift `m`, so `m` is held fixed with `stop_gradient`; every derivative is exact.)

    **Arguments:**

    - `x`: float array.
    - `w`: positive float, the sharpness (the paper uses 1000 on `[0, 1]` grids).
    - `axis`: int, the axis to reduce.

    **Returns:**

    `x` with `axis` removed.

    **Example:**

    ```python
    >>> import jax.numpy as jnp, voxax
    >>> float(voxax.energies.mellowmax(jnp.array([0.0, 1.0]), w=1e4))  # ~ 1 - log(2)/1e4
    0.9999306...
    ```
    """
    x = jnp.asarray(x)
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(jnp.result_type(float))
    n = x.shape[axis]
    m = jax.lax.stop_gradient(jnp.max(x, axis=axis, keepdims=True))
    # Guard against -inf/inf maxima (all entries -inf): keep the shift finite.
    m = jnp.where(jnp.isfinite(m), m, 0.0)
    w = _validate.finite_values("voxax.energies.mellowmax", "w", jnp.asarray(w, x.dtype), positive=True)  # traced: the kernel check
    lse = jax.nn.logsumexp(w * (x - m), axis=axis)
    return jnp.squeeze(m, axis=axis) + (lse - math.log(n)) / w


@_validate.checked_jit("voxax.energies.silhouettes", static_argnames=(), positive=("w",))
def silhouettes(W, w: float = 1000.0):
    """The three soft silhouettes of a voxel grid: mellowmax along x, y and z.

    `Sx[j, k] = mellowmax(W[:, j, k])` (the shadow cast along x), and likewise for y and
    z. These are the outlines a bandsaw can cut along each axis (paper, Sec. 4.3).

    **Arguments:**

    - `W`: `(..., nx, ny, nz)` float grid (leading axes are batch axes).
    - `w`: the mellowmax sharpness (1000 in the paper).

    **Returns:**

    `(Sx, Sy, Sz)` with shapes `(..., ny, nz)`, `(..., nx, nz)` and `(..., nx, ny)`.

    **Example:**

    ```python
    >>> mesh = voxax.data.hand()
    >>> W = voxax.voxelize(mesh.vertices, mesh.faces, voxax.Grid.cube(32))
    >>> Sx, Sy, Sz = voxax.energies.silhouettes(W)
    >>> Sx.shape, Sy.shape, Sz.shape
    ((32, 32), (32, 32), (32, 32))
    ```
    """
    return _silhouettes(_grid("voxax.energies.silhouettes", W), w)


def _silhouettes(W, w):
    return mellowmax(W, w, axis=-3), mellowmax(W, w, axis=-2), mellowmax(W, w, axis=-1)


@_validate.checked_jit("voxax.energies.cut_shape", static_argnames=(), positive=("w",))
def cut_shape(W, w: float = 1000.0):
    """The soft bandsaw cut shape: the three silhouettes extruded and intersected.

    `S[i, j, k] = Sx[j, k] * Sy[i, k] * Sz[i, j]`: the block that remains after cutting
    along the silhouette of `W` seen from each axis (paper, Sec. 4.3, Fig. 8).

    **Arguments:**

    - `W`: `(..., nx, ny, nz)` float grid.
    - `w`: the mellowmax sharpness.

    **Returns:**

    `(..., nx, ny, nz)` the cut shape `S`.

    **Example:**

    ```python
    >>> mesh = voxax.data.hand()
    >>> W = voxax.voxelize(mesh.vertices, mesh.faces, voxax.Grid.cube(32))
    >>> S = voxax.energies.cut_shape(W)     # ~1 inside the shape, and more material around it
    >>> S.shape, bool(jnp.all(S[W > 0.999] > 0.98)), bool(S.sum() > W.sum())
    ((32, 32, 32), True, True)
    ```
    """
    return _cut_shape(_grid("voxax.energies.cut_shape", W), w)


def _cut_shape(W, w):
    Sx, Sy, Sz = _silhouettes(W, w)
    return Sx[..., None, :, :] * Sy[..., :, None, :] * Sz[..., :, :, None]


@_validate.checked_jit("voxax.energies.bandsaw_cut", static_argnames=(), positive=("w",))
def bandsaw_cut(W, w: float = 1000.0):
    """The bandsaw cut energy `E_cut = mean((S - W)^2)` with `S = cut_shape(W, w)`.

    It measures the material a bandsaw cut would leave beyond the shape (paper, Sec.
    4.3). Voxels with `W > 1` (self-intersections) are penalised as well, on purpose.
    With batch axes, the mean runs over all of them too (use `jax.vmap` for one energy
    per instance).

    **Arguments:**

    - `W`: `(..., nx, ny, nz)` float grid.
    - `w`: the mellowmax sharpness (1000 in the paper; smaller is smoother).

    **Returns:**

    A scalar.

    **Example:**

    ```python
    >>> V, F = voxax.data.hand()
    >>> grid = voxax.Grid.cube(32)
    >>> e = voxax.energies.bandsaw_cut(voxax.voxelize(V, F, grid))
    >>> g = jax.grad(lambda V: voxax.energies.bandsaw_cut(voxax.voxelize(V, F, grid)))(jnp.asarray(V))
    >>> g.shape == V.shape
    True
    ```
    """
    W = _grid("voxax.energies.bandsaw_cut", W)
    S = _cut_shape(W, w)
    return jnp.mean((S - W) ** 2)


bandsaw = bandsaw_cut


@_validate.checked_jit("voxax.energies.self_intersection", static_argnames=(), scalar=("eps",))
def self_intersection(W, eps: float = 1e-3):
    """The self-intersection energy `E_sect` (paper, Sec. 4.2).

    `sum(W^2 over voxels with W > 1 + eps) / W.size`: voxels covered more than once by
    the surface (winding number above one) are penalised. `eps` hides rounding noise.
    The result is the mean over all voxels (batch axes included), so it does not grow
    with the resolution.

    **Arguments:**

    - `W`: `(..., nx, ny, nz)` float grid.
    - `eps`: non-negative float, the tolerance above 1.

    **Returns:**

    A scalar, zero when no voxel exceeds `1 + eps`.

    **Example:**

    ```python
    >>> m = voxax.data.get("bent_bar")
    >>> W = voxax.voxelize(m.vertices, m.faces, voxax.Grid.cube(32))
    >>> float(voxax.energies.self_intersection(W)) > 0
    True
    ```
    """
    W = _grid("voxax.energies.self_intersection", W, rank=0, mean=True)
    return jnp.sum(jnp.where(W > 1.0 + eps, W * W, 0.0)) / W.size


@_validate.checked_jit("voxax.energies.fold_periodic", static_argnames=("blocks",))
def fold_periodic(W, blocks: int = 3):
    """Folds a grid into one periodic cell: cut it into `blocks^3` blocks and sum them.

    A grid of shape `(blocks*n_x, blocks*n_y, blocks*n_z)` is cut into `blocks^3` blocks
    of `(n_x, n_y, n_z)` voxels and the blocks are added up (and so are any leading batch
    axes, e.g. instances), giving a cell that tiles space periodically (paper, Sec. 4.4).
    With `voxax.Grid.cube(3 * n)` and `blocks=3`, the cell is the middle third
    `[-1/3, 1/3]^3`, and whatever sticks out of it re-enters on the opposite side.
    The total sum is conserved.

    **Arguments:**

    - `W`: `(..., blocks*n_x, blocks*n_y, blocks*n_z)` float grid(s).
    - `blocks`: positive int, the number of blocks per axis.

    **Returns:**

    `(n_x, n_y, n_z)` the periodic cell.

    **Example:**

    ```python
    >>> cell = voxax.energies.fold_periodic(jnp.ones((27, 12, 12, 12)))  # 27 instances
    >>> cell.shape, float(cell[0, 0, 0])
    ((4, 4, 4), 729.0)
    ```
    """
    return _fold(_grid("voxax.energies.fold_periodic", W), blocks, "voxax.energies.fold_periodic")


def _fold(W, blocks, where: str, name: str = "W"):
    b = _validate.positive_int(where, "blocks", blocks)
    *batch, nx, ny, nz = W.shape
    if nx % b or ny % b or nz % b:
        raise ValueError(f"{where}: `{name}` of shape {(nx, ny, nz)} must be divisible by `blocks` = {b} on every "
                         "axis")
    W = W.reshape(-1, b, nx // b, b, ny // b, b, nz // b)
    return W.sum(axis=(0, 1, 3, 5))


@_validate.checked_jit("voxax.energies.tiling", static_argnames=("blocks", "normalize"))
def tiling(W_instances, blocks: int = 3, normalize: bool = False):
    """The space-filling energy `E_fill = sum((cell - 1)^2)` (paper, Sec. 4.4).

    `cell = fold_periodic(W_instances, blocks)` adds every instance's grid, folded into
    one periodic cell. The energy is zero when every voxel of the cell is covered exactly
    once.

    **Arguments:**

    - `W_instances`: `(..., blocks*n, blocks*n, blocks*n)` float grids, one per instance
      (all leading axes are summed over).
    - `blocks`: the number of blocks per axis (3 in the paper: 27 blocks).
    - `normalize`: if true, divide by the number of cell voxels (the paper's energy is
      the plain sum, the default).

    **Returns:**

    A scalar.

    **Example:**

    ```python
    >>> V, F = voxax.data.icosphere(2, radius=0.2)
    >>> shifts = jnp.stack(jnp.meshgrid(*[jnp.array([-2, 0, 2]) / 3] * 3, indexing="ij"), -1).reshape(27, 1, 3)
    >>> Vs = V + shifts                                     # 27 spheres, one per block
    >>> Ws = jax.vmap(lambda V: voxax.voxelize(V, F, voxax.Grid.cube(24)))(Vs)
    >>> Ws.shape
    (27, 24, 24, 24)
    >>> e = voxax.energies.tiling(Ws)   # the cell is 8^3 voxels, mostly left empty
    >>> bool(e > 0)
    True
    ```
    """
    where = "voxax.energies.tiling"
    cell = _fold(_grid(where, W_instances, "W_instances"), blocks, where, "W_instances")
    e = jnp.sum((cell - 1.0) ** 2)
    return e / cell.size if normalize else e


@_validate.checked_jit("voxax.energies.volume", static_argnames=("grid",))
def volume(W, grid):
    """The volume enclosed by the surface: `W.sum() * grid.voxel_volume`.

    Exact (up to rounding) for closed meshes inside the grid, because the voxel values
    are exact box-filtered winding numbers. Leading batch axes are kept: one volume per
    instance.

    **Arguments:**

    - `W`: `(..., *grid.shape)` float grid.
    - `grid`: the `voxax.Grid` that `W` lives on.

    **Returns:**

    A scalar (or `(...)` for batches).

    **Example:**

    ```python
    >>> V, F = voxax.data.box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.25))
    >>> grid = voxax.Grid.cube(32)
    >>> vol = voxax.energies.volume(voxax.voxelize(V, F, grid), grid)
    >>> round(float(vol), 9)
    0.75
    ```
    """
    where = "voxax.energies.volume"
    _validate.grid(where, grid)
    W = _grid(where, W, rank=0)
    d = len(grid.shape)
    if tuple(W.shape[W.ndim - d:]) != tuple(grid.shape):
        raise ValueError(f"{where}: `W` of shape {W.shape} must end in grid.shape {grid.shape}")
    return W.sum(axis=tuple(range(W.ndim - d, W.ndim))) * grid.voxel_volume


@_validate.checked_jit("voxax.energies.interpenetration", static_argnames=())
def interpenetration(W_a, W_b):
    """The overlap between two shapes voxelized on the same grid.

    `sum(clip(W_a, 0, 1) * clip(W_b, 0, 1)) / W_a.size`: the mean over the voxels of the
    product of the two occupancies, i.e. the overlapping volume divided by the grid's
    volume (exact in the limit of fine grids). Clipping to `[0, 1]` makes the energy
    ignore each shape's own self-overlaps and inverted parts. It is zero when the shapes
    are apart and its gradient pushes *both* shapes apart (it flows through the boundary
    voxels of each). This energy is not in the paper: use it to separate colliding
    objects, e.g. `self_intersection(W_a + W_b)` penalises the same overlaps more
    sharply.

    **Arguments:**

    - `W_a`, `W_b`: `(..., nx, ny, nz)` float grids of the same shape (same grid).

    **Returns:**

    A scalar.

    **Example:**

    ```python
    >>> Va, Fa = voxax.data.box((-0.5, -0.5, -0.5), (0.25, 0.5, 0.5))
    >>> Vb, Fb = voxax.data.box((0.0, -0.5, -0.5), (0.5, 0.5, 0.5))
    >>> grid = voxax.Grid.cube(32)
    >>> e = voxax.energies.interpenetration(voxax.voxelize(Va, Fa, grid), voxax.voxelize(Vb, Fb, grid))
    >>> round(float(e) * 8, 9)                    # overlap volume 0.25 (the grid's volume is 8)
    0.25
    ```
    """
    where = "voxax.energies.interpenetration"
    W_a = _grid(where, W_a, "W_a", rank=0, mean=True)
    W_b = _grid(where, W_b, "W_b", rank=0, mean=True)
    if W_a.shape != W_b.shape:
        raise ValueError(f"{where}: `W_a` and `W_b` must have the same shape, got {W_a.shape} and {W_b.shape}")
    return jnp.sum(jnp.clip(W_a, 0.0, 1.0) * jnp.clip(W_b, 0.0, 1.0)) / W_a.size

"""Plotting helpers: grid slices, silhouettes, meshes, gradients and energy histories.

Everything here draws with matplotlib and returns the `Figure` (pass `path=` to save it
as well). Winding numbers and gradients are signed, so grids use a diverging colour map
centred on 0 with a symmetric range. `mesh_plotly` gives an interactive 3D view with
plotly (an optional dependency: `pip install "voxax[plot]"`).

Outside Jupyter, the functions switch matplotlib to the non-interactive `Agg` backend
unless a backend has been chosen already, so they work on headless machines; call
`matplotlib.use(...)` first for an interactive window.

- [`slices`][voxax.plot.slices]: evenly spaced slices of a 3D grid (or a whole 2D grid).
- [`silhouettes`][voxax.plot.silhouettes]: the three mellowmax (or max) silhouettes.
- [`mesh`][voxax.plot.mesh]: a triangle mesh (or 2D polyline) coloured by a per-vertex or
  per-face quantity, e.g. the displacement from the input of an optimization.
- [`gradient_field`][voxax.plot.gradient_field]: per-vertex gradients as arrows.
- [`projections`][voxax.plot.projections]: the maximum of one or more 3D grids along x, y
  and z (e.g. before and after an optimization).
- [`history`][voxax.plot.history]: the energy history of `voxax.minimize` or an app report.
- [`mesh_plotly`][voxax.plot.mesh_plotly]: an interactive plotly rendering of a mesh.
- [`pyplot`][voxax.plot.pyplot]: `matplotlib.pyplot`, with the backend chosen as above.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from . import _validate
from ._optional import require

__all__ = ["slices", "silhouettes", "projections", "mesh", "gradient_field", "history", "mesh_plotly", "pyplot"]

_NAMES = "xyz"


def pyplot():
    """`matplotlib.pyplot`, switched to the non-interactive `Agg` backend outside IPython
    unless a backend has been chosen already.

    Every figure of voxax is drawn through it, so figures can be made on headless
    machines; close them with `pyplot().close(fig)` when making many.

    **Returns:** the `matplotlib.pyplot` module.

    **Example:**

    ```python
    >>> plt = voxax.plot.pyplot()
    >>> fig = voxax.plot.history([3.0, 2.0, 1.0])
    >>> plt.close(fig)
    ```
    """
    matplotlib = require("matplotlib", "voxax.plot")

    if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
        try:
            import IPython

            if IPython.get_ipython() is None:
                matplotlib.use("Agg")
        except ImportError:
            matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, where: str, dpi=110) -> None:
    """Saves `fig` to `path` (its format from the extension, PNG without one); an unknown
    extension or a file that cannot be written gives one line naming `where`."""
    path = _validate.file_path(where, "path", path)
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    formats = fig.canvas.get_supported_filetypes()
    if ext and ext not in formats:
        raise ValueError(f"{where}: `path` must end in one of {', '.join('.' + k for k in sorted(formats))}, got {path!r}")
    with _validate.writing(where, path):
        fig.savefig(path, dpi=dpi)


def _finish(fig, title, path, where: str, dpi=110):
    if title:
        fig.suptitle(title)
    if path is not None:
        _save(fig, path, where, dpi)
    return fig


def _symmetric_limit(values, vmax=None) -> float:
    if vmax is not None:
        return float(vmax)
    values = np.asarray(values, dtype=np.float64)
    finite = values[np.isfinite(values)]
    return max(float(np.max(np.abs(finite))) if finite.size else 0.0, 1e-12)


def _extent(grid, a0, a1):
    if grid is None:
        return None
    return (grid.lower[a0], grid.upper[a0], grid.lower[a1], grid.upper[a1])


# --------------------------------------------------------------------------------------
# Grids
# --------------------------------------------------------------------------------------


def slices(
    W,
    grid=None,
    axis: int | None = None,
    count: int = 4,
    title: str | None = None,
    path=None,
    cmap: str = "RdBu_r",
    *,
    vmax: float | None = None,
):
    """Draws `count` evenly spaced slices of a 3D grid (or the whole 2D grid).

    Winding numbers and gradients are signed, so a diverging colour map centred on 0 is
    used, with the symmetric range `[-vmax, vmax]` (by default the largest `|W|`). Each
    panel shows `W` with the first remaining axis to the right and the second up (the
    slice orthogonal to z shows x to the right and y up).

    **Arguments:**

    - `W`: `(nx, ny, nz)` or `(nx, ny)` array, e.g. the output of `voxax.voxelize`.
    - `grid`: the `voxax.Grid` of `W`, for axis extents in world units (optional).
    - `axis`: the axis the slices are orthogonal to (3D only); `None` picks the axis
      along which the non-zero part of `W` is thinnest (flat shapes show their outline).
    - `count`: how many slices to draw (3D only); they are spread over the range of
      indices along `axis` where `W` is non-zero.
    - `title`: an optional figure title.
    - `path`: if given, the figure is saved there (PNG, PDF, ... by extension).
    - `cmap`: a matplotlib colour map name.
    - `vmax`: the colour range's upper limit (default: `max |W|`).

    **Returns:**

    The matplotlib `Figure`, one image axis per slice plus a colour bar.

    **Example:**

    ```python
    >>> mesh = voxax.data.torus()
    >>> grid = voxax.Grid.cube(32)
    >>> fig = voxax.plot.slices(voxax.voxelize(mesh.vertices, mesh.faces, grid), grid, axis=2, count=3)
    >>> len(fig.axes)   # three slices and a colour bar
    4
    ```
    """
    plt = pyplot()
    W = np.asarray(W, dtype=np.float64)
    if W.ndim not in (2, 3):
        raise ValueError(f"voxax.plot.slices: expected a 2D or 3D grid, got shape {W.shape}")
    if grid is not None and tuple(grid.shape) != W.shape:
        raise ValueError(f"voxax.plot.slices: `W` has shape {W.shape} but the grid has shape {tuple(grid.shape)}")
    if axis is not None and (W.ndim != 3 or axis not in (0, 1, 2)):
        raise ValueError(f"voxax.plot.slices: `axis` must be None or 0, 1, 2 for a 3D grid, got {axis!r}")
    count = _validate.positive_int("voxax.plot.slices", "count", count, maximum=max(W.shape))
    limit = _symmetric_limit(W, vmax)
    if W.ndim == 3 and axis is None:
        extents = []
        for a in range(3):
            nz = np.nonzero(np.abs(W).max(axis=tuple(b for b in range(3) if b != a)) > 1e-12)[0]
            extents.append((nz[-1] - nz[0] + 1) / W.shape[a] if nz.size else 1.0)
        axis = int(np.argmin(extents))
    if W.ndim == 2:
        panels = [(W, "", (0, 1))]
    else:
        # Spread the slices over the occupied range along `axis` (the whole axis if empty).
        occupied = np.nonzero(np.abs(W).max(axis=tuple(a for a in range(3) if a != axis)) > 1e-12)[0]
        first, last = (occupied[0], occupied[-1]) if occupied.size else (0, W.shape[axis] - 1)
        idx = np.unique(np.linspace(first, last, int(count) + 2)[1:-1].round().astype(int))
        rest = tuple(a for a in range(3) if a != axis)
        panels = []
        for i in idx:
            label = f"{_NAMES[axis]} index {int(i)}"
            if grid is not None:
                centre = grid.lower[axis] + (int(i) + 0.5) * grid.spacing[axis]
                label += f" ({_NAMES[axis]} = {centre:.3g})"
            panels.append((np.take(W, int(i), axis=axis), label, rest))
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels) + 0.8, 3.4), squeeze=False, layout="constrained")
    im = None
    for ax, (img, label, (a0, a1)) in zip(axes[0], panels):
        im = ax.imshow(img.T, origin="lower", cmap=cmap, vmin=-limit, vmax=limit,
                       extent=_extent(grid, a0, a1), interpolation="nearest")
        ax.set_xlabel(_NAMES[a0])
        ax.set_ylabel(_NAMES[a1])
        ax.set_title(label, fontsize="medium")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85)
    return _finish(fig, title, path, "voxax.plot.slices")


def silhouettes(
    W,
    grid=None,
    *,
    method: str = "mellowmax",
    w: float = 1000.0,
    title: str | None = None,
    path=None,
    cmap: str = "RdBu_r",
    vmax: float | None = None,
):
    """Draws the three silhouettes of a 3D grid: its soft (or hard) maximum along x, y and z.

    These are the outlines that a bandsaw cutting along each axis follows (paper, Sec.
    4.3): `Sx[j, k] = mellowmax(W[:, j, k])` and likewise along y and z, computed with
    `voxax.energies.silhouettes` (`method="mellowmax"`) or with a plain maximum
    (`method="max"`). The panels show `Sx` over (y, z), `Sy` over (x, z) and `Sz` over
    (x, y), on the same symmetric diverging colour range as `slices`.

    **Arguments:**

    - `W`: `(nx, ny, nz)` array, e.g. the output of `voxax.voxelize`.
    - `grid`: the `voxax.Grid` of `W`, for axis extents in world units (optional).
    - `method`: `"mellowmax"` (the differentiable silhouettes the bandsaw energy uses) or
      `"max"`.
    - `w`: the mellowmax sharpness (1000 in the paper).
    - `title`, `path`, `cmap`: as for `slices`.
    - `vmax`: the colour range's upper limit (default: the largest `|S|`).

    **Returns:**

    The matplotlib `Figure`: three image axes (along x, y, z) and a colour bar.

    **Example:**

    ```python
    >>> mesh = voxax.data.hand()
    >>> grid = voxax.Grid.cube(32)
    >>> fig = voxax.plot.silhouettes(voxax.voxelize(mesh.vertices, mesh.faces, grid), grid)
    >>> [ax.get_title() for ax in fig.axes[:3]]
    ['along x', 'along y', 'along z']
    ```
    """
    plt = pyplot()
    W = np.asarray(W)
    if W.ndim != 3:
        raise ValueError(f"voxax.plot.silhouettes: expected a 3D grid (nx, ny, nz), got shape {W.shape}")
    if grid is not None and tuple(grid.shape) != W.shape:
        raise ValueError(f"voxax.plot.silhouettes: `W` has shape {W.shape} but the grid has shape {tuple(grid.shape)}")
    if method == "mellowmax":
        from .energies import silhouettes as _soft

        if not np.issubdtype(W.dtype, np.floating):
            W = W.astype(np.float64)
        sil = [np.asarray(s, dtype=np.float64) for s in _soft(W, w)]
    elif method == "max":
        W = np.asarray(W, dtype=np.float64)
        sil = [W.max(axis=a) for a in range(3)]
    else:
        raise ValueError(f"voxax.plot.silhouettes: `method` must be 'mellowmax' or 'max', got {method!r}")
    limit = _symmetric_limit(np.concatenate([s.ravel() for s in sil]), vmax)
    fig, axes = plt.subplots(1, 3, figsize=(10.4, 3.4), squeeze=False, layout="constrained")
    im = None
    for a, (ax, S) in enumerate(zip(axes[0], sil)):
        a0, a1 = (b for b in range(3) if b != a)
        im = ax.imshow(S.T, origin="lower", cmap=cmap, vmin=-limit, vmax=limit,
                       extent=_extent(grid, a0, a1), interpolation="nearest")
        ax.set_xlabel(_NAMES[a0])
        ax.set_ylabel(_NAMES[a1])
        ax.set_title(f"along {_NAMES[a]}", fontsize="medium")
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85)
    return _finish(fig, title, path, "voxax.plot.silhouettes")


def projections(
    grids,
    grid=None,
    *,
    labels=None,
    title: str | None = None,
    path=None,
    cmap: str = "magma",
    vmax: float | None = None,
):
    """Draws the maximum of one or more 3D grids along x, y and z: one row per grid.

    Made to compare grids, e.g. the winding numbers before and after removing
    self-intersections: every panel shares one colour range `[0, vmax]`, by default the
    largest value of all grids but at least 1, so values above 1 (overlaps) stand out.

    **Arguments:**

    - `grids`: one `(nx, ny, nz)` array, or a sequence of them (all the same shape).
    - `grid`: the `voxax.Grid` of the arrays, for axis extents in world units (optional).
    - `labels`: one name per array for the panel titles (default `"0"`, `"1"`, ...).
    - `title`, `path`, `cmap`: as for `slices`.
    - `vmax`: the colour range's upper limit.

    **Returns:**

    The matplotlib `Figure`: three image axes per grid (max along x, y, z, titled with the
    label and the largest value) and a colour bar.

    **Example:**

    ```python
    >>> m, grid = voxax.data.overlapping_cubes(), voxax.Grid.cube(16)
    >>> W = voxax.voxelize(m.vertices, m.faces, grid)
    >>> fig = voxax.plot.projections([W, W.clip(0, 1)], grid, labels=["before", "after"])
    >>> fig.axes[3].get_title()
    'after: max of W along x (1.000)'
    ```
    """
    plt = pyplot()
    if isinstance(grids, (list, tuple)):
        Ws = [np.asarray(W, dtype=np.float64) for W in grids]
    else:
        Ws = [np.asarray(grids, dtype=np.float64)]
    if not Ws or any(W.ndim != 3 for W in Ws):
        raise ValueError(f"voxax.plot.projections: expected 3D grids (nx, ny, nz), got shapes {[W.shape for W in Ws]}")
    if len({W.shape for W in Ws}) != 1:
        raise ValueError(f"voxax.plot.projections: the grids differ in shape: {[W.shape for W in Ws]}")
    if grid is not None and tuple(grid.shape) != Ws[0].shape:
        raise ValueError(f"voxax.plot.projections: `W` has shape {Ws[0].shape} but the grid has shape {tuple(grid.shape)}")
    labels = [str(i) for i in range(len(Ws))] if labels is None else [str(x) for x in labels]
    if len(labels) != len(Ws):
        raise ValueError(f"voxax.plot.projections: {len(labels)} labels for {len(Ws)} grids")
    top = float(vmax) if vmax is not None else max(max(float(np.nanmax(W)), 1.0) for W in Ws)
    fig, axes = plt.subplots(len(Ws), 3, figsize=(10.5, 3.3 * len(Ws)), squeeze=False, layout="constrained")
    im = None
    for r, (W, label) in enumerate(zip(Ws, labels)):
        for a in range(3):
            a0, a1 = (b for b in range(3) if b != a)
            ax = axes[r, a]
            im = ax.imshow(W.max(axis=a).T, origin="lower", cmap=cmap, vmin=0.0, vmax=top,
                           extent=_extent(grid, a0, a1), interpolation="nearest")
            ax.set_title(f"{label}: max of W along {_NAMES[a]} ({W.max():.3f})", fontsize=9)
            ax.set_xlabel(_NAMES[a0])
            ax.set_ylabel(_NAMES[a1])
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8)
    return _finish(fig, title, path, "voxax.plot.projections", dpi=100)


# --------------------------------------------------------------------------------------
# Meshes
# --------------------------------------------------------------------------------------


def _mesh_arrays(vertices, faces, where):
    v, f = _validate.mesh(where, vertices, faces, integer_vertices=True)
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def _face_values(values, n_vertices: int, faces: np.ndarray, where: str = "voxax.plot.mesh"):
    """Per-face values from per-vertex `(V,)`/`(V, d)` or per-face `(F,)`/`(F, d)` values."""
    q = np.asarray(values, dtype=np.float64)
    if q.ndim == 2:  # vectors (e.g. displacements): their lengths
        q = np.linalg.norm(q, axis=1)
    if q.ndim != 1 or q.shape[0] not in (n_vertices, len(faces)):
        raise ValueError(
            f"{where}: `values` must have shape (V,) = ({n_vertices},) per vertex or (F,) = ({len(faces)},) "
            f"per face (or (V, d) / (F, d) vectors, coloured by their length), got {np.shape(values)}"
        )
    if q.shape[0] == n_vertices:
        return q[faces].mean(axis=1), q
    return q, q


def _new_axes(plt, dim: int, ax):
    if ax is not None:
        return ax.figure, ax
    if dim == 3:
        fig = plt.figure(figsize=(5.6, 5.0), layout="constrained")
        return fig, fig.add_subplot(projection="3d")
    fig, ax = plt.subplots(figsize=(5.2, 4.6), layout="constrained")
    return fig, ax


def _equal_3d(ax, v):
    lo, hi = v.min(axis=0), v.max(axis=0)
    centre, half = 0.5 * (lo + hi), 0.5 * max(float(np.max(hi - lo)), 1e-12)
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_zlabel("z")


def _equal_2d(ax, points=None):
    """Equal axes labelled x, y; limits fitted to `points` (with a margin) when given."""
    if points is not None:
        lo, hi = points.min(axis=0), points.max(axis=0)
        pad = 0.05 * max(float(np.max(hi - lo)), 1e-12)
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")


def _shading(tri: np.ndarray, light=(0.4, -0.6, 0.7)) -> np.ndarray:
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    n = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    light = np.asarray(light, dtype=np.float64)
    return 0.45 + 0.55 * np.abs(n @ (light / np.linalg.norm(light)))


def mesh(
    vertices,
    faces=None,
    values=None,
    *,
    ax=None,
    cmap: str = "viridis",
    vmin: float | None = None,
    vmax: float | None = None,
    color="#8fb3d9",
    shade: bool = True,
    edgecolor=None,
    elev: float = 20.0,
    azim: float = -60.0,
    colorbar: bool = True,
    label: str | None = None,
    title: str | None = None,
    path=None,
):
    """Draws a triangle mesh in 3D (matplotlib `Poly3DCollection`), or a 2D polyline.

    Faces are coloured by `values` through `cmap` when given (a per-vertex quantity is
    averaged over each face's corners; vectors, such as the displacement of every vertex
    from the input of an optimization, are coloured by their length), otherwise in the
    single colour `color`. With `shade=True` the colours are darkened by a fixed light
    for a sense of depth. The 3D axes have equal scales on x, y and z. matplotlib sorts
    faces by depth, not per pixel, so intersecting or interleaved parts may be drawn in
    the wrong order: for an exact, interactive view use `mesh_plotly`.

    **Arguments:**

    - `vertices`: `(V, 3)` (or `(V, 2)`) float, e.g. `mesh.vertices`.
    - `faces`: `(F, 3)` int triangles (or `(F, 2)` segments).
    - `values`: optional `(V,)` per-vertex or `(F,)` per-face values, or `(V, d)` /
      `(F, d)` vectors (coloured by their length). When `V == F`, values are per vertex.
    - `ax`: an existing axes to draw into (3D axes for a 3D mesh); default: a new figure.
    - `cmap`, `vmin`, `vmax`: the colour map and its range (default: the values' range).
    - `color`: the face colour when `values` is None.
    - `shade`: darken faces that face away from a fixed light (3D only).
    - `edgecolor`: colour of the triangle edges (default: none drawn).
    - `elev`, `azim`: the 3D view angles in degrees.
    - `colorbar`: add a colour bar when `values` is given.
    - `label`: the colour bar's label.
    - `title`, `path`: an optional axes title; save the figure there if given.

    **Returns:**

    The matplotlib `Figure` (`fig.axes[0]` is the mesh's axes; its `collections[0]`
    holds one polygon per face).

    **Example:**

    ```python
    >>> m = voxax.data.icosphere(2)
    >>> moved = m.vertices * 1.1
    >>> fig = voxax.plot.mesh(moved, m.faces, values=moved - m.vertices, label="displacement")
    >>> len(fig.axes[0].collections[0].get_facecolor()) == m.n_faces
    True
    ```
    """
    import matplotlib.colors as mcolors

    plt = pyplot()
    vertices, faces, (values,) = _validate.unpack_mesh("voxax.plot.mesh", vertices, faces, values)
    v, f = _mesh_arrays(vertices, faces, "voxax.plot.mesh")
    dim = v.shape[1]
    fig, ax = _new_axes(plt, dim, ax)
    face_q = None
    if values is not None:
        face_q, raw = _face_values(values, len(v), f)
        finite = raw[np.isfinite(raw)]
        lo = float(finite.min()) if vmin is None and finite.size else (0.0 if vmin is None else float(vmin))
        hi = float(finite.max()) if vmax is None and finite.size else (1.0 if vmax is None else float(vmax))
        if hi - lo <= 1e-9 * max(abs(lo), abs(hi), 1e-300):  # (nearly) constant values
            mid, pad = 0.5 * (lo + hi), 5e-4 * max(abs(lo), abs(hi), 1.0)
            lo, hi = mid - pad, mid + pad
        norm = mcolors.Normalize(lo, hi)
        cm = plt.get_cmap(cmap)
        rgba = cm(norm(face_q))
    else:
        rgba = np.tile(mcolors.to_rgba(color), (len(f), 1))
    segments = v[f]
    if dim == 3:
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        if shade:
            rgba = rgba.copy()
            rgba[:, :3] *= _shading(segments)[:, None]
        coll = Poly3DCollection(segments, facecolors=rgba, edgecolors=edgecolor if edgecolor is not None else "none",
                                linewidths=0.2 if edgecolor is not None else 0.0)
        ax.add_collection3d(coll)
        _equal_3d(ax, v)
        ax.view_init(elev=elev, azim=azim)
    else:
        from matplotlib.collections import LineCollection

        coll = LineCollection(segments, colors=rgba, linewidths=2.0)
        ax.add_collection(coll)
        _equal_2d(ax, v)
    if values is not None and colorbar:
        sm = plt.cm.ScalarMappable(norm=norm, cmap=cmap)
        sm.set_array(face_q)
        cb = fig.colorbar(sm, ax=ax, shrink=0.7)
        if label:
            cb.set_label(label)
    if title:
        ax.set_title(title)
    if path is not None:
        _save(fig, path, "voxax.plot.mesh")
    return fig


def gradient_field(
    vertices,
    faces=None,
    gradient=None,
    W=None,
    grid=None,
    *,
    ax=None,
    scale: float | None = None,
    normalize: bool = False,
    color="#c0392b",
    title: str | None = None,
    path=None,
):
    """Draws per-vertex gradients (or any per-vertex vectors) as arrows on a mesh.

    In 2D, the polyline is drawn over the grid `W` (optional, diverging colours as in
    `slices`) with one arrow per vertex; in 3D, the mesh (as in `mesh`) with 3D arrows.
    Arrows point along `gradient`; for `dE/dv` the energy grows in that direction, so a
    descent step moves each vertex against its arrow.

    **Arguments:**

    - `vertices`: `(V, d)` float, `d` = 2 or 3; `faces`: `(F, d)` int.
    - `gradient`: `(V, d)` float, e.g. `jax.grad(energy)(vertices)`.
    - `W`: optional `(nx, ny)` grid drawn underneath (2D only); `grid`: its `voxax.Grid`.
    - `ax`: an existing axes to draw into; default: a new figure.
    - `scale`: arrow length per unit of gradient; default: the longest arrow is 15% of
      the mesh's bounding box.
    - `normalize`: draw unit-length arrows (times `scale`), showing directions only.
    - `color`: the arrows' colour.
    - `title`, `path`: an optional axes title; save the figure there if given.

    **Returns:**

    The matplotlib `Figure`.

    **Example:**

    ```python
    >>> c = voxax.data.circle_polyline(32, 0.5)
    >>> grid = voxax.Grid.cube(24, dim=2)
    >>> energy = lambda v: (voxax.voxelize(v, c.faces, grid) ** 2).sum()
    >>> g = jax.grad(energy)(jax.numpy.asarray(c.vertices))
    >>> fig = voxax.plot.gradient_field(c.vertices, c.faces, g, voxax.voxelize(c.vertices, c.faces, grid), grid)
    ```
    """
    plt = pyplot()
    vertices, faces, (gradient, W, grid) = _validate.unpack_mesh(
        "voxax.plot.gradient_field", vertices, faces, gradient, W, grid
    )
    if gradient is None:
        raise TypeError("voxax.plot.gradient_field: missing `gradient` (V, d)")
    v, f = _mesh_arrays(vertices, faces, "voxax.plot.gradient_field")
    g = np.asarray(gradient, dtype=np.float64)
    if g.shape != v.shape:
        raise ValueError(f"voxax.plot.gradient_field: `gradient` must have the vertices' shape {v.shape}, got {g.shape}")
    dim = v.shape[1]
    lengths = np.linalg.norm(g, axis=1)
    if normalize:
        g = np.divide(g, lengths[:, None], out=np.zeros_like(g), where=lengths[:, None] > 0)
        lengths = (lengths > 0).astype(np.float64)
    if scale is None:
        size = max(float(np.max(v.max(axis=0) - v.min(axis=0))), 1e-12)
        scale = 0.15 * size / max(float(lengths.max()) if lengths.size else 0.0, 1e-300)
    d = g * float(scale)
    if dim == 3:
        fig = mesh(v, f, ax=ax, color="#d9d9d9")
        ax = fig.axes[0] if ax is None else ax
        ax.quiver(v[:, 0], v[:, 1], v[:, 2], d[:, 0], d[:, 1], d[:, 2], color=color, linewidth=0.8,
                  arrow_length_ratio=0.25)
        _equal_3d(ax, np.concatenate([v, v + d]))
    else:
        fig, ax = _new_axes(plt, 2, ax)
        if W is not None:
            Wn = np.asarray(W, dtype=np.float64)
            if Wn.ndim != 2:
                raise ValueError(f"voxax.plot.gradient_field: `W` must be a 2D grid, got shape {Wn.shape}")
            limit = _symmetric_limit(Wn)
            im = ax.imshow(Wn.T, origin="lower", cmap="RdBu_r", vmin=-limit, vmax=limit,
                           extent=_extent(grid, 0, 1), interpolation="nearest")
            fig.colorbar(im, ax=ax, shrink=0.8)
        from matplotlib.collections import LineCollection

        ax.add_collection(LineCollection(v[f], colors="k", linewidths=1.2))
        ax.quiver(v[:, 0], v[:, 1], d[:, 0], d[:, 1], color=color, angles="xy", scale_units="xy", scale=1.0,
                  width=0.004)
        _equal_2d(ax, np.concatenate([v, v + d]) if W is None or grid is None else None)
    if title:
        ax.set_title(title)
    if path is not None:
        _save(fig, path, "voxax.plot.gradient_field")
    return fig


# --------------------------------------------------------------------------------------
# Histories
# --------------------------------------------------------------------------------------


def _history_series(source) -> dict[str, np.ndarray]:
    if isinstance(source, Mapping):
        series = dict(source)
    elif hasattr(source, "history") and isinstance(source.history, Mapping):
        series = dict(source.history)  # MinimizeResult, app reports
        if "energy" not in series and getattr(source, "energy_history", None) is not None:
            series = {"energy": source.energy_history, **series}
    elif hasattr(source, "energy_history"):
        series = {"energy": source.energy_history}
    else:
        what = "a MinimizeResult, an app report, a dict of 1D arrays or a 1D array of energies"
        try:
            arr = _validate.typed_array("voxax.plot.history", "result_or_history", source, "fiub", what)
        except TypeError:
            raise TypeError(f"voxax.plot.history: expected {what}, got {type(source).__name__}") from None
        if np.ndim(arr) != 1:
            raise TypeError(f"voxax.plot.history: expected {what}, got {type(source).__name__} of shape {np.shape(arr)}")
        series = {"energy": arr}
    out = {}
    for k, v in series.items():
        arr = np.asarray(_validate.typed_array("voxax.plot.history", f"series {str(k)!r}", v, "fiub", "a real 1D array"))
        if arr.ndim > 1:
            raise ValueError(f"voxax.plot.history: series {str(k)!r} must be 1D, got shape {arr.shape}")
        arr = arr.astype(np.float64).reshape(-1)
        if arr.size:
            out[str(k)] = arr
    return out


def history(
    result_or_history,
    keys=None,
    *,
    x: str = "step",
    log: bool | str = "auto",
    title: str | None = None,
    path=None,
):
    """Plots an optimization's recorded series (energy, energy terms, `max_w`, step size).

    One panel per series, sharing the x axis. With `log="auto"`, a panel gets a log scale
    when its values are positive and span more than two decades.

    **Arguments:**

    - `result_or_history`: a `voxax.MinimizeResult` (its `history`), an application's
      report (`voxax.apps`: its `history`), a dict of 1D arrays, or a 1D array of
      energies.
    - `keys`: the series to plot, in order (default: all except `"time"`, energy first).
    - `x`: `"step"` (1, 2, ...) or `"time"` (seconds, from the history's `"time"`).
    - `log`: `True`, `False` or `"auto"`.
    - `title`, `path`: an optional figure title; save the figure there if given.

    **Returns:**

    The matplotlib `Figure`, one axes per series (titled with the series' name).

    **Example:**

    ```python
    >>> quad = lambda y, args: jax.numpy.sum((y - 1.0) ** 2)
    >>> r = voxax.minimize(quad, jax.numpy.zeros(3), learning_rate=0.1, progress=False,
    ...                    stop=voxax.StopRules(max_steps=50))
    >>> fig = voxax.plot.history(r)
    >>> [ax.get_ylabel() for ax in fig.axes]
    ['energy', 'step_size']
    ```
    """
    plt = pyplot()
    series = _history_series(result_or_history)
    if x not in ("step", "time"):
        raise ValueError(f"voxax.plot.history: `x` must be 'step' or 'time', got {x!r}")
    times = series.get("time")
    if x == "time" and times is None:
        raise ValueError("voxax.plot.history: x='time' needs a 'time' series in the history")
    if keys is None:
        keys = [k for k in series if k != "time"]
        if "energy" in keys:
            keys.remove("energy")
            keys.insert(0, "energy")
    else:
        keys = [keys] if isinstance(keys, str) else list(keys)
        missing = [k for k in keys if k not in series]
        if missing:
            raise KeyError(f"voxax.plot.history: no series {missing}; recorded: {sorted(series)}")
    if not keys:
        raise ValueError("voxax.plot.history: nothing to plot (the history is empty)")
    n = len(keys)
    fig, axes = plt.subplots(n, 1, figsize=(6.4, 1.7 * n + 0.7), sharex=True, squeeze=False, layout="constrained")
    for ax, name in zip(axes[:, 0], keys):
        values = series[name]
        xs = times[: values.size] if x == "time" else np.arange(1, values.size + 1)
        ax.plot(xs, values, lw=1.3)
        finite = values[np.isfinite(values)]
        use_log = log is True or (
            log == "auto" and finite.size > 0 and finite.min() > 0 and finite.max() / finite.min() > 100
        )
        if use_log and finite.size and finite.min() > 0:
            ax.set_yscale("log")
            if log == "auto":  # at most 8 decades: a starting value of ~0 would squash the rest
                ax.set_ylim(bottom=max(finite.min(), finite.max() * 1e-8) * 0.8)
        ax.set_ylabel(name, fontsize="small")
        ax.grid(alpha=0.3)
    axes[-1, 0].set_xlabel("step" if x == "step" else "time (s)")
    return _finish(fig, title, path, "voxax.plot.history")


# --------------------------------------------------------------------------------------
# Interactive
# --------------------------------------------------------------------------------------


def mesh_plotly(
    vertices,
    faces=None,
    values=None,
    *,
    colorscale: str = "Viridis",
    color: str = "#8fb3d9",
    label: str | None = None,
    title: str | None = None,
    path=None,
):
    """An interactive 3D view of a triangle mesh with plotly (`Mesh3d`).

    Needs plotly (`pip install "voxax[plot]"`, or `pip install plotly`). Per-vertex values
    are interpolated across faces; per-face values colour whole faces. In Jupyter or Colab
    the returned figure displays itself; `fig.show()` opens it elsewhere.

    **Arguments:**

    - `vertices`: `(V, 3)` float; `faces`: `(F, 3)` int.
    - `values`: optional `(V,)` or `(F,)` values, or `(V, 3)` / `(F, 3)` vectors (coloured
      by their length). When `V == F`, values are per vertex.
    - `colorscale`: a plotly colour scale name; `color`: the colour without `values`.
    - `label`: the colour bar's title.
    - `title`: the figure title.
    - `path`: if given, the figure is written there as a standalone HTML file (plotly.js
      is embedded, so the file works offline).

    **Returns:**

    A `plotly.graph_objects.Figure` with one `Mesh3d` trace.

    **Raises:**

    `ImportError` with install instructions when plotly is missing.

    **Example:**

    ```python
    >>> m = voxax.data.torus()
    >>> fig = voxax.plot.mesh_plotly(m.vertices, m.faces, values=m.vertices[:, 2])  # doctest: +SKIP
    ```
    """
    try:
        import plotly.graph_objects as go
    except ImportError as err:
        raise ImportError(
            "voxax.plot.mesh_plotly needs plotly, an optional dependency: install it with "
            "`pip install \"voxax[plot]\"` (or `pip install plotly`), or use voxax.plot.mesh for "
            "a matplotlib rendering"
        ) from err
    vertices, faces, (values,) = _validate.unpack_mesh("voxax.plot.mesh_plotly", vertices, faces, values)
    v, f = _mesh_arrays(vertices, faces, "voxax.plot.mesh_plotly")
    if v.shape[1] != 3:
        raise ValueError("voxax.plot.mesh_plotly: needs a 3D triangle mesh; use voxax.plot.mesh for 2D polylines")
    kwargs = {}
    if values is not None:
        face_q, raw = _face_values(values, len(v), f, "voxax.plot.mesh_plotly")
        if raw.shape[0] == len(v):
            kwargs.update(intensity=raw, intensitymode="vertex")
        else:
            kwargs.update(intensity=face_q, intensitymode="cell")
        kwargs.update(colorscale=colorscale, showscale=True, colorbar={"title": {"text": label or ""}})
    else:
        kwargs.update(color=color)
    trace = go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
                      flatshading=True, **kwargs)
    fig = go.Figure(trace)
    fig.update_layout(scene={"aspectmode": "data", "xaxis_title": "x", "yaxis_title": "y", "zaxis_title": "z"},
                      margin={"l": 0, "r": 0, "t": 40 if title else 0, "b": 0}, title=title)
    if path is not None:
        path = _validate.file_path("voxax.plot.mesh_plotly", "path", path)
        with _validate.writing("voxax.plot.mesh_plotly", path):
            fig.write_html(path, include_plotlyjs=True)
    return fig

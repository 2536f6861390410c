"""Plotting helpers (matplotlib): grid slices of winding numbers and gradients."""

from __future__ import annotations

import numpy as np

__all__ = ["slices"]


def slices(W, grid=None, axis: int | None = None, count: int = 4, title: str | None = None, path=None, cmap: str = "RdBu_r"):
    """Draws `count` evenly spaced slices of a 3D grid (or the whole 2D grid).

    Winding numbers and gradients are signed, so a diverging colour map centred on 0 is
    used, with a symmetric range.

    **Arguments:**

    - `W`: `(nx, ny, nz)` or `(nx, ny)` array, e.g. the output of `voxax.voxelize`.
    - `grid`: the `voxax.Grid` of `W`, for axis extents in world units (optional).
    - `axis`: the axis the slices are orthogonal to (3D only); `None` picks the axis
      along which the non-zero part of `W` is thinnest (flat shapes show their outline).
    - `count`: how many slices to draw (3D only).
    - `title`: an optional figure title.
    - `path`: if given, the figure is saved there (PNG, PDF, ... by extension).
    - `cmap`: a matplotlib colour map name.

    **Returns:**

    The matplotlib `Figure`.

    **Example:**

    ```python
    >>> mesh = voxax.data.torus()
    >>> grid = voxax.Grid.cube(32)
    >>> fig = voxax.plot.slices(voxax.voxelize(mesh.vertices, mesh.faces, grid), grid)
    ```
    """
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "module://matplotlib_inline.backend_inline"):
        try:
            import IPython  # noqa: F401

            if IPython.get_ipython() is None:
                matplotlib.use("Agg")
        except ImportError:
            matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    W = np.asarray(W, dtype=np.float64)
    if W.ndim not in (2, 3):
        raise ValueError(f"slices: expected a 2D or 3D grid, got shape {W.shape}")
    vmax = max(float(np.max(np.abs(W))), 1e-12)
    if W.ndim == 3 and axis is None:
        extents = []
        for a in range(3):
            nz = np.nonzero(np.abs(W).max(axis=tuple(b for b in range(3) if b != a)) > 1e-12)[0]
            extents.append((nz[-1] - nz[0] + 1) / W.shape[a] if nz.size else 1.0)
        axis = int(np.argmin(extents))
    names = "xyz"
    if W.ndim == 2:
        panels = [(W, "", (0, 1))]
    else:
        # Spread the slices over the occupied range along `axis` (the whole axis if empty).
        occupied = np.nonzero(np.abs(W).max(axis=tuple(a for a in range(3) if a != axis)) > 1e-12)[0]
        first, last = (occupied[0], occupied[-1]) if occupied.size else (0, W.shape[axis] - 1)
        idx = np.unique(np.linspace(first, last, count + 2)[1:-1].round().astype(int))
        rest = tuple(a for a in range(3) if a != axis)
        panels = [(np.take(W, int(i), axis=axis), f"{names[axis]} index {int(i)}", rest) for i in idx]
    fig, axes = plt.subplots(1, len(panels), figsize=(3.2 * len(panels) + 0.8, 3.4), squeeze=False, layout="constrained")
    im = None
    for ax, (img, label, (a0, a1)) in zip(axes[0], panels):
        extent = None
        if grid is not None:
            extent = (grid.lower[a0], grid.upper[a0], grid.lower[a1], grid.upper[a1])
        im = ax.imshow(img.T, origin="lower", cmap=cmap, vmin=-vmax, vmax=vmax, extent=extent, interpolation="nearest")
        ax.set_xlabel(names[a0])
        ax.set_ylabel(names[a1])
        ax.set_title(label)
    fig.colorbar(im, ax=axes[0].tolist(), shrink=0.85)
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=110)
    return fig

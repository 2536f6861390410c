"""Draws the figures of the docs' "Conventions" page (committed as PNG next to this file).

    python docs/figures/make_figures.py        # needs voxax importable (installed, or PYTHONPATH=src)
"""

from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")

import jax  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

jax.config.update("jax_enable_x64", True)

import voxax  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def _grid_lines(ax, grid, **kw):
    for x in grid.edges(0):
        ax.plot([x, x], [grid.lower[1], grid.upper[1]], **kw)
    for y in grid.edges(1):
        ax.plot([grid.lower[0], grid.upper[0]], [y, y], **kw)


def grid_layout(path):
    """Cell indices and centres of a 2D grid, and W[i, j] drawn as W.T with origin='lower'."""
    grid = voxax.Grid(lower=(-1.0, -0.6), upper=(1.0, 0.6), shape=(5, 3))
    tri = voxax.data.Mesh(np.array([[-0.85, -0.45], [0.7, -0.3], [-0.2, 0.5]]), np.array([[0, 1], [1, 2], [2, 0]]))
    W = np.asarray(voxax.voxelize(tri.vertices, tri.faces, grid))
    centres = grid.centers()

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.9), layout="constrained")
    ax = axes[0]
    _grid_lines(ax, grid, color="0.6", lw=1)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            cx, cy = centres[i, j]
            ax.plot(cx, cy, "o", color="C0", ms=3)
            ax.text(cx, cy + 0.07, f"({i}, {j})", ha="center", va="bottom", fontsize=9)
    ax.plot(*grid.lower, "ks", ms=6)
    ax.annotate("grid.lower", grid.lower, xytext=(-0.7, -0.88), fontsize=9, arrowprops={"arrowstyle": "->"})
    ax.plot(*grid.upper, "ks", ms=6)
    ax.annotate("grid.upper", grid.upper, xytext=(0.55, 0.78), fontsize=9, arrowprops={"arrowstyle": "->"})
    hx, hy = grid.spacing
    ax.annotate("", (grid.lower[0] + hx, 0.66), (grid.lower[0], 0.66), arrowprops={"arrowstyle": "<->"})
    ax.text(grid.lower[0] + hx / 2, 0.7, "spacing[0]", ha="center", va="bottom", fontsize=9)
    ax.annotate("", (-1.06, grid.lower[1] + hy), (-1.06, grid.lower[1]), arrowprops={"arrowstyle": "<->"})
    ax.text(-1.09, grid.lower[1] + hy / 2, "spacing[1]", ha="right", va="center", fontsize=9, rotation=90)
    ax.set(xlim=(-1.25, 1.15), ylim=(-1.0, 0.95), aspect="equal", xlabel="x (index i)", ylabel="y (index j)",
           title="Grid(lower=(-1, -0.6), upper=(1, 0.6), shape=(5, 3)):\ncell (i, j) and its centre grid.centers()[i, j]")

    ax = axes[1]
    im = ax.imshow(W.T, origin="lower", extent=(grid.lower[0], grid.upper[0], grid.lower[1], grid.upper[1]),
                   cmap="RdBu_r", vmin=-1, vmax=1)
    _grid_lines(ax, grid, color="0.6", lw=0.8)
    closed = np.vstack([tri.vertices, tri.vertices[:1]])
    ax.plot(closed[:, 0], closed[:, 1], "k-", lw=1.5)
    for i in range(grid.shape[0]):
        for j in range(grid.shape[1]):
            cx, cy = centres[i, j]
            ax.text(cx, cy, f"{W[i, j]:.3f}", ha="center", va="center", fontsize=9,
                    color="white" if W[i, j] > 0.6 else "black")
    fig.colorbar(im, ax=ax, shrink=0.8)
    ax.set(xlabel="x", ylabel="y", aspect="equal",
           title="W = voxelize(triangle, grid): W[i, j] = fraction of cell (i, j) inside;\n"
           "drawn with imshow(W.T, origin='lower', extent=...)")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def orientation(path):
    """Counter-clockwise loops count +1, clockwise ones -1, overlaps add up."""
    grid = voxax.Grid.cube(64, dim=2)
    a = voxax.data.polygon_square((-0.85, -0.2), (-0.05, 0.6))
    b = voxax.data.polygon_square((-0.45, -0.6), (0.25, 0.2))
    c = voxax.data.circle_polyline(48, 0.3, center=(0.55, -0.35)).flipped()  # clockwise: inverted
    mesh = voxax.data.Mesh.concatenate(a, b, c)
    W = np.asarray(voxax.voxelize(mesh.vertices, mesh.faces, grid))

    fig, ax = plt.subplots(figsize=(6.2, 5.0), layout="constrained")
    im = ax.imshow(W.T, origin="lower", extent=(-1, 1, -1, 1), cmap="RdBu_r", vmin=-2, vmax=2)
    fig.colorbar(im, ax=ax, shrink=0.85, label="W (box-filtered winding number)")
    for part in (a, b, c):
        v, f = part.vertices, part.faces
        for s, e in f[:: max(1, len(f) // 8)]:
            p, q = v[s], v[e]
            mid, d = 0.5 * (p + q), q - p
            ax.annotate("", mid + 0.12 * d, mid - 0.12 * d, arrowprops={"arrowstyle": "->", "color": "k", "lw": 1.2})
            n = np.array([d[1], -d[0]]) / np.linalg.norm(d)  # outward normal of a CCW loop
            ax.annotate("", mid + 0.12 * n, mid, arrowprops={"arrowstyle": "->", "color": "C2", "lw": 1.0})
        for s, e in f:
            ax.plot(*np.stack([v[s], v[e]]).T, "k-", lw=0.8)
    ax.text(-0.8, 0.45, "1", fontsize=14, color="white")
    ax.text(-0.3, -0.05, "2", fontsize=14, color="white")
    ax.text(0.5, -0.4, "-1", fontsize=14, color="white")
    ax.set(xlabel="x", ylabel="y", title="counter-clockwise loops (outward normals, green) count +1,\n"
           "clockwise (inverted) ones -1, overlaps add up")
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main():
    grid_layout(os.path.join(HERE, "grid_layout.png"))
    orientation(os.path.join(HERE, "orientation.png"))
    print("wrote", os.path.join(HERE, "grid_layout.png"), "and orientation.png")


if __name__ == "__main__":
    main()

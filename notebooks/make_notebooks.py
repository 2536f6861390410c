"""Writes the notebooks in this folder (the source of truth: edit here, then run it).

    python notebooks/make_notebooks.py

Every notebook starts with a Colab-style set-up cell (installs voxax from the source tree
when it is not importable), then a cell of imports, then ONE cell tagged `parameters`
that holds every size knob (papermill's convention: `tests/test_notebooks.py` runs each
notebook with smaller values injected right after it). Outputs are never stored.
"""

from __future__ import annotations

import os
import sys

import nbformat

HERE = os.path.dirname(os.path.abspath(__file__))

SETUP = '''\
# Colab-style set-up: install voxax if it is not importable yet. Run from a clone of the
# voxax repository (pyproject.toml in this folder or the one above), this installs it from
# the source tree with pip (building the C++ kernels needs a C++17 compiler). Nothing is
# downloaded besides pip packages.
import importlib.util
import os
import subprocess
import sys
{extra}
if importlib.util.find_spec("voxax") is None:
    source = next((d for d in (".", "..") if os.path.exists(os.path.join(d, "pyproject.toml"))), None)
    if source is None:
        raise RuntimeError(
            "voxax is not installed and no voxax source tree was found here or one folder up: open this "
            "notebook from the notebooks/ folder of a clone of voxax, or `pip install /path/to/voxax` first"
        )
    subprocess.check_call([sys.executable, "-m", "pip", "install", "-q", os.path.abspath(source)])
    importlib.invalidate_caches()

%matplotlib inline'''

IMPORTS = '''\
import time

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

import voxax

jax.config.update("jax_enable_x64", True)  # float64: the exact checks below hold to ~1e-12
print("voxax", voxax.__version__, "| jax", jax.__version__, "|", jax.devices())'''


def md(text: str):
    return nbformat.v4.new_markdown_cell(text.strip("\n"))


def code(text: str, tags=None):
    cell = nbformat.v4.new_code_cell(text.strip("\n"))
    if tags:
        cell.metadata["tags"] = list(tags)
    return cell


def params(text: str):
    return code(text, tags=["parameters"])


def notebook(cells, setup_extra: str = ""):
    nb = nbformat.v4.new_notebook()
    nb.metadata = {
        "kernelspec": {"name": "python3", "display_name": "Python 3", "language": "python"},
        "language_info": {"name": "python"},
        "colab": {"provenance": []},
    }
    nb.cells = [cells[0], code(SETUP.format(extra=setup_extra)), code(IMPORTS), *cells[1:]]
    return nb


# ---------------------------------------------------------------------------------------
# 01 quickstart
# ---------------------------------------------------------------------------------------

QUICKSTART = [
    md(r"""
# voxax quickstart: voxelize a mesh, look at it, check the volume

voxax turns a closed triangle mesh into a grid of **box-filtered winding numbers**: every
voxel holds the average of the winding number over the voxel, i.e. the exact fraction of
the voxel inside the shape (1 inside, 0 outside, in between on the boundary, 2 where two
parts overlap). Because the box filter integrates the winding number exactly,

$$\sum_{ijk} W_{ijk}\,|\text{voxel}| = \text{volume enclosed by the mesh}$$

at *every* resolution, not only in the limit. This notebook voxelizes a demo mesh, plots
it, and checks that identity.
"""),
    params("""
# Parameters (the test suite runs this notebook with smaller values).
RESOLUTION = 64   # cells per axis of the [-1, 1]^3 grid
MESH = "hand"     # a built-in demo mesh: see voxax.data.names(3)
"""),
    md("""
## A mesh

`voxax.data` generates demo meshes procedurally (no downloads). Meshes follow trimesh's
convention: `vertices` float `(V, 3)`, `faces` int `(F, 3)`, counter-clockwise seen from
outside.
"""),
    code("""
print("built-in meshes:", ", ".join(voxax.data.names(3)))
mesh = voxax.data.get(MESH)
print(mesh, "| closed:", voxax.io.is_watertight(mesh.vertices, mesh.faces))
print("bounds:", mesh.bounds.round(3).tolist())
fig = voxax.plot.mesh(mesh.vertices, mesh.faces, title=f"'{MESH}'")
"""),
    md("""
## Voxelize

`voxax.Grid.cube(n)` is the cube $[-1, 1]^3$ split into `n` cells per axis. The result is
indexed `W[i, j, k]` with i along x, j along y and k along z; voxel `(i, j, k)` has its
centre at `grid.lower + (i + 0.5, j + 0.5, k + 0.5) * grid.spacing`, and
`grid.centers()` returns all centres in the same layout.
"""),
    code("""
grid = voxax.Grid.cube(RESOLUTION)
W = voxax.voxelize(mesh.vertices, mesh.faces, grid)
print(grid)
print("W:", W.shape, W.dtype, f"values in [{float(W.min()):.3f}, {float(W.max()):.3f}]")

centres = grid.centers()  # (nx, ny, nz, 3), same indexing as W
i, j, k = np.unravel_index(int(jnp.argmax(W)), W.shape)
print(f"W[{i}, {j}, {k}] = {float(W[i, j, k]):.3f}, voxel centre {centres[i, j, k].round(3).tolist()}")
fig = voxax.plot.slices(W, grid, axis=2, count=4, title="slices orthogonal to z")
"""),
    md("""
The three *silhouettes* (the maximum of `W` along x, y and z, softened by mellowmax) are
what the bandsaw application of notebook 04 works with:
"""),
    code("""
fig = voxax.plot.silhouettes(W, grid, title="silhouettes: mellowmax of W along each axis")
"""),
    md("""
## Check the volume

The mesh's own volume comes from the divergence theorem (`mesh.signed_volume()`); the
grid's is `sum(W) * grid.voxel_volume`. They agree to rounding error:
"""),
    code("""
volume_grid = float(W.sum()) * grid.voxel_volume
volume_mesh = mesh.signed_volume()
print(f"sum(W) * voxel volume = {volume_grid:.12f}")
print(f"mesh volume           = {volume_mesh:.12f}")
print(f"relative difference   = {abs(volume_grid - volume_mesh) / volume_mesh:.1e}")
assert abs(volume_grid - volume_mesh) < 1e-9 * volume_mesh
"""),
    md("""
It holds on any grid: coarse, odd or non-cubic shapes, anisotropic cells, even a grid
that cuts through the mesh (then it is the volume of the part inside the grid). Sampling
the winding number at the voxel centres instead (the "discretise first" approach of
`voxax.baselines.point_sampled`) only converges as the grid is refined:
"""),
    code("""
from voxax.baselines import point_sampled

lo, hi = mesh.bounds[0] - 0.05, mesh.bounds[1] + 0.05
print(f"{'grid shape':>14} {'voxax volume':>15} {'point-sampled':>15}   (mesh: {volume_mesh:.6f})")
for shape in [(3, 4, 5), (8, 8, 8), (16, 11, 7), (24, 24, 24)]:
    g = voxax.Grid(lo, hi, shape)
    v_exact = float(voxax.voxelize(mesh.vertices, mesh.faces, g).sum()) * g.voxel_volume
    v_points = float(point_sampled(mesh.vertices, mesh.faces, g).sum()) * g.voxel_volume
    print(f"{str(shape):>14} {v_exact:15.9f} {v_points:15.9f}")
"""),
    md("""
## Partial voxels hold exact fractions

A box from -0.3 to 0.45 along x (and -0.3 to 0.3 along y and z) on a 4-cell grid (cells
of side 0.5): voxel `(1, 1, 1)` spans $[-0.5, 0]^3$ and holds $0.6^3 = 0.216$ of it;
voxel `(2, 1, 1)` holds $0.9 \\cdot 0.6 \\cdot 0.6 = 0.324$.
"""),
    code("""
box = voxax.data.box((-0.3, -0.3, -0.3), (0.45, 0.3, 0.3))
Wb = voxax.voxelize(box.vertices, box.faces, voxax.Grid.cube(4))
print("W[:, 1, 1] =", np.asarray(Wb[:, 1, 1]).round(12))
np.testing.assert_allclose(Wb[:, 1, 1], [0.0, 0.216, 0.324, 0.0], atol=1e-12)
"""),
    md("""
## Speed

`voxelize` works under `jax.jit` (the grid is a static, hashable argument). The forward
pass is a multi-threaded C++ kernel:
"""),
    code("""
fast = jax.jit(voxax.voxelize, static_argnums=2)
fast(mesh.vertices, mesh.faces, grid).block_until_ready()  # compile once
t0 = time.perf_counter()
for _ in range(5):
    fast(mesh.vertices, mesh.faces, grid).block_until_ready()
print(f"{(time.perf_counter() - t0) / 5 * 1e3:.2f} ms per voxelization of {mesh.n_faces} faces on {grid.shape}")
"""),
    md("""
## Your own meshes

`voxax.io.load` reads anything trimesh reads (`.obj`, `.ply`, `.stl`, `.glb`, ...);
`voxax.io.normalize` centres a mesh and scales it to `max |v| = 0.8`, well inside
$[-1, 1]^3$. Here a torus goes through a file and back:
"""),
    code("""
import tempfile

path = os.path.join(tempfile.mkdtemp(), "torus.obj")
voxax.io.save(voxax.data.torus(), path)
loaded = voxax.io.normalize(voxax.io.load(path))
print(loaded, "| closed:", voxax.io.is_watertight(*loaded))
Wt = voxax.voxelize(loaded.vertices, loaded.faces, grid)
fig = voxax.plot.slices(Wt, grid, count=3, title="a torus loaded from a file")
"""),
    md("""
## Interactive 3D view

`voxax.plot.mesh_plotly` draws the mesh with plotly (an optional dependency:
`pip install "voxax[plot]"`), here coloured by height:
"""),
    code("""
try:
    view = voxax.plot.mesh_plotly(mesh.vertices, mesh.faces, values=mesh.vertices[:, 2], label="z")
except ImportError as err:  # plotly is not installed
    print(err)
    view = None
view
"""),
]


# ---------------------------------------------------------------------------------------
# 02 gradients
# ---------------------------------------------------------------------------------------

GRADIENTS = [
    md(r"""
# Gradients: finite differences vs voxax vs point sampling

voxax differentiates the *box-filtered* winding numbers exactly: moving the surface
changes a voxel's value only through the part of the surface inside the voxel (the
transport theorem), which gives the closed-form "sub-triangle splat" gradient of the
docs' page *How gradients are computed*. This notebook compares it with

- **central finite differences** of the exact voxelization (slow, but independent), and
- **point sampling** (`voxax.baselines.point_sampled`): the sharp winding number sampled at
  points and averaged per voxel ("discretise, then differentiate"). It is piecewise
  constant in the vertices, so its derivatives are zero almost everywhere.

The loss is a grid energy $L(V) = \sum_{ij} (W_{ij}(V) - T_{ij})^2$ that pulls a star
towards a target disc $T$.
"""),
    params("""
# Parameters (the test suite runs this notebook with smaller values).
RESOLUTION = 32   # pixels per axis of the 2D grid [-1, 1]^2
H = 1e-6          # finite-difference step
"""),
    md("## The shapes"),
    code("""
star = voxax.data.star_polyline(5, outer=0.7, inner=0.35)  # vertices (V, 2), segments (F, 2)
V0, F = jnp.asarray(star.vertices), star.faces
grid = voxax.Grid.cube(RESOLUTION, dim=2)
disc = voxax.data.circle_polyline(64, 0.5, center=(0.1, 0.05))
T = voxax.voxelize(disc.vertices, disc.faces, grid)


def loss(V):
    return jnp.sum((voxax.voxelize(V, F, grid) - T) ** 2)


W0 = voxax.voxelize(V0, F, grid)
print(f"{star.n_vertices} vertices, loss {float(loss(V0)):.4f}")
fig = voxax.plot.slices(W0 - T, grid, title="W - T (star minus target disc)")
"""),
    md("## voxax vs central finite differences"),
    code("""
def central_differences(f, V, h):
    V = np.asarray(V, dtype=np.float64)
    g = np.zeros_like(V)
    for idx in np.ndindex(*V.shape):
        e = np.zeros_like(V)
        e[idx] = h
        g[idx] = (float(f(V + e)) - float(f(V - e))) / (2 * h)
    return g


loss_jit = jax.jit(loss)
t0 = time.perf_counter()
g_voxax = np.asarray(jax.jit(jax.grad(loss))(V0))
t_voxax = time.perf_counter() - t0
t0 = time.perf_counter()
g_fd = central_differences(loss_jit, V0, H)
t_fd = time.perf_counter() - t0
err = np.abs(g_voxax - g_fd).max() / np.abs(g_fd).max()
print(f"max |voxax - FD| / max |FD| = {err:.1e}")
print(f"voxax: one backward pass ({t_voxax * 1e3:.0f} ms incl. compilation); FD: {2 * V0.size} forward passes ({t_fd * 1e3:.0f} ms)")
assert err < 1e-5
"""),
    md("""
`jax.test_util.check_grads` runs the same comparison along random directions (reverse
mode: voxax implements the VJP, not the JVP):
"""),
    code("""
from jax.test_util import check_grads

check_grads(loss, (V0,), order=1, modes=("rev",), eps=1e-6)
print("check_grads passed")
"""),
    md("## Point sampling: the gradient vanishes"),
    code("""
from voxax.baselines import point_sampled

T_points = point_sampled(disc.vertices, disc.faces, grid, supersample=2)


def loss_points(V):
    return jnp.sum((point_sampled(V, F, grid, supersample=2) - T_points) ** 2)


g_points_autodiff = np.asarray(jax.grad(loss_points)(V0))
g_points_fd_small = central_differences(jax.jit(loss_points), V0, H)
h_big = 0.5 * grid.spacing[0]  # half a pixel: now some samples flip
g_points_fd_big = central_differences(jax.jit(loss_points), V0, h_big)
print("point sampling, autodiff:          max |g| =", np.abs(g_points_autodiff).max())
print(f"point sampling, FD with h = {H:g}:   max |g| = {np.abs(g_points_fd_small).max():.3g}")
print(f"point sampling, FD with h = {h_big:.3g}: max |g| = {np.abs(g_points_fd_big).max():.3g}"
      " (non-zero only where a sample point lies within h of the surface)")
"""),
    code("""
fig, axes = plt.subplots(1, 3, figsize=(13, 4.2), layout="constrained")
W_points = point_sampled(V0, F, grid, supersample=2)
panels = [(g_voxax, W0 - T, "voxax (exact)"), (g_fd, W0 - T, f"finite differences, h = {H:g}"),
          (g_points_autodiff, W_points - T_points, "point sampled: autodiff gives 0")]
scale = 0.25 / np.abs(g_voxax).max()
for ax, (g, background, name) in zip(axes, panels):
    voxax.plot.gradient_field(V0, F, g, background, grid, ax=ax, scale=scale, title=name)
fig.suptitle("dL/dV: descent moves every vertex against its arrow")

fig2, ax = plt.subplots(figsize=(4.2, 4), layout="constrained")
ax.scatter(g_fd.ravel(), g_voxax.ravel(), s=12, label="voxax")
ax.scatter(g_fd.ravel(), g_points_fd_big.ravel(), s=12, marker="x", label="point sampled (FD)")
lim = np.abs(g_fd).max() * 1.1
ax.plot([-lim, lim], [-lim, lim], "k--", lw=0.8)
ax.set_xlabel("finite differences of voxax")
ax.set_ylabel("gradient")
_ = ax.legend()
"""),
    md(r"""
## In 3D

The same comparison for a sphere on a coarse grid, every vertex coordinate by finite
differences, and the volume gradient identity: $\partial\,\mathrm{vol} / \partial v =
\sum_{t \ni v} A_t\, n_t / 3$ (`voxax.reference.volume_gradient`), which the gradient of
`sum(W) * |voxel|` reproduces exactly.
"""),
    code("""
sphere = voxax.data.icosphere(1, radius=0.6)
S0, SF = jnp.asarray(sphere.vertices), sphere.faces
grid3 = voxax.Grid((-0.8, -0.75, -0.7), (0.8, 0.7, 0.75), (7, 8, 9))  # odd, non-cubic
c = jnp.asarray(np.random.default_rng(0).normal(size=grid3.shape))


def loss3(V):
    return jnp.sum(jnp.sin(voxax.voxelize(V, SF, grid3)) * c)


g3 = np.asarray(jax.grad(loss3)(S0))
g3_fd = central_differences(jax.jit(loss3), S0, H)
print(f"3D: max |voxax - FD| / max |FD| = {np.abs(g3 - g3_fd).max() / np.abs(g3_fd).max():.1e}")

volume = lambda V: jnp.sum(voxax.voxelize(V, SF, grid3)) * grid3.voxel_volume
g_vol = np.asarray(jax.grad(volume)(S0))
exact = voxax.reference.volume_gradient(sphere.vertices, sphere.faces)
print(f"volume gradient: max |voxax - exact| = {np.abs(g_vol - exact).max():.1e}")
fig = voxax.plot.gradient_field(S0, SF, g_vol, title="d volume / d vertices: outward normals")
"""),
]


# ---------------------------------------------------------------------------------------
# 03 self-intersections
# ---------------------------------------------------------------------------------------

SELF_INTERSECTIONS = [
    md(r"""
# Resolving self-intersections

Where a mesh overlaps itself, its winding number is 2 (or more), so voxels covered twice
hold values above 1. The paper's energy (section 4.2) penalises exactly those voxels,

$$E_\text{sect} = \frac{1}{N} \sum_{W_{ijk} > 1 + \varepsilon} W_{ijk}^2,$$

and an as-rigid-as-possible (ARAP) term keeps the shape. Minimizing
$E_\text{sect} + 0.005\,E_\text{ARAP}$ with Adam pushes the overlapping parts apart until
no voxel exceeds $1 + \varepsilon$: `voxax.apps.resolve_self_intersections` does all of it.
"""),
    params("""
# Parameters (the test suite runs this notebook with smaller values).
RESOLUTION = 64    # cells per axis of [-1, 1]^3 (paper: 128)
MAX_STEPS = 400    # most Adam steps of the voxel stage
MAX_ROUNDS = 20    # refinement rounds at most after the exact check
"""),
    md("## A bar bent into an overlapping spiral"),
    code("""
import voxax.apps

mesh = voxax.io.normalize(voxax.data.bent_bar())  # max |v| = 0.8, as the app does
grid = voxax.Grid.cube(RESOLUTION)
W = voxax.voxelize(mesh.vertices, mesh.faces, grid)
overlap = W > 1 + 1e-3
print(mesh, f"| max W = {float(W.max()):.3f}, {int(overlap.sum())} voxels covered twice")
print(f"E_sect = {float(voxax.energies.self_intersection(W)):.3e}")
fig = voxax.plot.mesh(mesh.vertices, mesh.faces, title="input: the bar passes through itself")
fig = voxax.plot.slices(W, grid, count=3, title="W (2 where the bar overlaps itself)")
"""),
    md("""
## Resolve

The app works in two stages. The *voxel stage* is the paper's: it normalizes the mesh,
optimizes on the `[-1, 1]^3` grid and stops as soon as no voxel exceeds `1 + eps` (or after
`max_steps`). A grid cannot see overlaps thinner than a voxel, so the app then checks the
result with the exact triangle-triangle test (`voxax.intersections`) and, while intersecting
pairs remain, *refines* on small fine grids placed around them (at most `max_rounds`
rounds). `report.resolved` is True only when the exact test finds no intersecting pair; the
report carries the exact counts before, after the voxel stage and at the end, and the
enclosed volume (kept within about 2% by a volume term unless `keep_volume=False`). The
result is mapped back to the input's frame.
"""),
    code("""
t0 = time.perf_counter()
resolved, report = voxax.apps.resolve_self_intersections(
    mesh, resolution=RESOLUTION, max_steps=MAX_STEPS, max_rounds=MAX_ROUNDS, progress=False
)
print(f"{time.perf_counter() - t0:.1f} s")
print(report.summary())
print(f"intersecting face pairs: {report.intersections_initial} before, "
      f"{report.intersections_after_voxel_stage} after the voxel stage, {report.intersections_final} at the end "
      f"({report.refinement_rounds} refinement rounds); resolved: {report.resolved}")
"""),
    code("""
fig = voxax.plot.history(report, title=f"{report.steps} steps, stopped by {report.stop_reason!r}")
"""),
    code("""
W_after = voxax.voxelize(resolved.vertices, resolved.faces, grid)
fig, axes = plt.subplots(1, 2, figsize=(9, 4), layout="constrained")
for ax, (w, name) in zip(axes, [(W, "before"), (W_after, "after")]):
    im = ax.imshow(np.asarray(w).max(axis=2).T, origin="lower", extent=(-1, 1, -1, 1), cmap="magma", vmin=0, vmax=2)
    ax.set(title=f"{name}: max of W along z = {float(w.max()):.3f}", xlabel="x", ylabel="y")
fig.colorbar(im, ax=axes.tolist(), shrink=0.8)

displacement = resolved.vertices - mesh.vertices
fig = voxax.plot.mesh(resolved.vertices, resolved.faces, values=displacement, label="displacement",
                      title="resolved, coloured by how far each vertex moved")
"""),
    md("""
## The same thing by hand

The app is a thin composition of public parts: `voxelize`, two energies and `minimize`
(its `max_w_threshold` rule stops as soon as no voxel is covered twice):
"""),
    code("""
V0 = jnp.asarray(mesh.vertices)


def energy(V, args):
    W = voxax.voxelize(V, mesh.faces, grid)
    e_sect = voxax.energies.self_intersection(W, 1e-3)
    e_arap = voxax.energies.arap(V, V0, mesh.faces)
    return e_sect + 0.005 * e_arap, {"sect": e_sect, "arap": e_arap, "max_w": W.max()}


result = voxax.minimize(energy, V0, has_aux=True, learning_rate=1e-2, progress=False,
                        stop=voxax.StopRules(max_steps=MAX_STEPS, max_w_threshold=1 + 1e-3))
print(f"{result.steps} steps, stop reason {result.stop_reason!r}, max W {result.history['max_w'][-1]:.4f}")
"""),
]


# ---------------------------------------------------------------------------------------
# 04 bandsaw
# ---------------------------------------------------------------------------------------

BANDSAW = [
    md(r"""
# Optimizing a shape for a bandsaw

A bandsaw cutting a block along x, y and z can only make *cut shapes*: the intersection
of the three silhouettes, each extruded along its axis. With soft silhouettes
$S_x, S_y, S_z$ (mellowmax of $W$ along each axis, sharpness $w = 1000$), the cut shape is
$S = S_x S_y S_z$, and the material that cutting cannot remove is measured by
$E_\text{cut} = \operatorname{mean}\,(S - W)^2$ (paper, section 4.3). Deforming the shape
as rigidly as possible to reduce $E_\text{cut}$ makes it cheaper to cut:
`voxax.apps.optimize_for_bandsaw`. Then `voxax.fabricate` writes printable templates
(SVG) and the exact cut solid.
"""),
    params("""
# Parameters (the test suite runs this notebook with smaller values).
RESOLUTION = 64              # cells per axis of [-1, 1]^3 (paper: 128)
MAX_STEPS = 300              # most Adam steps
OUT_DIR = "bandsaw-output"   # where the templates and cut solids are written
"""),
    md("## Silhouettes and the cut shape"),
    code("""
import voxax.apps
import voxax.fabricate

mesh = voxax.io.normalize(voxax.data.hand())
grid = voxax.Grid.cube(RESOLUTION)
W = voxax.voxelize(mesh.vertices, mesh.faces, grid)
S = voxax.energies.cut_shape(W)
print(f"E_cut = {float(voxax.energies.bandsaw_cut(W)):.3e}; cut shape volume / shape volume = "
      f"{float(S.sum() / W.sum()):.3f}")
fig = voxax.plot.silhouettes(W, grid, title="the three silhouettes of the input")
fig = voxax.plot.slices(S - W, grid, axis=1, count=3, title="S - W: what the cuts leave on (red)")
"""),
    md("## Optimize"),
    code("""
t0 = time.perf_counter()
optimized, report = voxax.apps.optimize_for_bandsaw(mesh, resolution=RESOLUTION, max_steps=MAX_STEPS, progress=False)
print(f"{time.perf_counter() - t0:.1f} s")
print(report.summary())
print(f"relative improvement of E_cut: {report.relative_improvement:.1%}")
"""),
    code("""
fig = voxax.plot.history(report)
W_opt = voxax.voxelize(optimized.vertices, optimized.faces, grid)
fig = voxax.plot.silhouettes(W_opt, grid, title="silhouettes after the optimization")
fig = voxax.plot.mesh(optimized.vertices, optimized.faces, values=optimized.vertices - mesh.vertices,
                      label="displacement", title="optimized, coloured by displacement")
"""),
    md("""
## Templates and the exact cut solid

`voxax.fabricate.bandsaw_templates` computes the exact silhouettes of the mesh (unions of
projected triangles), writes one SVG template per axis to scale (to glue on the block's
faces), and intersects the extruded silhouettes with manifold3d: the exact cut solid and
its waste volume.
"""),
    code("""
before = voxax.fabricate.bandsaw_templates(mesh, os.path.join(OUT_DIR, "input"), size_mm=100)
after = voxax.fabricate.bandsaw_templates(optimized, os.path.join(OUT_DIR, "optimized"), size_mm=100)
print(f"exact waste (cut solid - shape) / cut solid: input {before.waste_fraction:.1%}, "
      f"optimized {after.waste_fraction:.1%}")
print("written:", *[os.path.relpath(p) for p in after.svg_paths + (after.solid_path,)], sep="\\n  ")
"""),
    code("""
from IPython.display import SVG, display

for path in after.svg_paths:
    display(SVG(filename=path))
"""),
    code("""
fig = plt.figure(figsize=(10, 4.6), layout="constrained")
for n, (name, t) in enumerate([("input", before), ("optimized", after)]):
    ax = fig.add_subplot(1, 2, n + 1, projection="3d")
    voxax.plot.mesh(t.cut_solid.vertices, t.cut_solid.faces, ax=ax,
                    title=f"cut solid of the {name} shape: {t.waste_fraction:.0%} waste")
"""),
]


# ---------------------------------------------------------------------------------------
# 05 tiling
# ---------------------------------------------------------------------------------------

TILING = [
    md(r"""
# Tiling space with deformed copies of a shape

Place $B = 27$ copies of a mesh, each with its own translation, rotation (yaw, pitch,
roll) and vertex offsets, voxelize all of them on $[-1, 1]^3$ in one batched call, cut the
grid into $3^3 = 27$ blocks and add them up: that is one periodic cell (what sticks out of
the middle block re-enters on the opposite side). The energy

$$E_\text{fill} = \sum_\text{cell voxels} (\text{cell} - 1)^2 + \alpha\, E_\text{ARAP}$$

is zero when every point of space is covered exactly once (paper, section 4.4):
`voxax.apps.optimize_tiling`.
"""),
    params("""
# Parameters (the test suite runs this notebook with smaller values).
RESOLUTION = 48     # cells per axis of [-1, 1]^3, a multiple of 3 (paper: 192)
INSTANCES = 27      # copies of the mesh
MAX_STEPS = 200     # most Adam steps
ARAP_WEIGHT = 50.0  # paper: 0.005, which lets the shapes crumple (see optimize_tiling's docs)
MESH = "hand"
"""),
    md("## Folding 27 blocks into one periodic cell"),
    code("""
import voxax.apps

mesh = voxax.data.get(MESH)
grid = voxax.Grid.cube(RESOLUTION)
n = RESOLUTION // 3
blocks = jnp.arange(27.0).reshape(3, 3, 3)
W_blocks = jnp.repeat(jnp.repeat(jnp.repeat(blocks, n, 0), n, 1), n, 2)  # block b holds the value b
cell = voxax.energies.fold_periodic(W_blocks)
print(f"the cell is {cell.shape}; every cell voxel is the sum of one voxel of each block: {float(cell[0, 0, 0])} = 0 + 1 + ... + 26")
"""),
    md("## Optimize"),
    code("""
t0 = time.perf_counter()
placed, report = voxax.apps.optimize_tiling(
    mesh, instances=INSTANCES, resolution=RESOLUTION, max_steps=MAX_STEPS, arap_weight=ARAP_WEIGHT, progress=False
)
print(f"{time.perf_counter() - t0:.1f} s")
print(report.summary())
print(f"cell voxels covered exactly once: {report.coverage_initial:.1%} -> {report.coverage_final:.1%}")
"""),
    code("""
fig = voxax.plot.history(report, keys=["energy"])
cell_grid = voxax.Grid((report.cell_lower,) * 3, (report.cell_upper,) * 3, report.cell.shape)
fig = voxax.plot.slices(report.cell - 1.0, cell_grid, axis=2, count=4,
                        title="cell - 1 after the optimization (0: covered exactly once)")
"""),
    code("""
packed = voxax.data.Mesh.concatenate(*placed)
instance = np.concatenate([np.full(m.n_faces, b) for b, m in enumerate(placed)])
fig = voxax.plot.mesh(packed.vertices, packed.faces, values=instance, cmap="tab20", colorbar=False,
                      title=f"{len(placed)} instances in the [-1, 1]^3 frame")
"""),
    md("""
Repeating all instances with period `2/3` along x, y and z tiles space; the fraction of
each voxel value in the cell shows how well:
"""),
    code("""
values, counts = np.unique(np.round(np.asarray(report.cell)).astype(int), return_counts=True)
for v, c in zip(values, counts):
    print(f"cell voxels rounding to {v}: {c / report.cell.size:6.1%}")
"""),
]


# ---------------------------------------------------------------------------------------
# 06 batches
# ---------------------------------------------------------------------------------------

BATCHES = [
    md(r"""
# Batches: `vmap` over a family of shapes, `shard_map` over devices

Optimizations often handle many instances of one mesh (the 27 copies of the tiling, a
family of designs). `voxelize` takes leading batch axes on `vertices` (`(B, V, 3)` with
shared `faces (F, 3)`), works under `jax.vmap`, and under `shard_map` spreads a batch over
devices. Here JAX simulates 4 CPU devices (set in the first cell, before JAX starts).
"""),
    params("""
# Parameters (the test suite runs this notebook with smaller values).
RESOLUTION = 48   # cells per axis of [-1, 1]^3
FAMILY = 8        # shapes in the family (a multiple of the 4 simulated devices)
"""),
    md("## A family of ellipsoids"),
    code("""
sphere = voxax.data.icosphere(2, radius=0.5)
rng = np.random.default_rng(0)
axes_scale = rng.uniform(0.6, 1.4, (FAMILY, 1, 3))          # per-instance semi-axes (times 0.5)
shifts = rng.uniform(-0.2, 0.2, (FAMILY, 1, 3))
V = jnp.asarray(sphere.vertices[None] * axes_scale + shifts)  # (B, V, 3)
F = sphere.faces                                               # (F, 3), shared
grid = voxax.Grid.cube(RESOLUTION)

W = voxax.voxelize(V, F, grid)                                 # leading axes: (B, n, n, n)
W_vmap = jax.vmap(lambda v: voxax.voxelize(v, F, grid))(V)
W_loop = jnp.stack([voxax.voxelize(v, F, grid) for v in V])
print(W.shape, "| vmap == batch == loop:", bool(jnp.array_equal(W, W_vmap) and jnp.array_equal(W, W_loop)))

volumes = W.sum(axis=(1, 2, 3)) * grid.voxel_volume
exact = np.array([voxax.data.Mesh(np.asarray(v), F).signed_volume() for v in V])
print("max |volume(W) - volume(mesh)| =", float(np.abs(volumes - exact).max()))

fig, axs = plt.subplots(1, FAMILY, figsize=(1.8 * FAMILY, 2.1), layout="constrained")
for b, ax in enumerate(np.atleast_1d(axs)):
    ax.imshow(np.asarray(W[b, :, :, RESOLUTION // 2]).T, origin="lower", cmap="RdBu_r", vmin=-1, vmax=1)
    ax.set(title=f"#{b}: vol {float(volumes[b]):.3f}", xticks=[], yticks=[])
_ = fig.suptitle("the middle z-slice of every instance")
"""),
    md("""
## Batched gradients

The instances are independent, so the gradient of the *sum* of per-instance energies
holds every instance's own gradient: here the exact volume gradient of each ellipsoid.
`jax.vmap(jax.grad(...))` gives the same for any per-instance energy, here a fit to a
target grid:
"""),
    code("""
def volumes(v):  # (B, V, 3) -> (B,)
    return voxax.voxelize(v, F, grid).sum(axis=(-3, -2, -1)) * grid.voxel_volume


g = jax.jit(jax.grad(lambda v: volumes(v).sum()))(V)  # (B, V, 3)
exact_g = np.stack([voxax.reference.volume_gradient(np.asarray(v), F) for v in V])
print(g.shape, "| max error of the volume gradients:", float(np.abs(g - exact_g).max()))

target = voxax.voxelize(sphere.vertices, F, grid)


def fit(v):  # one instance: (V, 3) -> scalar
    return jnp.sum((voxax.voxelize(v, F, grid) - target) ** 2)


g_vmap = jax.jit(jax.vmap(jax.grad(fit)))(V)
g_loop = jnp.stack([jax.grad(fit)(v) for v in V])
print("vmap(grad) == loop of grads:", bool(jnp.allclose(g_vmap, g_loop, rtol=1e-12, atol=1e-14)))
"""),
    md("""
## Meshes with different face counts

Stack meshes of different sizes by padding: extra vertices anywhere, extra faces
degenerate (`(0, 0, 0)`), which contribute nothing. Faces then carry the batch axis too:
"""),
    code("""
def pad(mesh, n_vertices, n_faces):
    v = np.zeros((n_vertices, 3))
    v[: mesh.n_vertices] = mesh.vertices
    f = np.zeros((n_faces, 3), dtype=np.int32)
    f[: mesh.n_faces] = mesh.faces
    return v, f


meshes = [voxax.data.cube(0.8), voxax.data.icosphere(1, radius=0.5), voxax.data.torus(0.5, 0.2, 24, 12)]
nv, nf = max(m.n_vertices for m in meshes), max(m.n_faces for m in meshes)
Vp, Fp = map(np.stack, zip(*[pad(m, nv, nf) for m in meshes]))  # (3, nv, 3), (3, nf, 3)
Wp = voxax.voxelize(Vp, Fp, grid)
for m, w in zip(meshes, Wp):
    print(f"{m.n_faces:5d} faces: volume {float(w.sum()) * grid.voxel_volume:.6f} (mesh: {m.signed_volume():.6f})")
"""),
    md("""
## `shard_map` over devices

Each device voxelizes its share of the batch (the kernels are CPU code; on one machine
the simulated devices share its cores). The sharded result equals the unsharded one bit
for bit, and gradients flow back through the sharding:
"""),
    code("""
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P

shard_map = getattr(jax, "shard_map", None)
if shard_map is None:  # older JAX
    from jax.experimental.shard_map import shard_map

devices = Mesh(np.array(jax.devices()), ("batch",))
print(devices)
voxelize_sharded = jax.jit(shard_map(lambda v: voxax.voxelize(v, F, grid), mesh=devices,
                                     in_specs=P("batch"), out_specs=P("batch")))
V_sharded = jax.device_put(V, NamedSharding(devices, P("batch")))
W_sharded = voxelize_sharded(V_sharded)
print("sharding:", W_sharded.sharding.spec, "| equal to the unsharded batch:", bool(jnp.array_equal(W_sharded, W)))

g_sharded = jax.jit(jax.grad(lambda v: jnp.sum(voxelize_sharded(v)) * grid.voxel_volume))(V_sharded)
print("gradient through shard_map, max error:", float(np.abs(g_sharded - exact_g).max()))
"""),
    code("""
batched = jax.jit(lambda v: voxax.voxelize(v, F, grid))
batched(V).block_until_ready()
voxelize_sharded(V_sharded).block_until_ready()
for name, fn, x in [("one batched call", batched, V), ("shard_map over 4 devices", voxelize_sharded, V_sharded)]:
    t0 = time.perf_counter()
    for _ in range(3):
        fn(x).block_until_ready()
    print(f"{name:>26}: {(time.perf_counter() - t0) / 3 * 1e3:.1f} ms for {FAMILY} shapes on {grid.shape}")
"""),
]

MESHSDF = [
    md("""
# 07 · A sphere becomes a torus: MeshSDF through the voxelizer

A field `f_z = (1 - s)·sphere + s·torus`, `s = sigmoid(z)`, is meshed by marching cubes
(`voxax.isosurface_fn`); the mesh is voxelized (`voxax.voxelize`, the differentiable
renderer) and its three axis silhouettes (`voxax.energies.silhouettes`) are compared with a
torus's. The gradient reaches `z` through the vertices by the MeshSDF rule, so the surface
can change genus while the loss falls: the Euler characteristic goes from 2 (sphere) to 0
(torus). `voxax.apps.optimize_implicit` runs the loop.
"""),
    params("""
RESOLUTION = 32  # cells per axis of [-1, 1]^3
MAX_STEPS = 200
"""),
    code("""
grid = voxax.Grid.cube(RESOLUTION)
centers = jnp.asarray(grid.centers())


def field(z, x):
    s = jax.nn.sigmoid(z)
    return (1 - s) * voxax.fields.sphere(x, 0.6) + s * voxax.fields.torus(x, 0.5, 0.2)


torus = voxax.isosurface(voxax.fields.torus(centers, 0.5, 0.2), grid, close=True).to_mesh()
start = voxax.isosurface(field(-3.0, centers), grid, close=True).to_mesh()
print("start chi:", voxax.metrics.euler_characteristic(start), "| target chi:", voxax.metrics.euler_characteristic(torus))
"""),
    code("""
t0 = time.perf_counter()
z, report = voxax.apps.optimize_implicit(field, -3.0, torus, grid, steps=MAX_STEPS, learning_rate=0.2, target_euler=0)
print(report.summary())
print(f"s = sigmoid(z) = {float(jax.nn.sigmoid(z)):.3f}; the hole opens at s = 2/3 (f(0) = 0.9 s - 0.6)")
"""),
    code("""
final = voxax.isosurface(field(z, centers), grid, close=True).to_mesh()
print("final chi:", voxax.metrics.euler_characteristic(final),
      "| Chamfer to the torus:", voxax.metrics.chamfer(final, torus, n=20_000))
fig, ax = plt.subplots(1, 3, figsize=(12, 3.5))
ax[0].plot(report.loss_history); ax[0].set_yscale("log"); ax[0].set_title("silhouette loss")
ax[1].step(range(report.steps), report.euler_history, where="post"); ax[1].set_title("Euler characteristic")
W = voxax.voxelize(final.vertices, final.faces, grid)
ax[2].imshow(np.asarray(voxax.energies.silhouettes(W)[2]).T, origin="lower"); ax[2].set_title("final silhouette along z")
plt.tight_layout()
"""),
]

FAITHFUL_CONTOURING = [
    md("""
# 08 · Faithful Contouring: a mesh as sparse surface tokens, and back

`voxax.fc.encode` clips every triangle into the grid cells it meets and gives each of these
*active* cells a token: an anchor point (the minimizer of a quadratic error function over
the cell's surface pieces, so corners and creases are kept), a normal, and the signs of the
surface's crossings of the cell's 12 edges. `voxax.fc.decode` turns the tokens back into a
mesh by dual contouring. No signed distance field and no watertight repair: open surfaces
stay open.

The dense alternative, marching cubes on the voxelization
(`voxax.isosurface(voxax.voxelize(...), 0.5)`), needs an inside and an outside and rounds
every sharp edge to the grid. This notebook compares both on a CAD-like part built with
manifold3d booleans and on an open surface. Distances are reported in cells `h`:
two-sided Hausdorff, the Chamfer distance from the input to the output (mean squared
distance, in `h^2`) and the F-score at 0.005 of the grid's side (the paper's F@0.01 on
$[-1, 1]^3$).
"""),
    params("""
RESOLUTION = 96   # cells along the longest side of each shape's grid
SAMPLES = 50_000  # surface samples per mesh for the metrics
"""),
    md("""
## The shapes

A block with a cylindrical bore and a 45-degree chamfer along one edge (manifold3d's
booleans give an exact, closed mesh of 280 triangles), turned off the grid axes; and a wavy
open sheet with a crease along its middle, which has no inside at all.
"""),
    code("""
from manifold3d import Manifold


def cad_part() -> voxax.Mesh:
    block = Manifold.cube([1.2, 0.8, 0.5], center=True)
    bore = Manifold.cylinder(0.8, 0.2, 0.2, 64, center=True).translate([-0.25, 0.0, 0.0])
    # The chamfer: a bar turned by 45 degrees about x cuts the block's top front edge.
    cutter = Manifold.cube([1.4, 0.3, 0.3], center=True).rotate([45.0, 0.0, 0.0]).translate([0.0, -0.4, 0.25])
    m = (block - bore - cutter).rotate([12.0, 21.0, 7.0]).to_mesh()
    return voxax.Mesh(np.asarray(m.vert_properties, np.float64)[:, :3], np.asarray(m.tri_verts, np.int32))


def open_sheet(n: int = 32) -> voxax.Mesh:
    s = np.linspace(-0.7, 0.7, n + 1)
    x, y = np.meshgrid(s, s, indexing="ij")
    z = 0.15 * np.sin(3 * x) * np.cos(2 * y) + 0.25 * np.abs(x)
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None]).ravel()
    f = np.concatenate([np.stack([q, q + n + 1, q + n + 2], 1), np.stack([q, q + n + 2, q + 1], 1)])
    return voxax.Mesh(np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1), f.astype(np.int32))


shapes = {"CAD part": cad_part(), "open sheet": open_sheet()}
for name, mesh in shapes.items():
    rep = voxax.metrics.manifold_report(mesh)
    print(f"{name:10s} {mesh.n_faces:5d} faces, closed: {rep.closed}, boundary loops: {rep.n_boundary_loops}")
"""),
    md("""
## Encode, decode, measure

`voxax.fc.roundtrip` encodes on `Grid.around(mesh, RESOLUTION)`, decodes and measures the
result; the dense path runs on the same grid and is measured the same way.
"""),
    code("""
def measure(out, ref, grid, threshold):
    h = max(grid.spacing)
    return {
        "Hausdorff (h)": voxax.metrics.hausdorff(out, ref, n=SAMPLES) / h,
        "Chamfer (h^2)": voxax.metrics.chamfer(out, ref, convention="g2p", n=SAMPLES, to_surface=True) / h**2,
        "F-score (%)": 100 * voxax.metrics.f_score(out, ref, threshold, n=SAMPLES, to_surface=True),
    }


results = {}
for name, mesh in shapes.items():
    t0 = time.perf_counter()
    fc_mesh, report = voxax.fc.roundtrip(mesh, RESOLUTION, samples=SAMPLES)
    t_fc = time.perf_counter() - t0
    grid, h = report.grid, max(report.grid.spacing)
    t0 = time.perf_counter()
    W = voxax.voxelize(mesh.vertices.astype(np.float32), mesh.faces, grid)
    mc_mesh = voxax.isosurface(np.asarray(W), grid, 0.5).to_mesh()
    t_mc = time.perf_counter() - t0
    results[name] = {"input": mesh, "FC": fc_mesh, "MC": mc_mesh, "grid": grid}
    fc_row = {"Hausdorff (h)": report.hausdorff / h, "Chamfer (h^2)": report.chamfer_g2p / h**2,
              "F-score (%)": 100 * report.f_score}
    print(f"{name}: grid {grid.shape}, {report.tokens} tokens")
    for label, row, t in [("FC", fc_row, t_fc), ("voxelize + MC", measure(mc_mesh, mesh, grid, report.threshold), t_mc)]:
        print(f"  {label:14s}" + "".join(f"  {k} {v:9.4g}" for k, v in row.items()) + f"  ({t:.2f} s)")
    mr = report.manifold
    print(f"  FC output: {mr.n_boundary_loops} boundary loops, {mr.n_nonmanifold_edges} non-manifold edges "
          f"of {mr.n_edges}, chi {mr.euler_characteristic}")
"""),
    md("""
The tokens reproduce the part within a fraction of a cell (the Hausdorff distance is set by
a few cells on the rim of the bore, see below), while marching cubes on the
voxelization is off by about a cell along every sharp edge. On the open sheet the dense path
does not even apply: the winding number of an open surface is not an inside indicator, and
the 0.5 level set is a closed blob around part of the sheet, far from it. The tokens keep
the sheet open, with its one boundary loop.

Plain dual contouring places one vertex per cell, so a cell that two sheets cross (the two
faces of a sharp edge that passes just outside the cell, a part thinner than a cell) joins
them at that vertex, and the output gets a handful of non-manifold edges
(`anchors_per_cell=1`). The default, `anchors_per_cell="patches"`, gives such cells one
anchor per surface patch, the patches read from the cell's edge signs as marching cubes
joins them, at nearly the cost of one anchor per cell; `"components"` splits the cell's
pieces along the mesh edges inside it, many times slower. Both decode the part as a closed
2-manifold of genus 1:
"""),
    code("""
part, grid = shapes["CAD part"], results["CAD part"]["grid"]
for option in (1, "patches", "components"):
    rep = voxax.metrics.manifold_report(voxax.fc.decode(voxax.fc.encode(part, grid, anchors_per_cell=option)))
    print(f"anchors_per_cell={option!r:12}: closed {rep.closed}, {rep.n_nonmanifold_edges} non-manifold edges, "
          f"chi {rep.euler_characteristic}")
"""),
    md("""
## Where the error sits

Each output triangle coloured by the distance of its centroid to the input, in cells (same
colour scale for both methods): marching cubes cuts across every sharp edge and the rim of
the bore.
"""),
    code("""
fig = plt.figure(figsize=(13, 8))
for row, (name, r) in enumerate(results.items()):
    h = max(r["grid"].spacing)
    for col, key in enumerate(["input", "FC", "MC"]):
        m = r[key]
        ax = fig.add_subplot(2, 3, 3 * row + col + 1, projection="3d")
        if key == "input":
            voxax.plot.mesh(m.vertices, m.faces, ax=ax, title=f"{name}: input", elev=30, azim=-50)
            continue
        centroids = m.vertices[m.faces].mean(axis=1)
        d = voxax.closest_points(r["input"], centroids).distance / h
        voxax.plot.mesh(m.vertices, m.faces, d, ax=ax, vmin=0, vmax=0.5, elev=30, azim=-50,
                        label="distance (h)", title=f"{key}: {m.n_faces} triangles, max {d.max():.2f} h")
plt.tight_layout()
"""),
    md("""
Distances from samples of each output to the input, as cumulative distributions: the tokens
put nearly all of the surface within a few hundredths of a cell.
"""),
    code("""
fig, axes = plt.subplots(1, 2, figsize=(11, 3.5))
for ax, (name, r) in zip(axes, results.items()):
    h = max(r["grid"].spacing)
    for key in ("FC", "MC"):
        pts = voxax.metrics.sample_surface(r[key], SAMPLES).points
        d = np.sort(voxax.closest_points(r["input"], pts).distance / h)
        ax.plot(np.maximum(d, 1e-6), np.linspace(0, 1, len(d)), label=key)
    ax.set_xscale("log"); ax.set_xlabel("distance to the input (h)"); ax.set_title(name); ax.legend()
plt.tight_layout()
"""),
]

EXPLICIT_SURFACES = [
    md("""
# 10 · Explicit surface intersections: height-field hulls, axis selection, moulds

A closed shape can be written as the intersection of a few simple solids that are each
exact to query: a **double height field** (DHF) along an axis `d` (everything between the
first and the last hit of the lines parallel to `d`) and up to three **height fields**
(HF: everything behind the first hit along `d`). `voxax.esi` computes their depth maps
exactly (BVH ray casts, float64), selects the axes by branch and bound on the paper's
energy, answers inside/outside queries exactly and meshes the intersection;
`voxax.nesi` stores each height field as a small SIREN. A shape that equals its DHF along
an axis can be cast in a two-piece mould that parts along it:
`voxax.apps.optimize_for_molding` deforms a shape towards that.
"""),
    params("""
RESOLUTION = 128     # pixels per side of the depth maps used for meshing
N_DHF = 12           # candidate DHF axes (the paper: 50, plus the 3 coordinate axes)
N_HF = 16            # candidate HF axes (the paper: 80, plus the 6 signed coordinate axes)
MAX_HF = 2           # height fields at most
N_SAMPLES = 4000     # surface samples of the energy
N_POINTS = 20_000    # random points of the inside/outside checks
MOLD_RESOLUTION = 48
MOLD_STEPS = 200
"""),
    md("""
## Depth maps and the double height field of a torus

Every vertical line meets a torus lying in the xy-plane in at most one segment, so the
torus *is* its DHF along z: the occupancy of that one-solid ESI equals inside/outside
(the winding number) everywhere.
"""),
    code("""
torus = voxax.data.torus()
dm = voxax.esi.depth_map(torus, [0.0, 0.0, 1.0], resolution=RESOLUTION)
fig, ax = plt.subplots(1, 2, figsize=(8, 3.5))
for a, img, title in zip(ax, (dm.first, dm.last), ("first hit along +z", "last hit along +z")):
    a.imshow(img.T, origin="lower"); a.set_title(title); a.axis("off")
plt.tight_layout()

points = np.random.default_rng(0).uniform(-1.0, 1.0, size=(N_POINTS, 3))
inside = np.asarray(voxax.winding_number(torus.vertices, torus.faces, points)) >= 0.5
occupied = voxax.esi.occupancy(([0.0, 0.0, 1.0], np.zeros((0, 3))), torus, points)
print(f"DHF(z) occupancy equals inside/outside at {np.mean(occupied == inside):.2%} of {len(points)} points")
"""),
    md("""
## Selecting the axes of a mug

A mug is not a DHF along any axis (its cavity and its handle's hole), so the selection
adds height fields. `select` evaluates the energy `E = Dist + min(mu (Dist + eps1), eps2)`
for a DHF axis and `m = 0, 1, ...` height fields and prunes combinations whose lower bound
already exceeds the best `E` found.
"""),
    code("""
mug = voxax.data.mug()
t0 = time.perf_counter()
esi = voxax.esi.select(mug, n_dhf=N_DHF, n_hf=N_HF, max_hf=MAX_HF, n_samples=N_SAMPLES, resolution=64)
print(f"{time.perf_counter() - t0:.1f} s: DHF axis {np.round(esi.dhf_axis, 3)}, {len(esi.hf_axes)} HF(s)")
print("least E with m = 0, 1, ... height fields:", np.round(esi.by_m, 5))
print(f"combinations with height fields pruned without a full evaluation: {esi.prune_rate:.1%}")

# The ESI contains the shape: no point inside the mug is reported outside.
points = np.random.default_rng(1).uniform(mug.bounds[0], mug.bounds[1], size=(N_POINTS, 3))
inside = np.asarray(voxax.winding_number(mug.vertices, mug.faces, points)) >= 0.5
occupied = voxax.esi.occupancy(esi, mug, points)
print("inside points reported outside:", int(np.sum(inside & ~occupied)),
      f"| outside points reported inside: {np.mean(occupied & ~inside):.2%}")
"""),
    code("""
esi_mesh = voxax.esi.to_mesh(esi, mug, resolution=RESOLUTION)
dhf_mesh = voxax.esi.to_mesh((esi.dhf_axis, np.zeros((0, 3))), mug, resolution=RESOLUTION)
cd = lambda a: voxax.metrics.chamfer(a, mug, convention="l1_bbox", n=10_000)
print(f"Chamfer (L1 x 1000 / bbox diagonal): mug to itself {cd(mug):.2f} (the sampling floor), "
      f"ESI {cd(esi_mesh):.2f}, DHF alone {cd(dhf_mesh):.2f}")
fig = plt.figure(figsize=(9, 3.5))
for i, (m, title) in enumerate(((mug, "mug"), (dhf_mesh, "DHF alone"), (esi_mesh, "ESI"))):
    a = fig.add_subplot(1, 3, i + 1, projection="3d")
    a.plot_trisurf(*m.vertices.T, triangles=m.faces, linewidth=0, antialiased=False)
    a.set_title(title); a.set_axis_off(); a.view_init(25, -60)
plt.tight_layout()
"""),
    md("""
`voxax.nesi.fit` then stores each height field of such a selection as a small SIREN that
answers occupancy queries and casts rays directly (`voxax.nesi.occupancy`,
`voxax.nesi.raytrace`); `benchmarks/esi.py nesi` trains them and compares the Chamfer
distances with the exact ESI's.
"""),
    md("""
## Deforming a shape for a two-piece mould

Along x, the torus's hole is an undercut: lines parallel to x through the hole meet the
torus in two segments. `optimize_for_molding` minimizes the gap between the voxelized shape
and its soft DHF hull (plus ARAP) and reports the exact undercut volume
`volume(DHF) - volume(shape)` before and after.
"""),
    code("""
moulded, report = voxax.apps.optimize_for_molding(torus, 0, resolution=MOLD_RESOLUTION, max_steps=MOLD_STEPS,
                                                  learning_rate=3e-3, progress=False)
print(report.summary())
print(f"undercut volume: {report.undercut_volume_initial:.4g} -> {report.undercut_volume_final:.4g}")
fig, ax = plt.subplots(1, 2, figsize=(8, 3.5))
for a, m, title in zip(ax, (torus, moulded), ("input", "optimized")):
    d = voxax.esi.depth_map(m, [1.0, 0.0, 0.0], resolution=96)
    a.imshow(np.where(d.mask, d.last - d.first, np.nan).T, origin="lower"); a.set_title(f"{title}: DHF thickness along x")
    a.axis("off")
plt.tight_layout()
"""),
]

CVT = [
    md("""
# 09 · Quality meshes from fields: a restricted CVT next to marching cubes

Marching cubes (`voxax.isosurface`) is fast and watertight but cuts cells into slivers: its
worst triangles are nearly flat. `voxax.cvt.remesh` samples the same surface where grid lines
cross it, places seeds in proportion to area, optimises them towards a centroidal Voronoi
tessellation restricted to those samples (L-BFGS then Lloyd steps, or Lloyd steps only) and
reads the restricted Delaunay triangulation off the samples' nearest seeds: nearly
equilateral triangles with the topology of the surface. Both mesh a torus given as a field
(`voxax.fields.torus`), marching cubes at about the CVT's vertex count.

Triangle quality is `Q = (6 / sqrt 3) A / (p e_max)` (`voxax.metrics.triangle_quality`):
1 for an equilateral triangle, 0 for a degenerate one.
"""),
    params("""
N_SEEDS = 3000  # vertices of the CVT mesh
METHOD = "lbfgs"  # or "lloyd": cheaper to compile, slower to converge
STEPS = 60  # optimiser steps (L-BFGS is followed by 40 Lloyd steps)
"""),
    code("""
def field(p):
    return voxax.fields.torus(p, 0.6, 0.25)  # inside [-0.85, 0.85]^2 x [-0.25, 0.25]


# cells for about 50 fragments per seed (remesh refines a coarser grid itself)
box = voxax.Grid.cube(int(5 * np.sqrt(N_SEEDS)), half_width=1.0)
t0 = time.perf_counter()
cvt_mesh, report = voxax.cvt.remesh(field, N_SEEDS, grid=box, method=METHOD, steps=STEPS)
t_cvt = time.perf_counter() - t0
print(f"CVT: {report['n_fragments']} fragments on a {report['grid'].shape} grid, {report['n_vertices']} vertices, "
      f"closed 2-manifold: {report['closed'] and report['manifold']}, chi = {report['euler_characteristic']}, "
      f"{report['rounds']} manifold rounds, {t_cvt:.1f} s")


# marching cubes with about as many vertices: it puts about 1.1 vertices per h^2 of area
v, f = cvt_mesh.vertices, cvt_mesh.faces
area = 0.5 * np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1).sum()
cells = max(4, int(round(2.0 / np.sqrt(1.1 * area / len(v)))))
grid = voxax.Grid.cube(cells, half_width=1.0)
mc_mesh = voxax.isosurface(jax.jit(field)(grid.centers()), grid, 0.0).to_mesh()
print(f"marching cubes: {cells}^3 cells, {len(mc_mesh.vertices)} vertices, "
      f"chi = {voxax.metrics.euler_characteristic(mc_mesh)}")
"""),
    code("""
rows = []
for name, m in [("marching cubes", mc_mesh), ("CVT", cvt_mesh)]:
    q = voxax.metrics.triangle_quality(m)
    rows.append((name, q))
    print(f"{name:>15}: Q min {q.min():.4f} | Q mean {q.mean():.3f} | share with Q < 0.5: {np.mean(q < 0.5):.1%}")
print("two-sided Hausdorff distance between the meshes:",
      f"{voxax.metrics.hausdorff(mc_mesh, cvt_mesh, n=20_000):.4f}")

fig, ax = plt.subplots(1, 1, figsize=(6, 3.5))
bins = np.linspace(0, 1, 41)
for name, q in rows:
    ax.hist(q, bins=bins, alpha=0.6, density=True, label=name)
ax.set_xlabel("triangle quality Q"); ax.set_ylabel("density"); ax.legend(); ax.set_title("triangle quality")
plt.tight_layout()
"""),
    code("""
fig = plt.figure(figsize=(11, 4.5))
for i, (name, m) in enumerate([("marching cubes", mc_mesh), ("CVT", cvt_mesh)]):
    ax = fig.add_subplot(1, 2, i + 1, projection="3d")
    voxax.plot.mesh(m.vertices, m.faces, voxax.metrics.triangle_quality(m), ax=ax, vmin=0, vmax=1,
                    cmap="magma", label="Q", elev=45, title=f"{name}: faces coloured by quality")
plt.tight_layout()
"""),
]

DEVICE_FLAGS = '''
# Simulate 4 CPU devices for the shard_map section. This must run before JAX starts:
# restart the kernel (runtime) if JAX was imported already.
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_force_host_platform_device_count=4").strip()
'''

NOTEBOOKS = {
    "01_quickstart.ipynb": (QUICKSTART, ""),
    "02_gradients.ipynb": (GRADIENTS, ""),
    "03_self_intersections.ipynb": (SELF_INTERSECTIONS, ""),
    "04_bandsaw.ipynb": (BANDSAW, ""),
    "05_tiling.ipynb": (TILING, ""),
    "06_batches.ipynb": (BATCHES, DEVICE_FLAGS),
    "07_meshsdf.ipynb": (MESHSDF, ""),
    "08_faithful_contouring.ipynb": (FAITHFUL_CONTOURING, ""),
    "09_cvt.ipynb": (CVT, ""),
    "10_explicit_surfaces.ipynb": (EXPLICIT_SURFACES, ""),
}


def build() -> dict[str, nbformat.NotebookNode]:
    """The notebooks by file name, with deterministic cell ids and no outputs."""
    out = {}
    for name, (cells, extra) in NOTEBOOKS.items():
        nb = notebook([nbformat.from_dict(c) for c in cells], setup_extra=extra)
        stem = name.split("_")[0]
        for i, cell in enumerate(nb.cells):
            cell["id"] = f"c{stem}-{i:02d}"
        nbformat.validate(nb)
        out[name] = nb
    return out


def main(argv=None) -> int:
    target = (argv or sys.argv[1:] or [HERE])[0]
    for name, nb in build().items():
        path = os.path.join(target, name)
        with open(path, "w", encoding="utf-8") as fh:
            nbformat.write(nb, fh)
        print("wrote", path)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The `voxax mesh` command: a grid (from `voxax voxelize`) or an analytic field to a mesh file."""

from __future__ import annotations

import argparse
import sys

__all__ = ["add_mesh_command"]

_SDFS = {
    "sphere": "|x| - 0.6",
    "torus": "torus, radii 0.5 and 0.2, around z",
    "box": "box of half-sides 0.5, 0.4, 0.3",
    "gyroid": "gyroid sin x cos y + sin y cos z + sin z cos x at period 2 pi / 3, inside the unit ball",
}


def _sdf(name: str):
    import jax.numpy as jnp

    def sphere(x):
        return jnp.linalg.norm(x, axis=-1) - 0.6

    def torus(x):
        q = jnp.linalg.norm(x[..., :2], axis=-1) - 0.5
        return jnp.sqrt(q**2 + x[..., 2] ** 2) - 0.2

    def box(x):
        d = jnp.abs(x) - jnp.array([0.5, 0.4, 0.3])
        return jnp.linalg.norm(jnp.maximum(d, 0), axis=-1) + jnp.minimum(
            jnp.max(d, axis=-1), 0
        )

    def gyroid(x):
        y = x * 3 * jnp.pi
        g = jnp.sin(y[..., 0]) * jnp.cos(y[..., 1]) + jnp.sin(y[..., 1]) * jnp.cos(
            y[..., 2]
        )
        g = g + jnp.sin(y[..., 2]) * jnp.cos(y[..., 0])
        return jnp.maximum(g / (3 * jnp.pi), jnp.linalg.norm(x, axis=-1) - 0.9)

    return {"sphere": sphere, "torus": torus, "box": box, "gyroid": gyroid}[name]


def _mesh_cmd(args) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import voxax

    if (args.grid is None) == (args.sdf is None):
        raise SystemExit("voxax mesh: give either a grid file or --sdf NAME")
    if args.sdf is not None:
        grid = voxax.Grid.cube(args.resolution)
        fn = _sdf(args.sdf)
        values = np.asarray(fn(jax.numpy.asarray(grid.centers())))
        level = 0.0 if args.level is None else args.level
        inside = "below"
    else:
        path = args.grid
        if path.endswith(".npz"):
            data = np.load(path)
            if "W" not in data:
                raise SystemExit(f"voxax mesh: {path} has no array 'W'")
            values = data["W"]
            lower = data["lower"] if "lower" in data else (-1.0,) * values.ndim
            upper = data["upper"] if "upper" in data else (1.0,) * values.ndim
        else:
            values = np.load(path)
            lower, upper = (-1.0,) * values.ndim, (1.0,) * values.ndim
        if args.lower is not None:
            lower = args.lower
        if args.upper is not None:
            upper = args.upper
        grid = voxax.Grid(tuple(np.ravel(lower)), tuple(np.ravel(upper)), values.shape)
        level = 0.5 if args.level is None else args.level
        inside = args.inside
    iso = voxax.isosurface(values, grid, level, inside=inside, close=not args.open)
    mesh = iso.to_mesh()
    if mesh.n_faces == 0:
        print(
            "voxax mesh: the field does not cross the level; nothing written",
            file=sys.stderr,
        )
        return 1
    voxax.io.save(mesh, args.output)
    extra = f", volume {mesh.signed_volume():.8g}" if mesh.dim == 3 else ""
    print(
        f"wrote {args.output}: {mesh.n_vertices} vertices, {mesh.n_faces} faces{extra}"
    )
    return 0


def add_mesh_command(subparsers) -> argparse.ArgumentParser:
    """Adds `voxax mesh` to an `argparse` sub-parser collection and returns its parser.

    `voxax mesh W.npz -o out.ply` extracts the 0.5 level of a grid written by
    `voxax voxelize` (`.npz` with `W`, `lower`, `upper`; or a plain `.npy` on `[-1, 1]^d`),
    `voxax mesh --sdf sphere -n 128 -o sphere.ply` meshes a built-in field.
    """
    p = subparsers.add_parser(
        "mesh",
        help="extract an iso-surface (marching cubes) from a grid or a built-in field",
    )
    p.add_argument(
        "grid",
        nargs="?",
        help="a .npz (W, lower, upper) or .npy grid, e.g. from `voxax voxelize`",
    )
    p.add_argument(
        "--sdf",
        choices=sorted(_SDFS),
        help="mesh a built-in field instead: "
        + "; ".join(f"{k}: {v}" for k, v in _SDFS.items()),
    )
    p.add_argument(
        "--resolution",
        "-n",
        type=int,
        default=128,
        help="cells per axis for --sdf (grid [-1, 1]^3)",
    )
    p.add_argument(
        "--level",
        type=float,
        default=None,
        help="iso-value (default 0.5 for grids, 0 for --sdf)",
    )
    p.add_argument(
        "--inside",
        choices=["above", "below"],
        default="above",
        help="which side of the level is inside (grids)",
    )
    p.add_argument(
        "--lower", type=float, nargs="+", help="override the grid's lower corner"
    )
    p.add_argument(
        "--upper", type=float, nargs="+", help="override the grid's upper corner"
    )
    p.add_argument(
        "--open",
        action="store_true",
        help="do not close surfaces at the grid's boundary",
    )
    p.add_argument(
        "--output",
        "-o",
        default="mesh.ply",
        help="mesh file to write (any format trimesh writes)",
    )
    p.set_defaults(func=_mesh_cmd)
    return p

"""Deform a mesh so that a two-piece mould parting along an axis can cast it.

A solid can be cast in two mould halves that separate along an axis exactly when every
line parallel to the axis meets it in one segment: when it equals its double height field
(DHF) hull along the axis. `voxax.apps.optimize_for_molding` minimizes the gap between the
voxelized shape and its soft DHF hull (plus an ARAP term) and reports the exact undercut
volume, `volume(DHF) - volume(shape)`, before and after. The default input is a torus
moulded along x: its hole is an undercut.

    python examples/molding.py                         # torus along x at 48^3 (a minute)
    python examples/molding.py my_mesh.obj --axis 2

Writes `input.ply`, `optimized.ply`, `hull_input.ply`, `hull_optimized.ply` (the exact
DHF hulls, meshed from depth maps) and `history.png` to `--out`.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

import numpy as np  # noqa: E402

import voxax  # noqa: E402
import voxax.apps  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default="torus", help="a mesh file or a built-in mesh name")
    parser.add_argument("--axis", type=int, default=0, choices=(0, 1, 2), help="the mould's axis")
    parser.add_argument("--resolution", "-n", type=int, default=48, help="cells per axis")
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--learning-rate", type=float, default=3e-3)
    parser.add_argument("--out", "-o", default="out-molding", help="output folder")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)

    mesh = voxax.data.get(args.mesh) if args.mesh in voxax.data.names() else voxax.io.load(args.mesh)
    optimized, report = voxax.apps.optimize_for_molding(
        mesh,
        args.axis,
        resolution=args.resolution,
        max_steps=args.max_steps,
        learning_rate=args.learning_rate,
        progress=not args.quiet,
    )
    print(report.summary())
    print(
        f"undercut volume: {report.undercut_volume_initial:.4g} -> {report.undercut_volume_final:.4g}"
        f" ({1 - report.undercut_volume_final / max(report.undercut_volume_initial, 1e-300):.1%} less)"
    )
    os.makedirs(args.out, exist_ok=True)
    d = np.eye(3)[args.axis]
    for name, m in (("input", mesh), ("optimized", optimized)):
        voxax.io.save(m, os.path.join(args.out, f"{name}.ply"))
        hull = voxax.esi.to_mesh((d, ()), m, resolution=2 * args.resolution)
        voxax.io.save(hull, os.path.join(args.out, f"hull_{name}.ply"))
    report.plot_history(os.path.join(args.out, "history.png"))
    return 0


if __name__ == "__main__":
    sys.exit(main())

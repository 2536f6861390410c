"""Inflate a mesh inside a build volume: `voxax.minimize` with box bounds.

The energy `-volume(W) + 0.05 * ARAP` (the volume measured on the voxel grid) pushes every
vertex outwards; the bounds `lower <= vertex <= upper` keep the mesh inside a build
volume, which the sphere fills until it presses against the walls. With an optax solver
every step is projected onto the box; `--solver lbfgsb` uses jaxopt's L-BFGS-B
(`pip install "voxax[bounds]"`).

    python examples/bounded_minimize.py                      # Adam, 32^3, seconds
    python examples/bounded_minimize.py --solver lbfgsb

Prints how far the mesh reaches along each axis and writes `inflated.ply` to `--out`.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import voxax  # noqa: E402

LOWER = np.array([-0.6, -0.45, -0.35])
UPPER = np.array([0.6, 0.45, 0.35])


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", type=int, default=32, help="cells per axis of the [-1, 1]^3 grid")
    parser.add_argument("--max-steps", type=int, default=60, help="optimization steps")
    parser.add_argument("--solver", default="adam", choices=["adam", "sgd", "lbfgsb"], help="the solver")
    parser.add_argument("--out", default="voxax-bounded", help="output folder")
    args = parser.parse_args(argv)

    mesh = voxax.data.icosphere(2, radius=0.3)
    grid = voxax.Grid.cube(args.resolution)
    rest = jnp.asarray(mesh.vertices)

    def energy(v, _):
        W = voxax.voxelize(v, mesh.faces, grid)
        volume = jnp.sum(W) * grid.voxel_volume
        arap = voxax.energies.arap(v, rest, mesh.faces)
        return -volume + 0.05 * arap, {"volume": volume, "arap": arap}

    result = voxax.minimize(
        energy,
        rest,
        solver=args.solver,
        learning_rate=0.02,
        has_aux=True,
        bounds=(LOWER, UPPER),
        stop=voxax.StopRules(max_steps=args.max_steps),
        progress=False,
    )
    v = np.asarray(result.y)
    lo, hi = v.min(axis=0), v.max(axis=0)
    print(f"{result.steps} steps ({result.stop_reason}); volume {mesh.signed_volume():.4f} -> "
          f"{voxax.Mesh(v, mesh.faces).signed_volume():.4f}")
    for axis, name in enumerate("xyz"):
        print(f"  {name}: mesh spans [{lo[axis]:+.4f}, {hi[axis]:+.4f}] within the bounds "
              f"[{LOWER[axis]:+.2f}, {UPPER[axis]:+.2f}]")
    inside = bool(np.all(v >= LOWER) and np.all(v <= UPPER))
    print("every vertex inside the build volume:", inside)
    os.makedirs(args.out, exist_ok=True)
    voxax.io.save(voxax.Mesh(v, mesh.faces), os.path.join(args.out, "inflated.ply"))
    return 0 if inside else 1


if __name__ == "__main__":
    sys.exit(main())

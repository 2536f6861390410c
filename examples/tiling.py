"""Pack deformed copies of a mesh into a periodic cell that fills space.

The paper's section 4.4: every instance of the mesh gets its own translation, rotation
(yaw, pitch, roll) and vertex offsets. All instances are voxelized on [-1, 1]^3 in one
batched call, the grid is cut into 27 blocks that are summed into one periodic cell
(whatever sticks out re-enters on the other side), and `sum (cell - 1)^2 + alpha * ARAP`
is minimized with Adam: at the optimum every point of space is covered exactly once.

    python examples/tiling.py                              # 27 hands at 48^3 (a few minutes)
    python examples/tiling.py --resolution 192             # the paper's resolution (slow)
    python examples/tiling.py icosphere --instances 8
    python examples/tiling.py torus icosphere --instances 14 13

Writes `tiling.ply` (all instances), `tiled_2x2x2.ply` (the cell repeated twice along each
axis), `cell.png` (slices of the folded cell), `history.png` and `report.json` to `--out`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import jax

jax.config.update("jax_enable_x64", True)

import voxax  # noqa: E402
import voxax.apps  # noqa: E402


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("meshes", nargs="*", default=["hand"], help="mesh files or built-in mesh names")
    parser.add_argument("--instances", type=int, nargs="+", default=[27], help="total, or one count per mesh")
    parser.add_argument("--resolution", "-n", type=int, default=48, help="cells per axis, a multiple of 3 (paper: 192)")
    parser.add_argument("--max-steps", type=int, default=300)
    parser.add_argument("--arap-weight", type=float, default=50.0,
                        help="ARAP weight (paper: 0.005, which barely regularises; see optimize_tiling)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", "-o", default="out-tiling", help="output folder")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)

    meshes = [voxax.data.get(m) if m in voxax.data.names() else voxax.io.load(m) for m in args.meshes]
    instances = args.instances[0] if len(args.instances) == 1 else args.instances
    # Paper defaults (random initial placement in the cell, Adam with learning rate 1e-3,
    # stop when no vertex moves more than 1e-3 in a step) except for the ARAP weight:
    # the fill energy is a sum over voxels, so the paper's 0.005 lets shapes crumple.
    placed, report = voxax.apps.optimize_tiling(
        meshes, instances=instances, resolution=args.resolution, max_steps=args.max_steps,
        arap_weight=args.arap_weight, key=args.seed, progress=not args.quiet,
    )
    print(report.summary())
    print(f"cell voxels covered exactly once: {report.coverage_initial:.1%} -> {report.coverage_final:.1%} "
          f"(empty {report.empty_final:.1%}, overlapping {report.overlap_final:.1%})")

    os.makedirs(args.out, exist_ok=True)
    packed = voxax.data.Mesh.concatenate(*placed)
    voxax.io.save(packed, os.path.join(args.out, "tiling.ply"))
    # The cell tiles space with period 2/3 along x, y and z: show 2 x 2 x 2 cells.
    period = report.cell_upper - report.cell_lower
    copies = [packed.translated((i * period, j * period, k * period)) for i in (0, 1) for j in (0, 1) for k in (0, 1)]
    voxax.io.save(voxax.data.Mesh.concatenate(*copies), os.path.join(args.out, "tiled_2x2x2.ply"))

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = report.cell.shape[0]
    cell_grid = voxax.Grid((report.cell_lower,) * 3, (report.cell_upper,) * 3, (n, n, n))
    plt.close(voxax.plot.slices(report.cell, cell_grid, axis=2, count=4,
                                title=f"folded cell (1 = covered once): {report.coverage_final:.1%} covered once",
                                path=os.path.join(args.out, "cell.png")))
    plt.close(report.plot_history(os.path.join(args.out, "history.png")))
    with open(os.path.join(args.out, "report.json"), "w", encoding="utf-8") as fh:
        json.dump(report.to_dict(), fh, indent=1)
    print(f"wrote {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Resolving self-intersections on the full set of cases, checked beyond the working grid.

    PYTHONPATH=src python benchmarks/resolve.py [--resolution 128] [--cases bent_bar,letters,...]

For each case: `voxax.apps.resolve_self_intersections` with default settings (at the given
working resolution), then the exact intersection count of the result, the largest voxel
value on grids at 1x, 2x and 4x the working resolution and on the working grid shifted by
half a voxel (all in the working frame), the enclosed-volume change, the run time and the
refinement rounds. Prints one line per case and writes JSON with `--json`.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from _resolve_cases import deformed_hand, overlapping_letters, torus_knot_tube  # noqa: E402

import voxax  # noqa: E402
import voxax.apps  # noqa: E402

CASES = {
    "bent_bar": lambda: voxax.data.bent_bar(),
    "letters": lambda: overlapping_letters(),
    "torus_knot": lambda: torus_knot_tube(0.7),
    "hand_2": lambda: deformed_hand(2),
    "hand_3": lambda: deformed_hand(3),
    "hand_5": lambda: deformed_hand(5),
}


def check(out, report, resolution):
    """Exact count and the largest voxel value on finer and shifted grids (working frame)."""
    work = (out.vertices - report.centre) * report.scale
    h = 2.0 / resolution
    grids = {
        "1x": voxax.Grid.cube(resolution),
        "2x": voxax.Grid.cube(2 * resolution),
        "4x": voxax.Grid.cube(4 * resolution),
        "shifted": voxax.Grid(lower=(-1 + h / 2,) * 3, upper=(1 + h / 2,) * 3, shape=(resolution,) * 3),
    }
    max_w = {k: float(np.max(voxax.voxelize(work, out.faces, g))) for k, g in grids.items()}
    return voxax.intersections(out).count, max_w


def main(argv=None):
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=128, help="the working grid (128: the default of resolve_self_intersections)")
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--json")
    args = parser.parse_args(argv)
    rows = []
    for name in args.cases.split(","):
        mesh = CASES[name]()
        t0 = time.perf_counter()
        out, report = voxax.apps.resolve_self_intersections(mesh, resolution=args.resolution, progress=False)
        seconds = time.perf_counter() - t0
        count, max_w = check(out, report, args.resolution)
        volume = report.volume_final / report.enclosed_volume_initial - 1
        row = dict(case=name, faces=int(mesh.n_faces), resolved=report.resolved,
                   intersections_initial=report.intersections_initial,
                   intersections_after_voxel_stage=report.intersections_after_voxel_stage,
                   intersections_final=count, rounds=report.refinement_rounds,
                   refinement_steps=report.refinement_steps, voxel_steps=report.steps,
                   seconds=seconds, max_w=max_w, enclosed_volume_change=volume,
                   signed_volume_change=report.volume_final / report.volume_initial - 1,
                   volume_steps=report.volume_steps)
        rows.append(row)
        print(f"{name:11s} F={row['faces']:5d} resolved={report.resolved} pairs {report.intersections_initial}"
              f" -> {report.intersections_after_voxel_stage} (voxel stage) -> {count}; rounds {report.refinement_rounds}"
              f" ({report.refinement_steps} steps); max W " + " ".join(f"{k} {v:.5f}" for k, v in max_w.items())
              + f"; enclosed volume {100 * volume:+.2f}%; {seconds:.1f} s", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

"""Faithful Contouring next to marching cubes on the voxelization, on a CAD part and an open surface.

`voxax.fc.encode` turns a triangle mesh into sparse tokens (one QEF anchor, a normal and
12 edge signs per cell the surface meets) and `voxax.fc.decode` turns them back into a
mesh by dual contouring. The dense path `voxax.isosurface(voxax.voxelize(...), 0.5)` needs
a closed mesh and rounds every sharp edge to the grid; the tokens keep sharp edges and open
surfaces.

    python examples/faithful_contouring.py               # 64^3
    python examples/faithful_contouring.py -n 128 -o out
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

import voxax


def cad_part() -> voxax.Mesh:
    """A bracket: a plate with a bore and a slot, and a boss on top (manifold3d booleans)."""
    from manifold3d import Manifold

    plate = Manifold.cube([1.2, 0.8, 0.25], center=True)
    bore = Manifold.cylinder(0.4, 0.15, 0.15, 48, center=True).translate([-0.3, 0.0, 0.0])
    slot = Manifold.cube([0.5, 0.12, 0.4], center=True).translate([0.3, -0.15, 0.0])
    boss = Manifold.cube([0.3, 0.3, 0.3], center=True).translate([0.3, 0.15, 0.25])
    part = (plate - bore - slot + boss).rotate([17.0, 23.0, 9.0])
    m = part.to_mesh()
    v = np.asarray(m.vert_properties, np.float64)[:, :3]
    f = np.asarray(m.tri_verts, np.int64)
    v, inv = np.unique(v, axis=0, return_inverse=True)
    return voxax.Mesh(v, inv.reshape(-1)[f].astype(np.int32))


def open_surface(n: int = 32) -> voxax.Mesh:
    """A wavy open sheet with a crease (no inside, no outside)."""
    s = np.linspace(-0.7, 0.7, n + 1)
    x, y = np.meshgrid(s, s, indexing="ij")
    z = 0.15 * np.sin(3 * x) * np.cos(2 * y) + 0.25 * np.abs(x)
    v = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    q = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None]).ravel()
    f = np.concatenate([np.stack([q, q + n + 1, q + n + 2], 1), np.stack([q, q + n + 2, q + 1], 1)])
    return voxax.Mesh(v, f.astype(np.int32))


def distances(mesh: voxax.Mesh, reference: voxax.Mesh, h: float) -> dict:
    """Distances from the samples of `mesh` to `reference`, in cells."""
    d = voxax.closest_points(reference, voxax.metrics.sample_surface(mesh, 50_000).points).distance / h
    return {"mean": float(d.mean()), "p99": float(np.percentile(d, 99)), "max": float(d.max())}


def compare(name: str, mesh: voxax.Mesh, n: int, out: str) -> dict:
    grid = voxax.Grid.around(mesh.vertices, n)
    h = max(grid.spacing)
    t = time.perf_counter()
    tokens = voxax.fc.encode(mesh, grid)
    decoded = voxax.fc.decode(tokens)
    seconds = time.perf_counter() - t
    rep = voxax.metrics.manifold_report(decoded)
    row = {
        "grid": list(grid.shape),
        "tokens": len(tokens),
        "fc_seconds": seconds,
        "fc_distance_cells": distances(decoded, mesh, h),
        "fc_hausdorff_cells": voxax.metrics.hausdorff(decoded, mesh, n=20_000) / h,
        "fc_boundary_loops": rep.n_boundary_loops,
        "fc_euler_characteristic": rep.euler_characteristic,
    }
    voxax.io.save(decoded, os.path.join(out, f"{name}_fc.ply"))
    # The dense path: marching cubes on the box-filtered winding numbers (it treats an open
    # surface as the boundary of whatever its winding number makes of it).
    t = time.perf_counter()
    W = np.asarray(voxax.voxelize(mesh.vertices.astype(np.float32), mesh.faces, grid))
    iso = voxax.isosurface(W, grid, 0.5).to_mesh()
    row["mc_seconds"] = time.perf_counter() - t
    if iso.n_faces:
        row["mc_distance_cells"] = distances(iso, mesh, h)
        row["mc_hausdorff_cells"] = voxax.metrics.hausdorff(iso, mesh, n=20_000) / h
        voxax.io.save(iso, os.path.join(out, f"{name}_mc.ply"))
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", "-n", type=int, default=64, help="cells along the longest side")
    parser.add_argument("--out", "-o", default="out-fc", help="output folder")
    args = parser.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    report = {
        "cad_part": compare("cad_part", cad_part(), args.resolution, args.out),
        "open_surface": compare("open_surface", open_surface(), args.resolution, args.out),
    }
    for name, row in report.items():
        fc, line = row["fc_distance_cells"], f"{name:13s} {row['tokens']:8d} tokens"
        line += f"  FC mean {fc['mean']:.4f} p99 {fc['p99']:.4f} Hausdorff {row['fc_hausdorff_cells']:.3f} cells"
        if "mc_distance_cells" in row:
            mc = row["mc_distance_cells"]
            line += f" | MC mean {mc['mean']:.4f} p99 {mc['p99']:.4f} Hausdorff {row['mc_hausdorff_cells']:.3f} cells"
        print(line)
    with open(os.path.join(args.out, "report.json"), "w") as f:
        json.dump(report, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Quality meshes by a discrete centroidal Voronoi tessellation, next to marching cubes.

Meshes three kinds of input with `voxax.cvt.remesh`: a triangle mesh (the hand), an
implicit field (a torus) and a boolean combination of fields evaluated on the grid's rays
(a sphere minus a box), and compares triangle quality with marching cubes at about the
same vertex count.

    PYTHONPATH=src python examples/cvt_remesh.py [--seeds 2000] [--out cvt_out]
"""

import argparse
import os

import jax
import numpy as np

jax.config.update("jax_enable_x64", True)

import voxax  # noqa: E402
from voxax import cvt, fields, metrics  # noqa: E402


def describe(name, mesh, report=None):
    q = metrics.triangle_quality(mesh)
    mr = metrics.manifold_report(mesh)
    extra = f", {report['n_fragments']} samples, {report['time']['total']:.1f} s" if report else ""
    print(
        f"{name:>24}: {mesh.n_vertices:6d} vertices, chi {mr.euler_characteristic:4d}, "
        f"closed 2-manifold {mr.closed and mr.edge_manifold and mr.vertex_manifold}, "
        f"quality min {q.min():.3f} mean {q.mean():.3f}{extra}"
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, default=2000)
    ap.add_argument("--out", default="cvt_out")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)

    hand = voxax.data.hand()
    m, rep = cvt.remesh(hand, args.seeds, method="lloyd", steps=60)
    describe("hand (mesh)", m, rep)
    voxax.io.save(m, os.path.join(args.out, "hand_cvt.ply"))

    grid = voxax.Grid.cube(32, half_width=1.0)

    def torus(p):
        return fields.torus(p, 0.6, 0.25)

    m, rep = cvt.remesh(torus, args.seeds, grid=grid, method="lloyd", steps=60)
    describe("torus (field)", m, rep)
    voxax.io.save(m, os.path.join(args.out, "torus_cvt.ply"))
    for n in range(20, 80, 4):  # marching cubes with about as many vertices
        g = voxax.Grid.cube(n, half_width=1.0)
        iso = voxax.isosurface(np.asarray(torus(g.centers())), g, 0.0)
        if len(iso.vertices) >= m.n_vertices:
            break
    describe("torus (marching cubes)", voxax.Mesh(np.asarray(iso.vertices), np.asarray(iso.faces)))

    scene = cvt.CSG("difference", fields.sphere, lambda p: fields.box(p, 0.5, (0.6, 0.6, 0.6)))
    m, rep = cvt.remesh(scene, args.seeds, grid=voxax.Grid.cube(32, half_width=1.1), method="lloyd", steps=60)
    describe("sphere minus box (CSG)", m, rep)
    voxax.io.save(m, os.path.join(args.out, "csg_cvt.ply"))


if __name__ == "__main__":
    main()

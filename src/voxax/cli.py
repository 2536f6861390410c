"""The `voxax` command line."""

from __future__ import annotations

import argparse
import sys
import time


def _demo(args) -> int:
    import jax

    jax.config.update("jax_enable_x64", True)
    import numpy as np

    import voxax

    mesh = voxax.data.get(args.mesh)
    grid = voxax.Grid.cube(args.resolution)
    dtype = np.float32 if args.float32 else np.float64
    vertices = np.asarray(mesh.vertices, dtype=dtype)
    faces = np.asarray(mesh.faces)

    fn = jax.jit(lambda v, f: voxax.voxelize(v, f, grid))
    W = fn(vertices, faces).block_until_ready()  # compile + first run
    t0 = time.perf_counter()
    W = fn(vertices, faces).block_until_ready()
    elapsed = time.perf_counter() - t0

    volume_grid = float(np.asarray(W, dtype=np.float64).sum() * grid.voxel_volume)
    volume_exact = float(mesh.signed_volume())
    rel = abs(volume_grid - volume_exact) / max(abs(volume_exact), 1e-300)
    print(f"voxax {voxax.__version__} demo: mesh '{args.mesh}' ({len(vertices)} vertices, {len(faces)} faces)")
    print(f"  grid            {grid.shape} cells over [{grid.lower[0]}, {grid.upper[0]}]^3, {np.dtype(dtype).name}")
    print(f"  time            {elapsed * 1e3:.1f} ms per voxelization (jit-compiled, after warm-up)")
    print(f"  volume (grid)   {volume_grid:.12f}")
    print(f"  volume (exact)  {volume_exact:.12f}")
    print(f"  relative error  {rel:.2e}")
    print(f"  W range         [{float(W.min()):.4f}, {float(W.max()):.4f}]")
    voxax.plot.slices(W, grid, axis=None, count=4, title=f"voxax: '{args.mesh}' at {args.resolution}^3", path=args.output)
    print(f"  slices written  {args.output}")
    return 0


def _voxelize_cmd(args) -> int:
    import jax

    jax.config.update("jax_enable_x64", not args.float32)
    import numpy as np

    import voxax

    mesh = voxax.io.load(args.mesh) if args.mesh not in voxax.data.names() else voxax.data.get(args.mesh)
    if args.normalise:
        mesh = voxax.io.normalise(mesh)
    if mesh.dim == 3 and not voxax.io.is_watertight(mesh.vertices, mesh.faces):
        print("warning: the mesh is not closed; the result depends on the +z ray direction", file=sys.stderr)
    grid = voxax.Grid.cube(args.resolution, dim=mesh.dim) if not args.fit else voxax.Grid.around(mesh.vertices, args.resolution)
    dtype = np.float32 if args.float32 else np.float64
    W = np.asarray(voxax.voxelize(np.asarray(mesh.vertices, dtype), mesh.faces, grid))
    np.save(args.output, W)
    print(f"wrote {args.output}: shape {W.shape}, volume {W.sum() * grid.voxel_volume:.8g}, grid {grid}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="voxax", description="Exact differentiable voxelization for JAX.")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="voxelize a built-in mesh, check its volume and plot slices")
    demo.add_argument("--mesh", default="hand", help="a built-in mesh name (see voxax.data.names())")
    demo.add_argument("--resolution", "-n", type=int, default=128, help="cells per axis of the [-1, 1]^3 grid")
    demo.add_argument("--float32", action="store_true", help="use float32 instead of float64")
    demo.add_argument("--output", "-o", default="voxax-demo.png", help="PNG file for the slices")
    demo.set_defaults(func=_demo)

    vox = sub.add_parser("voxelize", help="voxelize a mesh file (or built-in name) into a .npy grid")
    vox.add_argument("mesh", help="a mesh file readable by trimesh, or a built-in mesh name")
    vox.add_argument("--resolution", "-n", type=int, default=128)
    vox.add_argument("--fit", action="store_true", help="fit the grid around the mesh instead of [-1, 1]^d")
    vox.add_argument("--normalise", action="store_true", help="centre and scale the mesh so max |v| = 0.8 first")
    vox.add_argument("--float32", action="store_true")
    vox.add_argument("--output", "-o", default="voxels.npy")
    vox.set_defaults(func=_voxelize_cmd)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())

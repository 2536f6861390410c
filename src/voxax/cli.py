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
    if args.normalize:
        mesh = voxax.io.normalize(mesh)
    if mesh.dim == 3 and not voxax.io.is_watertight(mesh.vertices, mesh.faces):
        print("warning: the mesh is not closed; the result depends on the +z ray direction", file=sys.stderr)
    grid = voxax.Grid.cube(args.resolution, dim=mesh.dim) if not args.fit else voxax.Grid.around(mesh.vertices, args.resolution)
    dtype = np.float32 if args.float32 else np.float64
    W = np.asarray(voxax.voxelize(np.asarray(mesh.vertices, dtype), mesh.faces, grid))
    np.save(args.output, W)
    print(f"wrote {args.output}: shape {W.shape}, volume {W.sum() * grid.voxel_volume:.8g}, grid {grid}")
    return 0


# -- applications ---------------------------------------------------------------------------


def _setup_jax(float32: bool):
    import jax

    jax.config.update("jax_enable_x64", not float32)


def _load_mesh(name: str):
    import os

    import voxax

    if os.path.exists(name):
        return voxax.io.load(name)
    try:
        return voxax.data.get(name)
    except ValueError:
        raise SystemExit(
            f"voxax: {name!r} is neither a mesh file nor a built-in mesh ({', '.join(voxax.data.names(3))})"
        ) from None


def _write_json(data, path) -> None:
    import json

    with open(path, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=2)


def _projections_before_after(mesh_a, mesh_b, grid, path, title):
    """Maximum of W along x, y and z for two meshes (e.g. before and after an optimization)."""
    import numpy as np

    import voxax
    from voxax.apps._common import pyplot

    plt = pyplot()
    Ws = [np.asarray(voxax.voxelize(m.vertices, m.faces, grid)) for m in (mesh_a, mesh_b)]
    vmax = max(max(float(W.max()), 1.0) for W in Ws)
    fig, axes = plt.subplots(2, 3, figsize=(10.5, 6.6), squeeze=False)
    im = None
    for r, (W, label) in enumerate(zip(Ws, ("before", "after"))):
        for axis in range(3):
            p, q = (a for a in range(3) if a != axis)
            ax = axes[r, axis]
            im = ax.imshow(W.max(axis=axis).T, origin="lower", cmap="magma", vmin=0.0, vmax=vmax,
                           extent=(grid.lower[p], grid.upper[p], grid.lower[q], grid.upper[q]),
                           interpolation="nearest")
            ax.set_title(f"{label}: max of W along {'xyz'[axis]} ({W.max():.3f})", fontsize=9)
            ax.set_xlabel("xyz"[p])
            ax.set_ylabel("xyz"[q])
    fig.colorbar(im, ax=axes.ravel().tolist(), shrink=0.8)
    fig.suptitle(title)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _resolve_cmd(args) -> int:
    import os

    _setup_jax(args.float32)
    import voxax
    from voxax import apps

    mesh = _load_mesh(args.mesh)
    os.makedirs(args.out, exist_ok=True)
    out, report = apps.resolve_self_intersections(
        mesh,
        resolution=args.resolution,
        eps=args.eps,
        arap_weight=args.arap_weight,
        learning_rate=args.learning_rate,
        max_steps=args.max_steps,
        normalize=not args.no_normalize,
        progress=not args.quiet,
    )
    print(report.summary())
    voxax.io.save(mesh, os.path.join(args.out, "input.ply"))
    voxax.io.save(out, os.path.join(args.out, "resolved.ply"))
    _write_json(report.to_dict(), os.path.join(args.out, "report.json"))
    if not args.no_figures:
        from voxax.apps._common import pyplot

        pyplot().close(report.plot_history(os.path.join(args.out, "history.png")))
        work = voxax.io.normalize(mesh) if not args.no_normalize else mesh
        after = voxax.data.Mesh((out.vertices - report.centre) * report.scale, out.faces)
        _projections_before_after(work, after, voxax.Grid.cube(args.resolution), os.path.join(args.out, "overlaps.png"),
                                  "largest winding number along each axis (above 1: overlaps)")
    print(f"wrote {args.out}/: input.ply, resolved.ply, report.json" + ("" if args.no_figures else ", history.png, overlaps.png"))
    return 0 if report.resolved else 1


def _bandsaw_cmd(args) -> int:
    import os

    _setup_jax(args.float32)
    import voxax
    from voxax import apps, fabricate

    mesh = _load_mesh(args.mesh)
    os.makedirs(args.out, exist_ok=True)
    out, report = apps.optimize_for_bandsaw(
        mesh,
        resolution=args.resolution,
        w=args.w,
        arap_weight=args.arap_weight,
        learning_rate=args.learning_rate,
        min_step=args.min_step if args.min_step > 0 else None,
        max_steps=args.max_steps,
        normalize=not args.no_normalize,
        progress=not args.quiet,
    )
    print(report.summary())
    voxax.io.save(mesh, os.path.join(args.out, "input.ply"))
    voxax.io.save(out, os.path.join(args.out, "optimized.ply"))
    data = report.to_dict()
    if not args.no_templates:
        before = fabricate.bandsaw_templates(mesh, os.path.join(args.out, "templates_input"), size_mm=args.size_mm)
        after = fabricate.bandsaw_templates(out, os.path.join(args.out, "templates_optimized"), size_mm=args.size_mm)
        data["exact_waste_fraction_input"] = before.waste_fraction
        data["exact_waste_fraction_optimized"] = after.waste_fraction
        print(f"  exact waste (cut solid - shape) / cut solid: input {before.waste_fraction:.1%}, "
              f"optimized {after.waste_fraction:.1%}")
    _write_json(data, os.path.join(args.out, "report.json"))
    if not args.no_figures:
        from voxax.apps._common import pyplot

        pyplot().close(report.plot_history(os.path.join(args.out, "history.png")))
    print(f"wrote {args.out}/")
    return 0


def _tile_cmd(args) -> int:
    import os

    _setup_jax(args.float32)
    import numpy as np

    import voxax
    from voxax import apps

    meshes = [_load_mesh(m) for m in args.meshes]
    os.makedirs(args.out, exist_ok=True)
    instances = args.instances if len(args.instances) > 1 else args.instances[0]
    placed, report = apps.optimize_tiling(
        meshes,
        instances=instances,
        resolution=args.resolution,
        arap_weight=args.arap_weight,
        learning_rate=args.learning_rate,
        max_steps=args.max_steps,
        min_step=args.min_step if args.min_step > 0 else None,
        deform=not args.rigid,
        init=args.init,
        seed=args.seed,
        progress=not args.quiet,
    )
    print(report.summary())
    voxax.io.save(voxax.data.Mesh.concatenate(*placed), os.path.join(args.out, "tiling.ply"))
    if args.separate:
        for b, m in enumerate(placed):
            voxax.io.save(m, os.path.join(args.out, f"instance_{b:02d}.ply"))
    _write_json(report.to_dict(), os.path.join(args.out, "report.json"))
    np.save(os.path.join(args.out, "cell.npy"), report.cell)
    if not args.no_figures:
        from voxax.apps._common import pyplot

        plt = pyplot()
        plt.close(report.plot_history(os.path.join(args.out, "history.png")))
        n = report.cell.shape[0]
        cell_grid = voxax.Grid((report.cell_lower,) * 3, (report.cell_upper,) * 3, (n, n, n))
        plt.close(voxax.plot.slices(report.cell, cell_grid, axis=2, count=4,
                                    title=f"periodic cell: {report.coverage_final:.1%} covered once",
                                    path=os.path.join(args.out, "cell.png")))
    print(f"wrote {args.out}/")
    return 0


def _add_common(p, resolution: int, learning_rate: float, arap_weight: float, max_steps: int, out: str):
    p.add_argument("--resolution", "-n", type=int, default=resolution, help=f"cells per axis of [-1, 1]^3 (default {resolution})")
    p.add_argument("--learning-rate", "--lr", type=float, default=learning_rate, help=f"Adam learning rate (default {learning_rate:g})")
    p.add_argument("--arap-weight", type=float, default=arap_weight, help=f"weight of the ARAP regulariser (default {arap_weight:g})")
    p.add_argument("--max-steps", type=int, default=max_steps, help=f"most optimization steps (default {max_steps})")
    p.add_argument("--out", "-o", default=out, help=f"output folder (default {out})")
    p.add_argument("--float32", action="store_true", help="optimize in float32 instead of float64")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")


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
    vox.add_argument("--normalize", action="store_true", help="centre and scale the mesh so max |v| = 0.8 first")
    vox.add_argument("--float32", action="store_true")
    vox.add_argument("--output", "-o", default="voxels.npy")
    vox.set_defaults(func=_voxelize_cmd)

    res = sub.add_parser(
        "resolve",
        help="remove self-intersections by an ARAP deformation (paper 4.2)",
        description="Remove self-intersections by an ARAP deformation (paper 4.2). Writes the input and the "
        "resolved mesh, report.json and figures; exits with status 1 if overlapping voxels remain.",
    )
    res.add_argument("mesh", help="a mesh file readable by trimesh, or a built-in mesh name (e.g. bent_bar)")
    _add_common(res, 128, 1e-2, 0.005, 2000, "voxax-resolve")
    res.add_argument("--eps", type=float, default=1e-3, help="voxels above 1 + eps count as overlapping")
    res.add_argument("--no-normalize", action="store_true", help="use the mesh as is (must lie in [-1, 1]^3)")
    res.set_defaults(func=_resolve_cmd)

    saw = sub.add_parser("bandsaw", help="deform a mesh for bandsaw cutting and write templates (paper 4.3)")
    saw.add_argument("mesh", help="a mesh file readable by trimesh, or a built-in mesh name (e.g. hand)")
    _add_common(saw, 128, 1e-3, 0.05, 1000, "voxax-bandsaw")
    saw.add_argument("--w", type=float, default=1000.0, help="mellowmax sharpness of the silhouettes")
    saw.add_argument("--min-step", type=float, default=5e-4, help="stop when no vertex moves more (0: never)")
    saw.add_argument("--size-mm", type=float, default=100.0, help="largest block side of the printed templates")
    saw.add_argument("--no-templates", action="store_true", help="skip the SVG templates and cut solids")
    saw.add_argument("--no-normalize", action="store_true", help="use the mesh as is (must lie in [-1, 1]^3)")
    saw.set_defaults(func=_bandsaw_cmd)

    tile = sub.add_parser("tile", help="pack copies of meshes into a periodic space-filling cell (paper 4.4)")
    tile.add_argument("meshes", nargs="+", help="mesh files or built-in mesh names (one or more)")
    _add_common(tile, 96, 1e-3, 0.005, 1000, "voxax-tile")  # the paper uses 192
    tile.add_argument("--instances", type=int, nargs="+", default=[27],
                      help="total instances, or one count per mesh (default 27)")
    tile.add_argument("--min-step", type=float, default=1e-3, help="stop when no vertex moves more (0: never)")
    tile.add_argument("--rigid", action="store_true", help="only rigid motions, no deformation")
    tile.add_argument("--init", choices=("random", "lattice"), default="random", help="initial placement")
    tile.add_argument("--seed", type=int, default=0, help="seed of the random placement")
    tile.add_argument("--separate", action="store_true", help="also write each instance to its own file")
    tile.set_defaults(func=_tile_cmd)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())

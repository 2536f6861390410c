"""The bodies of the `voxax` subcommands (the `run` of each entry of `voxax.cli.COMMANDS`)
and the pieces they share: loading meshes and grids, checking outputs, writing results.

`voxax.cli` imports this module only when a command runs, so that building the parser
(`voxax --help`, the documentation) imports nothing heavy.
"""

from __future__ import annotations

import contextlib
import os
import time
import warnings

from voxax.cli import UsageError, _warn

# -- shared pieces ----------------------------------------------------------------------------


def _setup_jax(float32: bool) -> None:
    import jax

    jax.config.update("jax_enable_x64", not float32)


def _load_mesh(name: str, dim: int | None = 3):
    """A mesh from a file, or a built-in mesh by name; `dim` (if given) is required."""
    import voxax

    if os.path.isdir(name):
        raise UsageError(f"{name!r} is a folder, not a mesh file")
    if os.path.exists(name):
        try:
            mesh = voxax.io.load(name)
        except Exception as err:  # trimesh raises many kinds for unreadable files
            raise UsageError(f"cannot read the mesh file {name!r}: {err}") from None
    elif os.sep in name or os.path.splitext(name)[1]:
        raise UsageError(f"no such mesh file: {name!r}")
    else:
        try:
            mesh = voxax.data.get(name)
        except (ValueError, KeyError):
            builtin = ", ".join(voxax.data.names(dim) if dim else voxax.data.names())
            raise UsageError(f"{name!r} is neither a mesh file nor a built-in mesh ({builtin})") from None
    if dim is not None and mesh.dim != dim:
        raise UsageError(f"{name!r} is a {mesh.dim}D mesh; this command needs a {dim}D triangle mesh")
    _note_unused_vertices(mesh)
    return mesh


def _note_unused_vertices(mesh) -> None:
    """Says when vertices that no face uses are left out of fits and bounds."""
    import numpy as np

    if mesh.n_faces:
        unused = mesh.n_vertices - len(np.unique(np.asarray(mesh.faces)))
        if unused:
            _warn(f"{unused} of the mesh's {mesh.n_vertices} vertices are used by no face; they are ignored "
                  "when fitting grids and bounds")


def _inside_out(mesh) -> float | None:
    """The enclosed volume of a closed 3D mesh whose faces point inwards, else None."""
    import voxax

    if mesh.dim != 3 or mesh.n_faces == 0 or not voxax.io.is_watertight(mesh.vertices, mesh.faces):
        return None
    volume = mesh.signed_volume()
    return volume if volume < 0 else None


def _flip_or_refuse(mesh, flip: bool, need_outward: bool):
    """`--flip` reverses every face; an inside-out closed mesh is refused (need_outward) or
    warned about (voxelize, whose negative values are then meaningful)."""
    import voxax

    if flip:
        mesh = voxax.Mesh(mesh.vertices, mesh.faces[:, ::-1], mesh.info)
    volume = _inside_out(mesh)
    if volume is not None:
        text = (f"the mesh is inside out: it is closed but encloses a negative volume ({volume:.6g}), so its faces "
                "point inwards")
        if need_outward:
            raise UsageError(f"{text}; pass --flip to reverse every face")
        _warn(f"{text}: its values are negative; pass --flip to reverse every face")
    return mesh


# Mesh formats the commands write (through trimesh).
_MESH_OUTPUTS = (".ply", ".obj", ".stl", ".off", ".glb")


def _check_output(path: str, suffixes: tuple[str, ...] = ()) -> None:
    """Refuses an output path early (before minutes of computing) if it cannot be written."""
    if suffixes and not path.lower().endswith(suffixes):
        raise UsageError(f"the output {path!r} must end in {' or '.join(suffixes)}")
    folder = os.path.dirname(os.path.abspath(path))
    if not os.path.isdir(folder):
        raise UsageError(f"the folder of the output {path!r} does not exist")


def _prepare_folder(path: str) -> None:
    if os.path.exists(path) and not os.path.isdir(path):
        raise UsageError(f"the output folder {path!r} is a file")
    os.makedirs(path, exist_ok=True)


def _start_app(args, meshes):
    """The set-up of the application commands: the output folder, JAX's precision, and the
    meshes read from the files `meshes`, outward-oriented (or flipped)."""
    _prepare_folder(args.out)
    _setup_jax(args.float32)
    return [_flip_or_refuse(_load_mesh(m), args.flip, need_outward=True) for m in meshes]


@contextlib.contextmanager
def _grid_check(mesh, normalize: bool):
    """With --no-normalize, warns in command-line words when the mesh leaves the
    [-1, 1]^3 grid, and keeps the library's own warning on this (worded for Python
    callers) quiet while the block runs."""
    with warnings.catch_warnings():
        outside = None if normalize else _outside(mesh.vertices, (-1.0,) * 3, (1.0,) * 3)
        if outside:
            _warn(f"{outside[1]}; what lies outside is not penalized; drop --no-normalize to scale the mesh "
                  "into the grid")
            warnings.filterwarnings("ignore", message=".*outside the grid", category=RuntimeWarning)
        yield


def _write_json(data, path) -> None:
    import json

    with open(path, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=2)


def _close(fig) -> None:
    import voxax

    voxax.plot.pyplot().close(fig)


def _optimization_options(args) -> dict:
    """The keyword arguments of the applications that `_add_optimization_options` adds."""
    return {"resolution": args.resolution, "arap_weight": args.arap_weight, "learning_rate": args.learning_rate,
            "max_steps": args.max_steps, "progress": not args.quiet}


# -- voxax demo -------------------------------------------------------------------------------


def _demo(args) -> int:
    _check_output(args.output)
    _setup_jax(False)
    import jax
    import numpy as np

    import voxax

    mesh = _load_mesh(args.mesh, dim=None)
    grid = voxax.Grid.cube(args.resolution, dim=mesh.dim)
    dtype = np.float32 if args.float32 else np.float64
    vertices = np.asarray(mesh.vertices, dtype=dtype)
    faces = np.asarray(mesh.faces)
    outside = _outside(vertices, grid.lower, grid.upper)
    if outside:
        _warn(f"{outside[1]}, so the volume from the grid counts only the part inside; "
              "use 'voxax voxelize --fit' for meshes of any size")

    fn = jax.jit(lambda v, f: voxax.voxelize(v, f, grid))
    W = fn(vertices, faces).block_until_ready()  # compile + first run
    t0 = time.perf_counter()
    W = fn(vertices, faces).block_until_ready()
    elapsed = time.perf_counter() - t0

    volume_grid = float(np.asarray(W, dtype=np.float64).sum() * grid.voxel_volume)
    volume_exact = float(mesh.signed_volume())
    rel = abs(volume_grid - volume_exact) / max(abs(volume_exact), 1e-300)
    d = mesh.dim
    print(f"voxax {voxax.__version__} demo: mesh '{args.mesh}' ({len(vertices)} vertices, {len(faces)} faces)")
    print(f"  grid            {grid.shape} cells over [{grid.lower[0]}, {grid.upper[0]}]^{d}, {np.dtype(dtype).name}")
    print(f"  time            {elapsed * 1e3:.1f} ms per voxelization (jit-compiled, after warm-up)")
    print(f"  volume (grid)   {volume_grid:.12f}")
    print(f"  volume (exact)  {volume_exact:.12f}")
    print(f"  relative error  {rel:.2e}")
    print(f"  W range         [{float(W.min()):.4f}, {float(W.max()):.4f}]")
    _close(voxax.plot.slices(W, grid, axis=None, count=4, title=f"voxax: '{args.mesh}' at {args.resolution}^{d}",
                             path=args.output))
    print(f"  slices written  {args.output}")
    return 0


# -- voxax voxelize ---------------------------------------------------------------------------


def _outside(vertices, lower, upper) -> tuple[bool, str] | None:
    """How the vertices' bounding box leaves the box `[lower, upper]`: (entirely outside?,
    a description), or None if it lies inside."""
    import numpy as np

    lo, hi = np.asarray(lower, np.float64), np.asarray(upper, np.float64)
    vmin, vmax = vertices.min(axis=0), vertices.max(axis=0)
    if np.all(vmin >= lo) and np.all(vmax <= hi):
        return None
    box = "[" + ", ".join(f"{a:.3g}..{b:.3g}" for a, b in zip(vmin, vmax)) + "]"
    where = "[" + ", ".join(f"{a:.3g}..{b:.3g}" for a, b in zip(lo, hi)) + "]"
    if np.any(vmax <= lo) or np.any(vmin >= hi):
        return True, f"the mesh (bounding box {box}) lies entirely outside the grid {where}"
    return False, f"parts of the mesh (bounding box {box}) lie outside the grid {where}"


def _voxelize(args) -> int:
    _check_output(args.output, (".npz", ".npy"))
    if args.fit and args.output.lower().endswith(".npy"):
        raise UsageError("--fit makes its own grid, which a .npy file cannot hold; write a .npz (W, lower, upper, "
                         "shape) instead")
    _setup_jax(args.float32)
    import numpy as np

    import voxax

    mesh = _flip_or_refuse(_load_mesh(args.mesh, dim=None), args.flip, need_outward=False)
    if args.normalize:
        mesh = voxax.io.normalize(mesh)
    if mesh.dim == 3 and not voxax.io.is_watertight(mesh.vertices, mesh.faces):
        _warn("the mesh is not closed; the result depends on the +z ray direction")
    dtype = np.float32 if args.float32 else np.float64
    vertices = np.asarray(mesh.vertices, dtype)
    if args.fit:
        grid = voxax.Grid.around(voxax.Mesh(vertices, mesh.faces), args.resolution)
    else:
        grid = voxax.Grid.cube(args.resolution, dim=mesh.dim)
        outside = _outside(vertices, grid.lower, grid.upper)
        if outside:
            whole, text = outside
            _warn(f"{text}{', so every voxel is 0' if whole else ' and are cut off'}; use --fit to fit the grid "
                  "around the mesh, or --normalize to scale the mesh into the grid")
    W = np.asarray(voxax.voxelize(vertices, mesh.faces, grid))
    if args.output.lower().endswith(".npy"):
        np.save(args.output, W)
    else:
        np.savez(args.output, W=W, lower=np.asarray(grid.lower, np.float64),
                 upper=np.asarray(grid.upper, np.float64), shape=np.asarray(grid.shape, np.int64))
    volume = float(np.sum(W, dtype=np.float64) * grid.voxel_volume)
    print(f"wrote {args.output}: W {W.shape} {W.dtype}, volume {volume:.8g}, grid {grid}")
    return 0


# -- voxax resolve ----------------------------------------------------------------------------


def _resolve(args) -> int:
    (mesh,) = _start_app(args, [args.mesh])
    import voxax
    from voxax import apps

    with _grid_check(mesh, not args.no_normalize):
        out, report = apps.resolve_self_intersections(
            mesh, eps=args.eps, normalize=not args.no_normalize, refine=not args.no_refine,
            max_rounds=args.max_rounds, round_steps=args.round_steps, time_budget=args.time_budget,
            keep_volume=not args.no_keep_volume, **_optimization_options(args)
        )
    print(report.summary())
    voxax.io.save(mesh, os.path.join(args.out, "input.ply"))
    voxax.io.save(out, os.path.join(args.out, "resolved.ply"))
    _write_json(report.to_dict(), os.path.join(args.out, "report.json"))
    if not args.no_figures:
        _close(report.plot_history(os.path.join(args.out, "history.png")))
        work = voxax.io.normalize(mesh) if not args.no_normalize else mesh
        after = voxax.Mesh((out.vertices - report.centre) * report.scale, out.faces)
        grid = voxax.Grid.cube(args.resolution)
        Ws = [voxax.voxelize(m.vertices, m.faces, grid) for m in (work, after)]
        _close(voxax.plot.projections(Ws, grid, labels=["before", "after"],
                                      title="largest winding number along each axis (above 1: overlaps)",
                                      path=os.path.join(args.out, "overlaps.png")))
    print(f"wrote {args.out}/: input.ply, resolved.ply, report.json"
          + ("" if args.no_figures else ", history.png, overlaps.png"))
    return 0 if report.resolved else 1


# -- voxax bandsaw ----------------------------------------------------------------------------


def _bandsaw(args) -> int:
    (mesh,) = _start_app(args, [args.mesh])
    import voxax
    from voxax import apps, fabricate

    with _grid_check(mesh, not args.no_normalize):
        out, report = apps.optimize_for_bandsaw(
            mesh, w=args.w, min_step=args.min_step or None, normalize=not args.no_normalize,
            **_optimization_options(args),
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
        _close(report.plot_history(os.path.join(args.out, "history.png")))
    print(f"wrote {args.out}/")
    return 0


# -- voxax tile -------------------------------------------------------------------------------


def _tile(args) -> int:
    meshes_given, counts = len(args.meshes), len(args.instances)
    if counts > 1 and counts != meshes_given:
        raise UsageError(f"--instances gives {counts} counts for {meshes_given} meshes (give one total or one per mesh)")
    if counts == 1 and args.instances[0] < meshes_given:
        raise UsageError(f"--instances {args.instances[0]} is fewer than the {meshes_given} meshes")
    meshes = _start_app(args, args.meshes)
    import numpy as np

    import voxax
    from voxax import apps

    instances = args.instances if counts > 1 else args.instances[0]
    placed, report = apps.optimize_tiling(
        meshes, instances=instances, min_step=args.min_step or None, deform=not args.rigid, init=args.init,
        key=args.seed, **_optimization_options(args),
    )
    print(report.summary())
    voxax.io.save(voxax.Mesh.concatenate(*placed), os.path.join(args.out, "tiling.ply"))
    if args.separate:
        for b, m in enumerate(placed):
            voxax.io.save(m, os.path.join(args.out, f"instance_{b:02d}.ply"))
    _write_json(report.to_dict(), os.path.join(args.out, "report.json"))
    np.save(os.path.join(args.out, "cell.npy"), report.cell)
    if not args.no_figures:
        _close(report.plot_history(os.path.join(args.out, "history.png")))
        n = report.cell.shape[0]
        cell_grid = voxax.Grid((report.cell_lower,) * 3, (report.cell_upper,) * 3, (n, n, n))
        crossing = f", {report.intersecting_instance_pairs} instance pairs intersect" if report.instances_intersect else ""
        _close(voxax.plot.slices(report.cell, cell_grid, axis=2, count=4,
                                 title=f"periodic cell: {report.coverage_final:.1%} covered once{crossing}",
                                 path=os.path.join(args.out, "cell.png")))
    print(f"wrote {args.out}/")
    if report.instances_intersect:
        _warn(f"the instances still intersect ({report.intersecting_instance_pairs} instance pairs by the exact "
              "triangle test): not a valid tiling; try a finer --resolution or more --max-steps")
        return 1
    return 0


# -- voxax mesh -------------------------------------------------------------------------------


def _read_grid(path: str):
    import numpy as np

    import voxax

    if os.path.isdir(path):
        raise UsageError(f"{path!r} is a folder, not a .npz grid")
    if not os.path.exists(path):
        raise UsageError(f"no such grid file: {path!r}")
    try:
        data = np.load(path)
    except (OSError, ValueError) as err:
        raise UsageError(f"cannot read {path!r} as a .npz grid: {err}") from None
    if not hasattr(data, "files") or not {"W", "lower", "upper", "shape"} <= set(data.files):
        raise UsageError(f"{path!r} must be a .npz with arrays W, lower, upper, shape (as 'voxax voxelize' writes)")
    W, shape = np.asarray(data["W"]), np.asarray(data["shape"])
    if W.dtype.kind != "f":
        raise UsageError(f"{path!r}: W must hold floats, got {W.dtype}")
    if shape.dtype.kind not in "iu" or shape.shape != (3,):
        raise UsageError(f"{path!r}: 'shape' must be 3 integers, got {shape.tolist()!r} ({shape.dtype})")
    if W.ndim != 3 or tuple(int(n) for n in shape) != W.shape:
        raise UsageError(f"{path!r}: W must be a 3D grid matching 'shape', got W {W.shape}")
    try:
        grid = voxax.Grid(lower=tuple(data["lower"].tolist()), upper=tuple(data["upper"].tolist()), shape=W.shape)
    except (TypeError, ValueError) as err:
        raise UsageError(f"{path!r}: not a valid grid: {err}") from None
    return W, grid


def _mesh(args) -> int:
    if (args.grid is None) == (args.sdf is None):
        raise UsageError("give either a grid file W.npz or --sdf NAME (exactly one)")
    _check_output(args.output, _MESH_OUTPUTS)
    _setup_jax(False)
    import numpy as np

    import voxax

    if args.sdf is None:
        W, grid = _read_grid(args.grid)
        if not np.all(np.isfinite(W)):
            raise UsageError(f"{args.grid!r}: W has NaN or Inf values")
        level = 0.5 if args.level is None else args.level
        with warnings.catch_warnings():  # an empty result is reported below, in command-line words
            warnings.filterwarnings("ignore", message=".*does not cross level")
            iso = voxax.isosurface(W, grid, level, inside="above", close=True)
    else:
        grid = voxax.Grid.cube(args.resolution)
        level = 0.0 if args.level is None else args.level
        values = getattr(voxax.fields, args.sdf)(grid.centers())
        iso = voxax.isosurface(np.asarray(values), grid, level, close=True)
    mesh = iso.to_mesh()
    if mesh.n_faces == 0:
        values = W if args.sdf is None else np.asarray(values)
        lo, hi = float(np.min(values)), float(np.max(values))
        hint = ""
        if args.sdf is None and hi < level and lo < -abs(level):
            hint = ("; the values are negative, as those of an inside-out mesh (faces pointing inwards): voxelize "
                    "it with --flip")
        raise UsageError(f"the level {level} does not cross the field (values in [{lo:.6g}, {hi:.6g}]): the mesh "
                         f"is empty{hint}")
    voxax.io.save(mesh, args.output)
    print(f"wrote {args.output}: {mesh.n_vertices} vertices, {mesh.n_faces} faces, "
          f"Euler characteristic {voxax.metrics.euler_characteristic(mesh)}, grid {grid}")
    return 0


def _fc(args) -> int:
    _check_output(args.output, _MESH_OUTPUTS)
    if args.report:
        _check_output(args.report, (".json",))
    mesh = _flip_or_refuse(_load_mesh(args.mesh, 3), args.flip, need_outward=True)
    import time

    import voxax

    anchors = "components" if args.components else args.anchors
    options = dict(lambda_d=args.lambda_d, anchors_per_cell=1 if anchors == "one" else anchors)
    grid = voxax.Grid.around(mesh, args.resolution)
    if args.report:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # said below, in command-line words
            out, rep = voxax.fc.roundtrip(mesh, grid=grid, progress=False, **options)
        topo, topo_in = rep.manifold, rep.input
        _write_json({"grid": {"lower": list(grid.lower), "upper": list(grid.upper), "shape": list(grid.shape)},
                     "tokens": rep.tokens, "encode_seconds": rep.encode_seconds,
                     "decode_seconds": rep.decode_seconds, "measure_seconds": rep.measure_seconds,
                     "hausdorff": rep.hausdorff, "chamfer_g2p": rep.chamfer_g2p, "f_score": rep.f_score,
                     "threshold": rep.threshold, "euler_characteristic": topo.euler_characteristic,
                     "boundary_loops": topo.n_boundary_loops, "boundary_edges": topo.n_boundary_edges,
                     "nonmanifold_edges": topo.n_nonmanifold_edges, "misoriented_edges": topo.n_misoriented_edges,
                     "components": topo.n_components, "closed": topo.closed, "oriented": topo.oriented,
                     "input_closed": topo_in.closed and topo_in.oriented}, args.report)
        tokens, seconds = rep.tokens, rep.encode_seconds + rep.decode_seconds
    else:
        t0 = time.perf_counter()
        tok = voxax.fc.encode(mesh, grid, **options)
        out = voxax.fc.decode(tok)
        tokens, seconds = len(tok), time.perf_counter() - t0
        topo, topo_in = voxax.fc.edge_topology(out), voxax.fc.edge_topology(mesh)
    if out.n_faces == 0:
        raise UsageError("the mesh has no surface inside the grid: nothing to write")
    voxax.io.save(out, args.output)
    print(f"wrote {args.output}: {out.n_vertices} vertices, {out.n_faces} faces from {tokens} tokens "
          f"on {grid.shape} in {seconds:.2f} s; {topo.n_nonmanifold_edges} non-manifold, "
          f"{topo.n_misoriented_edges} misoriented and {topo.n_boundary_edges} boundary edges, "
          f"Euler characteristic {topo.euler_characteristic}")
    if topo_in.closed and topo_in.oriented and not (topo.closed and topo.oriented):
        _warn("the input is a closed 2-manifold but the output is not"
              + (" (--anchors patches, the default, keeps it closed)" if anchors == "one" else ""))
    return 0


def _remesh(args) -> int:
    _check_output(args.output, _MESH_OUTPUTS)
    mesh = _flip_or_refuse(_load_mesh(args.mesh), args.flip, need_outward=True)
    _setup_jax(False)
    import voxax

    try:
        rep = voxax.cvt.remesh(mesh, args.seeds, alpha=args.alpha, method=args.method, steps=args.steps,
                               orient=not args.open)
    except ValueError as err:  # the API's option, named as this command's
        raise UsageError(str(err).replace("pass orient=False", "pass --open")) from None
    out = rep.mesh
    voxax.io.save(out, args.output)
    print(f"wrote {args.output}: {out.n_vertices} vertices, {out.n_faces} faces, "
          f"{'closed 2-manifold' if rep.closed and rep.manifold else 'NOT a closed 2-manifold'}, "
          f"Euler characteristic {rep.euler_characteristic}"
          + ("" if rep.source_euler_characteristic is None else f" (the input's {rep.source_euler_characteristic})")
          + f", triangle quality min {rep.quality_min:.3f} mean {rep.quality_mean:.3f}, {rep.n_fragments} surface "
          f"samples, {rep.time['total']:.1f} s")
    return 0 if rep.closed and rep.manifold else 1

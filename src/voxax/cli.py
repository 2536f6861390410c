"""The `voxax` command line.

Every subcommand is a [`Command`][voxax.cli.Command]: a name, a one-line help, a function
that adds its options to an `argparse` parser and a function that runs it. `COMMANDS`
lists them in the order `voxax --help` shows; adding a subcommand is adding an entry.

Mistakes in the input (a missing file, an unknown mesh name, an invalid option value,
an output the library refuses) end with one line on stderr, `voxax <command>: error:
...`, and exit status 2, never with a Python traceback (`voxax --traceback ...` shows
it). Building the parser imports nothing heavy, so `voxax --help` is instant and the
documentation can render the help without the compiled kernels.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import warnings
from collections.abc import Callable

__all__ = ["COMMANDS", "Command", "UsageError", "build_parser", "main"]


class UsageError(Exception):
    """A mistake in the command line or its input: reported in one line, exit status 2."""


@dataclasses.dataclass(frozen=True)
class Command:
    """One `voxax` subcommand.

    - `name`: the subcommand (`voxax <name> ...`).
    - `help`: one line for `voxax --help`.
    - `add_arguments`: `(parser) -> None`, adds the options (each with a `help=` text).
    - `run`: `(args) -> int`, runs the command on the parsed options; returns the exit
      status. Raises `UsageError` (or `ValueError`/`TypeError`/`OSError` from the
      library) for mistakes in the input.
    - `description`: a longer text for `voxax <name> --help` (default: `help`).
    """

    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]
    description: str | None = None


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line (raised, reported by `main`)."""

    def error(self, message):
        err = UsageError(f"{message} (see '{self.prog} --help')")
        err.prog = self.prog
        raise err


# -- option types: each check gives one clear line ------------------------------------------


def _integer(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def _resolution(multiple: int = 1, least: int = 1) -> Callable[[str], int]:
    least = max(least, multiple)

    def check(text: str) -> int:
        n = _integer(text)
        if n < least:
            raise argparse.ArgumentTypeError(f"the resolution must be at least {least}, got {n}")
        if n % multiple:
            raise argparse.ArgumentTypeError(f"the resolution must be a multiple of {multiple}, got {n}")
        return n

    check.__name__ = "resolution"
    return check


def _at_least(least: int) -> Callable[[str], int]:
    def check(text: str) -> int:
        n = _integer(text)
        if n < least:
            raise argparse.ArgumentTypeError(f"expected an integer >= {least}, got {n}")
        return n

    check.__name__ = "count"
    return check


def _positive(text: str) -> float:
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text}")
    return value


def _non_negative(text: str) -> float:
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text}")
    return value


# -- shared pieces ----------------------------------------------------------------------------


_prog = "voxax"  # the running command, in messages


def _warn(message: str) -> None:
    """One line on stderr: `voxax <command>: warning: <message>`."""
    print(f"{_prog}: warning: {' '.join(str(message).split())}", file=sys.stderr)


def _show_warning(message, category, filename, lineno, file=None, line=None) -> None:
    """Python warnings from the library, as one line each (installed by `main`)."""
    _warn(message)


def _add_optimization_options(p, resolution: int, learning_rate: float, arap_weight: float, max_steps: int,
                              out: str, multiple: int = 1) -> None:
    p.add_argument("--resolution", "-n", type=_resolution(multiple, least=2), default=resolution, metavar="N",
                   help=f"cells per axis of the [-1, 1]^3 grid (default {resolution}"
                   + (f"; a multiple of {multiple}" if multiple > 1 else "") + ")")
    p.add_argument("--learning-rate", "--lr", type=_positive, default=learning_rate, metavar="RATE",
                   help=f"Adam learning rate (default {learning_rate:g})")
    p.add_argument("--arap-weight", type=_non_negative, default=arap_weight, metavar="WEIGHT",
                   help=f"weight of the as-rigid-as-possible regularizer (default {arap_weight:g})")
    p.add_argument("--max-steps", type=_at_least(0), default=max_steps, metavar="STEPS",
                   help=f"most optimization steps (default {max_steps})")
    p.add_argument("--output", "--out", "-o", dest="out", default=out, metavar="FOLDER",
                   help=f"output folder (default {out})")
    p.add_argument("--float32", action="store_true", help="optimize in float32 instead of float64")
    p.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")


def _add_mesh_argument(p, example: str) -> None:
    p.add_argument("mesh", help=f"a mesh file readable by trimesh, or a built-in mesh name (e.g. {example})")
    _add_flip_option(p)


def _add_flip_option(p) -> None:
    p.add_argument("--flip", action="store_true",
                   help="reverse every face first (for an inside-out mesh, whose faces point inwards)")


# -- voxax demo -------------------------------------------------------------------------------


def _demo_arguments(p) -> None:
    p.add_argument("--mesh", default="hand", help="a built-in mesh name or a mesh file (default hand)")
    p.add_argument("--resolution", "-n", type=_resolution(), default=128, metavar="N",
                   help="cells per axis of the [-1, 1]^d grid (default 128)")
    p.add_argument("--float32", action="store_true", help="use float32 instead of float64")
    p.add_argument("--output", "-o", default="voxax-demo.png", metavar="PNG",
                   help="image file for the slices (default voxax-demo.png)")


# -- voxax voxelize ---------------------------------------------------------------------------


def _voxelize_arguments(p) -> None:
    p.add_argument("mesh", help="a mesh file readable by trimesh (3D), or a built-in mesh name (3D or 2D)")
    p.add_argument("--resolution", "-n", type=_resolution(), default=128, metavar="N",
                   help="cells per axis of [-1, 1]^d, or along the longest axis with --fit (default 128)")
    p.add_argument("--fit", action="store_true",
                   help="fit the grid around the mesh (cubic cells, 5%% margin) instead of [-1, 1]^d")
    p.add_argument("--normalize", action="store_true",
                   help="first centre the mesh and scale it so that its largest |coordinate| is 0.8")
    p.add_argument("--float32", action="store_true", help="voxelize in float32 instead of float64")
    _add_flip_option(p)
    p.add_argument("--output", "-o", default="voxels.npz", metavar="FILE",
                   help="output file: .npz with arrays W, lower, upper, shape (default voxels.npz), "
                   "or .npy with W alone (not with --fit, whose grid only a .npz keeps)")


# -- voxax resolve ----------------------------------------------------------------------------


def _resolve_arguments(p) -> None:
    _add_mesh_argument(p, "bent_bar")
    _add_optimization_options(p, 128, 1e-2, 0.005, 2000, "voxax-resolve")
    p.add_argument("--eps", type=_non_negative, default=1e-3,
                   help="voxels above 1 + EPS count as overlapping (default 0.001)")
    p.add_argument("--no-normalize", action="store_true", help="use the mesh as is (it must lie in [-1, 1]^3)")
    p.add_argument("--no-refine", action="store_true",
                   help="stop after the voxel stage: no exact check-and-refine rounds (faster; the result may "
                        "keep thin intersections below the voxel size)")
    p.add_argument("--max-rounds", type=_at_least(0), default=20,
                   help="refinement rounds on fine local grids at most (default 20)")
    p.add_argument("--round-steps", type=_at_least(1), default=200,
                   help="optimizer steps per refinement round (default 200)")
    p.add_argument("--time-budget", type=_positive, default=None, metavar="SECONDS",
                   help="stop refining after this many seconds (default: no limit)")
    p.add_argument("--no-keep-volume", action="store_true",
                   help="drop the volume term that keeps the enclosed volume close to the input's")


# -- voxax bandsaw ----------------------------------------------------------------------------


def _bandsaw_arguments(p) -> None:
    _add_mesh_argument(p, "hand")
    _add_optimization_options(p, 128, 1e-3, 0.05, 1000, "voxax-bandsaw")
    p.add_argument("--w", type=_positive, default=1000.0, help="mellowmax sharpness of the silhouettes (default 1000)")
    p.add_argument("--min-step", type=_non_negative, default=5e-4,
                   help="stop when no vertex moves more than this in a step; 0: never (default 0.0005)")
    p.add_argument("--size-mm", type=_positive, default=100.0,
                   help="largest block side of the printed templates, in mm (default 100)")
    p.add_argument("--no-templates", action="store_true", help="skip the SVG templates and cut solids")
    p.add_argument("--no-normalize", action="store_true", help="use the mesh as is (it must lie in [-1, 1]^3)")


# -- voxax tile -------------------------------------------------------------------------------


def _tile_arguments(p) -> None:
    p.add_argument("meshes", nargs="+", help="mesh files or built-in mesh names (one or more)")
    _add_optimization_options(p, 96, 1e-3, 0.005, 1000, "voxax-tile", multiple=3)  # the paper uses 192
    p.add_argument("--instances", type=_at_least(1), nargs="+", default=[27], metavar="COUNT",
                   help="total instances, or one count per mesh (default 27)")
    p.add_argument("--min-step", type=_non_negative, default=1e-3,
                   help="stop when no vertex moves more than this in a step; 0: never (default 0.001)")
    p.add_argument("--rigid", action="store_true", help="only rigid motions, no deformation")
    p.add_argument("--init", choices=("random", "lattice"), default="random",
                   help="initial placement: random (the paper's) or a lattice (default random)")
    p.add_argument("--seed", type=_integer, default=0, help="seed of the random placement (default 0)")
    p.add_argument("--separate", action="store_true", help="also write each instance to its own file")
    _add_flip_option(p)


# -- voxax mesh -------------------------------------------------------------------------------

_SDFS = ("sphere", "torus", "box", "gyroid", "chebyshev", "blob")


def _mesh_arguments(p) -> None:
    p.add_argument("grid", nargs="?", metavar="W.npz",
                   help="a grid written by 'voxax voxelize' (arrays W, lower, upper, shape); its 0.5 "
                   "level set (inside where W > 0.5) is extracted")
    p.add_argument("--sdf", choices=_SDFS, metavar="NAME",
                   help=f"instead of a grid file, mesh a built-in field on [-1, 1]^3: {', '.join(_SDFS)}")
    p.add_argument("--resolution", "-n", "-r", type=_resolution(least=2), default=64, metavar="N",
                   help="cells per axis for --sdf (default 64)")
    p.add_argument("--level", type=_number, default=None, metavar="X",
                   help="the iso-level (default 0.5 for a grid file, 0 for --sdf)")
    p.add_argument("--output", "-o", default="mesh.ply", metavar="FILE",
                   help="output mesh file, any format trimesh writes (.ply, .obj, .stl, ...; default mesh.ply)")


def _fc_arguments(p) -> None:
    _add_mesh_argument(p, "torus")
    p.add_argument("--resolution", "-n", "-r", type=_resolution(least=2), default=512, metavar="N",
                   help="cells along the longest side of a grid around the mesh (default 512)")
    p.add_argument("--anchors", choices=("patches", "one", "components"), default="patches",
                   help="anchors per cell: one per surface patch where several cross a cell (default; closed "
                        "meshes stay closed 2-manifolds), exactly one, or one per component of its pieces")
    p.add_argument("--components", action="store_true", help="the same as --anchors components")
    p.add_argument("--lambda-d", type=_positive, default=1e-3, metavar="X",
                   help="weight of the centroids in the anchors' QEF, in cell units (default 1e-3)")
    p.add_argument("--report", metavar="FILE.json", default=None,
                   help="also measure the result (Hausdorff, Chamfer, F-score, edge topology) and write it as JSON")
    p.add_argument("--output", "-o", default="fc.ply", metavar="FILE",
                   help="output mesh file, any format trimesh writes (default fc.ply)")


def _remesh_arguments(p) -> None:
    _add_mesh_argument(p, "hand")
    p.add_argument("--seeds", type=_at_least(4), default=20000, metavar="N",
                   help="number of seeds, about the number of output vertices (default 20000)")
    p.add_argument("--alpha", type=_positive, default=50.0, metavar="A",
                   help="surface samples per seed (default 50)")
    p.add_argument("--method", choices=("lbfgs", "lloyd"), default="lbfgs", help="the CVT optimiser (default lbfgs)")
    p.add_argument("--steps", type=_at_least(0), default=60, metavar="K", help="optimiser steps (default 60)")
    p.add_argument("--open", action="store_true",
                   help="mesh a surface that bounds no solid too (open, overlapping or inside-out parts), "
                        "without orienting it; the result is then not required to be a closed 2-manifold")
    p.add_argument("--output", "-o", default="remeshed.ply", metavar="FILE",
                   help="output mesh file, any format trimesh writes (default remeshed.ply)")


# -- the table of subcommands -----------------------------------------------------------------


def _run(name: str) -> Callable[[argparse.Namespace], int]:
    """The command body `name` of `voxax._cli_commands`, imported when the command runs (so
    that building the parser imports nothing heavy)."""

    def run(args: argparse.Namespace) -> int:
        from voxax import _cli_commands

        return getattr(_cli_commands, name)(args)

    run.__name__ = name
    return run


COMMANDS: list[Command] = [
    Command("demo", "voxelize a built-in mesh, check its volume and plot slices", _demo_arguments, _run("_demo")),
    Command("voxelize", "voxelize a mesh file (or built-in name) into a .npz (or .npy) grid",
            _voxelize_arguments, _run("_voxelize"),
            "Voxelize a mesh file (or a built-in mesh) on the grid [-1, 1]^d, or around the mesh with --fit. "
            "Writes W and the grid's corners and shape to a .npz file (W alone to a .npy file)."),
    Command("resolve", "remove self-intersections by an ARAP deformation (paper 4.2)", _resolve_arguments, _run("_resolve"),
            "Remove self-intersections by an ARAP deformation (paper 4.2). Writes the input and the resolved "
            "mesh, report.json and figures; exits with status 1 if overlapping voxels remain."),
    Command("bandsaw", "deform a mesh for bandsaw cutting and write templates (paper 4.3)",
            _bandsaw_arguments, _run("_bandsaw")),
    Command("tile", "pack copies of meshes into a periodic space-filling cell (paper 4.4)", _tile_arguments, _run("_tile")),
    Command("mesh", "extract a mesh from a voxelized grid (.npz) or a built-in field", _mesh_arguments, _run("_mesh"),
            "Extract a closed triangle mesh by marching cubes: the 0.5 level set of a grid written by "
            "'voxax voxelize' (inside where W > 0.5), or the zero level set of a built-in field (--sdf) "
            "sampled on [-1, 1]^3."),
    Command("fc", "Faithful Contouring: encode a mesh into sparse surface tokens and decode it", _fc_arguments, _run("_fc"),
            "Encode a mesh file (or built-in mesh) into Faithful Contour Tokens on a grid around it and decode "
            "them by dual contouring: no signed distance field, open and non-manifold surfaces and sharp edges "
            "kept. Writes the decoded mesh; --report also writes Hausdorff, Chamfer and F-score as JSON."),
    Command("remesh", "remesh a closed mesh with quality triangles (centroidal Voronoi)", _remesh_arguments, _run("_remesh"),
            "Remesh a closed triangle mesh (a file or a built-in mesh) into about --seeds vertices with "
            "well-shaped triangles: surface samples on grid lines, a restricted centroidal Voronoi "
            "tessellation, and its Delaunay triangulation. Exits with status 1 if the result is not a "
            "closed 2-manifold."),
]


def build_parser(commands: list[Command] | None = None) -> argparse.ArgumentParser:
    """The `voxax` argument parser with one subparser per entry of `commands` (default
    `COMMANDS`); each subparser's `run` default is the command's `run`."""
    parser = _Parser(prog="voxax", description="Exact differentiable voxelization for JAX.")
    parser.add_argument("--traceback", action="store_true",
                        help="on an error, show the Python traceback instead of a one-line message")
    parser.add_argument("--version", action="store_true",
                        help="print the version and exit (with --verbose: the build, the kernel library, the vector "
                             "paths and thread count this machine uses, the jax versions; voxax.show_config())")
    parser.add_argument("--verbose", "-v", action="store_true", help="with --version: the full configuration")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True,
                                help="the command to run (see 'voxax COMMAND --help')")
    for command in COMMANDS if commands is None else commands:
        p = sub.add_parser(command.name, help=command.help, description=command.description or command.help)
        command.add_arguments(p)
        p.set_defaults(run=command.run)
    return parser


def _one_line(err: BaseException) -> str:
    if isinstance(err, OSError) and err.strerror:
        return f"{err.strerror}: {err.filename!r}" if err.filename else err.strerror
    text = " ".join(str(err).split()) or type(err).__name__
    return text if isinstance(err, (UsageError, ValueError)) else f"{type(err).__name__}: {text}"


def _version(verbose: bool) -> int:
    import voxax

    if verbose:
        voxax.show_config()
    else:
        print(f"voxax {voxax.__version__}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Runs `voxax` with `argv` (default `sys.argv[1:]`) and returns the exit status:
    0 on success, 1 when a command reports failure (e.g. overlaps remain), 2 for a
    mistake in the input (after a one-line message on stderr), 130 on Ctrl-C."""
    global _prog
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    _prog = "voxax"
    command_at = next((i for i, a in enumerate(argv) if not a.startswith("-")), len(argv))
    show_traceback = "--traceback" in argv[:command_at]  # an option of `voxax` itself
    if "--version" in argv[:command_at]:  # no command needed
        return _version(verbose=bool({"--verbose", "-v"} & set(argv[:command_at])))
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            args, extra = parser.parse_known_args(argv)
            _prog = f"voxax {args.command}"
            if extra:
                raise UsageError(f"unrecognized arguments: {' '.join(extra)} (see '{_prog} --help')")
            return int(args.run(args))
    except (UsageError, ValueError, TypeError, OSError, MemoryError) as err:
        if show_traceback:
            raise
        print(f"{getattr(err, 'prog', _prog)}: error: {_one_line(err)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{_prog}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # `python -m voxax.cli`: the commands share the module voxax.cli
    from voxax.cli import main as _main

    sys.exit(_main())

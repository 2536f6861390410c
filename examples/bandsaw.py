"""Deform a mesh so that a bandsaw can cut it, and write the cutting templates.

The paper's section 4.3: cutting a block along the silhouettes seen from x, y and z leaves
the *cut shape* `S = Sx * Sy * Sz`, usually much more than the shape itself. Minimizing
`E_cut = mean((S - W)^2) + 0.05 * ARAP` (silhouettes by mellowmax with w = 1000) finds a
small deformation that makes the shape more cuttable, for instance straightening fingers.
`voxax.fabricate` then turns the shapes into printable SVG templates and exact cut solids.

    python examples/bandsaw.py                      # the built-in hand at 64^3 (seconds)
    python examples/bandsaw.py --resolution 128     # the paper's resolution
    python examples/bandsaw.py my_mesh.obj

Writes `input.ply`, `optimized.ply`, `history.png`, `silhouettes.png` and the folders
`templates_input/` and `templates_optimized/` (three SVG templates, the cut solid and a
report each) to `--out`.
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
import voxax.fabricate  # noqa: E402


def plot_silhouettes(before, after, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    for sil, style, label in ((before, "k--", "input"), (after, "C3-", "optimized")):
        for axis, ax in enumerate(axes):
            for i, poly in enumerate(sil[axis]):
                closed = np.vstack([poly, poly[:1]])
                ax.plot(closed[:, 0], closed[:, 1], style, lw=1.2, label=label if i == 0 else None)
    for axis, ax in enumerate(axes):
        p, q = voxax.fabricate.PLANE_AXES[axis]
        ax.set_aspect("equal")
        ax.set_title(f"silhouette along {'xyz'[axis]} (view from {voxax.fabricate.VIEWS[axis]})", fontsize=9)
        ax.set_xlabel("xyz"[p])
        ax.set_ylabel("xyz"[q])
    axes[0].legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh", nargs="?", default="hand", help="a mesh file or a built-in mesh name")
    parser.add_argument("--resolution", "-n", type=int, default=64, help="cells per axis (paper: 128)")
    parser.add_argument("--max-steps", type=int, default=1000)
    parser.add_argument("--size-mm", type=float, default=100.0, help="largest block side on the templates")
    parser.add_argument("--out", "-o", default="out-bandsaw", help="output folder")
    parser.add_argument("--quiet", "-q", action="store_true", help="no progress bar")
    args = parser.parse_args(argv)

    mesh = voxax.data.get(args.mesh) if args.mesh in voxax.data.names() else voxax.io.load(args.mesh)
    # Paper defaults: w = 1000, ARAP weight 0.05, Adam with learning rate 1e-3, stop when
    # no vertex moves more than 5e-4 in a step.
    optimized, report = voxax.apps.optimize_for_bandsaw(
        mesh, resolution=args.resolution, max_steps=args.max_steps, progress=not args.quiet
    )
    print(report.summary())
    print(f"relative improvement of the cut energy: {report.relative_improvement:.1%}")

    # Exact templates and cut solids, before and after.
    os.makedirs(args.out, exist_ok=True)
    before = voxax.fabricate.bandsaw_templates(mesh, os.path.join(args.out, "templates_input"), size_mm=args.size_mm)
    after = voxax.fabricate.bandsaw_templates(
        optimized, os.path.join(args.out, "templates_optimized"), size_mm=args.size_mm
    )
    for label, t in (("input", before), ("optimized", after)):
        print(f"{label:>10}: shape volume {t.volume_shape:.4f}, cut solid {t.volume_cut:.4f}, "
              f"waste {t.waste_volume:.4f} ({t.waste_fraction:.1%} of the cut solid)")

    voxax.io.save(mesh, os.path.join(args.out, "input.ply"))
    voxax.io.save(optimized, os.path.join(args.out, "optimized.ply"))
    plot_silhouettes(before.silhouettes, after.silhouettes, os.path.join(args.out, "silhouettes.png"))
    import matplotlib.pyplot as plt

    plt.close(report.plot_history(os.path.join(args.out, "history.png")))
    print(f"wrote {args.out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())

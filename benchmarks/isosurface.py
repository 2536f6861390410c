"""Marching cubes: voxax against scikit-image and PyMCubes, in one run, on the same fields.

Cases (float32 samples on n^3 grids over [-1, 1]^3):

- `sphere`: the distance field |x| - 0.6, level 0;
- `large`: `voxelize(data.large())` (about 100K faces), level 0.5 (`inside="above"`).

Timed at equal threads: scikit-image and PyMCubes run on one thread, so voxax runs with
`threads=1`; every repeat times each method once, in turn (interleaved), after one warm-up
call each, and the table gives medians. A separately labelled column gives voxax on all
cores (`threads=None`). The load average is recorded before and after.

- `voxax kernel`: the C++ topology (count + fill passes; exact-size arrays);
- `voxax isosurface`: the full eager `voxax.isosurface` (kernel, then the float64 vertex
  interpolation in JAX, blocked until ready);
- `skimage`: `skimage.measure.marching_cubes(..., allow_degenerate=False)` (Lewiner);
- `pymcubes`: `mcubes.marching_cubes`.

Before timing, the vertex counts of all three are printed (they agree up to the handling of
ambiguous cubes). Ratios are `time(other) / time(voxax isosurface, 1 thread)`.

Usage:

```bash
PYTHONPATH=src python benchmarks/isosurface.py --sizes 256 512 [--write-readme]
```

`--write-readme` replaces the section between the iso-surface markers in
`benchmarks/README.md`. 1024^3 is not run by default: its float32 input alone is 4 GiB and
scikit-image needs several times that.
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import sys
import time
from pathlib import Path

import numpy as np


def interleaved(fns: dict, repeats: int) -> dict:
    """Median seconds of each function: one warm-up call each, then `repeats` rounds that
    call every function once, in turn."""
    for fn in fns.values():
        fn()
    times = {k: [] for k in fns}
    for _ in range(repeats):
        for k, fn in fns.items():
            t = time.perf_counter()
            fn()
            times[k].append(time.perf_counter() - t)
    return {k: float(np.median(v)) for k, v in times.items()}


def load() -> str:
    return "/".join(f"{x:.1f}" for x in os.getloadavg())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    ap.add_argument(
        "--cases", nargs="+", default=["sphere", "large"], choices=["sphere", "large"]
    )
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write-readme", action="store_true")
    args = ap.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    import mcubes
    import skimage
    from skimage.measure import marching_cubes

    import voxax
    from voxax._kernels.contour import topology as host_topology

    rows = []
    load_before = load()
    for n in args.sizes:
        grid = voxax.Grid.cube(n)
        for case in args.cases:
            if case == "sphere":
                axes = [np.float32(-1 + (i + 0.5) * 2 / n) for i in range(n)]
                x = np.asarray(axes, np.float32)
                f = np.sqrt(
                    x[:, None, None] ** 2
                    + x[None, :, None] ** 2
                    + x[None, None, :] ** 2
                ) - np.float32(0.6)
                level, inside = 0.0, "below"
            else:
                mesh = voxax.data.large()
                f = np.asarray(
                    voxax.voxelize(mesh.vertices.astype(np.float32), mesh.faces, grid)
                )
                level, inside = 0.5, "above"
            f = np.array(
                f, np.float32, order="C", copy=True
            )  # writeable: scikit-image needs it
            e, fc = host_topology(f, level)
            v_sk, f_sk, _, _ = marching_cubes(f, level, allow_degenerate=False)
            v_mc, f_mc = mcubes.marching_cubes(f, level)
            print(
                f"{case} {n}^3: vertices voxax {len(e)}, skimage {len(v_sk)}, pymcubes {len(v_mc)}; "
                f"faces voxax {len(fc)}, skimage {len(f_sk)}, pymcubes {len(f_mc)}",
                flush=True,
            )
            del v_sk, f_sk, v_mc, f_mc
            times = interleaved(
                {
                    "kernel": lambda f=f, level=level: host_topology(f, level, 1),
                    "iso": lambda f=f, grid=grid, level=level, inside=inside: voxax.isosurface(
                        f, grid, level, inside=inside, threads=1
                    ).vertices.block_until_ready(),
                    "iso_all": lambda f=f, grid=grid, level=level, inside=inside: voxax.isosurface(
                        f, grid, level, inside=inside
                    ).vertices.block_until_ready(),
                    "skimage": lambda f=f, level=level: marching_cubes(f, level, allow_degenerate=False),
                    "pymcubes": lambda f=f, level=level: mcubes.marching_cubes(f, level),
                },
                args.repeats,
            )
            row = {"case": case, "n": n, "faces": len(fc), **times}
            rows.append(row)
            print(
                f"  kernel {times['kernel']:.3f} s, isosurface {times['iso']:.3f} s (all cores "
                f"{times['iso_all']:.3f} s), skimage {times['skimage']:.3f} s "
                f"({times['skimage'] / times['iso']:.2f}x), pymcubes {times['pymcubes']:.3f} s "
                f"({times['pymcubes'] / times['iso']:.2f}x); load {load()}",
                flush=True,
            )
            del f
    table = [
        "| case | grid | faces | voxax kernel, 1 thread | voxax isosurface, 1 thread | skimage / voxax "
        "(1 thread each) | PyMCubes / voxax (1 thread each) | skimage / kernel | voxax isosurface, "
        f"all {os.cpu_count()} cores (separate) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        table.append(
            f"| {r['case']} | {r['n']}^3 | {r['faces']} | {r['kernel']:.3f} s | {r['iso']:.3f} s | "
            f"{r['skimage'] / r['iso']:.2f}x | {r['pymcubes'] / r['iso']:.2f}x | "
            f"{r['skimage'] / r['kernel']:.2f}x | {r['iso_all']:.3f} s |"
        )
    machine = (
        f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
        f"scikit-image {skimage.__version__}, PyMCubes {getattr(mcubes, '__version__', '?')}"
    )
    text = "\n".join(table)
    print(text)
    if args.write_readme:
        readme = Path(__file__).with_name("README.md")
        start, end = (
            "<!-- isosurface-results:start -->",
            "<!-- isosurface-results:end -->",
        )
        cmd = "python benchmarks/isosurface.py " + " ".join(
            argv if argv is not None else sys.argv[1:]
        )
        body = (
            f"{start}\n\nMachine: {machine}. Command: `{cmd}`. Medians of {args.repeats} interleaved "
            f"repeats; load average (1/5/15 min) {load_before} before, {load()} after.\n\n{text}\n\n{end}"
        )
        old = readme.read_text()
        if start in old:
            new = re.sub(
                re.escape(start) + ".*?" + re.escape(end),
                lambda _: body,
                old,
                flags=re.DOTALL,
            )
        else:
            new = (
                old.rstrip()
                + "\n\n## Marching cubes: voxax vs scikit-image and PyMCubes\n\n"
                + (
                    "`isosurface.py` times `voxax.isosurface` (and its C++ kernel alone) against "
                    "`skimage.measure.marching_cubes` and `mcubes.marching_cubes` on float32 fields; "
                    "see its docstring for the cases.\n\n" + body + "\n"
                )
            )
        readme.write_text(new)


if __name__ == "__main__":
    main()

"""A short check of an installed voxax (a wheel), run from outside the source tree.

Imports the installed package (not the checkout's src/), prints `voxax.show_config()`,
voxelizes a torus under `jax.jit` and compares the volume from the grid with the mesh's
exact volume, and the gradient of that volume (`jax.grad` through the kernels) with the
closed-form gradient of a mesh's volume. Exits with status 1 on a failure. Run by
`.ci/run` and by cibuildwheel's test command (pyproject.toml).

    python tools/smoke_test.py
"""

from __future__ import annotations

import sys
import time
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def check(ok: bool, message: str) -> None:
    if not ok:
        print(f"smoke test FAILED: {message}", file=sys.stderr)
        sys.exit(1)


def main() -> None:
    started = time.perf_counter()
    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import numpy as np

    import voxax

    package = Path(voxax.__file__).resolve().parent
    check(not package.is_relative_to(ROOT / "src"), f"voxax was imported from the source tree ({package})")
    installed = metadata.version("voxax")
    check(voxax.__version__ == installed, f"voxax.__version__ {voxax.__version__!r} is not the installed {installed!r}")
    voxax.show_config()

    mesh = voxax.data.torus()
    vertices, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    grid = voxax.Grid.around(vertices, 24, pad=0.1)
    volume = jax.jit(lambda v: jnp.sum(voxax.voxelize(v, faces, grid)) * grid.voxel_volume)
    got = float(volume(vertices))
    exact = float(mesh.signed_volume())
    check(abs(got - exact) <= 1e-9 * abs(exact), f"volume from the grid {got!r} != exact volume {exact!r}")

    # d(volume)/d(vertex a) of a closed mesh: the sum over its faces (a, b, c) of (b x c) / 6.
    expected = np.zeros_like(vertices)
    for a, b, c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        np.add.at(expected, faces[:, a], np.cross(vertices[faces[:, b]], vertices[faces[:, c]]) / 6)
    grad = np.asarray(jax.jit(jax.grad(volume))(vertices))
    error = np.abs(grad - expected).max()
    check(error <= 1e-9 * np.abs(expected).max(), f"the volume gradient is off by {error:.3e}")
    print(f"smoke test passed: volume {got:.12f} (exact {exact:.12f}), gradient error {error:.2e}, "
          f"{time.perf_counter() - started:.1f} s")


if __name__ == "__main__":
    main()

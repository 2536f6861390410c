"""Fit a deformable template mesh to a target voxelization: Levenberg-Marquardt vs Adam.

A sphere (icosphere) is deformed until its voxelization matches that of a target shape
(an ellipsoid, by default). Each vertex moves along its template normal by an offset
`s_i` (`--param normal`, the default) or freely in 3D (`--param free`). The residuals are
the voxel differences plus a small umbrella-Laplacian term that keeps the surface smooth:

    r(s) = ( voxelize(v0 + s n0) - W_target ,  sqrt(lam) * L s )

Levenberg-Marquardt (`voxax.least_squares`, optimistix) linearizes r, which needs
forward-mode derivatives of `voxelize`; Adam (optax) only uses the gradient of
0.5 * |r|^2. The script reports how many steps, and how much time, each needs to reach
the same residual, with and without compilation.

Normal offsets are the better-posed problem: a voxelization does not change to first
order when vertices slide along the surface, so free 3D offsets leave a third of the
parameters to the smoothness term alone, and Levenberg-Marquardt then creeps along those
directions for many steps instead of meeting its tolerances.

    python examples/fit_template_lm.py                 # 24^3 grid, icosphere(2)
    python examples/fit_template_lm.py -n 32 --target box
    python examples/fit_template_lm.py --param free --linear-solver cholesky
"""

from __future__ import annotations

import argparse
import sys
import time

import jax

jax.config.update("jax_enable_x64", True)

import jax.numpy as jnp  # noqa: E402
import lineax as lx  # noqa: E402
import numpy as np  # noqa: E402
import optax  # noqa: E402

import voxax  # noqa: E402


def umbrella(faces: np.ndarray, n: int) -> jnp.ndarray:
    """The umbrella Laplacian L = I - D^-1 A of the mesh's edge graph, as a dense matrix."""
    A = np.zeros((n, n))
    for a, b in ((0, 1), (1, 2), (2, 0)):
        A[faces[:, a], faces[:, b]] = 1.0
        A[faces[:, b], faces[:, a]] = 1.0
    return jnp.asarray(np.eye(n) - A / A.sum(axis=1, keepdims=True))


def target_mesh(name: str) -> voxax.Mesh:
    if name == "box":
        return voxax.data.box((-0.55, -0.4, -0.3), (0.5, 0.45, 0.35))
    if name == "ellipsoid":
        m = voxax.data.icosphere(3)
        return voxax.Mesh(m.vertices * np.array([0.7, 0.5, 0.35]), m.faces)
    raise ValueError(f"unknown target {name!r}")


def problem(resolution: int, subdivisions: int, target: str, lam: float, param: str = "normal"):
    """The residual function `r(y, args)`, the initial parameters and the grid."""
    if param not in ("normal", "free"):
        raise ValueError(f"unknown parametrization {param!r}")
    grid = voxax.Grid.cube(resolution)
    tmpl = voxax.data.icosphere(subdivisions, radius=0.5)
    tgt = target_mesh(target)
    W_target = voxax.voxelize(tgt.vertices, tgt.faces, grid)
    v0 = jnp.asarray(tmpl.vertices)
    n0 = v0 / jnp.linalg.norm(v0, axis=1, keepdims=True)  # the sphere's vertex normals
    faces = jnp.asarray(tmpl.faces)
    L = umbrella(np.asarray(tmpl.faces), tmpl.n_vertices)
    scale = float(np.sqrt(lam))

    def residuals(y, args):
        d = y[:, None] * n0 if param == "normal" else y
        W = voxax.voxelize(v0 + d, faces, grid)
        return (W - W_target, scale * (L @ y))

    y0 = jnp.zeros(tmpl.n_vertices) if param == "normal" else jnp.zeros_like(v0)
    return residuals, y0, grid


def loss_of(residuals, d) -> float:
    return 0.5 * sum(float(jnp.sum(r**2)) for r in residuals(d, None))


def run_adam(residuals, y0, target_loss: float, lr: float, max_steps: int):
    """Adam until the loss reaches `target_loss`: (steps, seconds warm, seconds with
    compilation, final loss)."""
    opt = optax.adam(lr)
    value_and_grad = jax.value_and_grad(lambda y: 0.5 * sum(jnp.sum(r**2) for r in residuals(y, None)))

    @jax.jit
    def step(y, state):
        loss, g = value_and_grad(y)
        updates, state = opt.update(g, state, y)
        return optax.apply_updates(y, updates), state, loss

    t0 = time.perf_counter()
    jax.block_until_ready(step(y0, opt.init(y0)))  # compilation
    compile_seconds = time.perf_counter() - t0
    y, state = y0, opt.init(y0)
    t0 = time.perf_counter()
    for k in range(1, max_steps + 1):
        y_next, state, loss = step(y, state)  # `loss` is the loss at `y`
        if float(loss) <= target_loss:
            seconds = time.perf_counter() - t0
            return k - 1, seconds, seconds + compile_seconds, float(loss)
        y = y_next
    seconds = time.perf_counter() - t0
    return max_steps, seconds, seconds + compile_seconds, loss_of(residuals, y)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", "-n", type=int, default=24, help="cells per axis of [-1, 1]^3")
    parser.add_argument("--subdivisions", type=int, default=2, help="icosphere subdivisions of the template")
    parser.add_argument("--target", default="ellipsoid", choices=["ellipsoid", "box"])
    parser.add_argument("--param", default="normal", choices=["normal", "free"],
                        help="offsets along the template normals (one per vertex) or free 3D offsets")
    parser.add_argument("--lam", type=float, default=1e-2, help="weight of the smoothness residuals")
    parser.add_argument("--lm-steps", type=int, default=60)
    parser.add_argument("--adam-steps", type=int, default=3000)
    parser.add_argument("--lr", type=float, default=1e-2, help="Adam's learning rate")
    parser.add_argument("--linear-solver", default="cg", choices=["cg", "cholesky"],
                        help="LM's linear solves: matrix-free CG on the normal equations (voxax's default) or a "
                             "dense Cholesky of J^T J (one JVP and one VJP per parameter and step)")
    args = parser.parse_args(argv)

    residuals, y0, grid = problem(args.resolution, args.subdivisions, args.target, args.lam, args.param)
    initial = loss_of(residuals, y0)
    print(f"template: {args.param} offsets, {y0.size} parameters; grid {grid.shape}; initial loss {initial:.6g}")

    linear_solver = lx.Normal(lx.Cholesky()) if args.linear_solver == "cholesky" else None
    solve = lambda: voxax.least_squares(residuals, y0, solver="levenberg_marquardt", rtol=1e-4,  # noqa: E731
                                        atol=1e-6, max_steps=args.lm_steps, linear_solver=linear_solver)
    cold = solve()
    lm = solve()  # the same solve again, compiled
    state = "converged" if lm.converged else f"did not converge: {lm.message}"
    print(f"Levenberg-Marquardt ({args.linear_solver}): loss {lm.loss:.6g} after {lm.steps} steps, {state}; "
          f"{lm.seconds:.2f} s ({cold.seconds:.2f} s with compilation)")
    target_loss = lm.loss * 1.01
    steps, warm, with_compile, loss = run_adam(residuals, y0, target_loss, args.lr, args.adam_steps)
    reached = loss <= target_loss
    print(f"Adam (lr {args.lr}): loss {loss:.6g} after {steps} steps, {warm:.2f} s ({with_compile:.2f} s with "
          f"compilation); {'reached' if reached else 'did not reach'} 1.01 x the Levenberg-Marquardt loss")
    print(f"steps: Adam / Levenberg-Marquardt = {steps / max(lm.steps, 1):.3g}; "
          f"time (compiled): Adam / Levenberg-Marquardt = {warm / max(lm.seconds, 1e-9):.3g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

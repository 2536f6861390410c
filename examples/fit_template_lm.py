"""Fit a deformable template mesh to a target voxelization: Levenberg-Marquardt vs Adam.

A sphere (icosphere) is deformed, vertex by vertex, until its voxelization matches that of
a target shape (an ellipsoid, by default). The residuals are the voxel differences plus a
small umbrella-Laplacian term that keeps the surface smooth:

    r(d) = ( voxelize(v0 + d) - W_target ,  sqrt(lam) * L d )

Levenberg-Marquardt (`voxax.least_squares`, optimistix) uses the Jacobian of r, which
needs forward-mode derivatives of `voxelize`; Adam (optax) only uses the gradient of
0.5 * |r|^2. The script reports how many steps, and how much time, each needs to reach
the same residual.

    python examples/fit_template_lm.py                 # 24^3 grid, icosphere(2)
    python examples/fit_template_lm.py -n 32 --target box
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


def problem(resolution: int, subdivisions: int, target: str, lam: float):
    grid = voxax.Grid.cube(resolution)
    tmpl = voxax.data.icosphere(subdivisions, radius=0.5)
    tgt = target_mesh(target)
    W_target = voxax.voxelize(tgt.vertices, tgt.faces, grid)
    v0 = jnp.asarray(tmpl.vertices)
    faces = jnp.asarray(tmpl.faces)
    L = umbrella(np.asarray(tmpl.faces), tmpl.n_vertices)
    scale = float(np.sqrt(lam))

    def residuals(d, args):
        W = voxax.voxelize(v0 + d, faces, grid)
        return (W - W_target, scale * (L @ d))

    return residuals, jnp.zeros_like(v0), grid


def loss_of(residuals, d) -> float:
    return 0.5 * sum(float(jnp.sum(r**2)) for r in residuals(d, None))


def run_adam(residuals, d0, target_loss: float, lr: float, max_steps: int):
    opt = optax.adam(lr)
    value_and_grad = jax.value_and_grad(lambda d: 0.5 * sum(jnp.sum(r**2) for r in residuals(d, None)))

    @jax.jit
    def step(d, state):
        loss, g = value_and_grad(d)
        updates, state = opt.update(g, state, d)
        return optax.apply_updates(d, updates), state, loss

    d, state = d0, opt.init(d0)
    t0 = time.perf_counter()
    for k in range(1, max_steps + 1):
        d, state, _ = step(d, state)
        if k % 5 == 0 or k == max_steps:
            loss = loss_of(residuals, d)
            if loss <= target_loss:
                return d, k, time.perf_counter() - t0, loss
    return d, max_steps, time.perf_counter() - t0, loss_of(residuals, d)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolution", "-n", type=int, default=24, help="cells per axis of [-1, 1]^3")
    parser.add_argument("--subdivisions", type=int, default=2, help="icosphere subdivisions of the template")
    parser.add_argument("--target", default="ellipsoid", choices=["ellipsoid", "box"])
    parser.add_argument("--lam", type=float, default=1e-2, help="weight of the smoothness residuals")
    parser.add_argument("--lm-steps", type=int, default=30)
    parser.add_argument("--adam-steps", type=int, default=2000)
    parser.add_argument("--lr", type=float, default=1e-2, help="Adam's learning rate")
    parser.add_argument("--linear-solver", default="cholesky", choices=["cholesky", "cg"],
                        help="LM's linear solves: normal equations by Cholesky (dense J^T J) or by CG")
    args = parser.parse_args(argv)

    residuals, d0, grid = problem(args.resolution, args.subdivisions, args.target, args.lam)
    initial = loss_of(residuals, d0)
    print(f"template: {d0.shape[0]} vertices ({d0.size} parameters); grid {grid.shape}; initial loss {initial:.6g}")

    linear_solver = lx.Normal(lx.Cholesky()) if args.linear_solver == "cholesky" else None
    lm = voxax.least_squares(residuals, d0, solver="levenberg_marquardt", rtol=1e-4, atol=1e-6,
                             max_steps=args.lm_steps, linear_solver=linear_solver)
    print(f"Levenberg-Marquardt ({args.linear_solver}): loss {lm.loss:.6g} after {lm.steps} steps in {lm.seconds:.2f} s "
          f"(with compilation; {lm.message})")
    target_loss = lm.loss * 1.01
    _, steps, seconds, loss = run_adam(residuals, d0, target_loss, args.lr, args.adam_steps)
    reached = loss <= target_loss
    print(f"Adam (lr {args.lr}): loss {loss:.6g} after {steps} steps in {seconds:.2f} s "
          f"({'reached' if reached else 'did not reach'} 1.01 x the Levenberg-Marquardt loss)")
    print(f"loss reduction: Levenberg-Marquardt {initial / max(lm.loss, 1e-300):.3g}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

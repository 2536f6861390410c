"""A sphere turns into a torus by optimizing a latent code (MeshSDF, Fig. 3, in small).

The loss compares the three axis silhouettes of the extracted, voxelized mesh with a
torus's (`voxax.apps.optimize_implicit`); gradients reach the latent code through the
MeshSDF rule, so the surface may change genus on the way.

(a) analytic: `f_z = (1 - s) * sphere + s * torus` with `s = sigmoid(z)`.
(b) learned: a small DeepSDF trained on the sphere and the torus (two codes); the latent
    code is optimized from the sphere's code, and the Chamfer distance to the torus is
    reported before and after.

    python examples/meshsdf_topology.py [--small] [--resolution N] [--steps N]
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import optax

import voxax


def sphere_sdf(x):
    return voxax.fields.sphere(x, 0.6)


def torus_sdf(x):
    return voxax.fields.torus(x, 0.5, 0.2)


def mixed(z, x):
    s = jax.nn.sigmoid(z)
    return (1 - s) * sphere_sdf(x) + s * torus_sdf(x)


def extract(values, grid):
    return voxax.isosurface(values, grid, close=True).to_mesh()


def analytic(grid, steps, torus):
    z, report = voxax.apps.optimize_implicit(mixed, -3.0, torus, grid, steps=steps, learning_rate=0.2, target_euler=0)
    print("(a) analytic:", report.summary())
    print(f"    s = sigmoid(z): {float(jax.nn.sigmoid(-3.0)):.3f} -> {float(jax.nn.sigmoid(z)):.3f}")
    return report


def train_deepsdf(n_points, iterations, seed=0, learning_rate=5e-3):
    key = jax.random.key(seed)
    k_model, k_pts = jax.random.split(key)
    model = voxax.fields.DeepSDF(n_shapes=2, latent_size=4, width=64, depth=4, skip=2, key=k_model)
    near = jax.random.normal(k_pts, (2, n_points, 3)) * 0.35
    pts = jnp.concatenate([near, jax.random.uniform(k_pts, (2, n_points // 4, 3), minval=-1, maxval=1)], 1)
    sdf = jnp.stack([sphere_sdf(pts[0]), torus_sdf(pts[1])])
    index = jnp.broadcast_to(jnp.arange(2)[:, None], sdf.shape)
    opt = optax.adam(learning_rate)
    state = opt.init(model)

    @jax.jit
    def step(model, state):
        loss, g = jax.value_and_grad(voxax.fields.deepsdf_loss)(model, pts, sdf, index, clamp=0.2, code_sigma=1.0)
        updates, state = opt.update(g, state, model)
        return optax.apply_updates(model, updates), state, loss

    for _ in range(iterations):
        model, state, loss = step(model, state)
    return model, float(loss)


def learned(grid, steps, torus, iterations):
    t = time.perf_counter()
    model, loss = train_deepsdf(2048, iterations)
    print(f"(b) DeepSDF trained in {time.perf_counter() - t:.1f} s, final training loss {loss:.4f}")
    pts = jnp.asarray(grid.centers())

    def fn(z, x):
        return model.decode(z, x)

    start = extract(fn(model.codes[0], pts), grid)
    chi_start = voxax.metrics.euler_characteristic(start)
    c0 = voxax.metrics.chamfer(start, torus, n=20_000)
    z, report = voxax.apps.optimize_implicit(fn, model.codes[0], torus, grid, steps=steps, learning_rate=0.02)
    final = extract(fn(z, pts), grid)
    c1 = voxax.metrics.chamfer(final, torus, n=20_000)
    print("    latent optimization:", report.summary())
    print(f"    Euler characteristic {chi_start} -> {voxax.metrics.euler_characteristic(final)}; "
          f"Chamfer (CD-l2, sum over 2 x 20k samples) to the torus {float(c0):.5f} -> {float(c1):.5f} ({float(c0) / max(float(c1), 1e-30):.1f}x lower)")
    return report, float(c0), float(c1)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--small", action="store_true", help="a quick run on a 16^3 grid (for tests)")
    parser.add_argument("--resolution", type=int, default=32, help="grid cells per axis (default 32)")
    parser.add_argument("--steps", type=int, default=200, help="at most this many Adam steps (default 200)")
    parser.add_argument("--skip-deepsdf", action="store_true", help="run only the analytic variant")
    args = parser.parse_args(argv)
    n = 16 if args.small else args.resolution
    grid = voxax.Grid.cube(n)
    torus = extract(torus_sdf(jnp.asarray(grid.centers())), grid)
    analytic(grid, args.steps, torus)
    if not args.skip_deepsdf:
        learned(grid, 40 if args.small else args.steps, torus, 300 if args.small else 1500)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

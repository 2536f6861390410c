"""MeshSDF fast paths on an MLP field: how much of a 256^3 grid `isosurface_fn` evaluates.

The field is an MLP `3 -> width -> ... -> width -> 1` (`--depth` hidden layers) with
MaxMin activations (each pair of units -> (max, min), 1-Lipschitz and gradient-norm
preserving) whose weight matrices are divided by `max(1, ||V||_2)` while training, so the
trained network is 1-Lipschitz up to rounding. It is fitted briefly (Adam, L1 loss) to the
signed distance of a torus (R = 0.5, r = 0.2) on points uniform in [-1, 1]^3 and near the
surface.

**The Lipschitz bound.** After training, the spectral norm of every float32 weight matrix
is computed by an SVD in float64, and `L = prod_i ||W_i||_2` is a proven bound of the
network's Lipschitz constant in x (MaxMin is 1-Lipschitz; biases do not matter). The
network is evaluated in float32, so `lipschitz=` receives `L + 0.1`: the extra `0.1 r` (at
least 6.8e-4 at the finest blocks, r = 0.87 h at 256^3) is a margin for the forward pass's
rounding. That part is an estimate, not a proof: standard dot-product bounds give about
`n u |a||b|` per unit (`n = 128` terms, `u = 6e-8`), i.e. some 1e-5 per unit for
activations of order one and a few 1e-4 for a whole layer in the worst case, while the
typical error is much smaller. The empirical max |grad f| at the vertices is printed
for comparison only (it is not a proof).

Checks, each asserting the same mesh (faces and vertices, exactly) as dense evaluation:

- `lipschitz=L`: one call at the trained field;
- `band=`: the field `f - c` for `c = 0.3 h, 0.6 h, ...` (`--steps` steps, the surface moving
  about 0.3 h per step), each call starting from the previous call's samples (the first
  from the Lipschitz path's). Dense references for every step come from one dense float32
  evaluation: `f - c` in float32 is the same computation the field function does.

Usage:

```bash
PYTHONPATH=src python benchmarks/isosurface_fn.py [--n 256] [--steps 4] [--train-steps 1000]
```
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=256)
    ap.add_argument("--width", type=int, default=128)
    ap.add_argument("--depth", type=int, default=3)
    ap.add_argument("--train-steps", type=int, default=1000)
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)

    import jax

    jax.config.update("jax_enable_x64", True)
    import jax.numpy as jnp
    import optax

    import voxax
    from voxax import fields

    f32 = jnp.float32
    key = jax.random.key(args.seed)
    sizes = [3] + [args.width] * args.depth + [1]
    keys = jax.random.split(key, len(sizes))
    raw = []
    for k, (n_in, n_out) in zip(keys, zip(sizes[:-1], sizes[1:])):
        w = jax.random.normal(k, (n_out, n_in), f32) / np.sqrt(n_in)
        raw.append((w, jnp.zeros((n_out,), f32)))

    def maxmin(h):
        a, b = h[..., 0::2], h[..., 1::2]
        return jnp.concatenate([jnp.maximum(a, b), jnp.minimum(a, b)], -1)

    def spectral(w, v):
        # one power-iteration step from the previous right singular vector estimate `v`
        # (carried across training steps); the bound below uses exact SVDs instead
        wd = jax.lax.stop_gradient(w)
        u = wd @ v
        u = u / jnp.linalg.norm(u)
        v = wd.T @ u
        v = v / jnp.linalg.norm(v)
        return u @ w @ v, v

    def normalized(params, vs):
        out, new = [], []
        for (w, b), v in zip(params, vs):
            sigma, v = spectral(w, v)
            out.append((w / jnp.maximum(1.0, sigma), b))
            new.append(v)
        return out, new

    def mlp(weights, x):
        h = x.astype(f32)
        for w, b in weights[:-1]:
            h = maxmin(h @ w.T + b)
        w, b = weights[-1]
        return (h @ w.T + b)[..., 0]

    def target(x):
        return fields.torus(x, 0.5, 0.2)

    def loss(params, vs, x):
        weights, vs = normalized(params, vs)
        return jnp.mean(jnp.abs(mlp(weights, x) - target(x).astype(f32))), vs

    opt = optax.adam(optax.cosine_decay_schedule(3e-3, args.train_steps, 0.05))
    state = opt.init(raw)

    @jax.jit
    def step(params, vs, state, key):
        k1, k2, k3 = jax.random.split(key, 3)
        m = args.batch // 2
        uniform = jax.random.uniform(k1, (m, 3), f32, -1.0, 1.0)
        # near the surface: points of the torus, jittered
        u = jax.random.uniform(k2, (m, 2), f32, 0.0, 2 * np.pi)
        ring = jnp.stack([jnp.cos(u[:, 0]), jnp.sin(u[:, 0]), jnp.zeros(m, f32)], -1)
        tube = 0.5 * ring + 0.2 * (
            jnp.cos(u[:, 1])[:, None] * ring + jnp.sin(u[:, 1])[:, None] * jnp.array([0, 0, 1.0], f32)
        )
        near = tube + 0.05 * jax.random.normal(k3, (m, 3), f32)
        x = jnp.concatenate([uniform, near])
        (value, vs), grads = jax.value_and_grad(loss, has_aux=True)(params, vs, x)
        updates, state = opt.update(grads, state, params)
        return optax.apply_updates(params, updates), vs, state, value

    t0 = time.perf_counter()
    params = raw
    vs = [jnp.ones((w.shape[1],), f32) / np.sqrt(w.shape[1]) for w, _ in raw]
    for i in range(args.train_steps):
        key, sub = jax.random.split(key)
        params, vs, state, value = step(params, vs, state, sub)
        if i % 250 == 0 or i == args.train_steps - 1:
            print(f"train step {i}: L1 {float(value):.5f}", flush=True)
    t_train = time.perf_counter() - t0
    # final projection with exact spectral norms (the power iteration only tracks them)
    weights = []
    for w, b in params:
        w = np.asarray(w, np.float64)
        w = w / max(1.0, np.linalg.svd(w, compute_uv=False)[0])
        weights.append((w.astype(np.float32), np.asarray(b, np.float32)))
    norms = [float(np.linalg.svd(w.astype(np.float64), compute_uv=False)[0]) for w, _ in weights]
    L = float(np.prod(norms))
    L_used = L + 0.1
    print(f"trained in {t_train:.1f} s; spectral norms {[f'{s:.6f}' for s in norms]}; L = {L:.6f}", flush=True)
    wj = [(jnp.asarray(w), jnp.asarray(b)) for w, b in weights]

    field = jax.jit(lambda c, x: mlp(wj, x) - jnp.asarray(c, f32))

    def fn(c, x):
        return field(c, x)

    n = args.n
    grid = voxax.Grid.cube(n)
    h = grid.spacing[0]

    # dense float32 samples of the network, chunk by chunk (as isosurface_fn does)
    t0 = time.perf_counter()
    chunk = 1 << 16
    pts = grid.centers().reshape(-1, 3)
    dense = np.empty(len(pts), np.float32)
    for s in range(0, len(pts), chunk):
        dense[s : s + chunk] = np.asarray(field(np.float32(0.0), jnp.asarray(pts[s : s + chunk])))
    dense = dense.reshape(grid.shape)
    t_dense = time.perf_counter() - t0
    del pts
    print(f"dense evaluation: {grid.size} points in {t_dense:.1f} s", flush=True)
    exact = np.asarray(target(jnp.asarray(grid.centers())))
    print(f"max |f - sdf| over the grid: {np.abs(dense - exact).max():.4f} ({np.abs(dense - exact).max() / h:.2f} h)")
    del exact

    def reference(c):
        samples = (dense - np.float32(c)).astype(np.float64)
        return voxax.isosurface(samples, grid, 0.0), samples

    def same(a, b, what):
        assert np.array_equal(np.asarray(a.faces), np.asarray(b.faces)), what + ": faces differ"
        assert np.array_equal(np.asarray(a.vertices), np.asarray(b.vertices)), what + ": vertices differ"

    rows = []
    t0 = time.perf_counter()
    lip = voxax.isosurface_fn(fn, np.float32(0.0), grid, lipschitz=L_used)
    t_lip = time.perf_counter() - t0
    ref, ref_samples = reference(0.0)
    same(lip, ref, "lipschitz")
    mesh = ref.to_mesh()
    chi = voxax.metrics.euler_characteristic(mesh) if hasattr(voxax, "metrics") else None
    rows.append(("lipschitz", 0.0, lip.n_evaluated, t_lip, int(lip.n_faces)))
    print(
        f"lipschitz L = {L_used:.4f}: {lip.n_evaluated} evaluations ({lip.n_evaluated / grid.size:.2%}) in {t_lip:.2f} s; faces {int(lip.n_faces)}, chi {chi}",
        flush=True,
    )
    # empirical gradient norm at the surface vertices (for comparison only)
    g = jax.vmap(jax.grad(lambda x: mlp(wj, x)))(jnp.asarray(mesh.vertices, f32))
    print(f"empirical max |grad f| at the vertices: {float(jnp.max(jnp.linalg.norm(g, axis=-1))):.4f} (not a proof)")

    prev = lip.samples
    for k in range(1, args.steps + 1):
        c = np.float32(0.3 * h * k)
        t0 = time.perf_counter()
        band = voxax.isosurface_fn(fn, c, grid, band=prev)
        t_band = time.perf_counter() - t0
        ref, _ = reference(c)
        same(band, ref, f"band step {k}")
        rows.append(("band", float(c) / h, band.n_evaluated, t_band, int(band.n_faces)))
        print(
            f"band step {k} (f - {float(c) / h:.1f} h): {band.n_evaluated} evaluations ({band.n_evaluated / grid.size:.2%}) in {t_band:.2f} s",
            flush=True,
        )
        prev = band.samples

    print()
    print(
        f"MLP 3-{'-'.join([str(args.width)] * args.depth)}-1 (MaxMin), trained {args.train_steps} steps in {t_train:.0f} s; "
        f"L = {L:.6f} (product of spectral norms), lipschitz= {L_used:.4f}; dense {n}^3 evaluation {t_dense:.1f} s"
    )
    print("| path | field | evaluations | % of grid | time | faces | same mesh as dense |")
    print("|---|---|---|---|---|---|---|")
    for path, shift, ev, t, nf in rows:
        print(f"| {path} | f - {shift:.1f} h | {ev:,} | {ev / grid.size:.2%} | {t:.2f} s | {nf:,} | yes |")


if __name__ == "__main__":
    main()

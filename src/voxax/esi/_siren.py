"""The fused evaluation of the NESI networks: SIRENs on batches as matrix products, with
float32 sines and cosines as polynomials (one fused pass) and the input gradients that
the normal losses need carried forward alongside the activations."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..fields import Siren

__all__ = ["_apply", "_apply_with_gradient", "_cos32", "_sin32"]


def _reduce32(x):
    """`x = k pi + r` with `|r| <= pi/2` (float32; the product `k pi` in three exact parts for
    `|x| < 2^15`), and whether `k` is odd."""
    k = jnp.round(x * np.float32(1.0 / np.pi))
    r = x - k * np.float32(3.140625)
    r = r - k * np.float32(0.0009670257568359375)
    r = r - k * np.float32(6.277114152908325e-07)
    return r, (k.astype(jnp.int32) & 1) == 1


def _sin32_poly(x):
    r, odd = _reduce32(x)
    r2 = r * r
    poly = np.float32(1.0 / 362880) + r2 * np.float32(-1.0 / 39916800)
    poly = np.float32(-1.0 / 5040) + r2 * poly
    poly = np.float32(1.0 / 120) + r2 * poly
    poly = np.float32(-1.0 / 6) + r2 * poly
    y = r + r * r2 * poly
    return jnp.where(odd, -y, y)


def _cos32_poly(x):
    r, odd = _reduce32(x)
    r2 = r * r
    poly = np.float32(-1.0 / 3628800) + r2 * np.float32(1.0 / 479001600)
    poly = np.float32(1.0 / 40320) + r2 * poly
    poly = np.float32(-1.0 / 720) + r2 * poly
    poly = np.float32(1.0 / 24) + r2 * poly
    poly = np.float32(-0.5) + r2 * poly
    y = np.float32(1.0) + r2 * poly
    return jnp.where(odd, -y, y)


@jax.custom_jvp
def _sin32(x):
    """`sin` for float32 in one fused pass: reduction by pi in three parts (exact products
    for |x| < 2^15), a degree-11 odd polynomial on [-pi/2, pi/2] and the sign of the
    half-turn; absolute error below 2e-7 for |x| <= 100 (the sine layers' range), about
    4x cheaper on CPU than XLA's `sin`. Its derivative is `_cos32` (so training
    differentiates the sine, not the polynomial)."""
    return _sin32_poly(x)


@jax.custom_jvp
def _cos32(x):
    """`cos` for float32 like `_sin32` (a degree-12 even polynomial after the same
    reduction); its derivative is `-_sin32`."""
    return _cos32_poly(x)


@_sin32.defjvp
def _sin32_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    return _sin32(x), _cos32(x) * t


@_cos32.defjvp
def _cos32_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    return _cos32(x), -_sin32(x) * t


def _sincos(dtype):
    if dtype == jnp.float32:
        return _sin32, _cos32
    return jnp.sin, jnp.cos


def _apply(net: Siren, x):
    """A SIREN on a batch `x (n, in)` as batched matrix products; float32 networks use
    `_sin32`. Returns `(n,)` or `(n, out)` like calling the network."""
    x = x.astype(net.weights[0].dtype)
    h = x
    last = len(net.weights) - 1
    sin = _sincos(x.dtype)[0]
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        z = h @ w.T.astype(x.dtype) + b.astype(x.dtype)
        if i == last:
            h = z
        else:
            omega = net.first_omega_0 if i == 0 else net.omega_0
            h = sin(np.asarray(omega, x.dtype) * z)
    return h[:, 0] if net.out_size == 1 else h


def _apply_with_gradient(net: Siren, x):
    """A SIREN and its input gradient on a batch `x (n, 2)`, in one forward-mode pass.

    Every layer carries the activations `h (n, w)` and their derivatives along the two
    input axes `dh (n, 2, w)`: `dz = dh W^T`, `d sin(omega z) = omega cos(omega z) dz`,
    all as batched matrix products sharing one sine and cosine per unit (the first
    layer's `dz` is `W^T` itself). Differentiating the result by the parameters (the
    normal loss) is then one reverse pass over these products.

    **Returns:** `(value, gradient)`: `(n,)` and `(n, 2)` for one output, `(n, out)` and
    `(n, out, 2)` otherwise.
    """
    x = x.astype(net.weights[0].dtype)
    dt = x.dtype
    sin, cos = _sincos(dt)
    last = len(net.weights) - 1
    h, dh = x, None
    for i, (w, b) in enumerate(zip(net.weights, net.biases)):
        w = w.astype(dt)
        z = h @ w.T + b.astype(dt)
        dz = w.T[None] if dh is None else jnp.einsum("njk,ok->njo", dh, w)  # (n or 1, 2, out)
        if i == last:
            h, dh = z, dz
            break
        omega = np.asarray(net.first_omega_0 if i == 0 else net.omega_0, dt)
        a = omega * z
        h = sin(a)
        dh = (omega * cos(a))[:, None, :] * dz
    grad = jnp.swapaxes(dh, 1, 2)  # (n, out, 2)
    if net.out_size == 1:
        return h[:, 0], grad[:, 0]
    return h, grad

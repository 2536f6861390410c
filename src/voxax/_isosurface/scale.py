"""Power-of-two rescaling of fields too small or too large for the arithmetic of XLA.

XLA's CPU code flushes subnormal numbers to zero (inputs and results), so a field whose
values lie below ~2.2e-308 (float64; ~1.2e-38 for float32) would have no sign changes and
no edge gaps there, and a field near the top of the range overflows in `f_b - f_a`. The
interpolation `t = (level - f_a) / (f_b - f_a)` is the same for `2^k f` and `2^k level` when
no intermediate leaves the normal range (scaling by a power of two is exact). So such
fields (and the level) are scaled by a power of two that brings their largest magnitude
near 1 before any arithmetic; fields inside the safe range are left alone (their bits do
not change). The scale is exact: every normal scaled value is `2^k` times the original.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

# The exponents (of the largest |f| and |level|) outside which a field is rescaled.
_SAFE = {np.dtype(np.float64): (-900, 900), np.dtype(np.float32): (-90, 90)}


def _exponent(m: float) -> int:
    return int(np.frexp(m)[1])


def needs_scale(m: float, dtype) -> bool:
    """Whether a field with largest magnitude `m` (of `|f|` and `|level|`) is rescaled."""
    lo, hi = _SAFE[np.dtype(dtype)]
    return m > 0 and not lo <= _exponent(m) <= hi


def scale_exponent(m: float, dtype) -> int:
    """The `k` of `2^k m` in [0.5, 1) when a field of largest magnitude `m` (of `|f|` and
    `|level|`) is rescaled, else 0."""
    return -_exponent(m) if needs_scale(m, dtype) else 0


def _info(dtype):
    if dtype == jnp.float64:
        return jnp.int64, 52, 1023
    return jnp.int32, 23, 127


def _pow2(n, dtype):
    """`2^n` built from its bits (0 below the normal range, clamped above it)."""
    it, mb, bias = _info(dtype)
    n = jnp.clip(n, -bias, bias)
    bits = jnp.where(n > -bias, (n + bias).astype(it) << mb, 0).astype(it)
    return jax.lax.bitcast_convert_type(bits, dtype)


def rescale_traced(values, level: float):
    """The JAX form of `rescale_np` for traced values: `(scaled values, k)`, with `k` traced
    (0 inside the safe range; see `scaled_level` for the level). The values are decoded from their
    bits, so subnormal ones survive XLA's flush to zero; the gradient is `2^k` times the
    identity (clamped to the finite range)."""
    dtype = values.dtype
    it, mb, bias = _info(dtype)
    lo, hi = _SAFE[np.dtype(dtype)]
    bits = jax.lax.bitcast_convert_type(values, it)
    mag = bits & jnp.asarray(np.iinfo(np.dtype(it)).max, it)
    lvl = np.abs(np.asarray(level, dtype)).view(np.dtype(it))
    top = jnp.maximum(jnp.max(mag, initial=0), jnp.asarray(lvl, it))
    exp_field, mant = top >> mb, top & ((1 << mb) - 1)
    # floor(log2(mant)) of a subnormal maximum, from the exponent of its exact float value
    mant_log = (jax.lax.bitcast_convert_type(mant.astype(dtype), it) >> mb) - bias
    e = jnp.where(exp_field > 0, exp_field - bias + 1, mant_log + 2 - bias - mb)  # frexp's
    need = (top > 0) & ((e < lo) | (e > hi))
    k = jnp.where(need, -e, 0).astype(jnp.int32)
    ef, mf = mag >> mb, mag & ((1 << mb) - 1)
    sig = jnp.where(ef > 0, mf | (1 << mb), mf).astype(dtype)  # exact: < 2^(mb + 1)
    n = (jnp.maximum(ef, 1) - bias - mb).astype(jnp.int32) + k
    scaled = jnp.where(bits < 0, -sig, sig) * _pow2(n, dtype)
    scaled = jnp.where(need, scaled, values)
    factor = _pow2(jnp.maximum(k, 1 - bias), dtype)  # the gradient's, kept normal
    out = jax.lax.stop_gradient(scaled) + (values - jax.lax.stop_gradient(values)) * factor
    return out, k


def scaled_level(level: float, k, dtype):
    """`level * 2^k` for a traced `k` (`level` itself when `k` is 0)."""
    if level == 0.0:
        return jnp.zeros((), dtype)
    m, e = np.frexp(level)  # level = m 2^e, m in [0.5, 1)
    return jnp.asarray(m, dtype) * _pow2(e + k, dtype)


def unscale(x, k):
    """`x * 2^-k` for a traced `k` (two factors, so that each stays normal)."""
    half = k // 2
    return x * _pow2(-half, x.dtype) * _pow2(half - k, x.dtype)

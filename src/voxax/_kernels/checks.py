"""The value check of traced float arrays as an FFI kernel (csrc/common/check_ffi.cc)."""

from __future__ import annotations

import jax
import numpy as np

from ._loader import FINITE_CHECK

__all__ = ["finite_check_ffi"]


def finite_check_ffi(x, where: str, name: str, max_abs: float = float("inf"), positive: bool = False):
    """A 0 int32 scalar (one per `vmap` item), or a run-time error
    `"<where>: `<name>` must be finite ..."` at the first NaN or infinite element of the
    float32 / float64 array `x` (or `"... magnitude <= max_abs ..."`, or with `positive`
    `"... must be > 0 ..."` at the first element <= 0)."""
    call = jax.ffi.ffi_call(FINITE_CHECK, jax.ShapeDtypeStruct((), np.int32), vmap_method="sequential")
    return call(x, where=where, name=name, max_abs=np.float64(max_abs), positive=np.int32(bool(positive)))

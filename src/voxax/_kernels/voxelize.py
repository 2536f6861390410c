"""The voxelization kernels (`csrc/voxelize/`): the forward, backward and tangent FFI calls.

Arrays in, arrays out: the JAX primitives with their rules live in `voxax._voxelize`.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from ._loader import BACKWARD, FORWARD, TANGENT, grid_attributes

__all__ = ["BACKWARD", "FORWARD", "TANGENT", "call", "host_call"]


def call(target: str, result: jax.ShapeDtypeStruct, grid, *args):
    """The FFI kernel `target` (one of `FORWARD`, `TANGENT`, `BACKWARD`) on `args`, inside XLA."""
    return jax.ffi.ffi_call(target, result)(*args, **grid_attributes(grid))


def host_call(target: str, result: jax.ShapeDtypeStruct, grid, *args) -> np.ndarray:
    """The same kernel on NumPy arrays on the CPU device (the body of a host callback, for
    computations placed on other devices)."""
    cpu = jax.devices("cpu")[0]
    with jax.default_device(cpu):
        out = _host_jit(target, result, grid)(*[jax.device_put(np.asarray(a), cpu) for a in args])
    return np.asarray(out)


@functools.lru_cache(maxsize=64)
def _host_jit(target, result, grid):
    kernel = jax.ffi.ffi_call(target, result, vmap_method="expand_dims")
    return jax.jit(lambda *a: kernel(*a, **grid_attributes(grid)))

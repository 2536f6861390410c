"""The voxelization kernels (`csrc/voxelize/`): the forward, backward and tangent FFI calls,
and those of the sparse voxelization (`sparse_ffi.cc`).

Arrays in, arrays out: the JAX primitives with their rules live in `voxax._voxelize`.
"""

from __future__ import annotations

import functools

import jax
import numpy as np

from ._loader import (
    BACKWARD,
    FORWARD,
    SPARSE_BACKWARD,
    SPARSE_FORWARD,
    SPARSE_TANGENT,
    TANGENT,
    grid_attributes,
)

__all__ = ["BACKWARD", "FORWARD", "TANGENT", "SPARSE_BACKWARD", "SPARSE_FORWARD", "SPARSE_TANGENT", "call",
           "host_call", "sparse_call", "sparse_host_call"]


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


def _sparse_attributes(grid, strict):
    attrs = grid_attributes(grid)
    if strict is not None:  # the forward's: 1 makes an overflowing capacity an error
        attrs["strict"] = np.int64(1 if strict else 0)
    return attrs


def sparse_call(target: str, results, grid, strict, *args):
    """The sparse kernel `target` (`SPARSE_FORWARD`, with `strict` True or False, or
    `SPARSE_TANGENT` / `SPARSE_BACKWARD`, with `strict` None) on `args`, inside XLA;
    `results` is one `jax.ShapeDtypeStruct` or a tuple of them."""
    return jax.ffi.ffi_call(target, results)(*args, **_sparse_attributes(grid, strict))


def sparse_host_call(target: str, results, grid, strict, *args):
    """`sparse_call` on NumPy arrays on the CPU device (the body of a host callback)."""
    cpu = jax.devices("cpu")[0]
    with jax.default_device(cpu):
        out = _sparse_host_jit(target, results, grid, strict)(*[jax.device_put(np.asarray(a), cpu) for a in args])
    return jax.tree.map(np.asarray, out)


@functools.lru_cache(maxsize=64)
def _sparse_host_jit(target, results, grid, strict):
    kernel = jax.ffi.ffi_call(target, results)
    return jax.jit(lambda *a: kernel(*a, **_sparse_attributes(grid, strict)))

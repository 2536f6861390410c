"""Bindings of csrc/contour (marching cubes / squares): the eager count/fill entry points
through ctypes and the `voxax_marching_cubes` FFI call. Arrays in, arrays out."""

from __future__ import annotations

import ctypes

import jax
import jax.numpy as jnp
import numpy as np

from . import _loader
from ._ctypes import ERRLEN, I64, VP, declare, error_buffer
from ._ctypes import threads as resolve_threads

__all__ = ["Count", "marching_cubes", "topology"]

_SIGNATURES = {
    "voxax_mc_count": (
        ctypes.c_int,
        [VP, ctypes.c_int, ctypes.c_int, I64, ctypes.c_double, ctypes.c_int, ctypes.POINTER(VP), I64,
         ctypes.POINTER(ctypes.c_double), ctypes.c_char_p, ctypes.c_int64],
    ),
    "voxax_mc_fill": (ctypes.c_int, [VP, VP, VP]),
    "voxax_mc_release": (None, [VP]),
    "voxax_mc_slice_vertices": (ctypes.c_int64, [VP, ctypes.c_int64]),
}


def _lib():
    return declare(_SIGNATURES)


class Count:
    """Pass 1 of the C++ kernel on one array: the counts, the samples' range (`lo`, `hi`;
    NaN or Inf is a `ValueError`), and a context for pass 2.

    Holds a reference to the (contiguous) samples, which pass 2 reads again.
    """

    def __init__(self, values: np.ndarray, level: float, threads: int | None = None):
        lib = _lib()
        values = np.ascontiguousarray(values)
        if values.dtype not in (np.float32, np.float64):
            values = values.astype(np.float64)
        self.values = values
        self.dim = dim = values.ndim
        dtype = 0 if values.dtype == np.float32 else 1
        shape = (ctypes.c_int64 * 3)(*(list(values.shape) + [1] * (3 - dim)))
        counts = (ctypes.c_int64 * 2)()
        rng = (ctypes.c_double * 2)()
        self.ctx = ctypes.c_void_p()
        err = error_buffer()
        rc = lib.voxax_mc_count(
            values.ctypes.data, dtype, dim, shape, float(level), resolve_threads(threads),
            ctypes.byref(self.ctx), counts, rng, err, ERRLEN,
        )
        if rc != 0:
            msg = err.value.decode(errors="replace")
            raise (MemoryError if rc == 2 else ValueError)(msg)
        self.n_vertices, self.n_faces = int(counts[0]), int(counts[1])
        self.lo, self.hi = float(rng[0]), float(rng[1])  # the samples' range (all finite)

    def slice_vertices(self, i: int) -> int:
        """Vertices owned by x slice `i` (crossed edges with their lower cell there)."""
        return int(_lib().voxax_mc_slice_vertices(self.ctx, int(i)))

    def fill(self):
        """Pass 2: `edges (V, 2)` and `faces (F, d)` int32; releases the context."""
        lib = _lib()
        try:
            edges = np.zeros((self.n_vertices, 2), np.int32)
            faces = np.zeros((self.n_faces, self.dim), np.int32)
            if lib.voxax_mc_fill(self.ctx, edges.ctypes.data, faces.ctypes.data) != 0:
                raise MemoryError("voxax.isosurface: out of memory")
        finally:
            self.release()
        return edges, faces

    def release(self):
        if self.ctx:
            _lib().voxax_mc_release(self.ctx)
            self.ctx = ctypes.c_void_p()
        self.values = None

    def __del__(self):
        try:
            self.release()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass


def topology(values: np.ndarray, level: float, threads: int | None = None):
    """Exact-size topology of one field: `edges (V, 2)`, `faces (F, d)` (int32)."""
    return Count(values, level, threads).fill()


def marching_cubes(values, level: float, dim: int, vcap: int, fcap: int):
    """The FFI call: `edges (..., vcap, 2)`, `faces (..., fcap, dim)` and `counts (..., 2)` int32."""
    batch = values.shape[: values.ndim - dim]
    out = (
        jax.ShapeDtypeStruct(batch + (vcap, 2), jnp.int32),
        jax.ShapeDtypeStruct(batch + (fcap, dim), jnp.int32),
        jax.ShapeDtypeStruct(batch + (2,), jnp.int32),
    )
    call = jax.ffi.ffi_call(_loader.MARCHING_CUBES, out, vmap_method="expand_dims")
    return call(values, level=np.float64(level), dim=np.int64(dim))

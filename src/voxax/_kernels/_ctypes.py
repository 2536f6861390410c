"""Calling the kernels' eager host entry points (a plain C ABI) through ctypes.

ctypes releases the GIL while a foreign function runs, so the C++ thread pools work in
parallel with Python threads. Every entry point returns a status (0 on success) and writes
a message into an error buffer; [`check`][voxax._kernels.check] raises it as a `ValueError`.
"""

from __future__ import annotations

import ctypes
import os

import numpy as np

from . import _loader

__all__ = ["D", "ERRLEN", "I8", "I32", "I64", "VP", "check", "declare", "error_buffer", "pointer", "threads"]

ERRLEN = 512
D = ctypes.POINTER(ctypes.c_double)
I32 = ctypes.POINTER(ctypes.c_int32)
I64 = ctypes.POINTER(ctypes.c_int64)
I8 = ctypes.POINTER(ctypes.c_int8)
VP = ctypes.c_void_p

_DECLARED: set[str] = set()


def declare(signatures: dict) -> ctypes.CDLL:
    """The kernel library, with `{name: (restype, argtypes)}` set on its functions."""
    lib = _loader.library()
    for name, (res, args) in signatures.items():
        if name not in _DECLARED:
            fn = getattr(lib, name)
            fn.restype, fn.argtypes = res, args
            _DECLARED.add(name)
    return lib


def pointer(a: np.ndarray, kind):
    """A ctypes pointer to the data of a C-contiguous array."""
    return a.ctypes.data_as(kind)


def error_buffer():
    return ctypes.create_string_buffer(ERRLEN)


def check(status: int, err) -> None:
    """Raises the entry point's message as a `ValueError` when `status` is not 0."""
    if status != 0:
        raise ValueError(err.value.decode("utf-8", "replace"))


def threads(threads: int | None) -> int:
    """The thread count to pass: `threads`, or `VOXAX_NUM_THREADS`, or 0 for all cores."""
    if threads is None:
        env = os.environ.get("VOXAX_NUM_THREADS")
        return int(env) if env else 0
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)):
        raise TypeError(f"`threads` must be an int or None, got {type(threads).__name__}")
    if threads < 1:
        raise ValueError(f"`threads` must be >= 1 (or None for all cores), got {threads}")
    return int(threads)

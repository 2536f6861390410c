"""The thread count of NumPy's BLAS, set for a while.

NumPy's OpenBLAS runs a matrix product on every core and then keeps its threads spinning
for a moment. Code that alternates many mid-sized products with its own C++ thread pools
(the ESI selection) runs faster with one BLAS thread: the spinning threads take the cores
that the pools need. `single_threaded()` sets one BLAS thread for a `with` block and then
restores the count; where the library or its entry points cannot be found it does nothing.
A product's value does not depend on the thread count in OpenBLAS (each output element is
summed by one thread in one order), so results stay the same.
"""

from __future__ import annotations

import contextlib
import ctypes
import glob
import os
import threading

import numpy as np

__all__ = ["single_threaded"]

_NAMES = (
    ("scipy_openblas_get_num_threads64_", "scipy_openblas_set_num_threads64_"),
    ("scipy_openblas_get_num_threads", "scipy_openblas_set_num_threads"),
    ("openblas_get_num_threads64_", "openblas_set_num_threads64_"),
    ("openblas_get_num_threads", "openblas_set_num_threads"),
)
_LOCK = threading.Lock()
_DEPTH = [0, 0]  # nesting depth, saved count
_FUNCS: list = []


def _functions():
    """`(get, set)` of the OpenBLAS loaded by NumPy, or None."""
    if not _FUNCS:
        found = None
        root = os.path.dirname(os.path.dirname(np.__file__))
        for path in sorted(glob.glob(os.path.join(root, "numpy.libs", "*openblas*"))):
            try:
                lib = ctypes.CDLL(path, mode=getattr(os, "RTLD_NOLOAD", 0))
            except OSError:
                continue
            for get_name, set_name in _NAMES:
                if hasattr(lib, get_name) and hasattr(lib, set_name):
                    get, put = getattr(lib, get_name), getattr(lib, set_name)
                    get.restype, get.argtypes = ctypes.c_int, []
                    put.restype, put.argtypes = None, [ctypes.c_int]
                    found = (get, put)
                    break
            if found:
                break
        _FUNCS.append(found)
    return _FUNCS[0]


@contextlib.contextmanager
def single_threaded():
    """One BLAS thread inside the block (nested blocks and threads share one setting)."""
    funcs = _functions()
    if funcs is None:
        yield
        return
    get, put = funcs
    with _LOCK:
        if _DEPTH[0] == 0:
            _DEPTH[1] = int(get())
            put(1)
        _DEPTH[0] += 1
    try:
        yield
    finally:
        with _LOCK:
            _DEPTH[0] -= 1
            if _DEPTH[0] == 0:
                put(_DEPTH[1])

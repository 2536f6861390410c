"""What the kernel library was compiled for and which vector paths this machine takes
(`voxax_cpu_features`, csrc/common/cpu_features.cc)."""

from __future__ import annotations

import ctypes

from . import _loader

__all__ = ["FEATURES", "cpu_features"]

# The x86-64 extensions reported, in the order `voxax_cpu_features` writes them.
FEATURES = ("sse4.2", "avx", "avx2", "fma", "avx512f")


def cpu_features() -> dict:
    """The kernel library's build and the running CPU, as `voxax_cpu_features` reports them.

    **Returns:**

    A dict: `clones_built` (bool: the AVX2 clones are compiled in), `avx2_clones` (bool:
    the loader selected them on this machine), `built_with` (the extensions of `FEATURES`
    the whole library was compiled for: empty for a portable build), `cpu` (each of
    `FEATURES` to a bool, or None where the question does not apply: not x86-64) and
    `hardware_threads` (`std::thread::hardware_concurrency()`, 0 if unknown).
    """
    lib = _loader.library()
    fn = lib.voxax_cpu_features
    fn.restype, fn.argtypes = ctypes.c_int, [ctypes.POINTER(ctypes.c_int32), ctypes.c_int]
    count = fn(None, 0)
    expected = 2 + 2 * len(FEATURES) + 1
    if count != expected:
        raise RuntimeError(f"voxax: the kernels report {count} CPU values, expected {expected}")
    values = (ctypes.c_int32 * count)()
    fn(values, count)
    built = values[2:2 + len(FEATURES)]
    cpu = values[2 + len(FEATURES):2 + 2 * len(FEATURES)]
    return {
        "clones_built": bool(values[0]),
        "avx2_clones": bool(values[1]),
        "built_with": tuple(name for name, flag in zip(FEATURES, built) if flag),
        "cpu": {name: None if flag < 0 else bool(flag) for name, flag in zip(FEATURES, cpu)},
        "hardware_threads": int(values[-1]),
    }

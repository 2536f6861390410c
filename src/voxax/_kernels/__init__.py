"""The C boundary: the only code that knows the kernels' ABI.

- `_loader`: loads `libvoxax_kernels` and registers its FFI targets with XLA; the target
  names, the compiled constants and the grid as FFI attributes.
- `_ctypes`: the eager host entry points (a plain C ABI) through ctypes: signatures,
  pointers, error buffers and the one `threads` rule.
- `export`: what `jax.export` needs to serialize functions that call the kernels.
"""

from ._ctypes import ERRLEN, I8, I32, I64, VP, D, check, declare, error_buffer, pointer, threads
from ._loader import (
    BACKWARD,
    CLOSEST_POINTS,
    CVT_ASSIGN,
    FIRST_HITS,
    FORWARD,
    KNN,
    MARCHING_CUBES,
    SPARSE_BACKWARD,
    SPARSE_FORWARD,
    SPARSE_TANGENT,
    TANGENT,
    TARGETS,
    grid_attributes,
    kernel_constants,
    library,
    library_path,
)

__all__ = [
    "BACKWARD", "CLOSEST_POINTS", "CVT_ASSIGN", "FIRST_HITS", "FORWARD", "KNN", "MARCHING_CUBES", "SPARSE_BACKWARD",
    "SPARSE_FORWARD", "SPARSE_TANGENT", "TANGENT",
    "TARGETS", "grid_attributes", "kernel_constants", "library", "library_path",
    "D", "ERRLEN", "I8", "I32", "I64", "VP", "check", "declare", "error_buffer", "pointer", "threads",
]

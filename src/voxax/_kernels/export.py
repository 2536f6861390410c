"""`jax.export` of functions that call voxax's kernels."""

from __future__ import annotations

from .. import _kernels

__all__ = ["export_safety_checks", "ffi_targets"]


def ffi_targets() -> tuple[str, ...]:
    """The names of every XLA FFI target (custom call) voxax registers.

    **Returns:**

    A tuple of target names, such as `"voxax_forward"`.
    """
    return tuple(_kernels.TARGETS)


def export_safety_checks() -> list:
    """The `jax.export` safety checks to disable so that voxax's kernels can be exported.

    `jax.export` refuses custom calls it does not know to be stable. voxax's kernels are
    CPU custom calls registered when `voxax` is imported; pass this list as
    `disabled_checks` to export a jitted function that calls `voxax.voxelize` (its value,
    gradient or directional derivative). Serializing needs `flatbuffers`
    (`pip install voxax[export]`). The process that deserializes and runs the function
    must `import voxax` first, so that the targets are registered, and must use a
    compatible voxax version: the kernels' calling convention is not versioned.

    **Returns:**

    A list of `jax.export.DisabledSafetyCheck`, one per voxax FFI target.

    **Example:**

    ```python
    >>> import jax, voxax
    >>> mesh = voxax.data.box()
    >>> grid = voxax.Grid.cube(4)
    >>> fn = jax.jit(lambda v: voxax.voxelize(v, mesh.faces, grid))
    >>> exp = jax.export.export(fn, disabled_checks=voxax.export_safety_checks())(
    ...     jax.ShapeDtypeStruct(mesh.vertices.shape, mesh.vertices.dtype))
    >>> restored = jax.export.deserialize(exp.serialize())
    >>> restored.call(mesh.vertices).shape
    (4, 4, 4)
    ```
    """
    import jax.export

    return [jax.export.DisabledSafetyCheck.custom_call(name) for name in _kernels.TARGETS]

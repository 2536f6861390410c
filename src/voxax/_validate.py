"""Input checks shared by every public entry point.

Every function that takes meshes, grids, PRNG keys, dtypes or counts checks them here, so
that the same mistake gives the same message everywhere: `"<function>: `<argument>` must
..."`. Checks that need values (NaN, index ranges) run only on concrete arrays; under
`jax.jit` the C++ kernels (or the pure-JAX code) see the traced values instead.

Nothing here builds JAX arrays (callers convert after checking), except `finite_values`,
which ties a traced array to the kernels' value check.
"""

from __future__ import annotations

import contextlib
import math
import operator
import os
import warnings

import numpy as np

from ._constants import MAX_ABS_COORDINATE

__all__ = [
    "INT32_MAX",
    "is_concrete",
    "is_mesh_object",
    "mesh_object_arrays",
    "unpack_mesh",
    "is_mesh_pair",
    "mesh_like",
    "key_or_seed",
    "numpy_rng",
    "jax_key",
    "mesh",
    "grid",
    "key",
    "float_dtype",
    "positive_int",
    "positive_float",
    "finite_number",
    "face_kind",
    "coordinates",
    "ray_interval",
    "finite_values",
    "file_path",
    "writing",
    "flag",
]

INT32_MAX = int(np.iinfo(np.int32).max)


def is_concrete(x) -> bool:
    """Whether `x` holds values (not a JAX tracer)."""
    import jax

    return not isinstance(x, jax.core.Tracer)


def holds_tracer(x, depth: int = 0) -> bool:
    """Whether `x` is a JAX tracer or holds one (in a tuple, a list, a dict or a mesh
    object's `vertices` / `faces`)."""
    if not is_concrete(x):
        return True
    if depth > 3:
        return False
    if isinstance(x, (tuple, list)):
        return any(holds_tracer(a, depth + 1) for a in x)
    if isinstance(x, dict):
        return any(holds_tracer(a, depth + 1) for a in x.values())
    if is_mesh_object(x):
        return holds_tracer(x.vertices, depth + 1) or holds_tracer(x.faces, depth + 1)
    return False


def host_only(where: str, instead: str | None = None):
    """Marks a function that computes eagerly on the host (NumPy and the C++ kernels' eager
    entry points): called with a traced argument (under `jax.jit`, `jax.grad`,
    `jax.vmap`) it raises one `TypeError` that says so, and names the traceable function
    to use `instead` when there is one, rather than JAX's TracerArrayConversionError from
    deep inside."""
    import functools

    def decorate(fn):
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            if any(holds_tracer(a) for a in args) or any(holds_tracer(a) for a in kwargs.values()):
                hint = f"; under a trace use {instead}" if instead else ""
                raise TypeError(f"{where}: computes eagerly on the host (NumPy in, NumPy out) and cannot take "
                                f"traced values: call it outside jax.jit / jax.grad / jax.vmap{hint}")
            return fn(*args, **kwargs)

        return wrapper

    return decorate


def is_mesh_object(x) -> bool:
    """A `voxax.Mesh`, a `trimesh.Trimesh` or anything else with `.vertices` and `.faces`."""
    return not hasattr(x, "shape") and hasattr(x, "vertices") and hasattr(x, "faces")


def mesh_object_arrays(where: str, obj) -> tuple:
    """`(vertices, faces)` of a mesh object (see `is_mesh_object`)."""
    if not is_mesh_object(obj):
        raise TypeError(
            f"{where}: expected a voxax.Mesh, a trimesh.Trimesh or a (vertices, faces) pair, got {type(obj).__name__}"
        )
    vertices, faces = obj.vertices, obj.faces
    if not hasattr(vertices, "dtype"):
        vertices = np.asarray(vertices)
    if not hasattr(faces, "dtype"):
        faces = np.asarray(faces)
    if vertices.dtype.kind in "iub":  # trimesh keeps float64; other mesh types may not
        vertices = np.asarray(vertices, dtype=np.float64)
    return vertices, faces


def _rank(x) -> int:
    """`np.ndim(x)`, or -1 for what is not one array (a ragged list, a tuple of tracers)."""
    if hasattr(x, "ndim"):
        return x.ndim
    try:
        return np.ndim(x)
    except Exception:
        return -1


def is_mesh_pair(x) -> bool:
    """A `(vertices, faces)` pair: a tuple or list of two arrays of rank 2 or more."""
    return isinstance(x, (tuple, list)) and len(x) == 2 and all(_rank(a) >= 2 for a in x)


def _not_a_surface(where: str, value) -> None:
    """Raises a `TypeError` that says what to do for the common non-surface inputs."""
    kind = type(value).__name__
    if isinstance(value, (str, os.PathLike)):
        raise TypeError(f"{where}: got a file path ({os.fspath(value)!r}); load it first: voxax.io.load(path)")
    if hasattr(value, "geometry") and hasattr(value, "dump"):
        raise TypeError(
            f"{where}: got a trimesh.Scene; pass one mesh: scene.dump(concatenate=True) or voxax.io.load(path)"
        )
    from ._grid import Grid

    if isinstance(value, Grid):
        raise TypeError(f"{where}: got a voxax.Grid where the mesh goes: the mesh comes first, then the grid")
    raise TypeError(
        f"{where}: expected a voxax.Mesh, a trimesh.Trimesh, a (vertices, faces) pair or vertices and faces, "
        f"got {kind}"
    )


def unpack_mesh(where: str, vertices, faces, *params):
    """The one coercion of a surface argument: `f(vertices, faces, p1, ...)` or `f(mesh, p1, ...)`.

    `vertices` may be a mesh object (a `voxax.Mesh`, a `trimesh.Trimesh`, anything with
    `.vertices` and `.faces`) or a `(vertices, faces)` pair; then the values passed
    positionally after it sit one slot to the left (the `faces` slot holds `p1`), and values
    given by keyword sit in their own slots. Required parameters default to None, so the
    positional values are the leading run of non-None slots. A file path, a
    `trimesh.Scene` or a grid in the mesh's place get a `TypeError` that says what to pass.
    Returns `(vertices, faces, (p1, p2, ...))`.
    """
    from ._grid import Grid

    if isinstance(vertices, Grid):
        _not_a_surface(where, vertices)
    pair = is_mesh_pair(vertices)
    if not pair and not is_mesh_object(vertices):
        if isinstance(vertices, (str, os.PathLike)) or not hasattr(vertices, "__len__") and not hasattr(vertices, "shape"):
            _not_a_surface(where, vertices)
        if hasattr(vertices, "geometry") and hasattr(vertices, "dump"):
            _not_a_surface(where, vertices)
        if faces is None:
            if isinstance(vertices, (tuple, list)) and len(vertices) == 2 and all(
                    hasattr(a, "shape") for a in vertices):
                shapes = " and ".join(str(tuple(np.shape(a))) for a in vertices)
                raise ValueError(f"{where}: a (vertices, faces) pair needs two arrays of rank 2 or more "
                                 f"(vertices (V, d), faces (F, k)), got shapes {shapes}")
            raise TypeError(
                f"{where}: missing `faces` (pass `vertices, faces`, a (vertices, faces) pair or a voxax.Mesh)"
            )
        return vertices, faces, params
    v, f = vertices if pair else mesh_object_arrays(where, vertices)
    slots = (faces,) + params
    n = 0
    while n < len(slots) and slots[n] is not None:
        n += 1
    if n > len(params):
        raise TypeError(f"{where}: got a mesh object and `faces`; pass either a mesh or `vertices, faces`")
    shifted = tuple(slots[j] if j < n else params[j] for j in range(len(params)))
    return v, f, shifted


def _is_plain(x) -> bool:
    """True for inputs converted to NumPy (NumPy arrays, lists, tuples, scalars)."""
    return isinstance(x, (np.ndarray, list, tuple, np.generic, int, float))


def mesh_like(where: str, value) -> tuple:
    """`(vertices, faces)` from a `voxax.Mesh`, a `trimesh.Trimesh` or a `(vertices, faces)` pair.

    Mesh objects give float64 vertices and int32 faces. In a pair, NumPy arrays and nested
    lists are converted (integer vertices to float64, faces to int32; floating vertices
    keep their dtype) and other array types (JAX arrays, tracers) are returned unchanged;
    leading batch axes are allowed. Shapes and concrete face indices are checked.
    """
    if is_mesh_object(value):
        vertices, faces = mesh_object_arrays(where, value)
        vertices, faces = mesh(where, vertices, faces, allow_empty=True, finite=False)
        return np.asarray(vertices, dtype=np.float64), np.ascontiguousarray(np.asarray(faces, dtype=np.int32))
    if isinstance(value, (tuple, list)) and len(value) == 2:
        vertices, faces = value
        if _is_plain(vertices):
            vertices = np.asarray(vertices)
            if vertices.dtype.kind in "iub":
                vertices = vertices.astype(np.float64)
            vertices = np.ascontiguousarray(vertices)
        if _is_plain(faces):
            faces = np.asarray(faces)
            if faces.size == 0:
                d = np.shape(vertices)[-1] if np.ndim(vertices) >= 1 else 3
                faces = faces.astype(np.int32).reshape(0, d)
        vertices, faces = mesh(where, vertices, faces, batch=True, allow_empty=True, finite=False)
        if isinstance(faces, np.ndarray):
            faces = np.ascontiguousarray(faces.astype(np.int32))
        return vertices, faces
    _not_a_surface(where, value)


def face_kind(d: int) -> str:
    return "triangles (F, 3)" if d == 3 else "segments (F, 2)"


def mesh(
    where: str,
    vertices,
    faces,
    *,
    dim: int | None = None,
    batch: bool = False,
    integer_vertices: bool = False,
    allow_empty: bool = False,
    finite: bool = True,
    faces_dim: int | None = None,
    context: str | None = None,
):
    """Checks a `(vertices, faces)` pair; returns them (array-likes made NumPy arrays).

    **Arguments:**

    - `where`: the public function's name, which starts every message.
    - `vertices`: `(V, d)` (or `(..., V, d)` with `batch`) float array.
    - `faces`: `(F, d)` (or `(..., F, d)` with `batch`) int array.
    - `dim`: the required `d` (the grid's), or None for 2 or 3.
    - `batch`: whether leading batch axes are allowed (they must broadcast).
    - `integer_vertices`: accept integer vertices (converted to float64).
    - `allow_empty`: accept meshes without vertices or faces.
    - `finite`: check that concrete vertices are finite and within
      `MAX_ABS_COORDINATE` (face index ranges are always checked on concrete faces).
    - `faces_dim`: the required number of corners per face when it is not `d` (ARAP
      takes triangles of 2D vertices).
    - `context`: why `dim` is required, for the message (default: "for a {dim}D grid").
    """
    if is_mesh_object(vertices) or is_mesh_object(faces):
        raise TypeError(f"{where}: pass a mesh object in place of both `vertices` and `faces`, not as one of them")
    if not hasattr(vertices, "dtype"):
        vertices = np.asarray(vertices)
    if not hasattr(faces, "dtype"):
        faces = np.asarray(faces)
        if faces.size == 0 and faces.ndim <= 1:
            d0 = vertices.shape[-1] if vertices.ndim >= 1 else 3
            faces = np.zeros((0, d0), np.int32)
    vdtype = np.dtype(vertices.dtype)
    if vdtype.kind in "iub" and integer_vertices:
        vertices = np.asarray(vertices, dtype=np.float64)
        vdtype = np.dtype(np.float64)
    if vdtype not in (np.float32, np.float64):
        got = "integers" if vdtype.kind in "iub" else str(vdtype)
        raise TypeError(f"{where}: `vertices` must be float32 or float64, got {got}")
    fdtype = np.dtype(faces.dtype)
    if fdtype.kind not in "iu":
        raise TypeError(f"{where}: `faces` must be an integer array, got {fdtype}")
    dims = (2, 3) if dim is None else (dim,)
    lead = "(..., V, {})" if batch else "(V, {})"
    if vertices.ndim < 2 or vertices.shape[-1] not in dims or (not batch and vertices.ndim != 2):
        want = " or ".join(lead.format(d) for d in dims)
        grid_note = "" if dim is None else f" ({context})" if context else f" for a {dim}D grid"
        batch_note = "" if batch else " (use jax.vmap for batches)" if vertices.ndim > 2 else ""
        raise ValueError(f"{where}: `vertices` must have shape {want}{grid_note}{batch_note}, got {tuple(vertices.shape)}")
    d = vertices.shape[-1]
    k = d if faces_dim is None else faces_dim
    if faces.ndim < 2 or faces.shape[-1] != k or (not batch and faces.ndim != 2):
        kind = face_kind(k) if faces_dim is None else f"triangles (F, {k})"
        raise ValueError(
            f"{where}: `faces` of shape {tuple(faces.shape)} do not match the vertices: "
            f"{d}D vertices need {kind}"
        )
    if not all(isinstance(n, (int, np.integer)) for n in (*vertices.shape, *faces.shape)):
        raise ValueError(
            f"{where}: symbolic shapes (jax.export with shape polymorphism) are not supported; export with concrete "
            "vertex and face counts (pad meshes with degenerate faces to share one shape)"
        )
    nv, nf = vertices.shape[-2], faces.shape[-2]
    if not allow_empty and (nv == 0 or nf == 0):
        raise ValueError(f"{where}: empty mesh ({nv} vertices, {nf} faces)")
    if nv > INT32_MAX or nf > INT32_MAX:
        raise ValueError(f"{where}: at most 2^31 - 1 vertices and faces are supported")
    if batch:
        try:
            np.broadcast_shapes(tuple(vertices.shape[:-2]), tuple(faces.shape[:-2]))
        except ValueError:
            raise ValueError(
                f"{where}: batch axes of `vertices` {tuple(vertices.shape)} and `faces` "
                f"{tuple(faces.shape)} do not broadcast"
            ) from None
    if finite and is_concrete(vertices) and vertices.size:
        v = np.asarray(vertices)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"{where}: `vertices` contain NaN or Inf")
        if float(np.max(np.abs(v))) > MAX_ABS_COORDINATE:
            raise ValueError(f"{where}: vertex coordinates must have magnitude <= {MAX_ABS_COORDINATE:g}".replace("e+", "e"))
    if is_concrete(faces) and faces.size:
        f = np.asarray(faces)
        lo, hi = int(f.min()), int(f.max())
        if lo < 0 or hi >= nv:
            raise ValueError(f"{where}: face indices out of range: they must lie in [0, {nv}), got [{lo}, {hi}]")
    return vertices, faces


def grid(where: str, value, dim: int | None = None):
    """Checks that `value` is a `voxax.Grid` (of dimension `dim` when given)."""
    from ._grid import Grid

    if value is None:
        raise TypeError(f"{where}: missing `grid` (a voxax.Grid)")
    if not isinstance(value, Grid):
        raise TypeError(f"{where}: `grid` must be a voxax.Grid, got {type(value).__name__}")
    if dim is not None and value.dim != dim:
        raise ValueError(f"{where}: `grid` must be {dim}D, got a {value.dim}D grid")
    return value


def key(where: str, value):
    """Checks a JAX PRNG key (new-style `jax.random.key` or legacy `PRNGKey`); returns it as an array."""
    import jax
    import jax.numpy as jnp

    if value is None or isinstance(value, (bool, int, float, np.integer, np.floating, str, bytes)):
        raise TypeError(f"{where}: `key` must be a JAX PRNG key, e.g. jax.random.key(0), not {type(value).__name__}")
    if not hasattr(value, "dtype"):
        value = typed_array(where, "key", value, "u", "a JAX PRNG key, e.g. jax.random.key(0)")
    value = value if isinstance(value, jax.Array) else jnp.asarray(value)
    typed = jnp.issubdtype(value.dtype, jax.dtypes.prng_key)
    if not typed and not (value.dtype == jnp.uint32 and value.shape == (2,)):
        raise TypeError(
            f"{where}: `key` must be a JAX PRNG key (jax.random.key or PRNGKey), got {value.dtype}{tuple(value.shape)}"
        )
    return value


def float_dtype(where: str, dtype=None) -> np.dtype:
    """The working float dtype: `dtype` (float32 or float64), or float64 when x64 is on, else float32."""
    import jax

    if dtype is None:
        return np.dtype(np.float64) if jax.config.jax_enable_x64 else np.dtype(np.float32)
    try:
        dtype = np.dtype(dtype)
    except TypeError:
        raise TypeError(f"{where}: `dtype` must be float32 or float64, got {dtype!r}") from None
    if dtype not in (np.float32, np.float64):
        raise TypeError(f"{where}: `dtype` must be float32 or float64, got {dtype}")
    if dtype == np.float64 and not jax.config.jax_enable_x64:
        raise ValueError(
            f"{where}: dtype=float64 needs 64-bit JAX: call jax.config.update('jax_enable_x64', True) first"
        )
    return dtype


def positive_int(where: str, name: str, value, minimum: int = 1, multiple: int = 1, *, maximum: int | None = None,
                 bytes_each: float = 0.0) -> int:
    """Checks an integer argument `>= minimum` (and a multiple of `multiple`, at most
    `maximum`); returns it as int. With `bytes_each`, a count whose `count * bytes_each`
    bytes exceed the memory available gets a `MemoryError` (`check_allocation`) before
    anything is allocated."""
    if isinstance(value, bool):
        raise TypeError(f"{where}: `{name}` must be an int, got bool")
    try:
        out = operator.index(value)
    except TypeError:
        raise TypeError(f"{where}: `{name}` must be an int, got {type(value).__name__}") from None
    if out < minimum:
        raise ValueError(f"{where}: `{name}` must be at least {minimum}, got {out}")
    if out % multiple:
        raise ValueError(f"{where}: `{name}` must be a multiple of {multiple}, got {out}")
    if maximum is not None and out > maximum:
        raise ValueError(f"{where}: `{name}` must be at most {maximum}, got {out}")
    if bytes_each:
        check_allocation(where, float(out) * bytes_each, f"`{name}` = {out}", f"pass a smaller `{name}`")
    return int(out)


def positive_float(where: str, name: str, value, allow_zero: bool = False) -> float:
    """Checks a finite number `> 0` (or `>= 0`); returns it as float."""
    if isinstance(value, (bool, np.bool_, str, bytes)):
        raise TypeError(f"{where}: `{name}` must be a number, got {type(value).__name__}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise TypeError(f"{where}: `{name}` must be a number, got {type(value).__name__}") from None
    ok = out >= 0 if allow_zero else out > 0
    if not (ok and math.isfinite(out)):
        raise ValueError(f"{where}: `{name}` must be {'>= 0' if allow_zero else '> 0'} and finite, got {value}")
    return out


def positive_number(where: str, name: str, value, allow_zero: bool = False):
    """A parameter such as a sharpness or a tolerance, concrete or traced: a concrete one is
    checked by `positive_float` (and returned as a float); a traced one is returned tied
    to the value-check kernel (`finite_values`: finite, and `> 0` unless `allow_zero`), so
    that under `jax.jit` a bad value fails naming the function instead of giving NaN."""
    if is_concrete(value):
        return positive_float(where, name, value, allow_zero)
    import jax.numpy as jnp

    return finite_values(where, name, jnp.asarray(value), positive=not allow_zero)


def typed_array(where: str, name: str, value, kinds: str = "fiu", what: str = "a real array"):
    """`value` itself if it has a dtype (a NumPy or JAX array, traced or not), else as a
    NumPy array; its dtype's kind must be one of `kinds` (NumPy's letters: "f" float, "i"
    and "u" integers, "b" bool): else `TypeError` "`<name>` must be <what>"."""
    if not hasattr(value, "dtype"):
        try:
            value = np.asarray(value)
        except (TypeError, ValueError):
            raise TypeError(f"{where}: `{name}` must be {what}, got {type(value).__name__}") from None
    if np.dtype(value.dtype).kind not in kinds:
        raise TypeError(f"{where}: `{name}` must be {what}, got {value.dtype}")
    return value


def coordinates(where: str, name: str, value, d: int | None = 3, *, finite: bool = True):
    """Checks an array of points `(..., d)` (any `d >= 1` for `d=None`): a real (float or
    integer) dtype, never bool, complex or strings, and, when concrete and `finite`, finite
    values of magnitude at most `MAX_ABS_COORDINATE`. Array-likes become NumPy arrays;
    other arrays (JAX arrays, tracers) are returned unchanged."""
    if not hasattr(value, "dtype"):
        try:
            value = np.asarray(value)
        except (TypeError, ValueError):
            what = "points" if d is None else f"{d}D points"
            raise TypeError(f"{where}: `{name}` must be a real array of {what}, got {type(value).__name__}") from None
    kind = np.dtype(value.dtype).kind
    if kind not in "fiu":
        raise TypeError(f"{where}: `{name}` must be a real (float or integer) array, got {value.dtype}")
    if value.ndim < 1 or (d is not None and value.shape[-1] != d) or value.shape[-1] < 1:
        raise ValueError(f"{where}: `{name}` must have shape (..., {'d' if d is None else d}), got {tuple(value.shape)}")
    if not finite:
        return value
    if kind == "f" and is_concrete(value) and value.size:
        a = np.asarray(value)
        hi, lo = a.max(), a.min()  # NaN propagates through both reductions, Inf shows
        if not (np.isfinite(hi) and np.isfinite(lo)):
            raise ValueError(f"{where}: `{name}` contain NaN or Inf")
        if max(float(hi), -float(lo)) > MAX_ABS_COORDINATE:
            raise ValueError(f"{where}: `{name}` coordinates must have magnitude <= {MAX_ABS_COORDINATE:g}".replace("e+", "e"))
    elif kind in "iu" and is_concrete(value) and value.size:
        a = np.asarray(value)
        if max(abs(int(a.max())), abs(int(a.min()))) > MAX_ABS_COORDINATE:
            raise ValueError(f"{where}: `{name}` coordinates must have magnitude <= {MAX_ABS_COORDINATE:g}".replace("e+", "e"))
    return value


def finite_values(where: str, name: str, value, max_abs: float | None = None, positive: bool = False):
    """Checks that a float array holds finite values (of magnitude at most `max_abs` when
    given; all > 0 with `positive`), eagerly and under `jax.jit`: a concrete array is
    checked here (`ValueError`);
    a traced one is returned tied to the value check of the kernels
    (`voxax._kernels.checks`), which fails the computation with the same message (a
    `jax.errors.JaxRuntimeError`). Returns `value` (a traced value as the checked copy,
    which is what the caller must use)."""
    if is_concrete(value):
        a = np.asarray(value)
        if a.size:
            hi, lo = a.max(), a.min()  # NaN propagates through both reductions, Inf shows
            if not (np.isfinite(hi) and np.isfinite(lo)):
                raise ValueError(f"{where}: `{name}` must be finite (it contains NaN or Inf)")
            if max_abs is not None and max(float(hi), -float(lo)) > max_abs:
                raise ValueError(f"{where}: `{name}` must have magnitude <= {max_abs:g}".replace("e+", "e"))
            if positive and not lo >= np.finfo(a.dtype if a.dtype.kind == "f" else np.float64).tiny:
                raise ValueError(f"{where}: `{name}` must be > 0 (zero, negative and subnormal values are "
                                 f"refused), got {lo:g}")
        return value
    import jax
    import jax.numpy as jnp

    from ._kernels.checks import finite_check_ffi

    limit = float("inf") if max_abs is None else float(max_abs)
    checked = jax.lax.stop_gradient(value)
    if checked.dtype not in (jnp.float32, jnp.float64):  # float16, bfloat16: widened for the check
        checked = checked.astype(jnp.float32)
    flag = finite_check_ffi(checked, where, name, limit, positive)
    return jnp.where(flag == 0, value, jnp.nan)


def ray_interval(where: str, t_min, t_max) -> tuple:
    """Checks a ray interval `[t_min, t_max]` (numbers, not NaN, `t_min <= t_max`);
    returns it as floats."""
    out = []
    for name, t in (("t_min", t_min), ("t_max", t_max)):
        if not is_concrete(t):
            raise TypeError(f"{where}: `{name}` must be a concrete number (it bounds the kernel's search), "
                            "not a traced value")
        if isinstance(t, (str, bytes, bool)) or not isinstance(t, (int, float, np.integer, np.floating)):
            if not (hasattr(t, "shape") and np.shape(t) == () and np.dtype(t.dtype).kind in "fiu"):
                raise TypeError(f"{where}: `{name}` must be a number, got {type(t).__name__}")
        out.append(float(t))
    lo, hi = out
    if math.isnan(lo) or math.isnan(hi) or not lo <= hi:
        raise ValueError(f"{where}: the ray interval needs t_min <= t_max (neither NaN), got [{lo}, {hi}]")
    return lo, hi


def finite_number(where: str, name: str, value, note: str = "") -> float:
    """Checks a real, finite Python number (not a bool, string or array); returns it as float."""
    if isinstance(value, (bool, np.bool_, str, bytes, complex, np.complexfloating)):
        raise TypeError(f"{where}: `{name}` must be a real number{note}, got {type(value).__name__}")
    try:
        out = float(value)
    except (TypeError, ValueError, AttributeError):  # a tracer, an array of several values, ...
        raise TypeError(f"{where}: `{name}` must be a real number{note}, got {type(value).__name__}") from None
    if not math.isfinite(out):
        raise ValueError(f"{where}: `{name}` must be finite, got {value}")
    return out


def key_or_seed(where: str, key, seed=None, default=0):
    """The `key` of a function that took `seed=` before (kept one release, with a warning).

    Returns `key`, or `seed` when only the deprecated `seed` was given (with a
    `DeprecationWarning`), or `default` when neither was.
    """
    if seed is not None:
        warnings.warn(
            f"{where}: `seed` is deprecated and will be removed; pass `key` (an int or a JAX PRNG key)",
            DeprecationWarning,
            stacklevel=3,
        )
        if key is not None:
            raise TypeError(f"{where}: pass `key` or the deprecated `seed`, not both")
        return seed
    return default if key is None else key


def _int_key(where: str, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{where}: `key` must be an int or a JAX PRNG key, got {type(value).__name__}")
    if not 0 <= value <= _INT64[1]:
        raise ValueError(f"{where}: `key` must be an int in [0, 2^63) or a JAX PRNG key, got {value}")
    return int(value)


def numpy_rng(where: str, value) -> np.random.Generator:
    """A NumPy generator from `key`: an int seed or a JAX PRNG key (its key data seeds it)."""
    if isinstance(value, (int, np.integer, bool)) or value is None:
        return np.random.default_rng(_int_key(where, value))
    import jax

    data = np.asarray(jax.random.key_data(key(where, value)), dtype=np.uint32).ravel()
    return np.random.default_rng([int(w) for w in data])


def jax_key(where: str, value):
    """A JAX PRNG key from `key`: an int seed (`jax.random.key(int)`) or a JAX PRNG key."""
    import jax

    if value is None or isinstance(value, (bool, float, np.floating, str)):
        raise TypeError(f"{where}: `key` must be an int or a JAX PRNG key, got {type(value).__name__}")
    if isinstance(value, (int, np.integer)):
        return jax.random.key(_int_key(where, value))
    return key(where, value)


def _looks_like_faces(first, second) -> bool:
    """Whether `f(first, second, ...)` is `f(vertices, faces, ...)`: an array of rank 2 or
    more and an integer array of rank 2 or more (points, rays and counts are not)."""
    if not (hasattr(first, "shape") or isinstance(first, (list, tuple))) or _rank(first) < 2:
        return False
    if is_mesh_object(second) or _rank(second) < 2:
        return False
    kind = second.dtype.kind if hasattr(second, "dtype") else np.asarray(second).dtype.kind
    return kind in "iu"


def surface_first(fn):
    """Lets a function whose first parameter is one surface (`f(mesh, p1, ...)`) take the
    other surface forms too: `f(vertices, faces, p1, ...)` and `f(vertices, faces=faces,
    ...)`. The surface reaches `fn` as a mesh object or a `(vertices, faces)` pair (turn it
    into arrays with `mesh_like`), so every surface form goes through one coercion."""
    import functools
    import inspect

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        faces = kwargs.pop("faces", None)
        if not args:
            return fn(*args, **kwargs)
        first = args[0]
        if is_mesh_object(first) or is_mesh_pair(first):
            if faces is not None:
                raise TypeError(f"{fn.__name__}: got a mesh object and `faces`; pass either a mesh or `vertices, faces`")
            return fn(*args, **kwargs)
        if faces is None and len(args) >= 2 and _looks_like_faces(first, args[1]):
            faces, args = args[1], args[:1] + args[2:]
        if faces is None:
            return fn(*args, **kwargs)  # `fn` says what is wrong with its first argument
        return fn((first, faces), *args[1:], **kwargs)

    sig = inspect.signature(fn)
    params = [p for p in sig.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
    rest = [p for p in sig.parameters.values() if p.kind is inspect.Parameter.VAR_KEYWORD]
    extra = inspect.Parameter("faces", inspect.Parameter.KEYWORD_ONLY, default=None)
    wrapper.__signature__ = sig.replace(parameters=[*params, extra, *rest])
    return wrapper


def host_threads(where: str, threads) -> int:
    """The thread count for a host kernel (`voxax._kernels.threads`: None is
    `VOXAX_NUM_THREADS` or every core), its errors naming `where`."""
    from . import _kernels

    try:
        return _kernels.threads(threads)
    except (TypeError, ValueError) as err:
        raise type(err)(f"{where}: {err}") from None


def available_memory() -> int:
    """Bytes of memory available now (`MemAvailable`, else the physical memory)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return 1 << 62


def check_allocation(where: str, nbytes: float, what: str, hint: str = "use a coarser grid") -> None:
    """A `MemoryError` before allocating `nbytes` for `what` when they exceed the memory
    available."""
    available = available_memory()
    if nbytes > available:
        raise MemoryError(
            f"{where}: {what} needs about {nbytes / 2**30:.1f} GiB, more than the {available / 2**30:.1f} GiB "
            f"of memory available; {hint}"
        )


def int32_faces(faces):
    """Faces as an int32 JAX array. Concrete indices are cast (check their range first);
    traced ones are clipped to [-1, 2^31 - 1] first, so that indices beyond int32 stay out
    of range (and the kernels refuse them) instead of wrapping into it."""
    import jax.numpy as jnp

    kind = np.dtype(faces.dtype)
    if kind == np.int32:
        return jnp.asarray(faces)
    if is_concrete(faces):
        return jnp.asarray(np.asarray(faces).astype(np.int32))
    return jnp.clip(faces, -1 if kind.kind == "i" else 0, INT32_MAX).astype(jnp.int32)


def file_path(where: str, name: str, value) -> str:
    """`value` as a file name (`str` or `os.PathLike`, not bytes); else `TypeError`."""
    if isinstance(value, bytes):
        raise TypeError(f"{where}: `{name}` must be a file path (str or os.PathLike), got bytes")
    try:
        return os.fspath(value)
    except TypeError:
        raise TypeError(f"{where}: `{name}` must be a file path (str or os.PathLike), got {type(value).__name__}") from None


@contextlib.contextmanager
def writing(where: str, path: str):
    """Writing `path`: an `OSError` (missing folder, no permission, a folder of that name)
    is raised again, of the same type, as one line naming the function and the file."""
    try:
        yield
    except OSError as err:
        reason = err.strerror or str(err)
        raise type(err)(f"{where}: cannot write {path!r}: {reason}") from None


def flag(where: str, name: str, value) -> bool:
    """A yes/no option: `True` or `False` (NumPy's bools too), never a string or a number
    whose truth would be taken silently (`normalize="no"` is true)."""
    if not isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{where}: `{name}` must be True or False, got {type(value).__name__}")
    return bool(value)


_INT64 = (-(2**63), 2**63 - 1)


def real_value(where: str, name: str, value, kinds: str = "fiub", sequences: bool = True):
    """Checks a number or array argument that JAX will trace (a weight, a radius, a grid):
    a NumPy or JAX array or tracer of a dtype in `kinds`, or a Python number (not complex;
    an int within int64), or a nested list or tuple of them. Strings, None, objects and
    complex values get a `TypeError` naming the argument here, instead of JAX's message
    from inside the trace (lists and tuples too with `sequences=False`, for a value used
    as is). Returns `value` unchanged."""
    what = "a real number or array"
    if hasattr(value, "dtype"):
        if np.dtype(value.dtype).kind not in kinds:
            raise TypeError(f"{where}: `{name}` must be {what}, got {value.dtype}")
        return value
    if isinstance(value, bool):
        if "b" not in kinds:
            raise TypeError(f"{where}: `{name}` must be {what}, got bool")
        return value
    if isinstance(value, int):
        if not _INT64[0] <= value <= _INT64[1]:
            raise ValueError(f"{where}: `{name}` must fit in int64, got {value}")
        return value
    if isinstance(value, float):
        return value
    if isinstance(value, (list, tuple)) and value and sequences:
        for item in value:
            real_value(where, name, item, kinds)
        return value
    raise TypeError(f"{where}: `{name}` must be {what}, got {type(value).__name__}")


def checked_jit(where: str, static_argnames: tuple = (), positive: tuple = (), scalar: tuple = ()):
    """`jax.jit` with its traced arguments checked first, outside the trace, by
    `real_value` (arguments whose default is None may be None; pytrees of arrays, such as
    a `Grid` given as static, are left to the function). So that `f(W, w="3")` fails
    with `voxax.<ns>.<fn>: `w` must be a real number or array` rather than JAX's message
    about abstract arrays. The arguments named in `positive` (a sharpness, a width) must
    moreover be `> 0` and finite: concrete scalars here (`positive_float`), traced values
    by the value-check kernel under the trace (`finite_values`). Those and the arguments
    named in `scalar` must be scalars (a list or an array is a `TypeError`, not a
    broadcasting error from inside)."""
    import functools
    import inspect

    def decorate(fn):
        import jax

        jitted = jax.jit(fn, static_argnames=static_argnames)
        signature = inspect.signature(fn)

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                bound = signature.bind(*args, **kwargs)
            except TypeError as err:
                raise TypeError(f"{where}: {err}") from None
            for name, value in bound.arguments.items():
                param = signature.parameters[name]
                if name in static_argnames:
                    try:
                        hash(value)
                    except TypeError:
                        raise TypeError(f"{where}: `{name}` must be a Python int, float, bool or str (it is "
                                        f"static), got {type(value).__name__}") from None
                    continue
                if value is None and param.default is None:
                    continue
                if param.kind is inspect.Parameter.VAR_POSITIONAL:
                    for item in value:
                        real_value(where, name, item)
                elif isinstance(value, (dict,)) or hasattr(value, "tree_flatten"):
                    continue
                else:
                    real_value(where, name, value)
                    if (name in positive or name in scalar) and np.ndim(value) != 0:
                        raise TypeError(f"{where}: `{name}` must be a scalar, got shape {np.shape(value)}")
                    if name in positive:
                        checked = positive_number(where, name, value)
                        if not is_concrete(value):  # traced: the checked copy, tied to the kernel's check
                            bound.arguments[name] = checked
                    if isinstance(value, (list, tuple)):  # nested numbers: one array, not a pytree of scalars
                        bound.arguments[name] = np.asarray(value)
            return jitted(*bound.args, **bound.kwargs)

        wrapper.jitted = jitted
        return wrapper

    return decorate

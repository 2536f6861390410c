"""The voxelization as JAX primitives: forward, tangent (forward mode) and backward.

Three primitives, each lowered to its FFI kernel (or, on non-CPU backends, to a host
callback running the same kernel):

- `voxax_voxelize(vertices, faces) -> W`, whose JVP is the tangent primitive applied to
  the vertex tangents gathered at the face corners;
- `voxax_voxelize_tangent(vertices, faces, corner_tangents) -> dW`, linear in the corner
  tangents, with the backward primitive as its transpose;
- `voxax_voxelize_backward(vertices, faces, cotangent) -> corner gradients`, linear in the
  cotangent, with the tangent primitive as its transpose.

So `jax.jvp`, `jax.jacfwd`, `jax.linearize`, `jax.grad`, `jax.vjp`, `jax.jacrev` and
`jax.linear_transpose` of the linearized map all work, and `jax.vmap` of each of them
(every primitive has a batching rule). Second derivatives with respect to the vertices
(the derivative of the splat itself) are not implemented: their rules raise an error that
names the alternative, Gauss-Newton products `J^T H J` from one `jax.jvp` and one
`jax.vjp`.

All three take arrays whose leading (batch) axes have the same count; each such axis is 1
(broadcast) or the output's size. `voxax.voxelize` brings its inputs into that form.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jax.extend.core import Primitive
from jax.interpreters import ad, batching, mlir

from .._kernels import voxelize as kernels

__all__ = [
    "SECOND_DERIVATIVE_MESSAGE",
    "backward",
    "forward",
    "gather_corners",
    "host_callback_forced",
    "set_host_callback",
    "tangent",
]

SECOND_DERIVATIVE_MESSAGE = (
    "voxax.voxelize: second derivatives with respect to the vertices (jax.hessian, "
    "jax.jacfwd of jax.grad, jax.grad of a gradient, jax.jvp of a jax.jvp) are not "
    "implemented; they need the derivative of the sub-triangle splat itself. For "
    "Gauss-Newton curvature, use J^T H J products: dW = jax.jvp(voxelize, (v,), (t,))[1], "
    "then H dW with the energy's own second derivative in grid space, then "
    "jax.vjp(voxelize, v)[1](H dW) (or a least-squares solver such as "
    "voxax.least_squares, which builds them)."
)

# -- host callback switch ----------------------------------------------------------------

_FORCE_HOST_CALLBACK = False


def set_host_callback(enabled: bool) -> None:
    """Forces (or stops forcing) the host-callback lowering on a CPU backend."""
    global _FORCE_HOST_CALLBACK
    _FORCE_HOST_CALLBACK = bool(enabled)


def host_callback_forced() -> bool:
    """Whether the host-callback lowering is forced."""
    return _FORCE_HOST_CALLBACK


# -- shapes --------------------------------------------------------------------------------


def _batch_shape(*shapes_and_trailing) -> tuple:
    batches = [tuple(s[: len(s) - k]) for s, k in shapes_and_trailing]
    return tuple(np.broadcast_shapes(*batches))


def _out_aval(like, shape, dtype):
    """An abstract value of `shape` and `dtype` varying over the same mesh axes as `like`.

    Inside `shard_map` the kernels' results vary across the mesh axes their inputs vary
    over; typing them so keeps transposition (and the sums across devices it inserts for
    replicated inputs) correct.
    """
    try:
        from jax._src import core as _core

        return like.update(shape=shape, dtype=dtype, weak_type=False, sharding=_core.get_cur_mesh_sharding())
    except (ImportError, AttributeError, TypeError):  # a JAX without these internals
        return jax.core.ShapedArray(shape, dtype)


def _varying_axes(x) -> frozenset:
    aval = jax.typeof(x)
    mat = getattr(aval, "mat", None)
    if mat is not None:
        return frozenset(getattr(mat, "varying", ()))
    return frozenset(getattr(aval, "vma", ()))


def _same_varying(*args):
    """Casts every argument to vary over the union of the mesh axes any of them varies over."""
    axes = frozenset().union(*(_varying_axes(a) for a in args))
    if not axes:
        return args
    out = []
    for a in args:
        missing = axes - _varying_axes(a)
        out.append(jax.lax.pcast(a, tuple(sorted(missing)), to="varying") if missing else a)
    return tuple(out)


def _reduce_to(x, shape):
    """Sums `x` over the leading axes along which an input of `shape` was broadcast."""
    axes = tuple(a for a in range(len(shape)) if shape[a] == 1 and x.shape[a] != 1)
    if axes:
        x = jnp.sum(x, axis=axes, keepdims=True)
    return x.reshape(shape)


# -- primitives ----------------------------------------------------------------------------

forward_p = Primitive("voxax_voxelize")
tangent_p = Primitive("voxax_voxelize_tangent")
backward_p = Primitive("voxax_voxelize_backward")


def forward(vertices, faces, grid):
    """W = voxelize(vertices, faces): `(*Bv, V, d)`, `(*Bf, F, d)` int32 -> `(*B, *grid)`."""
    vertices, faces = _same_varying(vertices, faces)
    return forward_p.bind(vertices, faces, grid=grid)


def tangent(vertices, faces, corner_tangents, grid):
    """dW for per-corner tangents `(*Bt, F, d, d)` -> `(*B, *grid)` (linear in the tangents)."""
    vertices, faces, corner_tangents = _same_varying(vertices, faces, corner_tangents)
    return tangent_p.bind(vertices, faces, corner_tangents, grid=grid)


def backward(vertices, faces, cotangent, grid):
    """Corner gradients `(*B, F, d, d)` of `sum(cotangent * W)` (linear in the cotangent)."""
    vertices, faces, cotangent = _same_varying(vertices, faces, cotangent)
    return backward_p.bind(vertices, faces, cotangent, grid=grid)


def gather_corners(t, faces):
    """Per-corner values `(*B, F, k, d)` of per-vertex values `t: (*Bt, V, d)` (same batch rank)."""
    batch = _batch_shape((t.shape, 2), (faces.shape, 2))
    nb = int(np.prod(batch, dtype=np.int64))
    nv, d = t.shape[-2:]
    nf, k = faces.shape[-2:]
    tb = jnp.broadcast_to(t, batch + (nv, d)).reshape((nb, nv, d))
    fb = jnp.broadcast_to(faces, batch + (nf, k)).reshape((nb, nf, k))
    out = jax.vmap(lambda ti, fi: ti[fi])(tb, fb)
    return out.reshape(batch + (nf, k, d))


def _forward_abstract(vertices, faces, *, grid):
    batch = _batch_shape((vertices.shape, 2), (faces.shape, 2))
    return _out_aval(vertices, batch + grid.shape, vertices.dtype)


def _tangent_abstract(vertices, faces, corner_tangents, *, grid):
    batch = _batch_shape((vertices.shape, 2), (faces.shape, 2), (corner_tangents.shape, 3))
    return _out_aval(vertices, batch + grid.shape, vertices.dtype)


def _backward_abstract(vertices, faces, cotangent, *, grid):
    batch = _batch_shape((vertices.shape, 2), (faces.shape, 2), (cotangent.shape, grid.dim))
    nf, d = faces.shape[-2:]
    return _out_aval(vertices, batch + (nf, d, d), vertices.dtype)


forward_p.def_abstract_eval(_forward_abstract)
tangent_p.def_abstract_eval(_tangent_abstract)
backward_p.def_abstract_eval(_backward_abstract)


def _impl(prim):
    @functools.lru_cache(maxsize=256)
    def compiled(grid, on_host):
        del on_host  # part of the key: the lowering depends on it
        return jax.jit(functools.partial(prim.bind, grid=grid))

    def impl(*args, grid):
        return compiled(grid, _FORCE_HOST_CALLBACK)(*args)

    return impl


for _p in (forward_p, tangent_p, backward_p):
    _p.def_impl(_impl(_p))


# -- differentiation -----------------------------------------------------------------------


def _is_zero(t) -> bool:
    return type(t) is ad.Zero


def _forward_jvp(primals, tangents, *, grid):
    vertices, faces = primals
    dv = tangents[0]
    out = forward(vertices, faces, grid)
    if _is_zero(dv):
        return out, ad.Zero.from_primal_value(out)
    return out, tangent(vertices, faces, gather_corners(dv, faces), grid)


def _linear_jvp(fn, primals, tangents, *, grid):
    vertices, faces, x = primals
    dv, _, dx = tangents
    if not _is_zero(dv):
        raise NotImplementedError(SECOND_DERIVATIVE_MESSAGE)
    out = fn(vertices, faces, x, grid)
    if _is_zero(dx):
        return out, ad.Zero.from_primal_value(out)
    return out, fn(vertices, faces, dx, grid)


def _linear_transpose(adjoint, ct, vertices, faces, x, *, grid):
    if ad.is_undefined_primal(vertices) or ad.is_undefined_primal(faces):
        raise NotImplementedError(SECOND_DERIVATIVE_MESSAGE)
    if _is_zero(ct):
        return None, None, ad.Zero(x.aval)
    out = adjoint(vertices, faces, ct, grid)
    return None, None, _reduce_to(out, x.aval.shape).astype(x.aval.dtype)


ad.primitive_jvps[forward_p] = _forward_jvp
ad.primitive_jvps[tangent_p] = functools.partial(_linear_jvp, tangent)
ad.primitive_jvps[backward_p] = functools.partial(_linear_jvp, backward)
ad.primitive_transposes[tangent_p] = functools.partial(_linear_transpose, backward)
ad.primitive_transposes[backward_p] = functools.partial(_linear_transpose, tangent)


# -- batching: a new leading batch axis on every argument (size 1 where unbatched) ---------


def _batch_rule(prim, args, dims, *, grid):
    moved = [a[None] if d is None else jnp.moveaxis(a, d, 0) for a, d in zip(args, dims)]
    return prim.bind(*moved, grid=grid), 0


for _p in (forward_p, tangent_p, backward_p):
    batching.primitive_batchers[_p] = functools.partial(_batch_rule, _p)


# -- lowering: the FFI kernel on CPU, a host callback elsewhere ----------------------------

_TARGETS = {forward_p: kernels.FORWARD, tangent_p: kernels.TANGENT, backward_p: kernels.BACKWARD}


def _lowering(prim):
    target = _TARGETS[prim]

    def rule(ctx, *args, grid):
        aval = ctx.avals_out[0]
        result = jax.ShapeDtypeStruct(aval.shape, aval.dtype)
        platforms = tuple(getattr(ctx.module_context, "platforms", ()) or ())
        on_host = _FORCE_HOST_CALLBACK or any(p != "cpu" for p in platforms)
        if on_host:
            host = functools.partial(kernels.host_call, target, result, grid)

            def run(*a):
                return jax.pure_callback(host, result, *a)

        else:

            def run(*a):
                return kernels.call(target, result, grid, *a)

        return mlir.lower_fun(run, multiple_results=False)(ctx, *args)

    return rule


for _p in (forward_p, tangent_p, backward_p):
    mlir.register_lowering(_p, _lowering(_p))

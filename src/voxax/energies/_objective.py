"""Combining energies into an optimistix-shaped objective `fn(y, args) -> scalar`."""

from __future__ import annotations

from collections.abc import Callable, Mapping

import jax.numpy as jnp

from .. import _validate

__all__ = ["objective"]


def objective(terms: dict, weights: dict | None = None, extras: Callable | None = None) -> Callable:
    """Builds `fn(y, args) -> (total, aux)` from named energy terms, for `voxax.minimize`.

    Each term is a function `term(y, args) -> scalar`. The objective returns the weighted
    sum of the terms and an aux dict holding every (unweighted) term by name, which
    `voxax.minimize(..., has_aux=True)` records in its history. `extras(y, args) -> dict`
    may add more aux entries (e.g. `"max_w"` for the `max_w_threshold` stopping rule).

    Terms that share work (one voxelization feeding several grid energies) are better
    written as one hand-made function; this helper is for the simple cases. Any energy
    can be given the `fn(y, args)` shape with a lambda or `functools.partial`, e.g.
    `lambda y, args: voxax.energies.arap(y, rest, faces)`.

    **Arguments:**

    - `terms`: `{name: term}` with `term(y, args) -> scalar`.
    - `weights`: optional `{name: float}`; missing names weigh 1.
    - `extras`: optional `extras(y, args) -> dict` of more aux entries.

    **Returns:**

    `fn(y, args) -> (scalar, dict)`, to be used with `has_aux=True`.

    **Example:**

    ```python
    >>> V0, F = voxax.io.normalize(voxax.data.bent_bar())
    >>> grid = voxax.Grid.cube(32)
    >>> fn = voxax.energies.objective(
    ...     {"sect": lambda V, a: voxax.energies.self_intersection(voxax.voxelize(V, F, grid)),
    ...      "arap": lambda V, a: voxax.energies.arap(V, V0, F)},
    ...     weights={"arap": 0.005})
    >>> result = voxax.minimize(fn, V0, has_aux=True, progress=False, stop=voxax.StopRules(max_steps=5))
    >>> sorted(result.history)
    ['arap', 'energy', 'sect', 'step_size', 'time']
    ```
    """
    where = "voxax.energies.objective"
    if not isinstance(terms, Mapping):
        raise TypeError(f"{where}: `terms` must be a dict {{name: term(y, args)}}, got {type(terms).__name__}")
    if not terms:
        raise ValueError(f"{where}: `terms` must hold at least one term (got an empty dict)")
    for name, term in terms.items():
        if not callable(term):
            raise TypeError(f"{where}: `terms` must map names to functions term(y, args); {name!r} is a "
                            f"{type(term).__name__}")
    if weights is not None and not isinstance(weights, Mapping):
        raise TypeError(f"{where}: `weights` must be a dict {{name: float}} or None, got {type(weights).__name__}")
    terms = dict(terms)
    weights = {name: _validate.finite_number(where, f"weights[{name!r}]", value) if _validate.is_concrete(value)
               else value for name, value in dict(weights or {}).items()}
    unknown = set(weights) - set(terms)
    if unknown:
        raise ValueError(f"{where}: `weights` names unknown terms {sorted(unknown)}")
    if extras is not None and not callable(extras):
        raise TypeError(f"{where}: `extras` must be a function extras(y, args) -> dict or None, got "
                        f"{type(extras).__name__}")

    def fn(y, args=None):
        aux = {}
        total = 0.0
        for name, term in terms.items():
            value = jnp.asarray(term(y, args))
            aux[name] = value
            total = total + weights.get(name, 1.0) * value
        if extras is not None:
            aux.update(extras(y, args))
        return jnp.asarray(total), aux

    return fn

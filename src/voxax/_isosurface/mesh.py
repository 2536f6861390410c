"""The result of the iso-surface functions: `IsoMesh`."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

__all__ = ["IsoMesh"]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class IsoMesh:
    """An extracted iso-surface: a triangle mesh (3D) or segment polyline (2D) and how it was made.

    It unpacks like a mesh, `vertices, faces = iso`, and is a JAX pytree (it passes through
    `jax.jit` and `jax.vmap`). With a static `capacity` the arrays are padded: vertices
    beyond `n_vertices` are zero and faces beyond `n_faces` are `(0, 0, 0)` (degenerate, so
    `voxelize` and the energies ignore them).

    **Fields:**

    - `vertices`: `(V, d)` float, the vertex positions (float64 when x64 is enabled).
    - `faces`: `(F, d)` int32, triangles (3D) or segments (2D), oriented outward: normals
      point from the inside (`inside=`) to the outside.
    - `edges`: `(V, 2)` int32, for each vertex the flat (C-order) indices of the two grid
      cells whose centres bracket it (of the padded grid when `close` was used).
    - `n_vertices`, `n_faces`: int32 scalars, the counts of valid entries.
    - `min_gap`: float scalar, the smallest `|f_b - f_a|` over the crossed edges (`inf` for
      an empty mesh). A vertex moves by at most `h / min_gap` per unit change of a sample,
      so a small gap flags an ill-conditioned (large) gradient.
    - `samples`: the sampled field the mesh was extracted from (only set by
      [`isosurface_fn`][voxax.isosurface_fn]; pass it as `band=` to the next call).
    - `n_evaluated`: how many field evaluations `isosurface_fn` made (eager calls only).
    """

    vertices: jax.Array
    faces: jax.Array
    edges: jax.Array
    n_vertices: jax.Array
    n_faces: jax.Array
    min_gap: jax.Array
    samples: object = None
    n_evaluated: object = dataclasses.field(default=None, metadata={"static": True})

    def __iter__(self):
        yield self.vertices
        yield self.faces

    def to_mesh(self):
        """The valid part as a `voxax.Mesh` (eager, unbatched results only)."""
        from .._mesh import Mesh

        nv, nf = int(self.n_vertices), int(self.n_faces)
        return Mesh(np.asarray(self.vertices)[:nv], np.asarray(self.faces)[:nf])

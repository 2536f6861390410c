"""Self-intersecting test meshes for `resolve_self_intersections` (tests and benchmarks)."""

from __future__ import annotations

import numpy as np

import voxax


def _extrude(polygon, height, offset, rotation=None):
    """A closed, outward-oriented prism over a simple polygon (counter-clockwise, (n, 2))."""
    import manifold3d

    section = manifold3d.CrossSection([np.asarray(polygon, dtype=np.float64)])
    solid = manifold3d.Manifold.extrude(section, height)
    mesh = solid.to_mesh()
    v = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
    v[:, 2] -= height / 2
    if rotation is not None:
        v = v @ np.asarray(rotation).T
    return v + np.asarray(offset, dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def _refine_faces(vertices, faces, max_edge):
    """Splits faces (1-to-4, all at once) until no edge is longer than `max_edge`, so that
    the solid can bend."""
    import trimesh

    v, f = trimesh.remesh.subdivide_to_size(vertices, faces, max_edge)
    return np.asarray(v), np.asarray(f)


def overlapping_letters(max_edge=0.08):
    """An extruded "L" and an extruded "T" pushed into each other (two closed components
    whose union overlaps: winding number 2 in the overlap)."""
    L = [(0, 0), (0.9, 0), (0.9, 0.3), (0.3, 0.3), (0.3, 1.2), (0, 1.2)]
    T = [(0.3, 0), (0.6, 0), (0.6, 0.9), (0.9, 0.9), (0.9, 1.2), (0, 1.2), (0, 0.9), (0.3, 0.9)]
    va, fa = _extrude(L, 0.35, (-0.6, -0.6, 0.0))
    c, s = np.cos(0.3), np.sin(0.3)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    vb, fb = _extrude(T, 0.35, (-0.05, -0.55, 0.1), rot)
    v = np.concatenate([va, vb])
    f = np.concatenate([fa, fb + len(va)])
    v, f = _refine_faces(v, f, max_edge)
    return voxax.Mesh(v, f.astype(np.int32))


def torus_knot_tube(tube_radius=0.55, n_along=160, n_around=12):
    """A tube around a trefoil knot, thick enough to pass through itself."""
    t = 2 * np.pi * np.arange(n_along) / n_along
    c = np.stack([np.sin(t) + 2 * np.sin(2 * t), np.cos(t) - 2 * np.cos(2 * t), -np.sin(3 * t)], 1)
    d1 = np.stack([np.cos(t) + 4 * np.cos(2 * t), -np.sin(t) + 4 * np.sin(2 * t), -3 * np.cos(3 * t)], 1)
    d2 = np.stack([-np.sin(t) - 8 * np.sin(2 * t), -np.cos(t) + 8 * np.cos(2 * t), 9 * np.sin(3 * t)], 1)
    tangent = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    binormal = np.cross(d1, d2)
    binormal /= np.linalg.norm(binormal, axis=1, keepdims=True)
    normal = np.cross(binormal, tangent)
    s = 2 * np.pi * np.arange(n_around) / n_around
    v = (
        c[:, None, :]
        + tube_radius * np.cos(s)[None, :, None] * normal[:, None, :]
        - tube_radius * np.sin(s)[None, :, None] * binormal[:, None, :]
    ).reshape(-1, 3)
    i = np.arange(n_along)[:, None]
    j = np.arange(n_around)[None, :]
    a = i * n_around + j
    b = ((i + 1) % n_along) * n_around + j
    c2 = ((i + 1) % n_along) * n_around + (j + 1) % n_around
    d = i * n_around + (j + 1) % n_around
    f = np.concatenate([np.stack([a, b, c2], -1).reshape(-1, 3), np.stack([a, c2, d], -1).reshape(-1, 3)])
    v = v / np.abs(v).max() * 0.8
    return voxax.Mesh(v, f.astype(np.int32))


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def deformed_hand(seed, resolution=16):
    """`voxax.data.hand` under a random smooth deformation that makes it intersect itself:
    the fingers on one side of a random split swing sideways through their neighbours
    (a rotation about the knuckles, blended smoothly across the split and the knuckles),
    plus a small random sinusoidal warp."""
    rng = np.random.default_rng(seed)
    m = voxax.data.hand(resolution=resolution)
    v = m.vertices.copy()
    x_split = rng.uniform(-0.25, 0.25)
    y_knuckle = rng.uniform(-0.05, 0.1)
    side = float(rng.choice([-1, 1]))  # rotate the fingers on this side of the split ...
    angle = rng.uniform(0.3, 0.5) * side  # ... towards it
    w = _smoothstep((v[:, 1] - y_knuckle) / 0.15 + 0.5) * _smoothstep(side * (v[:, 0] - x_split) / 0.08 + 0.5)
    dx, dy = v[:, 0] - x_split, v[:, 1] - y_knuckle
    c, s = np.cos(angle * w), np.sin(angle * w)
    v[:, 0] = x_split + c * dx - s * dy
    v[:, 1] = y_knuckle + s * dx + c * dy
    k = rng.normal(size=(3, 3)) * 2.0
    phase = rng.uniform(0, 2 * np.pi, size=3)
    v += 0.02 * np.sin(v @ k + phase)
    return voxax.Mesh(v, m.faces)

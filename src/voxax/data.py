"""Procedurally generated demo meshes (no downloads, fully deterministic).

Every generator returns a [`Mesh`][voxax.Mesh]: a small frozen container of a
float64 vertex array `(V, d)` and an int32 face array `(F, k)`, following trimesh's
conventions (see the design notes):

- 3D surfaces: `vertices (V, 3)`, triangles `faces (F, 3)`, counter-clockwise seen from
  outside, so normals `(b - a) x (c - a)` point outwards and the signed volume is positive.
- 2D curves: `vertices (V, 2)`, segments `faces (F, 2)`, counter-clockwise, so the outward
  normal of a segment with direction `(dx, dy)` is `(dy, -dx)` and the signed area is
  positive.

All closed meshes here are watertight and consistently outward-oriented, except where a
generator deliberately says otherwise ([`with_inverted_component`][voxax.data.with_inverted_component]
has a flipped part; [`bent_bar`][voxax.data.bent_bar] and
[`overlapping_cubes`][voxax.data.overlapping_cubes] overlap themselves so that the winding
number reaches 2).

Generators are looked up by name with [`get`][voxax.data.get] and listed by
[`names`][voxax.data.names]:

>>> from voxax import data
>>> mesh = data.get("torus")
>>> mesh.dim, mesh.n_faces
(3, 2304)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from . import _validate
from ._mesh import Mesh, fit, from_manifold

__all__ = [
    "box",
    "cube",
    "icosphere",
    "torus",
    "bent_bar",
    "with_inverted_component",
    "overlapping_cubes",
    "hand",
    "mug",
    "large",
    "polygon_square",
    "circle_polyline",
    "star_polyline",
    "overlapping_squares",
    "get",
    "names",
]


# --------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------


def _periodic_grid_faces(n_u: int, n_v: int, periodic_u: bool = True) -> np.ndarray:
    """Triangles of an `(n_u, n_v)` vertex grid, periodic in v (and in u if asked).

    Vertex `(i, j)` has index `i * n_v + j`. With `P(u, v)` such that `dP/du x dP/dv`
    points outwards, the triangles are outward-oriented.
    """
    i = np.arange(n_u if periodic_u else n_u - 1)
    j = np.arange(n_v)
    i, j = np.meshgrid(i, j, indexing="ij")
    i1 = (i + 1) % n_u
    j1 = (j + 1) % n_v
    p00 = i * n_v + j
    p10 = i1 * n_v + j
    p11 = i1 * n_v + j1
    p01 = i * n_v + j1
    t1 = np.stack([p00, p10, p11], axis=-1).reshape(-1, 3)
    t2 = np.stack([p00, p11, p01], axis=-1).reshape(-1, 3)
    # Interleave so each quad's two triangles are adjacent in memory.
    return np.stack([t1, t2], axis=1).reshape(-1, 3)


def _closed_ring_segments(n: int) -> np.ndarray:
    i = np.arange(n)
    return np.stack([i, (i + 1) % n], axis=1)


# --------------------------------------------------------------------------------------
# 3D closed meshes
# --------------------------------------------------------------------------------------


def box(
    lower: Sequence[float] = (-0.5, -0.5, -0.5),
    upper: Sequence[float] = (0.5, 0.5, 0.5),
) -> Mesh:
    """An axis-aligned box, 8 vertices and 12 outward-oriented triangles.

    **Arguments:**

    - `lower`: `(3,)` lower corner.
    - `upper`: `(3,)` upper corner, componentwise greater than `lower`.

    **Returns:** `Mesh` with `vertices (8, 3)` and `faces (12, 3)`; its signed volume is
    exactly `prod(upper - lower)`.

    >>> box((0, 0, 0), (1, 2, 3)).signed_volume()
    6.0
    """
    lo = np.asarray(lower, dtype=np.float64).reshape(3)
    hi = np.asarray(upper, dtype=np.float64).reshape(3)
    if not np.all(hi > lo):
        raise ValueError(f"voxax.data.box: `upper` must be > `lower` componentwise (box needs upper > lower componentwise, got lower={lo}, upper={hi})")
    # Vertex index bits: 1 -> x at upper, 2 -> y at upper, 4 -> z at upper.
    bits = np.arange(8)
    corners = np.stack([(bits >> 0) & 1, (bits >> 1) & 1, (bits >> 2) & 1], axis=1)
    vertices = np.where(corners == 1, hi, lo)
    faces = np.array(
        [
            [0, 2, 3], [0, 3, 1],  # z = lower, normal -z
            [4, 5, 7], [4, 7, 6],  # z = upper, normal +z
            [0, 1, 5], [0, 5, 4],  # y = lower, normal -y
            [2, 6, 7], [2, 7, 3],  # y = upper, normal +y
            [0, 4, 6], [0, 6, 2],  # x = lower, normal -x
            [1, 3, 7], [1, 7, 5],  # x = upper, normal +x
        ]
    )  # fmt: skip
    return Mesh(vertices, faces)


def cube(size: float = 1.0) -> Mesh:
    """An axis-aligned cube of edge length `size` centred at the origin (12 triangles).

    **Arguments:**

    - `size`: edge length (> 0).

    **Returns:** `Mesh` with `vertices (8, 3)`, `faces (12, 3)`, volume `size**3`.

    >>> cube(2.0).bounds.tolist()
    [[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]
    """
    h = float(size) / 2.0
    return box((-h, -h, -h), (h, h, h))


def icosphere(
    subdivisions: int = 2,
    radius: float = 1.0,
    center: Sequence[float] = (0.0, 0.0, 0.0),
) -> Mesh:
    """A geodesic sphere: an icosahedron subdivided `subdivisions` times, projected to the sphere.

    **Arguments:**

    - `subdivisions`: number of 1-to-4 subdivision steps (>= 0).
    - `radius`: sphere radius; all vertices lie exactly on the sphere.
    - `center`: `(3,)` centre.

    **Returns:** `Mesh` with `faces (20 * 4**subdivisions, 3)` and
    `vertices (10 * 4**subdivisions + 2, 3)`. The enclosed volume approaches
    `4/3 pi radius**3` from below.

    >>> icosphere(1).n_faces
    80
    """
    subdivisions = _validate.positive_int("voxax.data.icosphere", "subdivisions", subdivisions, minimum=0, maximum=12)
    radius = _validate.positive_float("voxax.data.icosphere", "radius", radius)
    phi = (1.0 + math.sqrt(5.0)) / 2.0
    vertices = np.array(
        [
            [-1, phi, 0], [1, phi, 0], [-1, -phi, 0], [1, -phi, 0],
            [0, -1, phi], [0, 1, phi], [0, -1, -phi], [0, 1, -phi],
            [phi, 0, -1], [phi, 0, 1], [-phi, 0, -1], [-phi, 0, 1],
        ],
        dtype=np.float64,
    )  # fmt: skip
    faces = np.array(
        [
            [0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11],
            [1, 5, 9], [5, 11, 4], [11, 10, 2], [10, 7, 6], [7, 1, 8],
            [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9],
            [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1],
        ]
    )  # fmt: skip
    vertices /= np.linalg.norm(vertices, axis=1, keepdims=True)
    for _ in range(subdivisions):
        n_v = len(vertices)
        edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
        uniq, inverse = np.unique(np.sort(edges, axis=1), axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        mid = vertices[uniq].mean(axis=1)
        mid /= np.linalg.norm(mid, axis=1, keepdims=True)
        vertices = np.concatenate([vertices, mid])
        m = (inverse + n_v).reshape(3, -1).T  # midpoints of edges ab, bc, ca per face
        a, b, c = faces.T
        ab, bc, ca = m.T
        faces = np.stack(
            [
                np.stack([a, ab, ca], 1),
                np.stack([ab, b, bc], 1),
                np.stack([ca, bc, c], 1),
                np.stack([ab, bc, ca], 1),
            ],
            axis=1,
        ).reshape(-1, 3)
    center = np.asarray(center, dtype=np.float64).reshape(3)
    return Mesh(vertices * float(radius) + center, faces)


def torus(
    major: float = 0.6,
    minor: float = 0.25,
    n_major: int = 48,
    n_minor: int = 24,
) -> Mesh:
    """A torus around the z axis, centred at the origin.

    **Arguments:**

    - `major`: distance from the z axis to the centre of the tube.
    - `minor`: tube radius (`0 < minor < major`).
    - `n_major`: segments around the z axis.
    - `n_minor`: segments around the tube.

    **Returns:** `Mesh` with `vertices (n_major * n_minor, 3)` and
    `faces (2 * n_major * n_minor, 3)`. The enclosed volume approaches
    `2 pi**2 major minor**2`.

    >>> torus(n_major=8, n_minor=4).n_faces
    64
    """
    major = _validate.finite_number("voxax.data.torus", "major", major)
    minor = _validate.finite_number("voxax.data.torus", "minor", minor)
    n_major = _validate.positive_int("voxax.data.torus", "n_major", n_major, minimum=3)
    n_minor = _validate.positive_int("voxax.data.torus", "n_minor", n_minor, minimum=3)
    _validate.check_allocation("voxax.data.torus", 256.0 * n_major * n_minor, f"a {n_major} x {n_minor} torus",
                               "pass smaller `n_major`, `n_minor`")
    if not 0 < minor < major:
        raise ValueError(f"voxax.data.torus: `minor` and `major` must satisfy 0 < minor < major, got minor={minor}, major={major}")
    u = 2 * np.pi * np.arange(int(n_major)) / int(n_major)
    v = 2 * np.pi * np.arange(int(n_minor)) / int(n_minor)
    u, v = np.meshgrid(u, v, indexing="ij")
    rho = major + minor * np.cos(v)
    vertices = np.stack([rho * np.cos(u), rho * np.sin(u), minor * np.sin(v)], axis=-1)
    return Mesh(vertices.reshape(-1, 3), _periodic_grid_faces(int(n_major), int(n_minor)))


def bent_bar(
    radius: float = 0.45,
    width: float = 0.2,
    height: float = 0.2,
    turns: float = 1.25,
    spread: float = 0.06,
    rise: float = 0.08,
    roundness: float = 4.0,
    n_along: int = 120,
    n_around: int = 24,
) -> Mesh:
    """A rounded bar bent around the z axis by more than a full turn, so it overlaps itself.

    The bar's centre line is a flat spiral-helix: at angle `t` (in radians, from 0 to
    `2 pi turns`) it sits at distance `radius + spread * t / (2 pi)` from the z axis and at
    height `rise * t / (2 pi)` (the whole shape is then centred in z). Its cross-section
    is the superellipse `|y / (width/2)|**roundness + |z / (height/2)|**roundness = 1`
    (4 gives a rounded rectangle, 2 an ellipse). With `spread < width` and
    `rise < height`, the last `turns - 1` of a turn passes through the first one: the
    surface is one closed, consistently outward-oriented sheet that intersects itself, and
    the winding number is 2 in the overlap. This is the demo input for resolving
    self-intersections.

    `mesh.info["overlap_point"]` is a `(3,)` point where the winding number is 2 (midway
    between the two overlapping layers).

    **Arguments:**

    - `radius`: distance of the centre line from the z axis at the start.
    - `width`, `height`: radial and vertical size of the cross-section.
    - `turns`: how far the bar is bent, in full turns (> 1 for an overlap).
    - `spread`, `rise`: radial and vertical offset of the centre line per turn.
    - `roundness`: superellipse exponent of the cross-section (>= 2).
    - `n_along`: cross-sections along the bar (>= 2).
    - `n_around`: vertices per cross-section (>= 3).

    **Returns:** `Mesh` with `vertices (n_along * n_around + 2, 3)` and
    `faces (2 * n_around * n_along, 3)`.

    >>> m = bent_bar()
    >>> m.n_faces, m.info["overlap_point"].shape
    (5760, (3,))
    """
    n_along, n_around = int(n_along), int(n_around)
    if n_along < 2 or n_around < 3:
        raise ValueError("voxax.data.bent_bar: `n_along` must be >= 2 and `n_around` >= 3")
    a, b = width / 2.0, height / 2.0
    if not radius > a:
        raise ValueError("voxax.data.bent_bar: `radius` must be > width / 2")
    t = 2 * np.pi * float(turns) * np.arange(n_along) / (n_along - 1)
    s = 2 * np.pi * np.arange(n_around) / n_around
    e = 2.0 / float(roundness)
    cy = a * np.sign(np.cos(s)) * np.abs(np.cos(s)) ** e
    cz = b * np.sign(np.sin(s)) * np.abs(np.sin(s)) ** e
    z0 = -rise * float(turns) / 2.0  # centre the centre line in z

    def centre(tt):
        return radius + spread * tt / (2 * np.pi), z0 + rise * tt / (2 * np.pi)

    rho_c, z_c = centre(t)
    rho = rho_c[:, None] + cy[None, :]
    zz = z_c[:, None] + cz[None, :]
    ring = np.stack([rho * np.cos(t)[:, None], rho * np.sin(t)[:, None], zz], axis=-1)
    ring = ring.reshape(-1, 3)
    caps = np.array(
        [
            [rho_c[0] * np.cos(t[0]), rho_c[0] * np.sin(t[0]), z_c[0]],
            [rho_c[-1] * np.cos(t[-1]), rho_c[-1] * np.sin(t[-1]), z_c[-1]],
        ]
    )
    vertices = np.concatenate([ring, caps])
    side = _periodic_grid_faces(n_along, n_around, periodic_u=False)
    j = np.arange(n_around)
    j1 = (j + 1) % n_around
    c0, c1 = n_along * n_around, n_along * n_around + 1
    last = (n_along - 1) * n_around
    cap0 = np.stack([np.full(n_around, c0), j, j1], axis=1)
    cap1 = np.stack([np.full(n_around, c1), last + j1, last + j], axis=1)
    faces = np.concatenate([cap0, side, cap1])

    # A point midway between the first layer and the second layer, in the overlap.
    t_mid = 2 * np.pi * min(max(float(turns) - 1.0, 0.0), 1.0) / 2.0
    r1, z1 = centre(t_mid)
    r2, z2 = centre(t_mid + 2 * np.pi)
    rm, zm = (r1 + r2) / 2.0, (z1 + z2) / 2.0
    overlap_point = np.array([rm * np.cos(t_mid), rm * np.sin(t_mid), zm])
    return Mesh(vertices, faces, {"overlap_point": overlap_point})


def with_inverted_component(
    radius: float = 0.45,
    inverted_radius: float = 0.25,
    gap: float = 0.1,
    subdivisions: int = 3,
) -> Mesh:
    """A sphere plus a separate, smaller sphere with flipped (inward) orientation.

    The two spheres sit side by side along x with `gap` between them, the pair centred at
    the origin. Inside the normal sphere the winding number is +1, inside the flipped one
    it is -1, so the signed volume is (approximately)
    `4/3 pi (radius**3 - inverted_radius**3)`.

    `mesh.info` holds `"center"`, `"inverted_center"` (both `(3,)`), `"radius"`,
    `"inverted_radius"` and `"n_faces_inverted"`: the flipped sphere's faces are the last
    `n_faces_inverted` rows of `faces`.

    **Arguments:**

    - `radius`: radius of the normally oriented sphere.
    - `inverted_radius`: radius of the flipped sphere.
    - `gap`: distance between the two spheres (> 0).
    - `subdivisions`: icosphere subdivisions of each sphere.

    **Returns:** `Mesh` with `faces (2 * 20 * 4**subdivisions, 3)`.

    >>> m = with_inverted_component()
    >>> m.signed_volume() > 0, m.info["inverted_center"].tolist()
    (True, [0.5, 0.0, 0.0])
    """
    if not gap > 0:
        raise ValueError("voxax.data.with_inverted_component: `gap` must be > 0 so that the two components are disjoint")
    total = 2 * radius + gap + 2 * inverted_radius
    c_main = np.array([-total / 2 + radius, 0.0, 0.0])
    c_inv = np.array([total / 2 - inverted_radius, 0.0, 0.0])
    main = icosphere(subdivisions, radius, c_main)
    inv = icosphere(subdivisions, inverted_radius, c_inv).flipped()
    m = Mesh.concatenate(main, inv)
    return Mesh(
        m.vertices,
        m.faces,
        {
            "center": c_main,
            "inverted_center": c_inv,
            "radius": float(radius),
            "inverted_radius": float(inverted_radius),
            "n_faces_inverted": inv.n_faces,
        },
    )


def overlapping_cubes(
    lower_a: Sequence[float] = (-0.6, -0.6, -0.6),
    upper_a: Sequence[float] = (0.2, 0.2, 0.2),
    lower_b: Sequence[float] = (-0.2, -0.2, -0.2),
    upper_b: Sequence[float] = (0.6, 0.6, 0.6),
) -> Mesh:
    """Two axis-aligned boxes that overlap, concatenated (not unioned): W = 2 in the overlap.

    The defaults are the cubes `[-0.6, 0.2]^3` and `[-0.2, 0.6]^3`, overlapping in
    `[-0.2, 0.2]^3`; every face lies on a multiple of 0.2, so on `Grid.cube(n)` with `n`
    a multiple of 10 every voxel is exactly 0, 1 or 2. `mesh.info["overlap"]` is the overlap
    box as a `(2, 3)` array `[lower, upper]` (`None` if the boxes do not overlap).

    **Arguments:**

    - `lower_a`, `upper_a`: `(3,)` corners of the first box.
    - `lower_b`, `upper_b`: `(3,)` corners of the second box.

    **Returns:** `Mesh` with `vertices (16, 3)` and `faces (24, 3)`.

    >>> m = overlapping_cubes()
    >>> round(m.signed_volume(), 12), m.info["overlap"].tolist()
    (1.024, [[-0.2, -0.2, -0.2], [0.2, 0.2, 0.2]])
    """
    return _overlapping(box(lower_a, upper_a), box(lower_b, upper_b))


def hand(resolution: int = 16, max_abs: float = 0.75) -> Mesh:
    """A non-convex, hand-like solid: a rounded palm, four fingers and a thumb.

    Built from capsules and a rounded box with manifold3d boolean unions, so the result is
    a clean, watertight, outward-oriented 2-manifold. With the default `resolution` it has
    about 1.5K triangles (the benchmarks' "~1.5K-face mesh"). The fingers are spread
    apart and bent at the knuckles, so the shape is far from convex.

    **Arguments:**

    - `resolution`: circular segments of each sphere/capsule (rounded up by manifold3d
      to a multiple of 4); face count grows roughly quadratically with it.
    - `max_abs`: the result is centred and scaled so that `max |v| == max_abs`.

    **Returns:** `Mesh` with `vertices (V, 3)`, `faces (F, 3)`, `F` about 1.5K by default.

    >>> 1000 < hand().n_faces < 2000
    True
    """
    from manifold3d import Manifold

    seg = int(resolution)

    def ball(p, r):
        return Manifold.sphere(r, seg).translate(tuple(float(x) for x in p))

    def capsule(p, q, r):
        return Manifold.batch_hull([ball(p, r), ball(q, r)])

    # Palm: a rounded box (hull of eight corner balls).
    rc = 0.08
    palm_lo = np.array([-0.30, -0.38, -0.10])
    palm_hi = np.array([0.30, 0.22, 0.10])
    corners = [
        ball([x, y, z], rc)
        for x in (palm_lo[0] + rc, palm_hi[0] - rc)
        for y in (palm_lo[1] + rc, palm_hi[1] - rc)
        for z in (palm_lo[2] + rc, palm_hi[2] - rc)
    ]
    parts = [Manifold.batch_hull(corners)]

    # Fingers: two phalanx capsules each, spread apart and curled slightly towards -z.
    fingers = [  # (x at knuckle, length of the two segments, spread angle in degrees, radius)
        (-0.225, (0.20, 0.16), 12.0, 0.060),
        (-0.075, (0.24, 0.19), 4.0, 0.065),
        (0.075, (0.23, 0.18), -4.0, 0.065),
        (0.225, (0.19, 0.15), -12.0, 0.058),
    ]
    for x, (l1, l2), ang, r in fingers:
        a = math.radians(ang)
        direction = np.array([-math.sin(a), math.cos(a), 0.0])
        base = np.array([x, 0.16, 0.0])
        knuckle = base + l1 * direction + np.array([0.0, 0.0, -0.03])
        d2 = direction * math.cos(0.45) + np.array([0.0, 0.0, -math.sin(0.45)])
        tip = knuckle + l2 * d2
        parts.append(capsule(base, knuckle, r))
        parts.append(capsule(knuckle, tip, r * 0.92))

    # Thumb: out to the side (+x) and forward, bent towards the palm.
    t0 = np.array([0.22, -0.22, -0.01])
    t1 = np.array([0.42, -0.05, -0.06])
    t2 = np.array([0.50, 0.12, -0.12])
    parts.append(capsule(t0, t1, 0.075))
    parts.append(capsule(t1, t2, 0.065))

    solid = Manifold.batch_boolean(parts, _manifold_add())
    vertices, faces = from_manifold(solid)
    return Mesh(fit(vertices, max_abs)[0], faces)


def mug(segments: int = 48) -> Mesh:
    """A cup with a handle (manifold3d booleans): a cylinder of radius 0.5 and height 1
    hollowed from the top (wall 0.08, floor 0.12), and a ring of tube radius 0.07 on its
    side. Its handle's hole and the cup's cavity are what a double height field along the
    cup's axis cannot represent: the shape of the explicit-surface-intersection examples.

    **Arguments:**

    - `segments`: segments around the cylinders and the ring (>= 3).

    **Returns:** a closed, outward-oriented `Mesh`, centred near the origin.

    >>> m = mug(24)
    >>> import voxax
    >>> voxax.metrics.euler_characteristic(m), m.signed_volume() > 0  # genus 1: the handle
    (0, True)
    """
    from manifold3d import CrossSection, Manifold

    segments = int(segments)
    if segments < 3:
        raise ValueError(f"voxax.data.mug: `segments` must be >= 3, got {segments}")
    outer = Manifold.cylinder(1.0, 0.5, 0.5, segments)
    inner = Manifold.cylinder(1.0, 0.42, 0.42, segments).translate((0.0, 0.0, 0.12))
    ring = CrossSection.circle(0.07, 16).translate((0.28, 0.0)).revolve(segments)
    handle = ring.rotate((90.0, 0.0, 0.0)).translate((0.5, 0.0, 0.5))
    v, f = from_manifold((outer + handle) - inner)
    return Mesh(v - np.array([0.15, 0.0, 0.5]), f.astype(np.int32))


def _manifold_add():
    from manifold3d import OpType

    return OpType.Add


def large(n_faces_target: int = 100_000, max_abs: float = 0.75) -> Mesh:
    """A large mesh for benchmarks: a circular tube around a trefoil knot.

    The tube is a smooth, non-convex, watertight, outward-oriented surface with a
    `n_along x n_around` quad grid split into triangles; the counts are chosen so that
    `F = 2 * n_along * n_around >= n_faces_target` with near-square quads. Generation is
    pure NumPy: `large(1_000_000)` takes well under a second.

    `mesh.info` holds `"tube_radius"` (after scaling), `"n_along"` and `"n_around"`.

    **Arguments:**

    - `n_faces_target`: minimum number of triangles (>= 64).
    - `max_abs`: the result is centred and scaled so that `max |v| == max_abs`.

    **Returns:** `Mesh` with `faces (F, 3)`, `F >= n_faces_target` (and within about
    `2 sqrt(n_faces_target)` of it).

    >>> large(10_000).n_faces >= 10_000
    True
    """
    target = max(_validate.positive_int("voxax.data.large", "n_faces_target", n_faces_target, minimum=0,
                                        bytes_each=256.0), 64)
    tube_r = 0.4
    length = 28.8263  # length of the trefoil centre line below
    aspect = length / (2 * np.pi * tube_r)  # n_along / n_around for square quads
    n_around = max(8, int(round(math.sqrt(target / 2.0 / aspect))))
    n_along = max(8, int(math.ceil(target / (2.0 * n_around))))

    t = 2 * np.pi * np.arange(n_along) / n_along
    c = np.stack([np.sin(t) + 2 * np.sin(2 * t), np.cos(t) - 2 * np.cos(2 * t), -np.sin(3 * t)], 1)
    d1 = np.stack([np.cos(t) + 4 * np.cos(2 * t), -np.sin(t) + 4 * np.sin(2 * t), -3 * np.cos(3 * t)], 1)
    d2 = np.stack([-np.sin(t) - 8 * np.sin(2 * t), -np.cos(t) + 8 * np.cos(2 * t), 9 * np.sin(3 * t)], 1)
    # Frenet frame (the curvature of this trefoil never vanishes, so it is smooth and periodic).
    tangent = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    binormal = np.cross(d1, d2)
    binormal /= np.linalg.norm(binormal, axis=1, keepdims=True)
    normal = np.cross(binormal, tangent)
    s = 2 * np.pi * np.arange(n_around) / n_around
    # P(t, s) = c + r (cos s N - sin s B): dP/dt x dP/ds = T x (-B) = N at s = 0, outwards.
    vertices = (
        c[:, None, :]
        + tube_r * np.cos(s)[None, :, None] * normal[:, None, :]
        - tube_r * np.sin(s)[None, :, None] * binormal[:, None, :]
    ).reshape(-1, 3)
    faces = _periodic_grid_faces(n_along, n_around)
    vertices, _, scale = fit(vertices, max_abs)
    info = {"tube_radius": tube_r * scale, "n_along": n_along, "n_around": n_around}
    return Mesh(vertices, faces, info)


# --------------------------------------------------------------------------------------
# 2D closed polylines
# --------------------------------------------------------------------------------------


def polygon_square(
    lower: Sequence[float] = (-0.5, -0.5),
    upper: Sequence[float] = (0.5, 0.5),
) -> Mesh:
    """An axis-aligned rectangle as 4 counter-clockwise segments.

    **Arguments:**

    - `lower`: `(2,)` lower-left corner.
    - `upper`: `(2,)` upper-right corner.

    **Returns:** `Mesh` with `vertices (4, 2)` and `faces (4, 2)`; signed area exactly
    `prod(upper - lower)`.

    >>> polygon_square().signed_volume()
    1.0
    """
    lo = np.asarray(lower, dtype=np.float64).reshape(2)
    hi = np.asarray(upper, dtype=np.float64).reshape(2)
    if not np.all(hi > lo):
        raise ValueError(f"voxax.data.polygon_square: `upper` must be > `lower`, got lower={lo}, upper={hi}")
    vertices = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    return Mesh(vertices, _closed_ring_segments(4))


def circle_polyline(
    n: int = 64,
    radius: float = 0.5,
    center: Sequence[float] = (0.0, 0.0),
) -> Mesh:
    """A regular `n`-gon inscribed in a circle, counter-clockwise.

    **Arguments:**

    - `n`: number of vertices and segments (>= 3).
    - `radius`: circumradius.
    - `center`: `(2,)` centre.

    **Returns:** `Mesh` with `vertices (n, 2)` and `faces (n, 2)`; signed area
    `n / 2 * radius**2 * sin(2 pi / n)`.

    >>> circle_polyline(4, radius=1.0).signed_volume()
    2.0
    """
    n = int(n)
    if n < 3:
        raise ValueError("voxax.data.circle_polyline: `n` must be >= 3")
    a = 2 * np.pi * np.arange(n) / n
    vertices = float(radius) * np.stack([np.cos(a), np.sin(a)], 1) + np.asarray(center, float)
    return Mesh(vertices, _closed_ring_segments(n))


def star_polyline(
    n_points: int = 5,
    outer: float = 0.7,
    inner: float = 0.3,
    center: Sequence[float] = (0.0, 0.0),
    rotation: float = math.pi / 2,
) -> Mesh:
    """A non-convex star with `n_points` tips, counter-clockwise.

    Vertices alternate between radius `outer` (tips, the first at angle `rotation`) and
    radius `inner`.

    **Arguments:**

    - `n_points`: number of tips (>= 2).
    - `outer`, `inner`: tip and notch radii (`0 < inner < outer` for a star shape).
    - `center`: `(2,)` centre.
    - `rotation`: angle of the first tip, radians.

    **Returns:** `Mesh` with `vertices (2 n_points, 2)` and `faces (2 n_points, 2)`;
    signed area `n_points * outer * inner * sin(pi / n_points)`.

    >>> star_polyline().n_faces
    10
    """
    n_points = int(n_points)
    if n_points < 2:
        raise ValueError("voxax.data.star_polyline: `n_points` must be >= 2")
    n = 2 * n_points
    a = float(rotation) + 2 * np.pi * np.arange(n) / n
    r = np.where(np.arange(n) % 2 == 0, float(outer), float(inner))
    vertices = np.stack([r * np.cos(a), r * np.sin(a)], 1) + np.asarray(center, float)
    return Mesh(vertices, _closed_ring_segments(n))


def overlapping_squares(
    lower_a: Sequence[float] = (-0.6, -0.6),
    upper_a: Sequence[float] = (0.2, 0.2),
    lower_b: Sequence[float] = (-0.2, -0.2),
    upper_b: Sequence[float] = (0.6, 0.6),
) -> Mesh:
    """Two overlapping rectangles, concatenated: W = 2 in the overlap (2D `overlapping_cubes`).

    `mesh.info["overlap"]` is the overlap box as a `(2, 2)` array `[lower, upper]`.

    **Returns:** `Mesh` with `vertices (8, 2)` and `faces (8, 2)`.

    >>> round(overlapping_squares().signed_volume(), 12)
    1.28
    """
    return _overlapping(polygon_square(lower_a, upper_a), polygon_square(lower_b, upper_b))


# --------------------------------------------------------------------------------------
# Lookup by name
# --------------------------------------------------------------------------------------

_REGISTRY: dict[str, tuple[Callable[..., Mesh], int]] = {
    "box": (box, 3),
    "cube": (cube, 3),
    "icosphere": (icosphere, 3),
    "torus": (torus, 3),
    "bent_bar": (bent_bar, 3),
    "with_inverted_component": (with_inverted_component, 3),
    "overlapping_cubes": (overlapping_cubes, 3),
    "hand": (hand, 3),
    "mug": (mug, 3),
    "large": (large, 3),
    "polygon_square": (polygon_square, 2),
    "circle_polyline": (circle_polyline, 2),
    "star_polyline": (star_polyline, 2),
    "overlapping_squares": (overlapping_squares, 2),
}

_ALIASES = {
    "sphere": "icosphere",
    "inverted": "with_inverted_component",
    "square": "polygon_square",
    "circle": "circle_polyline",
    "star": "star_polyline",
}


def names(dim: int | None = None) -> tuple[str, ...]:
    """Names of the demo meshes accepted by [`get`][voxax.data.get], sorted.

    **Arguments:**

    - `dim`: if 2 or 3, only the meshes of that dimension.

    **Returns:** a tuple of names. ([`get`][voxax.data.get] also accepts the aliases
    `sphere`, `inverted`, `square`, `circle`, `star` and hyphens for underscores.)

    >>> "torus" in names(3), "star_polyline" in names(2)
    (True, True)
    """
    return tuple(sorted(k for k, (_, d) in _REGISTRY.items() if dim is None or d == dim))


def get(name: str, **kwargs: Any) -> Mesh:
    """Build the demo mesh called `name`, passing `kwargs` to its generator.

    **Arguments:**

    - `name`: one of [`names()`][voxax.data.names] (case-insensitive; `-` and `_` are
      interchangeable; aliases `sphere`, `inverted`, `square`, `circle`, `star`).
    - `**kwargs`: keyword arguments of the generator, e.g. `subdivisions=3`.

    **Returns:** the `Mesh`.

    >>> get("sphere", subdivisions=0).n_faces
    20
    """
    key = str(name).strip().lower().replace("-", "_")
    key = _ALIASES.get(key, key)
    if key not in _REGISTRY:
        raise ValueError(f"voxax.data.get: unknown demo mesh {name!r}; available: {', '.join(names())}")
    fn, _ = _REGISTRY[key]
    return fn(**kwargs)


def _overlapping(a: Mesh, b: Mesh) -> Mesh:
    """Both meshes as one, with the box where their bounds overlap (or None) in `info`."""
    lo = np.maximum(a.bounds[0], b.bounds[0])
    hi = np.minimum(a.bounds[1], b.bounds[1])
    overlap = np.stack([lo, hi]) if np.all(hi > lo) else None
    m = Mesh.concatenate(a, b)
    return Mesh(m.vertices, m.faces, {"overlap": overlap})

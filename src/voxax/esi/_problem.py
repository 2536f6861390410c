"""The selection problem: everything precomputed for the energy of any combination of
candidate axes (surface samples, height-field boundary samples, the column ray casts)."""

from __future__ import annotations

import concurrent.futures
import functools
import math
import os

import numpy as np

from .. import _kernels
from .._kernels import blas as _blas
from .._kernels import esi as _kesi
from .._mesh import Mesh, face_normals
from .._spatial import BVH
from ._depth import _BOTTOM, ON_SURFACE_PIXELS, _depth_map, height_field_solid
from ._frames import _canonical, _used, bounding_sphere, exact_scale, frame_for


def _area(mesh: Mesh) -> float:
    """The area of a triangle mesh."""
    return (
        0.5
        * np.linalg.norm(
            np.cross(
                mesh.vertices[mesh.faces[:, 1]] - mesh.vertices[mesh.faces[:, 0]],
                mesh.vertices[mesh.faces[:, 2]] - mesh.vertices[mesh.faces[:, 0]],
            ),
            axis=1,
        ).sum()
    )


class _Problem:
    """Everything precomputed for the energy of any combination of candidate axes.

    Height fields are indexed by signed direction `k`; a DHF along a line is the pair of
    its two signed directions. The mesh is scaled into `[-1/1.1, 1/1.1]^3` first.
    """

    def __init__(self, mesh: Mesh, dirs: np.ndarray, *, resolution, n_samples, seed, threads, progress=None):
        from ..metrics import sample_surface

        # first an exact power of two for meshes far from unit size (the same bits as at
        # unit size), then the centre and scale
        pre = exact_scale(bounding_sphere(mesh)[1])
        V = mesh.vertices if pre == 1.0 else mesh.vertices * pre
        used = V[_used(mesh.n_vertices, mesh.faces)]
        lo, hi = used.min(0), used.max(0)
        self.center = 0.5 * (lo + hi)
        self.scale = (1.0 / 1.1) / float(0.5 * (hi - lo).max())
        self.mesh = Mesh((V - self.center) * self.scale, mesh.faces)
        self.threads = threads
        self.bvh = BVH(self.mesh)
        c, rad = bounding_sphere(self.mesh)
        self.sphere = (c, rad)
        self.eps = 1e-9 * rad
        normals = face_normals(self.mesh.vertices, self.mesh.faces)
        area_s = _area(self.mesh)
        S = sample_surface(self.mesh, n_samples, seed)
        self.P = S.points
        self.Pn = S.normals
        self.n_samples = n_samples
        line_dirs = self._signed_directions(dirs)
        self.vec = np.array([s * line_dirs[li] for li, s in self.dirs])
        K = len(self.dirs)
        self.D = np.zeros((n_samples, K))
        self.visP = np.zeros((n_samples, K), bool)
        pixel = 2.0 * rad / resolution
        #: height-field samples this close to S count as on S (the depth maps are linear
        #: between pixels); the surface samples stand for them
        self.on_surface = max(5e-4, ON_SURFACE_PIXELS * pixel)
        self.B, self.Bn, self.Bd = [], [], []
        # one line (then one direction) per thread, each single-threaded (the BVH builds of
        # the height-field solids are; the results do not depend on the order), and one
        # BLAS thread (see `voxax._kernels.blas`)
        workers = max(1, min(_kernels.threads(threads) or (os.cpu_count() or 1), K))
        inner = 1 if workers > 1 else threads
        frames = [frame_for(ld / np.linalg.norm(ld), c, rad, resolution) for ld in line_dirs]
        rng = np.random.default_rng(seed + 7)
        seeds = [int(rng.integers(2**31)) for _ in self.dirs]

        with concurrent.futures.ThreadPoolExecutor(workers) as pool, _blas.single_threaded():
            self.maps = dict(enumerate(pool.map(lambda fr: _depth_map(self.bvh, fr, normals, inner), frames)))
            self._casts = self._column_casts()
            step = progress(K) if progress is not None else None
            terms = functools.partial(self._boundary_terms, inner=inner, seeds=seeds, area_s=area_s)
            for k, (dist, hit, b, bn, bd) in enumerate(pool.map(terms, range(K))):
                if step is not None:
                    step()
                self.D[:, k] = dist
                self.visP[:, k] = ~hit
                self.B.append(b)
                self.Bn.append(bn)
                self.Bd.append(bd)
        self._hit: dict = {}
        self._T: dict = {}
        self._TP: dict = {}
        self._maybe: dict = {}
        self._terms: dict = {}
        self._registries: dict = {}
        self._samples = None  # see `samples`
        self.n_full = 0
        self.n_rays = 0

    def _signed_directions(self, dirs) -> list:
        """Sets `dirs` (the signed directions, grouped by line so that one depth map serves
        both signs: `(line, sign)` each), `key` and `_lines`; returns each line's direction."""
        lines: dict = {}
        self.dirs = []  # (line, sign) per signed direction
        keys: dict = {}
        for d in dirs:
            lk, s = _canonical(d)
            if lk not in lines:
                lines[lk] = len(lines)
            kk = (lines[lk], s)
            if kk not in keys:
                keys[kk] = len(keys)
                self.dirs.append(kk)
        self.key = keys
        self._lines = lines
        line_dirs = [None] * len(lines)
        for lk, li in lines.items():
            line_dirs[li] = np.asarray(lk)
        return line_dirs

    def _boundary_terms(self, k, *, inner, seeds, area_s):
        """Signed direction `k`'s terms: the distances of the hidden surface samples to its
        height field's boundary, which of them it hides, and the samples of that boundary
        off S (points, normals, their distances to S not yet taken)."""
        from ..metrics import sample_surface

        c, rad = self.sphere
        n_samples = self.n_samples
        li, s = self.dirs[k]
        solid, n_tw = height_field_solid(self.maps[li], s)
        hit = (_kesi.column_hits(self.P, np.full(n_samples, k), self._casts, inner) & 1) == 1
        # distances to the height field's boundary, needed only where S is hidden: to its
        # top and walls, or straight down to its bottom (a point of S projects inside it)
        tw = Mesh(solid.vertices, solid.faces[:n_tw])
        dist = np.zeros(n_samples)
        if hit.any():
            fr = self.maps[li].frame
            below = (self.P[hit] - fr.center) @ fr.d * s + _BOTTOM * fr.radius
            dist[hit] = np.minimum(BVH(tw).closest_points(self.P[hit], threads=inner).distance, below)
        a_tw = _area(tw)
        nb = int(round(n_samples * a_tw / area_s))
        bs = sample_surface(tw, nb, seeds[k])
        inside = ((bs.points - c) ** 2).sum(1) <= (rad * (1 + 1e-9)) ** 2
        pts, nrm = bs.points[inside], bs.normals[inside]
        # which samples lie off S: a search pruned just beyond the on-surface distance
        # (most samples lie farther: their distances are taken when needed, `distances`)
        bd = self.bvh.closest_points(pts, threads=inner, max_distance=self.on_surface * (1 + 1e-9)).distance
        off = bd > self.on_surface
        return dist, hit, pts[off], nrm[off], np.full(int(off.sum()), np.nan)

    def registry(self, hk) -> np.ndarray:
        """`(len(hk), n)` int8: whether the ray of boundary sample `g` (of `samples()`)
        along HF candidate `hk[c]` meets S (-1: not cast yet); one per list of candidates,
        shared by all DHFs (a sample's ray along a direction is the same ray for each)."""
        key = tuple(int(k) for k in hk)
        reg = self._registries.get(key)
        if reg is None:
            reg = self._registries[key] = np.full((len(key), len(self.samples()[0])), -1, np.int8)
        return reg

    def _column_casts(self) -> _kesi.Casts:
        """The tables of the selection's exact ray casts (C++, `csrc/esi/columns_host.cc`),
        for every line at once: the lists of the triangles over each cell of a `G x G` grid
        of the line's frame, ordered by their top depth (cells about a third of the mesh's
        mean edge wide or a depth-map pixel, the smaller, `G <= 512`), and the column test's
        table: per signed direction the frame (`params`, 15 numbers) and the depth limits per
        cell as `sign * depth < limit` (`lims`, `G^2`), from the least and largest depth of
        the triangles whose `(x, y)` bounding box (widened by a margin) meets the cell. A ray
        along `+d` from a point above its cell's largest depth (or along `-d` below the
        least) cannot meet S: its hit would be a point of a triangle over that cell. The
        others look at the cell's triangles (`cast`)."""
        nl = len(self.maps)
        # cells about a third of a mean edge wide (a few triangles per cell), and no coarser
        # than the depth maps' pixels
        V, F = self.mesh.vertices, self.mesh.faces
        edge = float(np.linalg.norm(V[F[:, 1]] - V[F[:, 0]], axis=1).mean()) if len(F) else 1.0
        fine = np.ceil(3.0 * self.maps[0].frame.radius / max(edge, 1e-12))
        G = int(np.clip(max(fine, self.maps[0].frame.resolution), 16, 512))
        K = len(self.dirs)
        frames = np.zeros((nl, 15))
        for li in range(nl):
            fr = self.maps[li].frame
            R = fr.radius * (1 + 1e-6)
            M = np.stack([fr.u, fr.v, fr.d], 1)
            frames[li] = np.concatenate([M.ravel(), fr.center @ M, [1.0, R, 2.0 * R / G]])
        delta = 1e-6 * self.maps[0].frame.radius
        offsets, entries, lo, hi = _kesi.column_lists(self.mesh.vertices, self.mesh.faces, frames, G, delta, self.threads)
        params = np.zeros((K, 15))
        lims = np.zeros((K, G * G))
        line_of = np.zeros(K, np.int64)
        for k, (li, s) in enumerate(self.dirs):
            params[k] = frames[li]
            params[k, 12] = float(s)
            lims[k] = hi[li] if s > 0 else -lo[li]
            line_of[k] = li
        tris = self.mesh.vertices[self.mesh.faces].reshape(-1, 9)
        return _kesi.Casts.make(params, self.vec, line_of, G, lims, offsets, entries, tris, self.eps)

    def distances(self, k: int, idx: np.ndarray) -> np.ndarray:
        """The distances to S of the boundary samples `idx` of HF k (exact closest points,
        taken once, when first asked for)."""
        return self.distances_many([(k, idx)])[0]

    def distances_many(self, items) -> list:
        """`distances(k, idx)` of every `(k, idx)` of `items`, in one call."""
        need = [(k, idx[np.isnan(self.Bd[k][idx])]) for k, idx in items]
        need = [(k, i) for k, i in need if len(i)]
        if need:
            d = self.bvh.closest_points(np.concatenate([self.B[k][i] for k, i in need]), threads=self.threads).distance
            at = 0
            for k, i in need:
                self.Bd[k][i] = d[at : at + len(i)]
                at += len(i)
        return [self.Bd[k][idx] for k, idx in items]

    def samples(self) -> tuple[np.ndarray, np.ndarray]:
        """Every height field's boundary samples stacked (`B[k]` is rows `off[k]:off[k + 1]`)."""
        if self._samples is None:
            self._samples = (np.concatenate(self.B), np.concatenate([[0], np.cumsum([len(b) for b in self.B])]))
        return self._samples

    def cast(self, points: np.ndarray, ks: np.ndarray) -> np.ndarray:
        """Whether the ray from each point along its direction `ks[i]` meets S (exact, C++:
        the triangles listed over the point's cell, after the column test)."""
        ks = np.ascontiguousarray(ks, np.int64)
        if not len(ks):
            return np.zeros(0, bool)
        out = _kesi.column_hits(points, ks, self._casts, self.threads)
        self.n_rays += int(np.count_nonzero(out & 2))
        return (out & 1).astype(bool)

    def may_hit(self, points: np.ndarray, k2: int) -> np.ndarray:
        """`(n,)` bool: False where the ray from a point along direction k2 certainly misses
        S (by `columns`), True where it may hit."""
        return self.may_hit_many(points, np.full(len(points), k2))

    def may_hit_many(self, points: np.ndarray, ks: np.ndarray) -> np.ndarray:
        """`may_hit` of each point along its own direction `ks[i]` (C++)."""
        ks = np.ascontiguousarray(ks, np.int64)
        if not len(ks):
            return np.zeros(0, bool)
        c = self._casts
        return _kesi.column_test(points, ks, c.params, c.G, c.lims, self.threads)

    def _maybe_bits(self, k: int, k2: int) -> np.ndarray:
        """`maybe` of every boundary sample of HF k along k2, as packed bits (kept)."""
        bits = self._maybe.get((k, k2))
        if bits is None:
            bits = self._maybe[(k, k2)] = np.packbits(self.may_hit(self.B[k], k2))
        return bits

    def maybe(self, k: int, k2: int, idx) -> np.ndarray:
        """`(len(idx),)` bool: False where the ray of boundary sample `idx` (None: all) of
        HF k along direction k2 certainly misses S (by `columns`), True where it may hit."""
        bits = self._maybe_bits(k, k2)
        if idx is None:
            return np.unpackbits(bits, count=len(self.B[k])).view(bool)
        idx = np.asarray(idx)
        return ((bits[idx >> 3] >> (7 - (idx & 7)).astype(np.uint8)) & 1).astype(bool)

    def index(self, d) -> int:
        """The signed-direction index of a candidate direction."""
        lk, s = _canonical(np.asarray(d, np.float64))
        return self.key[(self._lines[lk], s)]

    def hit(self, k: int, k2: int, idx=None) -> np.ndarray:
        """Whether the rays from the boundary samples `idx` (default: all) of HF k along
        direction k2 hit S (cast once per sample and direction, then cached)."""
        idx = np.arange(len(self.B[k])) if idx is None else idx
        self._ensure([(k, k2, idx)])
        return self._hit[(k, k2)][idx] == 1

    def _ensure(self, requests) -> None:
        """Cast, in one call, the rays of `(k, k2, idx)` requests not cast yet."""
        todo: dict = {}
        for k, k2, idx in requests:
            h = self._hit.get((k, k2))
            if h is None:
                h = self._hit[(k, k2)] = np.full(len(self.B[k]), -1, np.int8)
            miss = idx[h[idx] < 0]
            if not len(miss):
                continue
            mb = self.maybe(k, k2, miss)
            h[miss[~mb]] = 0
            miss = miss[mb]
            if not len(miss):
                continue
            if (k, k2) in todo:  # several requests: the union, ascending
                mark = np.zeros(len(h), bool)
                mark[todo[(k, k2)]] = True
                mark[miss] = True
                miss = np.flatnonzero(mark)
            todo[(k, k2)] = miss
        if not todo:
            return
        keys = list(todo)
        sel = [todo[key] for key in keys]
        origins = np.concatenate([self.B[k][i] for (k, _), i in zip(keys, sel)])
        ks = np.repeat(np.array([k2 for _, k2 in keys], np.int64), [len(i) for i in sel])
        res = self.cast(origins, ks)
        at = 0
        for key, i in zip(keys, sel):
            self._hit[key][i] = res[at : at + len(i)]
            at += len(i)

    def floaters(self, k: int, others) -> np.ndarray:
        """The indices (ascending) of HF k's boundary samples inside every HF of `others`:
        the rays along each of them hit S. Filtered one direction at a time (in the order
        given), so later directions cast only the rays of the samples still inside."""
        idx = self._may_float(k, others)
        for k2 in others:
            if not len(idx):
                break
            idx = idx[self.hit(k, k2, idx)]
        return idx

    def _may_float(self, k: int, others) -> np.ndarray:
        """The indices of HF k's boundary samples whose rays along all of `others` may hit
        S (`maybe`): a superset of the floaters, found without casting rays."""
        if not len(others):
            return np.arange(len(self.B[k]))
        bits = self._maybe_bits(k, others[0])
        for k2 in others[1:]:
            bits = bits & self._maybe_bits(k, k2)
        return np.flatnonzero(np.unpackbits(bits, count=len(self.B[k])))

    def filter_many(self, items) -> list:
        """`floaters(k, others)` of every `(k, others)` in `items`, casting the rays of all
        of them in one call per filtering step."""
        alive = [self._may_float(k, others) for k, others in items]
        step = 0
        while True:
            live = [t for t, (_, others) in enumerate(items) if step < len(others) and len(alive[t])]
            if not live:
                return alive
            self._ensure([(items[t][0], items[t][1][step], alive[t]) for t in live])
            for t in live:
                k, k2 = items[t][0], items[t][1][step]
                alive[t] = alive[t][self._hit[(k, k2)][alive[t]] == 1]
            step += 1

    def prefetch(self, combos) -> None:
        """Cast the rays that `energy` needs for every combination in `combos`, in one call
        per filtering step instead of one per pair of directions."""
        items = {}
        for ks in combos:
            ks = sorted(set(ks))
            for k in ks:
                items[(k, tuple(k2 for k2 in ks if k2 != k))] = None
        self.filter_many(list(items))

    def cd_st(self, ks) -> float:
        return float(self.D[:, list(ks)].min(1).mean())

    def T(self, k: int, k2: int, angle: float) -> np.ndarray:
        """T of the angle between the normals of HF k's boundary samples and direction k2."""
        t = self._T.get((k, k2, angle))
        if t is None:
            t = _T_of(self.Bn[k] @ self.vec[k2], angle)
            self._T[(k, k2, angle)] = t
        return t

    def TP(self, k: int, angle: float) -> np.ndarray:
        """On of the surface samples for direction k: T where visible, 1 elsewhere."""
        t = self._TP.get((k, angle))
        if t is None:
            t = np.where(self.visP[:, k], _T_of(self.Pn @ self.vec[k], angle), 1.0)
            self._TP[(k, angle)] = t
        return t

    def TPall(self, angle: float) -> np.ndarray:
        """`(K, N)`: `TP` of every direction."""
        t = self._TP.get(("all", angle))
        if t is None:
            t = self._TP[("all", angle)] = np.stack([self.TP(k, angle) for k in range(len(self.dirs))])
        return t

    def visT(self) -> np.ndarray:
        """`(K, N)`: `visP` transposed (rows are contiguous)."""
        t = self._TP.get("visT")
        if t is None:
            t = self._TP["visT"] = np.ascontiguousarray(self.visP.T)
        return t

    def TPmin(self, angle: float) -> np.ndarray:
        """The least On of each surface sample over every direction."""
        t = self._TP.get(("min", angle))
        if t is None:
            t = self.TP(0, angle)
            for k in range(1, len(self.dirs)):
                t = np.minimum(t, self.TP(k, angle))
            self._TP[("min", angle)] = t
        return t

    def _visible_terms(self, ks, angle: float) -> tuple[float, int]:
        """The surface samples visible along one of the directions `ks` (sorted): the sum of
        their On values (the least over the directions) and their count."""
        vis = self.visP[:, ks].any(1)
        on_p = np.ones(self.n_samples)
        for k in ks:
            on_p = np.minimum(on_p, self.TP(k, angle))
        return float(on_p[vis].sum()), int(vis.sum())

    def energy(self, ks, eps1: float, eps2: float, angle: float = 85.0) -> dict:
        """E (Eq. 1-5) of the ESI bounded by the signed directions `ks`.

        S~'s surface is the part of S visible along one of the directions (sampled by the
        surface samples themselves, at distance 0) and the "floaters": boundary samples of
        a height field that are off S and inside all the other height fields.
        """
        ks = sorted(set(ks))
        self.n_full += 1
        tot_on, n = self._visible_terms(ks, angle)
        tot_d = 0.0
        for k in ks:
            keep = self.floaters(k, [k2 for k2 in ks if k2 != k])
            if not len(keep):
                continue
            # a floater is inside every other height field, so its rays along their axes
            # hit S (v = 0, On = 1 there): only its own axis can cover it
            on = self.T(k, k, angle)[keep]
            tot_on += float(on.sum())
            tot_d += float(self.distances(k, keep).sum())
            n += len(keep)
        cd_st = self.cd_st(ks)
        if n == 0:
            return dict(E=math.inf, dist=math.inf, cd_st=cd_st, cd_ts=math.inf, mu=1.0)
        cd_ts = tot_d / n
        mu = tot_on / n
        dist = cd_st + cd_ts
        E = dist + min(mu * (dist + eps1), eps2)
        return dict(E=E, dist=dist, cd_st=cd_st, cd_ts=cd_ts, mu=mu)


def _T_of(cos, angle):
    theta = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    return 0.5 * np.tanh(theta - angle) + 0.5

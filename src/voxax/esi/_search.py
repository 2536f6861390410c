"""Branch and bound over the choices of height fields: the lower bounds of E below one
DHF (`_Dhf`) and the best-first search of one level (`_search`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .._kernels import blas as _blas
from .._kernels import esi as _kesi
from ._problem import _Problem

_CHUNK = 8  # leaves whose rays are cast together (exhaustive search)


def _top_sums(c: np.ndarray, r: int) -> list:
    """`out[s][j]` = the sum of the `s` largest of `c[j:]` (`s <= r`), with `out[s][len(c)] = 0`."""
    n = len(c)
    out = [np.zeros(n + 1) for _ in range(r + 1)]
    if r == 1 and n:  # the suffix maxima (of values >= 0 and the 0 past the end)
        out[1][:n] = np.maximum.accumulate(np.asarray(c, np.float64)[::-1])[::-1]
        return out
    top: list = []
    for j in range(n - 1, -1, -1):
        top = sorted(top + [float(c[j])], reverse=True)[:r]
        for s in range(1, r + 1):
            out[s][j] = sum(top[:s])
    return out


class _Node(NamedTuple):
    """A partial choice of HFs `hs` (ascending candidate indices) below one DHF."""

    hs: tuple
    rr: np.ndarray  # indices into `_Dhf.rows` of the surface samples hidden from every axis so far
    cur: np.ndarray  # their least distance to the boundary of one of the height fields so far
    n_vis: int  # surface samples visible along one of the axes so far
    vis: np.ndarray  # (N,) bool: which
    base: np.ndarray  # (N,) the least On of each surface sample over the axes so far
    alive: np.ndarray  # (R,) bool: the candidate floaters inside every HF of `hs` (but their own)


class _Dhf:
    """Everything one DHF fixes of E, for the exact energies and lower bounds of E of its
    choices of HFs (the nodes of its search tree).

    With the DHF along `(kp, km)` and HFs from the candidates `hk`:

    - `CD(S, S~)` sums `min(D)` over the surface samples hidden from the DHF (`rows`);
    - the visible surface samples count at distance 0;
    - the *candidate floaters* are the boundary samples that can be floaters of some choice
      of HFs: for each HF candidate `j` those of `HF(j)` inside both sides of the DHF
      (block `j`), and those of each side of the DHF inside the other (the last two
      blocks). `IN[j, row]` says whether a row's ray along HF candidate `j` hits S (cast
      as needed, a block at a time; `BK` says which blocks are known along which
      candidates). The floaters of a choice of HFs are the rows of its blocks that lie
      inside all of its other HFs.
    """

    def __init__(self, prob: _Problem, kp: int, km: int, hk, angle: float):
        self.prob, self.kp, self.km, self.angle = prob, kp, km, angle
        self.hk = hk = list(hk)
        self.nh = len(hk)
        visd = prob.visP[:, kp] | prob.visP[:, km]
        self.rows = np.flatnonzero(~visd)
        self.cur = np.minimum(prob.D[self.rows, kp], prob.D[self.rows, km])
        self.Dr = prob.D[np.ix_(self.rows, hk)]
        self.Vr = prob.visP[np.ix_(self.rows, hk)]
        inf = np.full((len(self.rows), 1), np.inf)
        self.suf = np.concatenate([np.minimum.accumulate(self.Dr[:, ::-1], axis=1)[:, ::-1], inf], 1)
        self.sufv = np.concatenate(
            [np.logical_or.accumulate(self.Vr[:, ::-1], axis=1)[:, ::-1], np.zeros_like(inf, bool)], 1
        )
        self.visd = visd
        self.base = np.minimum(prob.TP(kp, angle), prob.TP(km, angle))
        self.tpmin = prob.TPmin(angle)
        self.same = np.array([k in (kp, km) for k in hk], bool)
        self.built = False

    def _build(self) -> None:
        """The candidate floaters: the boundary samples of every HF candidate inside both
        sides of the DHF, and those of each side inside the other (one C++ call)."""
        prob, kp, km, nh = self.prob, self.kp, self.km, self.nh
        bk = list(self.hk) + [kp, km]
        pts, soff = prob.samples()
        blocks = [(soff[k], soff[k + 1], kp, km) for j, k in enumerate(self.hk) if not self.same[j]]
        blocks += [(soff[kp], soff[kp + 1], km, -1), (soff[km], soff[km + 1], kp, -1)]
        inside, n_cast = _kesi.column_inside(pts, blocks, prob._casts, prob.threads)
        prob.n_rays += n_cast
        empty = np.zeros(0, np.int64)
        bidx = [
            empty if j < nh and self.same[j] else np.flatnonzero(inside[soff[k] : soff[k + 1]])
            for j, k in enumerate(bk)
        ]
        sizes = np.array([len(i) for i in bidx])
        self.off = np.concatenate([[0], np.cumsum(sizes)])
        R = int(self.off[-1])
        self.R = R
        self.gid = np.concatenate([soff[k] + i for k, i in zip(bk, bidx)]).astype(np.int64)
        self.hkarr = np.asarray(self.hk, np.int64)
        self.wd = np.concatenate(prob.distances_many(list(zip(bk, bidx))))
        self.wt = np.concatenate([prob.T(k, k, self.angle)[i] for k, i in zip(bk, bidx)])
        self.IN = np.zeros((nh, R), bool)
        # which blocks' rows are known along which HF candidates (BK[b, j]): a height field
        # along the DHF's own line changes nothing; a block is not filtered by its own
        # height field
        self.BK = np.zeros((nh + 2, nh), bool)
        self.IN[self.same] = True
        self.BK[:, self.same] = True
        for j in range(nh):
            self.IN[j, self.off[j] : self.off[j + 1]] = True
            self.BK[j, j] = True
        self.brows = [np.arange(self.off[b], self.off[b + 1]) for b in range(nh + 2)]
        self.built = True

    def ensure(self, blocks, cols) -> None:
        """Know `IN` of the rows of `blocks` along the HF candidates `cols`, a whole block
        along a candidate at a time, casting the rays not cast yet through the problem's
        registry (a boundary sample's ray along a direction is the same ray for every
        DHF), in one C++ call."""
        blocks = np.asarray(blocks, np.int64)
        cols = np.asarray(cols, np.int64)
        if not len(blocks) or not len(cols):
            return
        bi, ci = np.nonzero(~self.BK[np.ix_(blocks, cols)])
        if not len(bi):
            return
        prob = self.prob
        pairs = np.stack([blocks[bi], cols[ci]], 1)
        reg, pts = prob.registry(self.hk), prob.samples()[0]
        prob.n_rays += _kesi.column_known(
            pairs, self.off, self.IN, self.gid, self.hkarr, reg, reg.shape[1], pts, prob._casts, prob.threads
        )
        self.BK[pairs[:, 0], pairs[:, 1]] = True

    def root_cd(self) -> float:
        """The `CD(S, S~)` bound of the DHF with the best of every HF."""
        return float(np.minimum(self.cur, self.suf[:, 0]).sum() / self.prob.n_samples) * (1 - 1e-9)

    def root(self) -> _Node:
        if not self.built:
            self._build()
        n_vis = self.prob.n_samples - len(self.rows)
        return _Node((), np.arange(len(self.rows)), self.cur, n_vis, self.visd, self.base, np.ones(self.R, bool))

    def _blocks(self, hs) -> list:
        """The blocks of the DHF and of the HFs `hs`."""
        return [self.nh, self.nh + 1] + [j for j in hs if not self.same[j]]

    def children(self, node: _Node, m: int, eps1: float, eps2: float, best: float = math.inf):
        """Lower bounds of E over the subtrees of the children of `node` (each adds one HF
        `h` after the node's; `r - 1` more follow), as `(H, bounds, state)`. When the
        children are leaves (`r = 1`) the bounds are their energies, summed in another
        order and scaled by `1 - 1e-9`. Children whose bound exceeds `best` are left out."""
        prob, nh, N = self.prob, self.nh, self.prob.n_samples
        hs, rr, cur, n_vis = node.hs, node.rr, node.cur, node.n_vis
        r = m - len(hs)
        start = hs[-1] + 1 if hs else 0
        H = np.arange(start, nh - r + 1)
        # the hidden surface samples' sums (C++): `C`, their distances with child `h`;
        # `cd`, `CD(S, S~)` with the best of the HFs after it too; `vn` and `vmax`, how many
        # turn visible with child `h`, and with it or an HF after it
        C, Vn, cd, vn, vmax = _kesi.bound_samples(rr, cur, self.Dr, self.suf, self.Vr, self.sufv, start, len(H), r > 1)
        cd = cd / N

        def prune(E, *arrays):
            keep = E <= best
            if keep.all():
                return (E,) + arrays
            return (E[keep],) + tuple(a[..., keep] for a in arrays)

        # (the children's columns of `C` and `Vn` are `pos`: pruning does not copy them)
        pos = np.arange(len(H))
        cd, H, pos, vn, vmax = prune(cd * (1 - 1e-9), cd, H, pos, vn, vmax)[1:]  # the cheap part first
        if not len(H):
            return H, cd, None
        blocks = self._blocks(hs)
        nr = np.concatenate([self.brows[b] for b in blocks])
        nr = nr[node.alive[nr]]
        self.ensure(blocks, np.arange(H[0], nh) if r > 1 else H)
        # the node's candidate floaters that child `h` keeps (C++): the sums of their
        # distances `td`, On values `tt` and count `nd`; below, with more HFs to come,
        # `Md[h3 - s3, h]` (`Mt`) sums the distances (On values) of those that HF `h3`
        # would remove (only the HFs after the first child, h3 > H[0], can follow a child)
        s3 = int(H[0]) + 1
        (td, tt, nd), Md, Mt = _kesi.bound_removals(self.IN, nr, H, None, s3 if r > 1 else nh, self.wd, self.wt, prob.threads)
        # each block's rows inside the node's HFs: count, distances, On values
        # (the blocks before `start` play no part)
        cnt, bwd, bwt = np.zeros((3, nh))
        cnt[start:], bwd[start:], bwt[start:] = _kesi.bound_blocks(
            node.alive, self.off[start : nh + 1], self.wd, self.wt, r == 1
        )
        a = prob.on_surface
        on_vis = float(np.minimum(node.base, self.tpmin)[node.vis].sum())
        if r == 1:
            # exact: every term of E; first with the On of the visible surface samples
            # bounded below, then exactly for the children still within the bound
            td = td + bwd[H]
            tt = tt + bwt[H]
            nd = nd + cnt[H]
            n = n_vis + vn + nd

            def energy(on):
                with np.errstate(divide="ignore", invalid="ignore"):
                    cd_ts = np.where(n > 0, td / np.maximum(n, 1), np.inf)
                    mu = np.where(n > 0, (on + tt) / np.maximum(n, 1), 1.0)
                dist = cd + cd_ts
                E = dist + np.minimum(mu * (dist + eps1), eps2)
                E = E * (1 - 1e-9)
                E[~np.isfinite(dist)] = np.inf
                return E

            E, H, pos, cd, td, tt, n = prune(energy(on_vis), H, pos, cd, td, tt, n)
            if not len(H):
                return H, E, None
            hkH = [self.hk[j] for j in H]
            TP = prob.TPall(self.angle)
            z = np.flatnonzero(node.vis & (node.base > 0))
            on = np.minimum(node.base[z][None, :], TP[np.ix_(hkH, z)]).sum(1)
            on = on + (Vn[:, pos] * TP[np.ix_(hkH, self.rows[rr])].T).sum(0)
            return H, energy(on), (node, H, C, Vn, pos)
        # the next r - 1 HFs can remove at most the floaters of their r - 1 best
        lat = np.arange(s3, nh)[:, None] > H[None, :]
        vmax = n_vis + vmax
        topc = _top_sums(cnt, r - 1)[r - 1]

        def bound(td, tt, nd, Md, Mt, lat, vmax, cd, xm):
            top = max(len(Md) - (r - 1), 0)
            td = np.maximum(td - np.sort(np.where(lat, Md, 0.0), axis=0)[top:].sum(0), 0.0)
            tt = np.maximum(tt - np.sort(np.where(lat, Mt, 0.0), axis=0)[top:].sum(0), 0.0)
            n0 = vmax + nd
            with np.errstate(divide="ignore", invalid="ignore"):
                r1 = np.where(n0 > 0, td / np.maximum(n0, 1), np.inf)
                r2 = np.where(n0 + xm > 0, (td + a * xm) / np.maximum(n0 + xm, 1), np.inf)
                mu = np.where(n0 + xm > 0, (on_vis + tt) / np.maximum(n0 + xm, 1), 0.0)
            dist = cd + np.minimum(r1, r2)
            E = dist + np.minimum(mu * (dist + eps1), eps2)
            E = E * (1 - 1e-9)
            E[~np.isfinite(dist)] = np.inf
            return E

        # first with the floaters of the child and of the HFs after it unknown (at most
        # their blocks' rows inside the node's HFs, each farther from S than `a`)
        E = bound(td, tt, nd, Md, Mt, lat, vmax, cd, cnt[H] + topc[H + 1])
        E, H, pos, cd, td, tt, nd, Md, Mt, lat, vmax = prune(E, H, pos, cd, td, tt, nd, Md, Mt, lat, vmax)
        if not len(H) or not hs:
            # (at the root this would cast the rays of nearly every candidate floater along
            # every HF: measured slower on the knot)
            return H, E, (node, H, C, Vn, pos)
        # then, below the root, with the child's own rows inside the node's HFs known, less what the HFs
        # after it can remove (their rays are cast for the children still within the bound)
        rc = np.concatenate([self.brows[h] for h in H])
        col = np.repeat(np.arange(len(H)), self.off[H + 1] - self.off[H])
        keep = node.alive[rc]
        rc, col = rc[keep], col[keep]
        self.ensure(H, np.arange(H[0] + 1, nh))
        (od, ot, _), rd, rt = _kesi.bound_removals(self.IN, rc, H, col, s3, self.wd, self.wt, prob.threads)
        E2 = bound(td + od, tt + ot, nd + cnt[H], Md + rd, Mt + rt, lat, vmax, cd, topc[H + 1])
        return H, np.maximum(E, E2), (node, H, C, Vn, pos)

    def child(self, state, o: int) -> _Node:
        """The node of child `o` of a `children` result. Its candidate floaters are the rows
        of its own blocks and of the blocks after its last HF that lie inside its HFs (the
        rays along the new HF are cast here)."""
        node, H, C, Vn, pos = state
        c = int(pos[o])
        prob, h, nh = self.prob, int(H[o]), self.nh
        k = self.hk[h]
        blocks = self._blocks(node.hs + (h,)) + list(range(h + 1, nh))
        mine = np.zeros(self.R, bool)
        mine[self.off[h + 1] :] = True  # the blocks after h, then the DHF's two
        for j in node.hs + (h,):
            if not self.same[j]:
                mine[self.off[j] : self.off[j + 1]] = True
        self.ensure(blocks, [h])
        alive = node.alive & mine & self.IN[h]
        keep = ~Vn[:, c]
        return _Node(
            node.hs + (h,),
            node.rr[keep],
            C[keep, c],
            node.n_vis + int(Vn[:, c].sum()),
            node.vis | prob.visT()[k],
            np.minimum(node.base, prob.TP(k, self.angle)),
            alive,
        )

    def leaf_energy(self, state, o: int, eps1: float, eps2: float) -> float:
        """E of leaf `o` of a `children` result with `r = 1`: the arithmetic of
        `_Problem.energy`, term for term and in its order, so the same value to the bit."""
        node, H, C, Vn, pos = state
        c = int(pos[o])
        prob, nh, h = self.prob, self.nh, int(H[o])
        k = self.hk[h]
        prob.n_full += 1
        vis = node.vis | prob.visT()[k]
        on_p = np.minimum(node.base, prob.TP(k, self.angle))
        tot_on, n = float(on_p[vis].sum()), int(vis.sum())
        blocks = {self.kp: nh, self.km: nh + 1}
        for j in node.hs + (h,):
            if not self.same[j]:
                blocks[self.hk[j]] = j
        tot_d = 0.0
        for kk in sorted(blocks):
            b = blocks[kk]
            sl = slice(self.off[b], self.off[b + 1])
            keep = node.alive[sl] & self.IN[h, sl]
            if not keep.any():
                continue
            tot_on += float(self.wt[sl][keep].sum())
            tot_d += float(self.wd[sl][keep].sum())
            n += int(keep.sum())
        z = np.zeros(prob.n_samples)
        keep = ~Vn[:, c]
        z[self.rows[node.rr[keep]]] = C[keep, c]
        cd_st = float(z.mean())
        if n == 0:
            return math.inf
        cd_ts = tot_d / n
        mu = tot_on / n
        dist = cd_st + cd_ts
        return dist + min(mu * (dist + eps1), eps2)


def _search(prob: _Problem, dk, hk, m, eps1, eps2, angle, exhaustive, *, cap=math.inf, first=None):
    """`_search_level` with one BLAS thread (its many mid-sized products run faster so, next
    to the casts' thread pools; see `voxax._kernels.blas`)."""
    with _blas.single_threaded():
        return _search_level(prob, dk, hk, m, eps1, eps2, angle, exhaustive, cap=cap, first=first)


def _search_level(prob: _Problem, dk, hk, m, eps1, eps2, angle, exhaustive, *, cap=math.inf, first=None):
    """The least `(E, i, hfs)` over DHF candidates `dk` (pairs of signed indices) and `m`
    HFs from `hk`, by branch and bound on the lower bounds of `_Dhf` (best first),
    counting leaves and full evaluations. With `cap`, only combinations with E <= cap are
    sought (`best` stays `[cap, inf, ()]` when there is none). `first`: the DHF searched
    first (then the others from the least bound of their roots' children up)."""
    n_h = len(hk)
    best = [cap, math.inf, ()]
    leaves = math.comb(n_h, m) * len(dk)
    n0 = prob.n_full

    def consider(E, i, hs):
        if (E, i, hs) < tuple(best):
            best[0], best[1], best[2] = E, i, hs

    if m == 0 or exhaustive:
        import itertools

        combos = list(itertools.combinations(range(n_h), m))
        for i, (kp, km) in enumerate(dk):
            for c0 in range(0, len(combos), _CHUNK):
                chunk = combos[c0 : c0 + _CHUNK]
                prob.prefetch([[kp, km] + [hk[j] for j in hs] for hs in chunk])
                for hs in chunk:
                    consider(prob.energy([kp, km] + [hk[j] for j in hs], eps1, eps2, angle)["E"], i, tuple(hs))
        return best, leaves, prob.n_full - n0
    terms = []
    for kp, km in dk:
        key = (kp, km, tuple(hk), angle)
        t = prob._terms.get(key)
        if t is None:
            t = prob._terms[key] = _Dhf(prob, kp, km, hk, angle)
        terms.append(t)

    def expand(i, node, kids=None):
        t = terms[i]
        H, E, state = t.children(node, m, eps1, eps2, best[0]) if kids is None else kids
        leaf = len(node.hs) + 1 == m
        for o in np.argsort(E, kind="stable"):
            if E[o] > best[0]:
                break  # sorted: the rest is beyond the bound too
            if leaf:
                consider(t.leaf_energy(state, int(o), eps1, eps2), i, node.hs + (int(H[o]),))
            else:
                expand(i, t.child(state, int(o)))

    # the DHF `first` (the best one with m - 1 HFs) gives an incumbent; then every other
    # DHF's root is bounded, and they are searched from the least bound up
    if first is not None:
        expand(first, terms[first].root())
    roots = []
    for i, t in enumerate(terms):
        if i != first and t.root_cd() <= best[0]:
            node = t.root()
            kids = t.children(node, m, eps1, eps2, best[0])
            roots.append((float(kids[1].min()) if len(kids[0]) else math.inf, i, node, kids))
    roots.sort(key=lambda x: x[:2])
    for lb, i, node, kids in roots:
        if lb > best[0]:
            break
        expand(i, node, kids)
    return best, leaves, prob.n_full - n0

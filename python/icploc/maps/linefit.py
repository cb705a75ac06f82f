"""Wall line segments from an occupancy grid.

Works in *cell units*: cell ``grid[iy, ix]`` has its centre at ``(x, y) = (ix, iy)``. The
caller (:class:`icploc.Map`) maps that to metres with the resolution and origin.

Pipeline:

1. **Surface cells**: occupied cells with a free 4-neighbour (the faces a laser can hit).
   A one- or two-cell-thick wall is all surface; a thick wall gives its two faces.
2. **Thinning** (scikit-image ``thin``) of the surface cells to a one-pixel skeleton, traced into pixel chains between end
   points and junctions (closed loops too).
3. **Split** each chain where it bends (Douglas-Peucker on the chain, tolerance ~1 cell).
4. **Refit** each piece by total least squares on *all* surface cells within a band around
   it (not only the skeleton pixels, which lean to one side of a staircase).
5. **Merge** collinear neighbouring pieces (walls cut by T-junctions or door frames) when
   the joint fit stays tight; drop pieces whose cells a longer line already explains.
6. End points are the extreme projections of the supporting cell centres, extended by half a
   cell (a cell says the wall reaches anywhere inside it).

Surface cells no kept line explains are returned with normals from their neighbourhood,
for the sampler's fallback (clutter, curved or ragged walls).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage
from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]

_FOUR = np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]], dtype=bool)


@dataclass
class LineFit:
    """Result of :func:`fit_lines`, in cell units (see module doc)."""

    lines: FloatArray  # (K, 4) x1, y1, x2, y2; the left normal points to free space
    rms: FloatArray  # (K,) RMS perpendicular residual of the supporting cells
    support: NDArray[np.int64]  # (K,) number of supporting surface cells
    surface: FloatArray  # (M, 2) surface cell centres (x, y)
    explained: NDArray[np.bool_]  # (M,) surface cell lies on a kept line
    surface_normals: FloatArray  # (M, 2) unit normals from the local structure

    @property
    def explained_fraction(self) -> float:
        n = int(self.explained.shape[0])
        return float(self.explained.sum()) / n if n else 1.0


def surface_mask(
    occupied: NDArray[np.bool_], free: NDArray[np.bool_] | None, reach: int = 3
) -> NDArray[np.bool_]:
    """Occupied cells with a non-occupied 4-neighbour that lie within ``reach`` cells of free
    space (anti-aliased maps put a rim of unknown cells between walls and free space; faces
    that only look into unknown space are left out). ``free=None``: non-occupied is free."""
    occupied = np.asarray(occupied, dtype=bool)
    if free is None:
        free = ~occupied
    boundary = occupied & ndimage.binary_dilation(~occupied, structure=_FOUR)
    near_free = ndimage.binary_dilation(
        np.asarray(free, dtype=bool), structure=np.ones((3, 3), dtype=bool), iterations=reach
    )
    surf = boundary & near_free
    if not surf.any():
        # no free space recorded near any wall: use every boundary cell
        surf = boundary
    return surf


def _trace_chains(skel: NDArray[np.bool_]) -> list[NDArray[np.int64]]:
    """Ordered pixel chains of an 8-connected skeleton, as (n, 2) arrays of (x, y)."""
    h, w = skel.shape
    wp = w + 2
    pad = np.zeros((h + 2, wp), dtype=bool)
    pad[1:-1, 1:-1] = skel
    flat = pad.ravel()
    offs = (-wp - 1, -wp, -wp + 1, -1, 1, wp - 1, wp, wp + 1)
    idx = np.flatnonzero(flat)
    count = np.zeros(flat.size, dtype=np.int8)
    for o in offs:
        count[idx] += flat[idx + o]
    on = flat.tolist()
    is_node = ((count != 2) & flat).tolist()
    visited = bytearray(flat.size)
    chains: list[list[int]] = []

    def walk(start: int, first: int) -> list[int]:
        chain = [start, first]
        visited[first] = 1
        prev, cur = start, first
        while True:
            nxt = -1
            for o in offs:
                k = cur + o
                if k == prev or not on[k]:
                    continue
                if is_node[k] or not visited[k]:
                    nxt = k
                    break
            if nxt < 0:
                return chain
            chain.append(nxt)
            if is_node[nxt] or nxt == start:
                return chain
            visited[nxt] = 1
            prev, cur = cur, nxt

    nodes = idx[np.asarray(is_node, dtype=bool)[idx]]
    for n in nodes.tolist():
        for o in offs:
            m = n + o
            if not on[m]:
                continue
            if is_node[m]:
                if n < m:
                    chains.append([n, m])
            elif not visited[m]:
                chains.append(walk(n, m))
    # closed loops without any node (e.g. the skeleton of a room's inner face)
    for p in idx.tolist():
        if is_node[p] or visited[p]:
            continue
        visited[p] = 1
        nb = [p + o for o in offs if on[p + o]]
        if not nb:
            continue
        chain = walk(p, nb[0])
        chains.append(chain)
    out = []
    for c in chains:
        a = np.asarray(c, dtype=np.int64)
        out.append(np.column_stack([a % wp - 1, a // wp - 1]))
    return out


def _split(pts: FloatArray, tol: float) -> list[tuple[int, int]]:
    """Douglas-Peucker split of an ordered chain into index ranges (inclusive)."""
    n = len(pts)
    out: list[tuple[int, int]] = []
    stack = [(0, n - 1)]
    while stack:
        i, j = stack.pop()
        if j - i < 2:
            out.append((i, j))
            continue
        seg = pts[i : j + 1]
        d = pts[j] - pts[i]
        length = float(np.hypot(d[0], d[1]))
        rel = seg - pts[i]
        if length < 1e-9:
            dist = np.hypot(rel[:, 0], rel[:, 1])
        else:
            dist = np.abs(d[0] * rel[:, 1] - d[1] * rel[:, 0]) / length
        k = int(np.argmax(dist))
        if dist[k] > tol and 0 < k < j - i:
            stack.append((i + k, j))
            stack.append((i, i + k))
        else:
            out.append((i, j))
    out.sort()
    return out


def _tls(
    pts: FloatArray, hint: FloatArray | None = None
) -> tuple[FloatArray, FloatArray, float, float]:
    """Total least squares line: centroid, unit direction, RMS and max |residual|."""
    c = pts.mean(axis=0)
    q = pts - c
    cov = q.T @ q
    evals, evecs = np.linalg.eigh(cov)
    u = evecs[:, 1]
    if hint is not None and float(u @ hint) < 0:
        u = -u
    r = q[:, 0] * -u[1] + q[:, 1] * u[0]
    return c, u, float(np.sqrt(np.mean(r * r))), float(np.max(np.abs(r)))


class _Fitter:
    def __init__(self, surface: FloatArray) -> None:
        self.s = surface
        self.tree = cKDTree(surface)

    def band(self, a: FloatArray, b: FloatArray, tol: float, reach: float) -> NDArray[np.int64]:
        """Indices of surface cells within ``tol`` of segment a-b (extended by ``reach``)."""
        d = b - a
        length = float(np.hypot(d[0], d[1]))
        if length < 1e-9:
            return np.zeros(0, dtype=np.int64)
        u = d / length
        cand = np.asarray(
            self.tree.query_ball_point(0.5 * (a + b), 0.5 * length + reach + tol), dtype=np.int64
        )
        if cand.size == 0:
            return cand
        q = self.s[cand] - a
        t = q @ u
        s = q[:, 0] * -u[1] + q[:, 1] * u[0]
        sel = (np.abs(s) <= tol) & (t >= -reach) & (t <= length + reach)
        return np.sort(cand[sel])

    def fit(
        self, idx: NDArray[np.int64], hint: FloatArray
    ) -> tuple[FloatArray, FloatArray, float, float] | None:
        if idx.size < 2:
            return None
        pts = self.s[idx]
        c, u, rms, mx = _tls(pts, hint)
        t = (pts - c) @ u
        return c + u * t.min(), c + u * t.max(), rms, mx


@dataclass
class _Seg:
    a: FloatArray
    b: FloatArray
    idx: NDArray[np.int64]
    rms: float
    maxdev: float

    @property
    def length(self) -> float:
        return float(np.hypot(*(self.b - self.a)))

    @property
    def u(self) -> FloatArray:
        d = self.b - self.a
        return d / max(float(np.hypot(d[0], d[1])), 1e-12)


def _refine(f: _Fitter, a: FloatArray, b: FloatArray, band: float) -> _Seg | None:
    seg: _Seg | None = None
    for tol in (1.0, band):
        idx = f.band(a, b, tol, reach=0.75)
        r = f.fit(idx, b - a)
        if r is None:
            return seg
        a, b, rms, mx = r
        seg = _Seg(a, b, idx, rms, mx)
    return seg


def _grow(f: _Fitter, seg: _Seg, band: float, max_rms: float) -> _Seg:
    """Extend a segment along its line while contiguous surface cells continue it."""
    for _ in range(50):
        idx = f.band(seg.a, seg.b, band, reach=1.5)
        if idx.size <= seg.idx.size:
            return seg
        r = f.fit(idx, seg.u)
        if r is None:
            return seg
        a, b, rms, mx = r
        if rms > max_rms or mx > band + 0.25:
            return seg
        seg = _Seg(a, b, idx, rms, mx)
    return seg


def _merge_round(
    f: _Fitter, segs: list[_Seg], band: float, max_angle: float, gap: float, max_rms: float
) -> tuple[list[_Seg], bool]:
    if len(segs) < 2:
        return segs, False
    ends = np.array([[s.a, s.b] for s in segs]).reshape(-1, 2)
    pairs = cKDTree(ends).query_pairs(gap, output_type="ndarray")
    if len(pairs) == 0:
        return segs, False
    i, j = pairs[:, 0] // 2, pairs[:, 1] // 2
    keep = i != j
    i, j = i[keep], j[keep]
    u = np.array([s.u for s in segs])
    sin = np.abs(u[i, 0] * u[j, 1] - u[i, 1] * u[j, 0])
    ok = sin < np.sin(max_angle)
    order = np.argsort(sin[ok], kind="stable")
    i, j = i[ok][order], j[ok][order]
    used = np.zeros(len(segs), dtype=bool)
    new: list[_Seg] = []
    changed = False
    for a_, b_ in zip(i.tolist(), j.tolist(), strict=True):
        if used[a_] or used[b_]:
            continue
        sa, sb = segs[a_], segs[b_]
        idx = np.union1d(sa.idx, sb.idx)
        hint = sa.u if sa.length >= sb.length else sb.u
        r = f.fit(idx, hint)
        if r is None:
            continue
        a, b, rms, mx = r
        if rms > max_rms or mx > band + 0.25:
            continue
        seg = _refine(f, a, b, band)
        if seg is None or seg.rms > max_rms:
            continue
        used[a_] = used[b_] = True
        new.append(seg)
        changed = True
    new.extend(s for k, s in enumerate(segs) if not used[k])
    return new, changed


def _local_normals(
    pts: FloatArray, tree: cKDTree, surface: FloatArray, free: NDArray[np.bool_], radius: float
) -> FloatArray:
    """Unit normals of surface cells: neighbourhood PCA, or the free-space gradient where the
    neighbourhood is not line-like; oriented towards free space."""
    n = np.zeros((len(pts), 2))
    if len(pts) == 0:
        return n
    h, w = free.shape
    dens = ndimage.uniform_filter(free.astype(np.float64), size=5, mode="constant")
    gy, gx = np.gradient(dens)
    nbrs = tree.query_ball_point(pts, radius)
    for k, (p, nb) in enumerate(zip(pts, nbrs, strict=True)):
        ix, iy = int(round(p[0])), int(round(p[1]))
        g = np.array([gx[iy, ix], gy[iy, ix]]) if 0 <= ix < w and 0 <= iy < h else np.zeros(2)
        v = None
        if len(nb) >= 3:
            q = surface[nb] - surface[nb].mean(axis=0)
            evals, evecs = np.linalg.eigh(q.T @ q)
            if evals[0] < 0.3 * evals[1]:
                v = evecs[:, 0]
        if v is None:
            v = g if float(np.hypot(g[0], g[1])) > 1e-9 else np.array([1.0, 0.0])
        v = v / float(np.hypot(v[0], v[1]))
        if float(v @ g) < 0:
            v = -v
        n[k] = v
    return n


def _consistent(surface: FloatArray, seg: _Seg) -> _Seg:
    """Make a thin segment consistent with its raster.

    A line through a set of cells must pass within ``h = (|n_x| + |n_y|) / 2`` of each cell
    centre (the half-width of a cell seen along the line's normal n). Total least squares can
    break that on short, nearly axis-parallel staircases (one step: the fit tilts towards the
    step and leaves the end cells). Then take instead the centroid of the set of lines
    ``y' = m x' + b`` (local frame of the fit) that pass through every cell: the middle of what
    the raster allows. Unchanged when that set is empty (a noisy wall, not a digital line).
    """
    from scipy.optimize import linprog
    from scipy.spatial import ConvexHull, HalfspaceIntersection

    pts = surface[seg.idx]
    u = seg.u
    nrm = np.array([-u[1], u[0]])
    c = pts.mean(axis=0)
    x = (pts - c) @ u
    y = (pts - c) @ nrm
    h = 0.5 * (abs(nrm[0]) + abs(nrm[1]))
    # |y - m x - b| <= h  as  A [m, b] <= rhs
    one = np.ones_like(x)
    a_ub = np.vstack([np.column_stack([-x, -one]), np.column_stack([x, one])])
    rhs = np.concatenate([h - y, h + y])
    # interior point: maximise the margin t in A [m, b] + t <= rhs
    lp = linprog(
        [0.0, 0.0, -1.0],
        A_ub=np.column_stack([a_ub, np.ones(len(a_ub))]),
        b_ub=rhs,
        bounds=[(-1.0, 1.0), (None, None), (None, 1.0)],
        method="highs",
    )
    if lp.status != 0 or lp.x[2] <= 1e-9:
        return seg
    try:
        hs = HalfspaceIntersection(np.column_stack([a_ub, -rhs]), lp.x[:2])
        v = hs.intersections[ConvexHull(hs.intersections).vertices]
    except Exception:  # noqa: BLE001 - degenerate (qhull): keep the least-squares fit
        return seg
    xs, ys = v[:, 0], v[:, 1]
    xn, yn = np.roll(xs, -1), np.roll(ys, -1)
    cr = xs * yn - xn * ys
    area = cr.sum() / 2.0
    if abs(area) < 1e-15:
        return seg
    m = float(((xs + xn) * cr).sum() / (6.0 * area))
    b = float(((ys + yn) * cr).sum() / (6.0 * area))
    d = u + m * nrm
    d = d / np.hypot(d[0], d[1])
    c2 = c + b * nrm
    t = (pts - c2) @ d
    r = (pts - c2) @ np.array([-d[1], d[0]])
    return _Seg(
        c2 + d * t.min(),
        c2 + d * t.max(),
        seg.idx,
        float(np.sqrt(np.mean(r * r))),
        float(np.max(np.abs(r))),
    )


def _free_count(free: NDArray[np.bool_], p: FloatArray) -> int:
    h, w = free.shape
    ix = np.rint(p[:, 0]).astype(int)
    iy = np.rint(p[:, 1]).astype(int)
    ok = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
    return int(free[iy[ok], ix[ok]].sum())


def fit_lines(
    occupied: NDArray[np.bool_],
    free: NDArray[np.bool_] | None = None,
    *,
    split_tolerance: float = 1.0,
    band: float = 0.75,
    min_length: float = 4.0,
    merge_angle_deg: float = 3.0,
    merge_gap: float = 2.5,
    max_rms: float = 0.45,
    extend: float = 0.5,
) -> LineFit:
    """Fit wall segments to an occupancy grid (all lengths in cells).

    ``occupied``/``free`` are boolean ``grid[iy, ix]`` arrays (``free=None``: every
    non-occupied cell is free). ``min_length`` drops shorter pieces (their cells stay in the
    unexplained fallback set); ``band`` is the half-width of the band of cells a line is fitted
    to; ``extend`` lengthens each line at both ends (half a cell by default).
    """
    from skimage.morphology import thin

    occupied = np.asarray(occupied, dtype=bool)
    if occupied.ndim != 2:
        raise ValueError(f"occupancy grid must be 2-D, got shape {occupied.shape}")
    free_m = ~occupied if free is None else np.asarray(free, dtype=bool)
    surf = surface_mask(occupied, free_m)
    ys, xs = np.nonzero(surf)
    surface = np.column_stack([xs, ys]).astype(np.float64)
    empty = LineFit(
        np.zeros((0, 4)),
        np.zeros(0),
        np.zeros(0, dtype=np.int64),
        surface,
        np.zeros(len(surface), dtype=bool),
        np.zeros((len(surface), 2)),
    )
    if len(surface) < 2:
        empty.surface_normals[:] = (1.0, 0.0)
        return empty

    f = _Fitter(surface)
    skel = thin(surf)
    segs: list[_Seg] = []
    for chain in _trace_chains(skel):
        pts = chain.astype(np.float64)
        if len(pts) < 2:
            continue
        for i, j in _split(pts, split_tolerance):
            if j - i < 1:
                continue
            s = _refine(f, pts[i], pts[j], band)
            if s is not None:
                segs.append(s)

    for _ in range(12):
        segs, changed = _merge_round(f, segs, band, np.deg2rad(merge_angle_deg), merge_gap, max_rms)
        if not changed:
            break

    segs = [_grow(f, s, band, max_rms) for s in segs]

    # longest first; drop pieces that are (mostly) explained already, or too short
    segs.sort(key=lambda s: -s.length)
    claimed = np.zeros(len(surface), dtype=bool)
    kept: list[_Seg] = []
    for s in segs:
        if s.length + 1.0 < min_length or s.idx.size < 3:
            continue
        if claimed[s.idx].mean() > 0.8:
            continue
        claimed[s.idx] = True
        kept.append(s)

    explained = np.zeros(len(surface), dtype=bool)
    lines = np.zeros((len(kept), 4))
    for k, s in enumerate(kept):
        explained[f.band(s.a, s.b, 1.0, reach=0.5)] = True
        if s.maxdev > 0.5 and s.maxdev < 1.0:
            s = kept[k] = _consistent(surface, s)
        u = s.u
        a, b = s.a - extend * u, s.b + extend * u
        # orient so the left normal faces free space
        nrm = np.array([-u[1], u[0]])
        t = np.linspace(0.0, 1.0, max(2, int(s.length) + 1))[:, None]
        along = a + t * (b - a)
        if _free_count(free_m, along - 1.5 * nrm) > _free_count(free_m, along + 1.5 * nrm):
            a, b = b, a
        lines[k] = (a[0], a[1], b[0], b[1])

    rest = ~explained
    normals = np.zeros((len(surface), 2))
    normals[rest] = _local_normals(surface[rest], f.tree, surface, free_m, 2.5)
    if kept:
        # explained cells take the normal of (one of) their lines
        for k, s in enumerate(kept):
            d = lines[k, 2:] - lines[k, :2]
            d = d / np.hypot(d[0], d[1])
            normals[s.idx] = (-d[1], d[0])
    return LineFit(
        lines=lines,
        rms=np.array([s.rms for s in kept]),
        support=np.array([s.idx.size for s in kept], dtype=np.int64),
        surface=surface,
        explained=explained,
        surface_normals=normals,
    )

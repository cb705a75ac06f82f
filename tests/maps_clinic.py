"""A simulated clinic wing for the line-extraction tests: solid walls (convex polygons),
rasterised at 5 cm (a cell is occupied when its centre lies inside a wall), and the ground
truth of every wall face free space sees.

Dimensions are on the 5 cm grid, as plans drawn in 5 cm steps are, except the glass facade
(12 degrees off the grid) and one 7-degree partition: those test sloped faces.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

RES = 0.05
W, H = 32.0, 12.0  # metres


def rect(x0: float, y0: float, x1: float, y1: float) -> NDArray[np.float64]:
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=np.float64)


def rotated(cx: float, cy: float, length: float, thick: float, deg: float) -> NDArray[np.float64]:
    th = math.radians(deg)
    u = np.array([math.cos(th), math.sin(th)])
    n = np.array([-u[1], u[0]])
    c = np.array([cx, cy])
    hl, ht = length / 2, thick / 2
    return np.array([c - hl * u - ht * n, c + hl * u - ht * n, c + hl * u + ht * n, c - hl * u + ht * n])


def polygons() -> list[NDArray[np.float64]]:
    p: list[NDArray[np.float64]] = []
    # outer walls (0.2 m), the east end is the glass facade below
    p += [rect(0.5, 0.5, 28.0, 0.7), rect(0.5, 11.3, 28.0, 11.5), rect(0.5, 0.5, 0.7, 11.5)]
    # corridor walls (0.15 m) at y 5.0 and 7.0 with 0.9 m doors
    for y0 in (4.85, 7.0):
        xs = [0.7, 3.0, 3.9, 8.0, 8.9, 13.0, 13.9, 18.0, 18.9, 23.0, 23.9, 28.0]
        for a, b in zip(xs[0::2], xs[1::2], strict=True):
            p.append(rect(a, y0, b, y0 + 0.15))
    # room walls (0.1 m)
    for x in (5.5, 10.5, 15.5, 20.5, 25.5):
        p += [rect(x, 0.7, x + 0.1, 4.85), rect(x, 7.15, x + 0.1, 11.3)]
    # short walls and partitions 0.5 .. 1.4 m
    p += [
        rect(2.0, 2.0, 2.1, 2.8),  # 0.8 m
        rect(7.0, 3.0, 8.4, 3.1),  # 1.4 m
        rect(12.0, 9.0, 12.1, 9.5),  # 0.5 m
        rect(17.0, 1.5, 18.0, 1.6),  # 1.0 m
        rect(22.0, 8.5, 22.1, 9.7),  # 1.2 m
        rotated(9.0, 9.5, 1.3, 0.1, 7.0),  # a partition 7 degrees off
    ]
    # pillars 0.4 m square in the corridor; furniture blocks 1 m x 0.6 m in rooms
    p += [rect(x, 5.8, x + 0.4, 6.2) for x in (6.0, 16.0, 26.0)]
    p += [
        rect(1.5, 9.5, 2.5, 10.1),
        rect(11.5, 1.2, 12.1, 2.2),
        rect(16.5, 9.0, 17.5, 9.6),
        rect(21.5, 2.5, 22.5, 3.1),
        rect(26.5, 9.8, 27.5, 10.4),
    ]
    # glass facade at the east end: 0.1 m thick, 12 degrees off vertical
    p.append(rotated(28.7, 6.0, 11.3, 0.1, 90.0 + 12.0))
    return p


def _inside(poly: NDArray[np.float64], x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.bool_]:
    ok = np.ones(x.shape, dtype=bool)
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        ok &= (b[0] - a[0]) * (y - a[1]) - (b[1] - a[1]) * (x - a[0]) >= 0
    return ok


def inside_any(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.bool_]:
    out = np.zeros(np.shape(x), dtype=bool)
    for poly in polygons():
        out |= _inside(poly, x, y)
    return out


def grid() -> NDArray[np.bool_]:
    """Occupied cells ``grid[iy, ix]`` (origin 0, 0)."""
    nx, ny = int(round(W / RES)), int(round(H / RES))
    yy, xx = np.mgrid[:ny, :nx]
    return inside_any((xx + 0.5) * RES, (yy + 0.5) * RES)


def inside_grid(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Within the grid (free space outside the building is free space too)."""
    return (x > 0.0) & (x < W) & (y > 0.0) & (y < H)


def face_samples(step: float = 0.01) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Points every ``step`` along every polygon edge that free space sees, their outward unit normals, and the length of the edge each lies on."""
    pts, nrms, lens = [], [], []
    for poly in polygons():
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            d = b - a
            length = float(np.hypot(*d))
            u = d / length
            n = np.array([u[1], -u[0]])  # polygons are CCW: outward is the right normal
            t = (np.arange(int(length / step)) + 0.5) * step
            q = a + t[:, None] * u
            probe = q + 0.02 * n
            seen = ~inside_any(probe[:, 0], probe[:, 1]) & inside_grid(probe[:, 0], probe[:, 1])
            pts.append(q[seen])
            nrms.append(np.tile(n, (int(seen.sum()), 1)))
            lens.append(np.full(int(seen.sum()), length))
    return np.concatenate(pts), np.concatenate(nrms), np.concatenate(lens)


def exact_faces() -> NDArray[np.float64]:
    """Every polygon edge as a segment whose left normal faces out (for exact-wall scans)."""
    segs = []
    for poly in polygons():
        for i in range(len(poly)):
            a, b = poly[i], poly[(i + 1) % len(poly)]
            segs.append([b[0], b[1], a[0], a[1]])  # reversed: left normal = outward
    return np.array(segs)

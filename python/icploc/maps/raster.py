"""Rasterising line segments into an occupancy grid (every cell a segment touches)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray


def supercover_cells(p: NDArray[np.float64], q: NDArray[np.float64]) -> NDArray[np.int64]:
    """(n, 2) integer (ix, iy) of every cell the segment p-q passes through.

    Coordinates are in cell units with cell ``(ix, iy)`` centred at ``(ix, iy)``, i.e.
    covering ``[ix - 0.5, ix + 0.5) x [iy - 0.5, iy + 0.5)``.
    """
    a = np.asarray(p, dtype=np.float64) + 0.5
    b = np.asarray(q, dtype=np.float64) + 0.5
    d = b - a
    ts = [np.array([0.0, 1.0])]
    for k in range(2):
        if d[k] != 0.0:
            lo, hi = min(a[k], b[k]), max(a[k], b[k])
            edges = np.arange(math.ceil(lo), math.floor(hi) + 1, dtype=np.float64)
            ts.append((edges - a[k]) / d[k])
    t = np.unique(np.clip(np.concatenate(ts), 0.0, 1.0))
    mids = np.concatenate([[0.0], 0.5 * (t[:-1] + t[1:]), [1.0]])
    cells = np.floor(a[None, :] + mids[:, None] * d[None, :]).astype(np.int64)
    return np.unique(cells, axis=0)


def rasterize_lines(lines_cells: NDArray[np.float64], shape: tuple[int, int]) -> NDArray[np.bool_]:
    """Boolean grid ``[iy, ix]`` of the cells touched by (K, 4) segments in cell units."""
    grid = np.zeros(shape, dtype=bool)
    h, w = shape
    for x1, y1, x2, y2 in np.asarray(lines_cells, dtype=np.float64).reshape(-1, 4):
        c = supercover_cells(np.array([x1, y1]), np.array([x2, y2]))
        ok = (c[:, 0] >= 0) & (c[:, 0] < w) & (c[:, 1] >= 0) & (c[:, 1] < h)
        grid[c[ok, 1], c[ok, 0]] = True
    return grid

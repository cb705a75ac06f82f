"""Uniform sampling of wall segments (the paper's §2.2) and point-map thinning."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def line_normals(lines: FloatArray) -> FloatArray:
    """(K, 2) unit left normals (direction rotated +90 degrees) of (K, 4) segments."""
    d = lines[:, 2:4] - lines[:, 0:2]
    length = np.hypot(d[:, 0], d[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        n = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    return n


def sample_lines(
    lines: FloatArray, spacing: float
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Points every ``spacing`` metres along each segment, with unit normals.

    A segment of length L gets ``n = ceil(L / spacing)`` points at the centres of n equal
    pieces, so neighbours on a segment are ``L / n <= spacing`` apart, the ends are half a
    step in (no duplicates where segments meet) and even a short segment gets one point.
    Returns ``(points (N, 2), normals (N, 2), line index (N,))``; normals are the segment's
    left normal (towards free space for lines fitted from a grid).
    """
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive finite number, got {spacing!r}")
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    d = lines[:, 2:4] - lines[:, 0:2]
    length = np.hypot(d[:, 0], d[:, 1])
    keep = length > 0
    lines, d, length = lines[keep], d[keep], length[keep]
    src = np.flatnonzero(keep)
    n = np.maximum(1, np.ceil(length / spacing - 1e-9)).astype(np.int64)
    seg = np.repeat(np.arange(len(lines)), n)
    start = np.cumsum(n) - n
    k = np.arange(int(n.sum())) - np.repeat(start, n)
    t = (k + 0.5) / n[seg]
    pts = lines[seg, 0:2] + t[:, None] * d[seg]
    nrm = np.column_stack([-d[:, 1], d[:, 0]]) / length[:, None]
    return pts, nrm[seg], src[seg]


def thin_points(points: FloatArray, spacing: float) -> NDArray[np.int64]:
    """Indices of a subset with one point per ``spacing``-sized square cell (the point nearest
    the cell's mean), sorted."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(points) == 0:
        return np.zeros(0, dtype=np.int64)
    if not (np.isfinite(spacing) and spacing > 0):
        raise ValueError(f"spacing must be a positive finite number, got {spacing!r}")
    key = np.floor((points - points.min(axis=0)) / spacing + 1e-6).astype(np.int64)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    ncell = int(inv.max()) + 1
    cnt = np.bincount(inv, minlength=ncell).astype(np.float64)
    mean = np.column_stack([np.bincount(inv, points[:, i], ncell) for i in range(2)]) / cnt[:, None]
    d2 = ((points - mean[inv]) ** 2).sum(axis=1)
    order = np.lexsort((d2, inv))
    first = np.ones(len(order), dtype=bool)
    first[1:] = inv[order][1:] != inv[order][:-1]
    return np.sort(order[first])


def estimate_normals(points: FloatArray, radius: float, k: int = 8) -> FloatArray:
    """Unit normals of a point map from the PCA of each point's neighbourhood (the ``k``
    nearest within ``radius``; fewer than 2 neighbours gives the x axis). Sign is arbitrary."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    n = np.tile([1.0, 0.0], (len(points), 1))
    if len(points) < 2:
        return n
    from scipy.spatial import cKDTree
    kk = min(k + 1, len(points))
    dist, idx = cKDTree(points).query(points, k=kk, distance_upper_bound=radius)
    valid = np.isfinite(dist)
    safe = np.where(valid, idx, 0)
    nb = points[safe]  # (N, kk, 2)
    w = valid[..., None].astype(np.float64)
    cnt = w.sum(axis=1)
    mean = (nb * w).sum(axis=1) / np.maximum(cnt, 1)
    q = (nb - mean[:, None, :]) * w
    cxx = (q[..., 0] ** 2).sum(axis=1)
    cyy = (q[..., 1] ** 2).sum(axis=1)
    cxy = (q[..., 0] * q[..., 1]).sum(axis=1)
    # direction of the smallest eigenvalue of [[cxx, cxy], [cxy, cyy]]
    theta = 0.5 * np.arctan2(2 * cxy, cxx - cyy)  # major axis
    nn = np.column_stack([-np.sin(theta), np.cos(theta)])
    ok = cnt[:, 0] >= 3
    n[ok] = nn[ok]
    return n

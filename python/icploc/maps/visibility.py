"""Which map points a scanner could see: field of view, range, and occlusion by walls.

The per-scan fast path is the Rust z-buffer :meth:`icploc.MapIndex.visible` (used by
:meth:`icploc.Map.visible`). :func:`visible_exact` here is a numpy reference: a point is
visible when the ray to it crosses no wall segment before reaching it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


def in_fov(
    points: FloatArray, pose: Sequence[float], fov: float, max_range: float
) -> NDArray[np.bool_]:
    """Points within ``max_range`` of the sensor and within ``fov`` (radians) centred on its heading."""
    d = np.asarray(points, dtype=np.float64).reshape(-1, 2) - np.array([pose[0], pose[1]])
    r = np.hypot(d[:, 0], d[:, 1])
    ok = r <= max_range
    if fov < 2 * math.pi:
        bearing = np.arctan2(d[:, 1], d[:, 0]) - pose[2]
        bearing = (bearing + math.pi) % (2 * math.pi) - math.pi
        ok &= np.abs(bearing) <= 0.5 * fov
    return ok


def visible_exact(
    points: FloatArray,
    lines: FloatArray,
    pose: Sequence[float],
    fov: float = 2 * math.pi,
    max_range: float = 30.0,
    *,
    tolerance: float = 0.05,
    chunk: int = 2_000_000,
) -> NDArray[np.int64]:
    """Indices (sorted) of ``points`` in the field of view with no wall crossing the ray
    from the sensor closer than ``tolerance`` metres before the point (so a point's own wall,
    and walls meeting it at a corner, do not hide it)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    cand = np.flatnonzero(in_fov(pts, pose, fov, max_range))
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    if len(cand) == 0 or len(lines) == 0:
        return cand.astype(np.int64)
    o = np.array([pose[0], pose[1]], dtype=np.float64)
    # only walls that can lie within range
    a, b = lines[:, :2] - o, lines[:, 2:] - o
    ab = b - a
    t = np.clip(-(a * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-300), 0.0, 1.0)
    near = np.hypot(*(a + t[:, None] * ab).T) <= max_range
    a, ab = a[near], ab[near]
    blocked = np.zeros(len(cand), dtype=bool)
    step = max(1, chunk // max(1, len(a)))
    for s in range(0, len(cand), step):
        q = pts[cand[s : s + step]] - o  # rays o -> q, parameter u in [0, 1]
        r = np.hypot(q[:, 0], q[:, 1])
        # solve o + u q = a + v ab
        den = q[:, None, 0] * ab[None, :, 1] - q[:, None, 1] * ab[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = (a[None, :, 0] * ab[None, :, 1] - a[None, :, 1] * ab[None, :, 0]) / den
            v = (a[None, :, 0] * q[:, None, 1] - a[None, :, 1] * q[:, None, 0]) / den
        umax = 1.0 - tolerance / np.maximum(r, 1e-12)
        hit = (np.abs(den) > 1e-12) & (u > 1e-9) & (u < umax[:, None]) & (v >= 0.0) & (v <= 1.0)
        blocked[s : s + step] = hit.any(axis=1)
    return cand[~blocked].astype(np.int64)


def visible_in_grid(
    classes: NDArray[np.uint8],
    resolution: float,
    origin: Sequence[float],
    pose: Sequence[float],
    points: FloatArray,
    tolerance: float,
) -> NDArray[np.bool_]:
    """Which ``points`` a sensor at ``pose`` sees through an occupancy grid: the ray to a
    point must cross only free cells (unknown cells occlude, as occupied ones do) up to
    ``tolerance`` metres before the point. ``classes[iy, ix]``: 0 free, 1 occupied, 2
    unknown; ``origin`` (x, y, yaw) of the grid's outer corner. The ray walk is in Rust."""
    from icploc._core import grid_visible

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    c, s = math.cos(origin[2]), math.sin(origin[2])

    def local(xy: FloatArray) -> FloatArray:
        q = xy - np.array([origin[0], origin[1]])
        return np.column_stack([c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]])

    sensor = local(np.array([[pose[0], pose[1]]], dtype=np.float64))[0]
    return np.asarray(
        grid_visible(
            np.ascontiguousarray(classes, dtype=np.uint8),
            (0.0, 0.0),
            float(resolution),
            (float(sensor[0]), float(sensor[1])),
            np.ascontiguousarray(local(pts)),
            float(tolerance),
        ),
        dtype=bool,
    )

"""Scores for the real-data benchmark: position error against the reference, false
``tracking``, time lost, and how well the scans fit the map at the estimated poses."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from icploc.trajectory import pose_errors
from numpy.typing import NDArray

__all__ = ["FALSE_TRACKING_M", "map_fit", "summarise"]

#: a scan reported ``tracking`` (or, for peers without a status, any scan) farther than
#: this from the reference counts as a false ``tracking`` scan
FALSE_TRACKING_M = 0.5


def position_errors(est: NDArray[np.float64], ref: NDArray[np.float64]) -> NDArray[np.float64]:
    e, _ = pose_errors(est, ref)
    # a non-finite estimate is as wrong as can be: it counts, it is not dropped
    return np.where(np.isfinite(e), e, np.inf)


def summarise(
    est: NDArray[np.float64] | None,
    ref: NDArray[np.float64] | None,
    status: Sequence[str] | None,
) -> dict[str, float | int | None]:
    """median / p95 / max position error (m), false-``tracking`` count, lost share.

    ``status``: one of tracking / degraded / lost per scan, or None for a method without
    one (then every scan counts as claimed: a scan > 0.5 m off is a false ``tracking``)."""
    out: dict[str, float | int | None] = {}
    n = len(est) if est is not None else len(status or [])
    out["scans"] = n
    if status is not None:
        st = np.asarray(list(status))
        out["lost_share"] = float(np.mean(st == "lost")) if n else 0.0
        out["tracking_share"] = float(np.mean(st == "tracking")) if n else 0.0
        claimed = st == "tracking"
    else:
        out["lost_share"] = None
        out["tracking_share"] = None
        claimed = np.ones(n, dtype=bool)
    if est is None or ref is None:
        return out
    e = position_errors(est, ref)
    out["median_m"] = float(np.median(e))
    # "higher": the sample at or above the 95th percentile (no interpolation towards inf)
    out["p95_m"] = float(np.percentile(e, 95, method="higher"))
    out["max_m"] = float(np.max(e))
    out["false_tracking"] = int(np.sum(claimed & (e > FALSE_TRACKING_M)))
    out["over_0_5m"] = int(np.sum(e > FALSE_TRACKING_M))
    out["over_5m"] = int(np.sum(e > 5.0))
    return out


def map_fit(
    est: NDArray[np.float64],
    ranges: NDArray[np.float64],
    angles: NDArray[np.float64],
    map_points: NDArray[np.float64],
    max_range: float,
    cap: float = 1.0,
) -> NDArray[np.float64]:
    """Per scan: the median distance (capped at ``cap``) from its beam endpoints, placed at
    the estimated pose, to the nearest occupied cell centre."""
    from scipy.spatial import cKDTree

    tree = cKDTree(map_points)
    out = np.full(len(est), cap)
    ca, sa = np.cos(angles), np.sin(angles)
    for i, (p, r) in enumerate(zip(est, ranges, strict=True)):
        if not np.all(np.isfinite(p)):
            continue
        v = (r > 0.05) & (r < max_range)
        if not v.any():
            continue
        c, s = math.cos(p[2]), math.sin(p[2])
        x = p[0] + r[v] * (c * ca[v] - s * sa[v])
        y = p[1] + r[v] * (s * ca[v] + c * sa[v])
        d, _ = tree.query(np.column_stack([x, y]), k=1, distance_upper_bound=cap)
        out[i] = float(np.median(np.minimum(d, cap)))
    return out

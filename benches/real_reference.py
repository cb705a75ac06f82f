"""A reference trajectory for a log that has none (laserazosSM3): sequential scan-to-submap
point-to-point ICP (``numpy_icp.NumpyIcp``, cKDTree), started from the odometry increment,
against the points of the previous ``window`` scans placed at their reference poses. No
loop closure: it drifts slowly over a long run, which is why the benchmark scores
laserazos by map fit and lost share and shows the error against this reference only as a
secondary, labelled figure.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from numpy_icp import NumpyIcp
from real_odometry import compose_steps, relative_motions

__all__ = ["build_reference"]


def _world(p: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    c, s = math.cos(p[2]), math.sin(p[2])
    return np.column_stack([p[0] + c * xy[:, 0] - s * xy[:, 1], p[1] + s * xy[:, 0] + c * xy[:, 1]])


def build_reference(
    ranges: NDArray[np.float64],
    angles: NDArray[np.float64],
    odom: NDArray[np.float64],
    max_range: float,
    window: int = 30,
    min_inliers: int = 50,
) -> NDArray[np.float64]:
    steps = relative_motions(odom)
    ca, sa = np.cos(angles), np.sin(angles)
    pts = []
    for r in ranges:
        v = (r > 0.05) & (r < max_range)
        pts.append(np.column_stack([r[v] * ca[v], r[v] * sa[v]]))
    poses = [np.asarray(odom[0], dtype=np.float64)]
    world = [_world(poses[0], pts[0])]
    for i in range(1, len(ranges)):
        pred = compose_steps(poses[-1], steps[i - 1 : i])[-1]
        sub = np.vstack(world[-window:])
        if len(pts[i]) >= min_inliers and len(sub) >= min_inliers:
            icp = NumpyIcp(sub, max_distance=0.5, min_distance=0.05, decay=0.6, max_iterations=40)
            res = icp.align(pts[i], pred)
            p = np.asarray(res.pose) if res.inliers >= min_inliers else pred
        else:
            p = pred
        poses.append(p)
        world.append(_world(p, pts[i]))
    return np.asarray(poses)

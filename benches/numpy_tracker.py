"""The numpy + scipy tracker baseline for the end-to-end replay figure: predict with the
odometry increment since the last scan, correct with the cKDTree point-to-point ICP of
``numpy_icp.py`` started from the prediction. No gating, no covariance: the afternoon
version a user would write, which the Localizer has to beat.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from numpy_icp import NumpyIcp


def _compose(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], math.remainder(a[2] + b[2], 2 * math.pi))


def _between(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float, float]:
    c, s = math.cos(a[2]), math.sin(a[2])
    dx, dy = b[0] - a[0], b[1] - a[1]
    return (c * dx + s * dy, -s * dx + c * dy, math.remainder(b[2] - a[2], 2 * math.pi))


class NumpyTracker:
    """Odometry predict + ICP correct, one scan at a time."""

    def __init__(
        self,
        map_points: NDArray[np.float64],
        initial_pose: tuple[float, float, float],
        max_distance: float = 0.5,
        min_distance: float = 0.1,
        decay: float = 0.6,
        max_iterations: int = 30,
        workers: int = 1,
    ) -> None:
        self.icp = NumpyIcp(map_points, max_distance, min_distance, decay, max_iterations, workers=workers)
        self.pose = tuple(float(v) for v in initial_pose)
        self._last_odo: tuple[float, float, float] | None = None

    def update(self, scan_xy: NDArray[np.float64], odometry: tuple[float, float, float]) -> tuple[float, float, float]:
        odo = tuple(float(v) for v in odometry)
        if self._last_odo is not None:
            self.pose = _compose(self.pose, _between(self._last_odo, odo))  # type: ignore[arg-type]
        self._last_odo = odo  # type: ignore[assignment]
        res = self.icp.align(scan_xy, self.pose)
        if res.inliers >= self.icp.min_inliers:
            self.pose = res.pose
        return self.pose  # type: ignore[return-value]

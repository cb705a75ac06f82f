"""Scan preparation: a laser scan as the points the localizer matches (robot base frame)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from icploc._core import prepare_points
from icploc.config import LocalizerConfig
from icploc.messages import BEAM_DAZZLE, BEAM_INVALID, BEAM_NO_RETURN, Scan

__all__ = ["prepare_scan"]


_BAD_FLAGS = BEAM_NO_RETURN | BEAM_DAZZLE | BEAM_INVALID


class _TrigCache:
    """cos / sin of the beam angles (plus mounting), recomputed only when the angles change."""

    def __init__(self) -> None:
        self._angles: NDArray[np.float64] | None = None
        self._theta = 0.0
        self.cos: NDArray[np.float64] = np.zeros(0)
        self.sin: NDArray[np.float64] = np.zeros(0)

    def get(
        self, angles: NDArray[np.float64], theta: float
    ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        prev = self._angles
        if prev is not angles or self._theta != theta:
            if (
                prev is None
                or self._theta != theta
                or prev.shape != angles.shape
                or not np.array_equal(prev, angles)
            ):
                self.cos = np.cos(angles + theta)
                self.sin = np.sin(angles + theta)
            self._angles = angles
            self._theta = theta
        return self.cos, self.sin


def prepare_scan(
    scan: Scan,
    config: LocalizerConfig,
    trig: _TrigCache | None = None,
) -> NDArray[np.float64]:
    """The scan's usable beams as (M, 2) points in the robot base frame.

    Drops beams without a return (``inf``/NaN, flagged), at or beyond the max range (the
    scanner's own, or ``scan.max_range`` in the config), nearer than ``scan.min_range``;
    keeps every ``decimation``-th of the rest; applies the laser mounting offset.
    """
    sc = config.scan
    hi = sc.max_range if sc.max_range > 0.0 else scan.max_range
    if hi != math.inf:
        hi = hi * sc.max_range_margin
    lo = sc.min_range if sc.min_range > scan.min_range else scan.min_range
    if trig is None:
        trig = _TrigCache()
    c, s = trig.get(scan.angles, sc.laser_theta)
    # NaN and inf are never kept (inf < inf is False); the core's loop, the same products
    return prepare_points(
        scan.ranges, scan.flags, c, s, lo, hi, sc.decimation, _BAD_FLAGS,
        (sc.laser_x, sc.laser_y),
    )  # fmt: skip

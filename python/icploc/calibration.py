"""Online odometry calibration: the base's distance scale, turn scale and heading drift.

Real wheel odometry is off systematically: a worn tyre makes every metre 1 % short, an
unequal wheel pair adds a heading drift per metre, a wheel base off by a little scales every
turn. :class:`OdometryCalibration` learns the three factors from pairs of consecutive
accepted scan matches — the motion the scans say against the motion the odometry says —
with a slow exponential forgetting filter, bounded, and only from motions the scans
constrain well (the along-track error of a fit in a corridor is not evidence). The
localizer applies the factors to every odometry increment before predicting::

    dx, dy  *= scale                   (distance scale)
    dtheta  = dtheta * turn_scale + drift * distance      (wheel base; heading drift, rad/m)

so where the walls say nothing, dead reckoning drifts less than the raw odometry.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from icploc.se2 import Pose, wrap_angle

__all__ = ["OdometryCalibration"]


@dataclass
class OdometryCalibration:
    """Scale, turn scale and heading drift of the odometry (see the module docstring).

    ``memory``: the filter's memory in metres driven (and radians turned for the turn
    scale): evidence older than that fades. ``max_scale`` / ``max_turn_scale``: the factors
    stay within 1 +- these; ``max_drift``: the drift within +- this (rad/m).
    ``min_distance`` / ``min_turn``: a pair of scans moved at least this far / turned this
    much before its motion counts."""

    memory: float = 30.0
    max_scale: float = 0.05
    max_turn_scale: float = 0.1
    max_drift: float = math.radians(2.0)
    min_distance: float = 0.2
    min_turn: float = 0.1
    enabled: bool = True
    scale: float = 1.0
    turn_scale: float = 1.0
    drift: float = 0.0
    #: metres and radians of evidence so far (the filter starts unsure: factors move only
    #: as evidence accumulates)
    distance_seen: float = 0.0
    turn_seen: float = 0.0
    _sd: float = 0.0  # sum of weights x (observed / odometry distance)
    _w: float = 0.0
    _st: float = 0.0  # turn: sum odo_turn * measured_turn, sum odo_turn^2
    _tt: float = 0.0
    _sdr: float = 0.0  # drift: sum heading residual, sum distance
    _dd: float = 0.0

    @property
    def factors(self) -> tuple[float, float, float]:
        """(scale, turn_scale, drift rad/m)."""
        return (self.scale, self.turn_scale, self.drift)

    def apply(self, d: Sequence[float]) -> Pose:
        """The odometry increment ``d`` (robot frame) corrected by the learned factors."""
        dx, dy, dth = float(d[0]), float(d[1]), float(d[2])
        if not self.enabled:
            return (dx, dy, dth)
        dist = math.hypot(dx, dy)
        return (
            dx * self.scale,
            dy * self.scale,
            dth * self.turn_scale + self.drift * dist,
        )

    def observe(self, odometry: Sequence[float], measured: Sequence[float]) -> None:
        """One pair: ``odometry`` the raw odometry increment between two accepted scans,
        ``measured`` the motion between their scan-matched poses (both in the first scan's
        frame). The caller passes only motions the scans constrain (see the module
        docstring)."""
        if not self.enabled:
            return
        ox, oy, oth = float(odometry[0]), float(odometry[1]), float(odometry[2])
        mx, my, mth = float(measured[0]), float(measured[1]), float(measured[2])
        dist = math.hypot(ox, oy)
        turn = abs(oth)
        if dist >= self.min_distance:
            # the measured motion projected on the odometry's direction, per odometry metre
            ratio = (mx * ox + my * oy) / (dist * dist)
            if 0.5 < ratio < 1.5:
                f = math.exp(-dist / self.memory)
                self._sd = self._sd * f + dist * ratio
                self._w = self._w * f + dist
                self.distance_seen += dist
                w = min(1.0, self.distance_seen / self.memory)
                est = self._sd / self._w
                self.scale = 1.0 + w * _clamp(est - 1.0, self.max_scale)
        # heading: residual = measured - (odometry turn x turn scale), split between the
        # drift per metre (straight stretches) and the turn scale (turns)
        resid = wrap_angle(mth - oth * self.turn_scale - self.drift * dist)
        if abs(resid) > math.radians(10.0):
            return  # a bad pair, not a bias
        if turn >= self.min_turn:
            f = math.exp(-turn / self.memory)
            self._st = self._st * f + oth * (mth - self.drift * dist)
            self._tt = self._tt * f + oth * oth
            self.turn_seen += turn
            w = min(1.0, self.turn_seen / self.memory)
            est = self._st / self._tt
            self.turn_scale = 1.0 + w * _clamp(est - 1.0, self.max_turn_scale)
        elif dist >= self.min_distance:
            f = math.exp(-dist / self.memory)
            self._sdr = self._sdr * f + wrap_angle(mth - oth * self.turn_scale)
            self._dd = self._dd * f + dist
            w = min(1.0, self.distance_seen / self.memory)
            self.drift = w * _clamp(self._sdr / self._dd, self.max_drift)


def _clamp(v: float, lim: float) -> float:
    return max(-lim, min(lim, v))

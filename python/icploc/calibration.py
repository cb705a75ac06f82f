"""Online odometry calibration: the base's distance scale, sideways skew, turn scale and
heading drift.

Real wheel odometry is off systematically: a worn tyre makes every metre 1 % short, an
unequal wheel pair adds a heading drift per metre, a wheel base off by a little scales every
turn, a misaligned wheel or caster pulls the base sideways a little per metre (the real
Freiburg course odometry: 0.7 % of the distance). :class:`OdometryCalibration` learns the
four factors from pairs of consecutive
accepted scan matches — the motion the scans say against the motion the odometry says —
with a slow exponential forgetting filter, bounded, and only from motions the scans
constrain well (the along-track error of a fit in a corridor is not evidence). The
localizer applies the factors to every odometry increment before predicting::

    dtheta' = dtheta * turn_scale + drift * distance     (wheel base; heading drift, rad/m)
    (dx, dy) = rot((dx, dy) * scale, (dtheta' - dtheta) / 2) + skew * (-dy, dx)

(distance scale; the chord turned by half the heading correction, as a heading error that
grows steadily along the step moves its end sideways; skew: sideways per metre forward),
so where the walls say nothing, dead reckoning drifts less than the raw odometry. The
skew is learned from what stays sideways after that half-angle turn, so a heading drift is
not counted twice.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from icploc.config import LocalizerSection
from icploc.se2 import Pose, wrap_angle

__all__ = ["OdometryCalibration"]

#: the defaults (one source: the config model, ``localizer.calibration_*`` in a config file)
_L = LocalizerSection()


@dataclass
class OdometryCalibration:
    """Scale, turn scale and heading drift of the odometry (see the module docstring).

    ``memory``: the filter's memory in metres driven (and radians turned for the turn
    scale): evidence older than that fades. ``max_scale`` / ``max_turn_scale``: the factors
    stay within 1 +- these; ``max_drift``: the drift within +- this (rad/m); ``max_skew``:
    the skew within +- this (sideways per metre forward). ``min_distance`` / ``min_turn``: a
    straight pair (turned less than ``min_turn``) counts for the scale and drift when it
    moved at least ``min_distance``; a pair that turned at least ``min_turn`` counts for the
    turn scale. The bounds, the memory and ``enabled`` default to the ``localizer:``
    section's ``calibration_*`` / ``calibrate_odometry`` (:class:`icploc.config.LocalizerSection`);
    the rest are the filter's own constants."""

    memory: float = _L.calibration_memory
    max_scale: float = _L.calibration_max_scale
    max_turn_scale: float = _L.calibration_max_turn_scale
    max_drift: float = math.radians(_L.calibration_max_drift_deg)
    max_skew: float = _L.calibration_max_skew
    min_distance: float = 0.2
    min_turn: float = 0.1
    #: the shrinkage prior's weight: metres driven (turn: rad^2 turned) of "no correction"
    prior: float = 20.0
    prior_turn: float = 10.0
    enabled: bool = _L.calibrate_odometry
    scale: float = 1.0
    turn_scale: float = 1.0
    drift: float = 0.0
    skew: float = 0.0
    #: metres and radians of evidence so far (the filter starts unsure: factors move only
    #: as evidence accumulates)
    distance_seen: float = 0.0
    turn_seen: float = 0.0
    _sd: float = 0.0  # scale: sum distance x (ratio - 1), sum distance
    _w: float = 0.0
    _sk: float = 0.0  # skew: sum distance x sideways ratio (weights: _w)
    _st: float = 0.0  # turn: sum odo_turn x heading residual, sum odo_turn^2
    _tt: float = 0.0
    _td: float = 0.0  # heading: the weighted normal equations of (turn scale - 1, drift)
    _sdr: float = 0.0
    _dd: float = 0.0

    @classmethod
    def from_config(cls, settings: LocalizerSection) -> OdometryCalibration:
        """A calibration with a config's ``localizer:`` settings (``calibration_*``,
        ``calibrate_odometry``); the filter's own constants at their defaults."""
        return cls(
            memory=settings.calibration_memory,
            max_scale=settings.calibration_max_scale,
            max_turn_scale=settings.calibration_max_turn_scale,
            max_drift=math.radians(settings.calibration_max_drift_deg),
            max_skew=settings.calibration_max_skew,
            enabled=settings.calibrate_odometry,
        )

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
        th = dth * self.turn_scale + self.drift * dist
        h = 0.5 * (th - dth)
        c, s = math.cos(h), math.sin(h)
        x, y = dx * self.scale, dy * self.scale
        return (c * x - s * y - self.skew * dy, s * x + c * y + self.skew * dx, th)

    def uncertainty(self, d: Sequence[float]) -> tuple[float, float]:
        """The variance the factors not yet learned leave on the increment ``d``: (along
        the motion, m^2; heading, rad^2). Each factor's spread starts at half its bound
        and shrinks as evidence builds up against its prior; a base whose turns read 5 %
        short is then no six-sigma surprise before the calibration has seen it turn."""
        if not self.enabled:
            return 0.0, 0.0
        dist = math.hypot(float(d[0]), float(d[1]))
        turn = abs(float(d[2]))
        s_scale = 0.5 * self.max_scale * math.sqrt(self.prior / (self.prior + self._w))
        s_turn = 0.5 * self.max_turn_scale * math.sqrt(self.prior_turn / (self.prior_turn + self._tt))
        s_drift = 0.5 * self.max_drift * math.sqrt(self.prior / (self.prior + self._dd))
        s_skew = 0.5 * self.max_skew * math.sqrt(self.prior / (self.prior + self._w))
        return ((s_scale**2 + s_skew**2) * dist * dist), (s_turn * turn) ** 2 + (s_drift * dist) ** 2

    def observe(self, odometry: Sequence[float], measured: Sequence[float]) -> None:
        """One pair: ``odometry`` the raw odometry increment between two accepted scans,
        ``measured`` the motion between their scan-matched poses (both in the first scan's
        frame). The caller passes only motions the scans constrain (see the module
        docstring). Each factor is a ridge estimate with exponential forgetting: the sums
        of evidence over ``memory`` metres (radians), shrunk towards no correction by a
        prior worth ``prior`` metres (``prior_turn`` rad^2) that fades as evidence builds
        up (over ``memory``), so a few early pairs cannot swing it."""
        if not self.enabled:
            return
        ox, oy, oth = float(odometry[0]), float(odometry[1]), float(odometry[2])
        mx, my, mth = float(measured[0]), float(measured[1]), float(measured[2])
        dist = math.hypot(ox, oy)
        turn = abs(oth)
        resid = wrap_angle(mth - oth)
        if abs(resid) > math.radians(5.0) + self.max_turn_scale * turn + self.max_drift * dist:
            return  # a bad pair, not a bias (factors within their bounds are a bias)
        straight = turn < self.min_turn
        if straight and dist < self.min_distance:
            return
        if straight:
            # a straight stretch: the distance scale, and the skew (what is sideways once
            # the chord is turned by half the heading residual: a heading error growing
            # along the pair moves its end sideways by that much)
            ratio = (mx * ox + my * oy) / (dist * dist)
            side = (my * ox - mx * oy) / (dist * dist) - 0.5 * resid
            if abs(ratio - 1.0) > 0.2 or abs(side) > 0.2:
                return
            f = math.exp(-dist / self.memory)
            self._sd = self._sd * f + dist * (ratio - 1.0)
            self._sk = self._sk * f + dist * side
            self._w = self._w * f + dist
            self.distance_seen += dist
            w0 = self.prior * math.exp(-self.distance_seen / self.memory)
            self.scale = 1.0 + _clamp(self._sd / (self._w + w0), self.max_scale)
            self.skew = _clamp(self._sk / (self._w + w0), self.max_skew)
        else:
            self.turn_seen += turn
            self.distance_seen += dist
        # the heading: residual = (turn_scale - 1) x odometry turn + drift x distance, one
        # weighted least-squares fit over every pair (heading noise grows with the distance
        # and the turn); real routes seldom drive 2 m without turning, so the drift must be
        # read from turning pairs too
        w = 1.0 / max(dist + turn, 1e-3)
        f = math.exp(-(dist + turn) / self.memory)
        self._st = self._st * f + w * oth * resid
        self._tt = self._tt * f + w * oth * oth
        self._td = self._td * f + w * oth * dist
        self._sdr = self._sdr * f + w * dist * resid
        self._dd = self._dd * f + w * dist * dist
        # the priors fade as the sums fill, with the same forgetting (over ``memory`` of
        # distance plus turn): a prior fading with the turn alone outweighed the evidence
        # of a route that turns a little at a time for hundreds of metres (a 5 % turn
        # scale read as 1.5 % after 200 m), and the drift took up the rest
        seen = self.distance_seen + self.turn_seen
        pa = self.prior_turn * math.exp(-seen / self.memory)
        pb = self.prior * math.exp(-seen / self.memory)
        a11, a12, a22 = self._tt + pa, self._td, self._dd + pb
        det = a11 * a22 - a12 * a12
        if det <= 0.0:
            return
        a = (self._st * a22 - self._sdr * a12) / det
        b = (a11 * self._sdr - a12 * self._st) / det
        self.turn_scale = 1.0 + _clamp(a, self.max_turn_scale)
        self.drift = _clamp(b, self.max_drift)


def _clamp(v: float, lim: float) -> float:
    return max(-lim, min(lim, v))

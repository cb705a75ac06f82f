"""The odometry motion model: how far a motion can be off, growing with how far it went.

AMCL-style alphas (Thrun, Burgard & Fox, *Probabilistic Robotics* §5.4; nav2 AMCL's
``alpha1..alpha5``), with the same meanings, applied to a motion of length ``trans`` and
turn ``rot`` (its heading change)::

    var(heading)  = alpha1 rot^2 + alpha2 trans^2     turn from turn, turn from travel
    var(along)    = alpha3 trans^2 + alpha4 rot^2     travel from travel, travel from turn
    var(sideways) = alpha5 trans^2 + alpha4 rot^2     drift across the direction of travel

plus ``turn_walk |rot|`` along and sideways (``localizer.turn_walk_variance``): a turn's
position error adds up per radian as its sub-steps' errors do, a random walk that the squared
``alpha4`` term, fitted to motions with no turn on the spot, leaves out.
"along" is the direction of the motion's chord. (AMCL's differential model splits the motion
into turn-drive-turn; on real pairs of odometry and scan-matched motions the first turn of
short steps is pure lateral jitter, and a fit then inflates ``alpha1`` tenfold: here the
sideways drift has its own alpha, as in nav2's omni model.)
:class:`MotionModel` propagates a pose and its covariance through a motion;
:func:`fit_alphas` fits the alphas to paired motions by maximum likelihood — how the
defaults in :class:`icploc.config.LocalizerSection` were found, on the 2,000 real motions
of ``../shared/data/freiburg_course`` composed into steps of ~0.5 m (5 motions), the
spacing of real logs.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc._core import noise_factor
from icploc.config import LocalizerSection
from icploc.fusion import CHI2_3_MEDIAN
from icploc.se2 import Pose, compose, inverse

__all__ = ["MotionModel", "NoiseGain", "fit_alphas"]

#: below this translation (m) a motion is a turn on the spot: rot1 is taken as 0
_MIN_TRANS = 0.01
#: the defaults (one source: the config model, ``localizer.noise_gain_*`` in a config file)
_L = LocalizerSection()


@dataclass(frozen=True)
class MotionModel:
    """AMCL-style odometry noise (variances, see the module docstring) plus a per-step
    process noise floor (standard deviations ``floor_xy`` m, ``floor_theta`` rad) that keeps
    the filter responsive while standing still (a push, a slip)."""

    alpha1: float
    alpha2: float
    alpha3: float
    alpha4: float
    alpha5: float = 0.0
    floor_xy: float = 0.0
    floor_theta: float = 0.0
    #: multiplies every alpha (the online noise estimate; 1 = as configured)
    gain: float = 1.0
    #: along- and cross-track variance per radian turned (m^2/rad), linear in the turn: a
    #: random walk over the turn (``localizer.turn_walk_variance``; scaled by ``gain`` too)
    turn_walk: float = 0.0
    #: a step that travelled farther than this (m) adds no walk: the walk is a turn on the
    #: spot's, the alphas cover a step as long as the motions they were fitted to (0: any)
    walk_max_travel: float = 0.0

    @classmethod
    def from_config(cls, lc: LocalizerSection) -> MotionModel:
        """The configured model: ``lc``'s alphas and process noise floors."""
        return cls(
            lc.alpha1,
            lc.alpha2,
            lc.alpha3,
            lc.alpha4,
            lc.alpha5,
            floor_xy=lc.process_sigma_xy,
            floor_theta=lc.process_sigma_theta,
            turn_walk=lc.turn_walk_variance,
            walk_max_travel=lc.turn_walk_max_travel,
        )

    def motion_covariance(self, d: Sequence[float]) -> NDArray[np.float64]:
        """3x3 covariance of the motion ``d`` (dx, dy, dtheta) in its start frame."""
        q00, q01, q11, q22 = self._motion_q(float(d[0]), float(d[1]), float(d[2]))
        return np.array([[q00, q01, 0.0], [q01, q11, 0.0], [0.0, 0.0, q22]])

    def _motion_q(self, dx: float, dy: float, dth: float) -> tuple[float, float, float, float]:
        """The motion covariance's entries (xx, xy, yy, theta-theta), in floats."""
        t = math.hypot(dx, dy)
        g = self.gain
        t2, r2 = t * t, dth * dth
        v_th = g * (self.alpha1 * r2 + self.alpha2 * t2)
        far = self.walk_max_travel > 0.0 and t > self.walk_max_travel
        v_turn = self.alpha4 * r2 + (0.0 if far else self.turn_walk * abs(dth))
        v_al = g * (self.alpha3 * t2 + v_turn)
        v_lat = g * (self.alpha5 * t2 + v_turn)
        if t >= _MIN_TRANS:
            c, s = dx / t, dy / t
        else:
            c, s = 1.0, 0.0
        fxy = self.floor_xy * self.floor_xy
        q00 = c * c * v_al + s * s * v_lat + fxy
        q01 = c * s * (v_al - v_lat)
        q11 = s * s * v_al + c * c * v_lat + fxy
        return q00, q01, q11, v_th + self.floor_theta * self.floor_theta

    def predict(
        self, pose: Pose, covariance: NDArray[np.float64], d: Sequence[float]
    ) -> tuple[Pose, NDArray[np.float64]]:
        """``pose`` moved by ``d`` (robot frame) and its covariance
        P' = F P F^T + G Q G^T (F = d(pose ⊕ d)/d pose, G rotates the motion's frame into
        the map). In floats: this runs for every scan."""
        dx, dy, dth = float(d[0]), float(d[1]), float(d[2])
        pred = compose(pose, (dx, dy, dth))
        c, s = math.cos(pose[2]), math.sin(pose[2])
        a = -s * dx - c * dy
        b = c * dx - s * dy
        (p00, p01, p02), (_, p11, p12), (_, _, p22) = covariance.tolist()
        # F P F^T with F = [[1, 0, a], [0, 1, b], [0, 0, 1]]
        f00 = p00 + 2 * a * p02 + a * a * p22
        f01 = p01 + a * p12 + b * p02 + a * b * p22
        f02 = p02 + a * p22
        f11 = p11 + 2 * b * p12 + b * b * p22
        f12 = p12 + b * p22
        q00, q01, q11, q22 = self._motion_q(dx, dy, dth)
        # G Q G^T: rotate the motion's (x, y) block by the heading
        g00 = c * c * q00 - 2 * c * s * q01 + s * s * q11
        g01 = c * s * (q00 - q11) + (c * c - s * s) * q01
        g11 = s * s * q00 + 2 * c * s * q01 + c * c * q11
        P = np.array(
            [
                [f00 + g00, f01 + g01, f02],
                [f01 + g01, f11 + g11, f12],
                [f02, f12, p22 + q22],
            ]
        )
        return pred, P


@dataclass
class NoiseGain:
    """The odometry noise learned online: the factor on the motion model's variances that
    makes the prediction consistent with the scan matches that explain the scan.

    For one scan with prediction ``(x_p, P)`` and a trusted scan pose ``(z, R)`` the factor
    ``g`` that makes ``v' (g P + R)^-1 v`` equal to the median of its chi-square
    distribution (3 degrees of freedom) is solved for (so the median of the factors is
    unbiased when the covariances are right); the learned gain is the median of the last ``window`` such
    factors, within ``[1, max_gain]`` (never below the configured alphas). Unlike a mean of
    the chi-square statistic over the *accepted* fits, whose gate truncates it at the accept
    quantile (odometry that is off by more than its model says then never raises the gain),
    the caller also feeds the fits the gate turned down but the map supports (they verify
    and explain the scan at least as well as the prediction): that is where odometry worse
    than its model shows. The median keeps a few wrong fits from raising it much (10 % of
    the fits 1 m off: about 1.2 over simulated runs; 30 %: about 1.9). ``P`` already holds
    the gain in use (``current``): the factors are relative to it. The defaults are the
    ``localizer:`` section's ``noise_gain_max`` / ``noise_gain_window`` /
    ``noise_gain_min_samples`` (:class:`icploc.config.LocalizerSection`)."""

    max_gain: float = _L.noise_gain_max
    window: int = _L.noise_gain_window
    #: factors kept before the median is used (until then: 1)
    min_samples: int = _L.noise_gain_min_samples
    _g: deque[float] = field(default_factory=deque, repr=False)
    #: the gain of the factors in ``_g`` (None: to be computed; read once a scan)
    _gain: float | None = field(default=None, repr=False)

    @classmethod
    def from_config(cls, settings: LocalizerSection) -> NoiseGain:
        """A noise gain with a config's ``localizer:`` settings (``noise_gain_*``)."""
        return cls(
            max_gain=settings.noise_gain_max,
            window=settings.noise_gain_window,
            min_samples=settings.noise_gain_min_samples,
        )

    @property
    def gain(self) -> float:
        if self._gain is not None:
            return self._gain
        if len(self._g) < self.min_samples:
            g = 1.0
        else:
            v = sorted(self._g)
            n = len(v)
            m = v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])
            g = min(max(m, 1.0), self.max_gain)
        self._gain = g
        return g

    def observe(
        self,
        pred: Sequence[float],
        P: NDArray[np.float64],
        meas: Sequence[float],
        R: NDArray[np.float64],
        current: float = 1.0,
    ) -> None:
        """One trusted scan pose ``meas`` (covariance ``R``) against the prediction ``pred``
        (covariance ``P``, made with the gain ``current``)."""
        v = (meas[0] - pred[0], meas[1] - pred[1], math.remainder(meas[2] - pred[2], math.tau))
        # bisection on log g within [1e-3, 4 max_gain] (the statistic falls as g grows; at
        # an end when the root lies beyond it); None: an input is not finite
        g = noise_factor(v, P, R, self.max_gain, CHI2_3_MEDIAN)
        if g is None:
            return
        self._g.append(g * max(float(current), 1e-6))
        while len(self._g) > self.window:
            self._g.popleft()
        self._gain = None

    def reset(self) -> None:
        self._g.clear()
        self._gain = None


def fit_alphas(
    odometry: ArrayLike,
    reference: ArrayLike,
    floor_xy: float = 0.002,
    floor_theta: float = 0.002,
    rounds: int = 6,
) -> tuple[float, float, float, float, float]:
    """Maximum-likelihood alphas (module docstring) from paired relative motions:
    ``odometry`` and ``reference`` are (N, 3) arrays of (dx, dy, dtheta), row i one motion as
    the odometry measured it and as it was. The error of each is odometry relative to the
    reference; a systematic bias counts as noise here (what an uncalibrated base shows).
    Coordinate descent on the log-alphas."""
    o = np.asarray(odometry, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    if o.shape != r.shape or o.shape[0] < 4:
        raise ValueError(f"fit_alphas: need two equal (N >= 4, 3) arrays, got {o.shape}, {r.shape}")
    refs = [(float(b[0]), float(b[1]), float(b[2])) for b in r]
    odos = [(float(a[0]), float(a[1]), float(a[2])) for a in o]
    errs: list[NDArray[np.float64]] = [
        np.array(compose(inverse(b), a), dtype=np.float64) for a, b in zip(odos, refs, strict=True)
    ]

    def nll(la: NDArray[np.float64]) -> float:
        a1, a2, a3, a4, a5 = (float(v) for v in np.exp(la))
        mm = MotionModel(a1, a2, a3, a4, a5, floor_xy=floor_xy, floor_theta=floor_theta)
        tot = 0.0
        for e, b in zip(errs, refs, strict=True):
            Q = mm.motion_covariance(b)
            tot += float(np.linalg.slogdet(Q)[1] + e @ np.linalg.solve(Q, e))
        return tot

    la = np.log(np.array([0.05, 1e-3, 1e-3, 1e-3, 1e-3]))
    best = nll(la)
    for _ in range(rounds):
        for p in range(la.shape[0]):
            for step in (2.0, 1.0, 0.5, 0.25, -0.25, -0.5, -1.0, -2.0):
                t = la.copy()
                t[p] += step
                v = nll(t)
                if v < best:
                    best, la = v, t
    a1, a2, a3, a4, a5 = (float(v) for v in np.exp(la))
    return a1, a2, a3, a4, a5

"""The outer localization loop: odometry predicts, ICP corrects, the information decides.

Per scan::

    odometry at the scan stamp ─► calibrate the increment (learned scale, turn scale,
        heading drift) ─► predict: pose ⊕ increment, covariance grown by the AMCL-style
        motion model (noise with distance and turn)
    scan ─► prepare (drop bad beams, mount) ─► ICP from the prediction, its thresholds
        following the map's resolution and measured fit quality
    ─► the scan pose's covariance, calibrated (correlated beams, the map's resolution)
    ─► chi-square test of prediction against scan pose: accept / inflate / reject
    ─► one information update (a corridor's open axis keeps the prediction by itself)
    ─► verify the fused pose (beams ending on walls, residual against the expected noise)
    ─► status: ``tracking`` only when the correction was consistent, the pose verified and
        its covariance tight, no rival pose disputes it (the prediction a fit taken against
        the odometry overruled, followed until the map refutes it) and, right after a
        stretch not tracking, the fit pins the pose in every direction; ``degraded``
        otherwise; ``lost`` when the scans contradict the pose for several scans in a row
        or the pose is too uncertain to match from
    ─► Estimate(stamp, pose, covariance, status, ...)

While lost the reported pose is the dead-reckoned continuation of the last pose with a
growing covariance; the recovery strategy (:mod:`icploc.recovery`: local, then global with
:mod:`icploc.relocalize`) ranks hypotheses (``Estimate.hypotheses``) and the pose jumps
only to a lock the localizer itself verified. Nothing but the Localizer writes its pose.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.calibration import OdometryCalibration
from icploc.config import LocalizerConfig
from icploc.fitcheck import FitCheck, FitChecker, MapQuality
from icploc.fusion import (
    CHI2_3,
    axis_measurements,
    chi2_3_same_tail,
    fuse,
    heading_nis,
    mahalanobis2,
    scan_covariance,
)
from icploc.kidnap import CheckVerdict, KidnapTrigger
from icploc.median import median
from icploc.messages import Odometry, Scan
from icploc.motion import MotionModel, NoiseGain
from icploc.recovery import Candidate, LocalRecovery, Recovery, RecoveryStep, RecoveryView
from icploc.scanprep import _TrigCache, prepare_scan
from icploc.se2 import Pose, between, compose, wrap_angle
from icploc.status import Reason, Status

__all__ = [
    "Estimate",
    "Localizer",
    "OdometryBuffer",
    "Reason",
    "Recovery",
    "Status",
    "prepare_scan",
    "run",
]


#: a fit whose translational information's smallest eigenvalue is below this share of its
#: largest can slide along that direction (a corridor, an aisle)
_SLIDE_DEGENERACY = 0.1
#: a fit that does not verify is retried from the prediction turned by this many standard
#: deviations of its heading either way, at least by ``_HEADING_RETRY_MIN_DEG``
_HEADING_RETRY_SIGMAS = 2.0
_HEADING_RETRY_MIN_DEG = 3.0


@dataclass(frozen=True)
class Estimate:
    """The localizer's answer for one scan."""

    stamp: float
    pose: Pose  #: robot base pose (x, y, theta) in the map frame
    covariance: NDArray[np.float64]  #: 3x3 of (x, y, theta)
    status: Status
    inlier_ratio: float
    iterations: int
    time: float  #: seconds spent in :meth:`Localizer.update`
    accepted: bool = False  #: the ICP correction was fused in (possibly inflated)
    #: why the scan is not ``tracking`` or what happened ("" when tracking on a plain fit):
    #: too_few_points, icp_failed, low_inlier_ratio, not_converged, jump, inconsistent
    #: (chi-square rejected), inflated (chi-square: measurement inflated), odometry_off
    #: (chi-square failed but the map, or several scans agreeing, prefer the scan pose:
    #: the prediction's covariance inflated),
    #: contradicted (the fused pose explains far less of the scan than usual), unverified,
    #: uncertain (covariance too wide to promise the pose), disputed (the prediction an
    #: odometry_off fit overruled still explains the scans as well), unconstrained (a
    #: corridor fit right after a stretch not tracking), unsettled (a pose a fit took
    #: against the odometry, or the first after a stretch without a verified fit, not yet
    #: confirmed at the map's usual hit share), reverted (the rival an odometry_off fit
    #: overruled explained the scan clearly better: the pose went back to it),
    #: relocalized, lock_unverified (a recovery's
    #: lock the localizer's verification refused: degraded), suspect (a kidnap
    #: check is out, or found a better pose elsewhere to re-check: :mod:`icploc.kidnap`),
    #: unconfirmed (a lock whose strict check is out), elsewhere (the check found the
    #: better pose again: lost), refuted (a lock a distinct pose beats: still lost), lost
    #: (declared lost), or while lost the recovery's state (searching, confirming,
    #: ambiguous, locked)
    reason: str = Reason.NONE
    degeneracy: float = float("nan")  #: lambda_min / lambda_max of the fit (nan: no fit)
    prediction: Pose = (0.0, 0.0, 0.0)  #: the odometry prediction for this scan
    odometry: Pose | None = None  #: the (interpolated) odometry pose used
    num_points: int = 0  #: beams used for matching
    #: the scan match's pose and calibrated covariance (None: no usable fit)
    measurement: Pose | None = None
    measurement_covariance: NDArray[np.float64] | None = None
    #: chi-square statistic of prediction vs measurement, the gate's (the joint 3-dof one,
    #: or the heading's own at its tail if larger: ``gating.heading_test``; nan: no fit)
    nis: float = float("nan")
    #: verification of the reported pose: share of beams ending on walls, their RMS residual
    hit_ratio: float = float("nan")
    residual: float = float("nan")
    #: the learned odometry factors (distance scale, turn scale, heading drift rad/m)
    calibration: tuple[float, float, float] = (1.0, 1.0, 0.0)
    #: the learned sideways skew of the odometry (m sideways per m forward)
    calibration_skew: float = 0.0
    #: while lost: the recovery's ranked hypotheses (the pose itself stays dead-reckoned)
    hypotheses: tuple[Candidate, ...] = ()
    #: False: the scan was outside the mapped area, the pose coasted (:mod:`icploc.outside`)
    mapped: bool = True

    @property
    def x(self) -> float:
        return self.pose[0]

    @property
    def y(self) -> float:
        return self.pose[1]

    @property
    def theta(self) -> float:
        return self.pose[2]


class OdometryBuffer:
    """Odometry samples in time order; poses interpolated (SE(2), shortest heading) to any stamp.

    Headings are unwrapped on insertion, so a heading crossing ±π interpolates the short
    way. Beyond the newest sample the pose is extrapolated at the last velocity for at
    most ``max_extrapolation`` seconds, then held. Before the oldest sample: ``None``.
    """

    def __init__(self, maxlen: int = 4096, max_extrapolation: float = 0.25) -> None:
        self.maxlen = maxlen
        self.max_extrapolation = max_extrapolation
        self._t: list[float] = []
        self._x: list[float] = []
        self._y: list[float] = []
        self._th: list[float] = []  # unwrapped

    def __len__(self) -> int:
        return len(self._t)

    @property
    def first_stamp(self) -> float | None:
        return self._t[0] if self._t else None

    @property
    def last_stamp(self) -> float | None:
        return self._t[-1] if self._t else None

    def add(self, odom: Odometry | tuple[float, Sequence[float]]) -> None:
        pose: Sequence[float]
        if isinstance(odom, Odometry):
            stamp, pose = odom.stamp, odom.pose
        else:
            stamp, pose = odom
        stamp = float(stamp)
        x, y, th = float(pose[0]), float(pose[1]), float(pose[2])
        if not (
            math.isfinite(stamp) and math.isfinite(x) and math.isfinite(y) and math.isfinite(th)
        ):
            return  # a NaN odometry sample is dropped, never interpolated
        if self._t:
            if stamp < self._t[-1]:
                return  # out of order: dropped (logs with shuffled stamps)
            th = self._th[-1] + wrap_angle(th - self._th[-1])
            if stamp == self._t[-1]:
                self._x[-1], self._y[-1], self._th[-1] = x, y, th
                return
        self._t.append(stamp)
        self._x.append(x)
        self._y.append(y)
        self._th.append(th)
        if len(self._t) > self.maxlen:
            drop = len(self._t) - self.maxlen
            del self._t[:drop], self._x[:drop], self._y[:drop], self._th[:drop]

    def pose_at(self, stamp: float) -> Pose | None:
        t = self._t
        if not t or stamp < t[0]:
            return None
        i = bisect.bisect_right(t, stamp)
        if i == len(t):
            j = len(t) - 1
            if j == 0:
                return (self._x[0], self._y[0], wrap_angle(self._th[0]))
            dt = min(stamp - t[j], self.max_extrapolation)
            span = t[j] - t[j - 1]
            if dt <= 0.0 or span <= 0.0 or span > 4 * self.max_extrapolation:
                return (self._x[j], self._y[j], wrap_angle(self._th[j]))
            f = 1.0 + dt / span
            a, b = j - 1, j
        else:
            a, b = i - 1, i
            f = (stamp - t[a]) / (t[b] - t[a])
        return (
            self._x[a] + f * (self._x[b] - self._x[a]),
            self._y[a] + f * (self._y[b] - self._y[a]),
            wrap_angle(self._th[a] + f * (self._th[b] - self._th[a])),
        )


def _as_index(map_: Any, config: LocalizerConfig) -> Any:
    """A ``MapIndex`` from a Map (``.index(spacing)``), a MapIndex, or (N, 2) points."""
    from icploc._core import MapIndex

    if isinstance(map_, MapIndex):
        return map_
    if isinstance(map_, (str, os.PathLike)):
        from icploc.maps import Map

        map_ = Map.load(os.fspath(map_))
    if hasattr(map_, "index") and callable(map_.index):
        return map_.index(config.map.spacing)
    pts = np.asarray(map_, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise TypeError(
            "Localizer: map must be an icploc Map, a MapIndex or an (N, 2) array of points, "
            f"got {type(map_).__name__} {getattr(pts, 'shape', '')}"
        )
    return MapIndex(pts)


@dataclass
class _Rival:
    """The prediction a fit overruled (``odometry_off``), followed by odometry and its own
    scan fits while it still explains the scans (:meth:`Localizer._dispute`)."""

    pose: Pose
    covariance: NDArray[np.float64]
    misses: int = 0  #: scans in a row it did not verify or explained clearly less


@dataclass
class _Counters:
    scans: int = 0
    bad_in_row: int = 0
    point_to_point_fallbacks: int = 0
    heading_retries: int = 0
    status_counts: dict[str, int] = field(default_factory=lambda: {s.value: 0 for s in Status})


#: a sample spacing below this is no resolution (coincident map points: walls sampled twice)
_MIN_RESOLUTION = 0.005


def _map_resolution(map_: Any, index: Any, configured: float) -> float:
    """The map's resolution: configured, a grid's cell size, else its sample spacing (at
    least ``_MIN_RESOLUTION``: the median spacing of a map whose walls were sampled twice
    is zero, and the verification's raster would not fit in memory)."""
    if configured > 0.0:
        return configured
    res = getattr(map_, "resolution", None)
    if isinstance(res, (int, float)) and res > 0 and math.isfinite(res):
        return float(res)
    try:
        sp = float(index.spacing)
    except (AttributeError, ValueError):
        sp = 0.05
    return max(sp, _MIN_RESOLUTION) if sp > 0 and math.isfinite(sp) else 0.05


class Localizer:
    """ICP localization against a known map, odometry as prior and fallback.

    ``map`` is an ``icploc.Map`` (its ``index(config.map.spacing)`` is used), an
    ``icploc.MapIndex`` or an (N, 2) array of map points. ``initial_pose`` (or
    ``config.localizer.initial_pose``) is the robot's start pose in the map frame; without
    one the localizer starts ``lost`` and its recovery localizes globally. ``recovery``: the
    strategy used while lost (:class:`icploc.recovery.Recovery`); by default the one
    ``localizer.relocalization`` names (global: :class:`icploc.relocalize.GlobalRelocalization`;
    local: :class:`icploc.recovery.LocalRecovery`). It can be replaced later through the
    :attr:`recovery` attribute — the one way to plug recovery in.
    """

    def __init__(
        self,
        map: Any,
        config: LocalizerConfig | None = None,
        initial_pose: Sequence[float] | None = None,
        *,
        recovery: Recovery | None = None,
    ) -> None:
        self.config = (config or LocalizerConfig()).validate()
        self.index = _as_index(map, self.config)
        self.map = map
        # the core's verified start (a window search when a fit does not explain the scan) is
        # off in the localizer's ICPs: here the chi-square gate, the verification and the
        # recovery strategies decide what a doubtful fit means
        self.icp_config = self.config.icp.to_icp_config(window_search=False)
        lc = self.config.localizer
        if recovery is None:
            if lc.relocalization == "global":
                from icploc.relocalize import GlobalRelocalization

                recovery = GlobalRelocalization.deferred(config=self.config)
            else:
                recovery = LocalRecovery.from_config(self.config)
        #: the strategy used while lost (see :mod:`icploc.recovery`)
        self.recovery: Recovery = recovery
        # the residual may be learned up to half the ICP's final correspondence distance
        # floor (a 5 cm grid from another pass: walls 4-6 cm from the scan's); the usual hit
        # share only from fits with at least the verification's floor of beams on walls
        self.quality = MapQuality.from_config(
            _map_resolution(map, self.index, self.config.map.resolution), self.config
        )
        self.checker = FitChecker(self.index, self.quality, see_through=lc.verify_see_through)
        #: independent beams of a scan: the beams on one wall share its error (its shape,
        #: another pass's wall, the grid's quantisation), whatever the map's resolution
        self._independent_beams = lc.scan_independent_beams
        self.motion_model = MotionModel.from_config(lc)
        self.calibration = OdometryCalibration.from_config(lc)
        self.odometry = OdometryBuffer(max_extrapolation=min(0.25, lc.max_odometry_gap))
        self._trig = _TrigCache()
        self._counters = _Counters()
        self._last_odom: Pose | None = None
        self._lost_odom: Pose | None = None
        #: the calibration's anchor: (raw odometry, scan-matched pose) of a verified fit
        self._anchor: tuple[Pose, Pose] | None = None
        #: the last rejected scan pose: (pose, covariance, odometry then, agreeing in a row)
        self._rejected: tuple[Pose, NDArray[np.float64], Pose | None, int] | None = None
        #: the odometry noise learned online (icploc.motion.NoiseGain)
        self._noise = NoiseGain.from_config(lc)
        self._map_points: NDArray[np.float64] | None = None
        self._map_normals: NDArray[np.float64] | None = None
        self.last_estimate: Estimate | None = None
        self._icp_configs: dict[Any, Any] = {}
        g = self.config.gating
        self._chi2_accept = _chi2_3(g.chi2_accept)
        self._chi2_reject = _chi2_3(g.chi2_reject)
        self._lost_scans = 0
        #: weakly constrained fits held back in a row (``unconstrained``)
        self._held = 0
        #: after a fit taken against the odometry: verified scans still needed that explain
        #: the scan as well as this map's fits usually do (``unsettled``, :meth:`_settle`)
        self._unsettled = 0
        #: the last scan's fit was accepted beyond the accept quantile (``inflated``)
        self._inflated = False
        #: the last scan's fit was rejected and grew the prediction's covariance
        self._grown = False
        #: the growth the rejected fits since the last accepted one applied, multiplied
        #: (at most ``noise_gain_max``: the cap holds over scans, not per scan)
        self._growth = 1.0
        #: since the last fit that measured the position along every direction (at least
        #: ``tracking_min_axis_independent`` independent measurements along its weakest),
        #: an accepted fit measured one less (a corridor's length) ...
        self._loose = False
        #: ... or left it to the odometry (fewer than ``min_axis_independent``)
        self._unpinned = False
        #: the odometry's travel since then (m): the pose along that direction is
        #: dead-reckoned over it (:meth:`_drift`)
        self._coasted_m = 0.0
        #: the hit share an unsettled pose's fits must reach (the usual one before it)
        self._settle_hit = 0.0
        #: scans in a row without a verified fit
        self._untracked = 0
        #: the raw odometry increment of the current scan (None: none)
        self._step: Pose | None = None
        #: the prediction a fit overruled (``odometry_off``), followed alongside
        #: (:meth:`_dispute`)
        self._rival: _Rival | None = None
        #: while lost: consistent fits from the dead reckoning in a row (:meth:`_coast`)
        self._coast_streak = 0
        self._coast_inlier_ratio = 0.0
        #: the last coasting fit passed only as a weak one (:meth:`_coast_fit`)
        self._coast_weak = False
        #: kidnap detection while tracking (:mod:`icploc.kidnap`): the trigger, a check
        #: running on the worker thread (future, odometry then, strict), a better pose
        #: elsewhere awaiting its re-check (pose, odometry then, scan count), and whether
        #: the current pose is a lock whose strict check has not come back yet
        self._trigger = KidnapTrigger.from_config(self.config.kidnap)
        self._check_inflight: tuple[Any, Pose | None, bool] | None = None
        self._check_executor: Any = None
        self._elsewhere: tuple[Pose, Pose | None, int] | None = None
        self._lock_unconfirmed = False
        self._recover_unconfirmed = False
        #: the kidnap checks' verdicts so far (at most 100): "", "unsure", "suspect"
        #: (elsewhere, to be re-checked), "elsewhere" (declared lost), "refuted" (a lock)
        self.kidnap_verdicts: list[str] = []
        #: hook: called after every update with (scan, points, estimate), returns the
        #: estimate to report (:mod:`icploc.startrefine` while it refines the start)
        self.review: Callable[[Scan, NDArray[np.float64], Estimate], Estimate] | None = None
        #: the outside-the-map monitor (:func:`icploc.outside.attach`; attached below on a
        #: map with unknown space unless ``outside.enabled`` is false), None: off
        self.outside: Any = None
        pose = initial_pose if initial_pose is not None else lc.initial_pose
        self.pose: Pose
        self.covariance: NDArray[np.float64]
        self.status: Status
        if pose is not None:
            self.reset(pose)
        else:
            self.pose = (0.0, 0.0, 0.0)
            self.covariance = _unknown_covariance()
            self.status = Status.LOST
        if self.config.outside.enabled:  # icploc.outside: on a map with unknown space
            from icploc.outside import attach_default

            attach_default(self)

    # -- state -----------------------------------------------------------------------------
    def reset(
        self,
        pose: Sequence[float],
        covariance: NDArray[np.float64] | None = None,
        status: Status = Status.TRACKING,
    ) -> None:
        """Set the pose (the initial pose, or a pose the user knows)."""
        if len(pose) != 3 or not all(math.isfinite(float(v)) for v in pose):
            raise ValueError(f"Localizer.reset: pose must be three finite numbers, got {pose!r}")
        lc = self.config.localizer
        self.pose = (float(pose[0]), float(pose[1]), wrap_angle(float(pose[2])))
        if covariance is None:
            covariance = np.diag(
                [lc.initial_sigma_xy**2, lc.initial_sigma_xy**2, lc.initial_sigma_theta**2]
            )
        self.covariance = np.array(covariance, dtype=np.float64).reshape(3, 3)
        self.status = status
        c = self._counters
        c.bad_in_row = 0
        self._lost_scans = 0
        self._lost_odom = None
        self._coast_streak = 0
        self._anchor = None
        self._rejected = None
        self._rival = None
        self._unsettled = 0
        self._inflated = False
        self._grown = False
        self._growth = 1.0
        self._loose = False
        self._unpinned = False
        self._coasted_m = 0.0
        self._untracked = 0
        self._forget_checks()
        self.recovery.reset()
        if self.outside is not None:  # icploc.outside: a reset between scans ends a stretch
            self.outside.on_reset(self)

    def _forget_checks(self) -> None:
        self._trigger.reset()
        self._check_inflight = None  # a running check's verdict no longer applies
        self._elsewhere = None
        self._lock_unconfirmed = False
        self._recover_unconfirmed = False

    def declare_lost(self) -> None:
        """Switch to ``lost`` now (e.g. a kidnapping known from outside): the pose is
        dead-reckoned and the recovery runs from the next scan on."""
        self.status = Status.LOST
        self._lost_scans = 0
        self._lost_odom = None
        self._coast_streak = 0
        self._anchor = None
        self._rival = None
        self._unsettled = 0
        self._inflated = False
        self._grown = False
        self._growth = 1.0
        self._loose = False
        self._unpinned = False
        self._coasted_m = 0.0
        self._untracked = 0
        self._forget_checks()
        self.recovery.reset()
        if self.outside is not None:  # icploc.outside: a reset between scans ends a stretch
            self.outside.on_reset(self)

    @property
    def last_odometry(self) -> Pose | None:
        """The odometry pose at the last scan (None before the first with odometry)."""
        return self._last_odom

    def prepare(self, scan: Scan) -> NDArray[np.float64]:
        """``scan`` as this localizer uses it: (N, 2) points in the robot base frame."""
        return prepare_scan(scan, self.config, self._trig)

    @property
    def status_counts(self) -> dict[str, int]:
        return dict(self._counters.status_counts)

    @property
    def scans_processed(self) -> int:
        return self._counters.scans

    def add_odometry(self, odom: Odometry) -> None:
        """Feed an odometry sample (for :meth:`update` calls without explicit odometry)."""
        self.odometry.add(odom)

    # -- the loop --------------------------------------------------------------------------
    def update(self, scan: Scan, odometry: Odometry | Sequence[float] | None = None) -> Estimate:
        """Localize one scan. ``odometry`` is the odometry pose at the scan's stamp (an
        :class:`Odometry` or an (x, y, theta)); without it the pose is interpolated from the
        samples given to :meth:`add_odometry`; with neither the robot is assumed still."""
        t0 = time.perf_counter()
        odom = self._odometry_at(scan.stamp, odometry)
        pred, pred_cov = self._predict(odom)
        pts = prepare_scan(scan, self.config, self._trig)
        hook = self.outside  # icploc.outside: a scan outside the map is coasted there
        est = None if hook is None else hook.before(self, scan, pts, pred, pred_cov, odom, t0)
        if est is None and self.status is Status.LOST:
            est = self._update_lost(scan, pts, pred, pred_cov, odom, t0)
        elif est is None:
            est = self._update_tracking(scan, pts, pred, pred_cov, odom, t0)
        if hook is not None:
            est = hook.after(self, est, pts)
        if self.review is not None:  # hook: icploc.startrefine
            est = self.review(scan, pts, est)
        self._counters.scans += 1
        self._counters.status_counts[est.status.value] += 1
        self.last_estimate = est
        return est

    def _odometry_at(
        self, stamp: float, odometry: Odometry | Sequence[float] | None
    ) -> Pose | None:
        if odometry is None:
            return self.odometry.pose_at(stamp)
        if isinstance(odometry, Odometry):
            p = odometry.pose
        else:
            p = tuple(odometry)  # type: ignore[assignment]
        x, y, th = float(p[0]), float(p[1]), float(p[2])
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(th)):
            return None
        return (x, y, th)

    def _predict(self, odom: Pose | None) -> tuple[Pose, NDArray[np.float64]]:
        if odom is None or self._last_odom is None:
            if odom is not None:
                self._last_odom = odom
            self._step = None
            return self.motion_model.predict(self.pose, self.covariance, (0.0, 0.0, 0.0))
        raw = between(self._last_odom, odom)
        self._last_odom = odom
        self._step = raw
        return self._move(self.pose, self.covariance, raw)

    def _move(
        self, pose: Pose, cov: NDArray[np.float64], raw: Pose | None
    ) -> tuple[Pose, NDArray[np.float64]]:
        """``pose`` moved on by the raw odometry increment ``raw`` (calibrated), its
        covariance grown by the motion model (None: the robot stood still)."""
        if raw is None:
            return self.motion_model.predict(pose, cov, (0.0, 0.0, 0.0))
        d = self.calibration.apply(raw)
        model = self.motion_model
        gain = self.config.localizer.lost_noise_gain
        if self.status is Status.LOST and gain != 1.0:
            # nothing corroborates the dead reckoning: odometry that lost us is likely off
            # by more than its usual noise (a bias, a slip), and the local search window
            # grows with this covariance
            model = dataclasses.replace(model, gain=model.gain * gain)
        pred, P = model.predict(pose, cov, d)
        if self.config.localizer.calibration_uncertainty:
            v_al, v_th = self.calibration.uncertainty(raw)
            if v_al > 0.0 or v_th > 0.0:
                P = P.copy()
                P[0, 0] += v_al
                P[1, 1] += v_al
                P[2, 2] += v_th
        return pred, P

    def _match_index(self, pred: Pose) -> Any:
        mc = self.config.map
        if not mc.visibility_culling:
            return self.index
        from icploc._core import MapIndex

        if self._map_points is None:
            self._map_points = self.index.points
            self._map_normals = self.index.normals if self.index.has_normals else None
        sensor = compose(pred, self.config.scan.mounting)
        idx = self.index.visible(
            sensor, fov=math.radians(mc.visibility_fov_deg), max_range=mc.visibility_max_range
        )
        if idx.shape[0] < self.config.scan.min_points:
            return self.index
        normals = None if self._map_normals is None else self._map_normals[idx]
        return MapIndex(self._map_points[idx], normals)

    def _icp_config_for(
        self, pts: NDArray[np.float64], pred_cov: NDArray[np.float64] | None
    ) -> Any:
        """The ICP settings for this scan, from the map's quality and the prediction's
        uncertainty: the final correspondence distance is at least 3 expected residuals plus
        half a cell, the robust scale at least one expected residual (the configured values
        are floors: they suit exact maps); the first correspondence threshold opens to cover
        ``icp.correspondence_sigmas`` standard deviations of the prediction (position plus
        heading times the median range), up to ``icp.max_correspondence_cap``. Quantised so
        configs are reused."""
        ic = self.config.icp
        q = self.quality
        sig = q.sigma
        lo = max(ic.min_correspondence_distance, 3.0 * sig + 0.5 * q.resolution)
        robust = max(ic.robust_scale, sig)
        hi = max(ic.max_correspondence_distance, 2.0 * lo)
        if ic.adaptive_correspondence and pred_cov is not None:
            sxy = math.sqrt(max(float(pred_cov[0, 0] + pred_cov[1, 1]), 0.0))
            sth = math.sqrt(max(float(pred_cov[2, 2]), 0.0))
            if ic.correspondence_sigmas * (sxy + 30.0 * sth) > hi and pts.shape[0]:
                r = pts[:: max(1, pts.shape[0] // 16)]
                rng = median(np.hypot(r[:, 0], r[:, 1]).tolist())
                hi = max(hi, min(ic.max_correspondence_cap, ic.correspondence_sigmas * (sxy + rng * sth)))
        key = (round(lo, 2), round(robust, 2), round(math.ceil(hi / 0.1) * 0.1, 1))
        cfg = self._icp_configs.get(key)
        if cfg is None:
            cfg = ic.to_icp_config(
                min_correspondence_distance=key[0],
                robust_scale=key[1],
                max_correspondence_distance=max(key[2], key[0]),
                window_search=False,  # see __init__
            )
            self._icp_configs[key] = cfg
        return cfg

    def _run_icp(
        self,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64] | None = None,
        count: bool = True,
    ) -> Any:
        """ICP from ``pred``; ``count``: a point-to-point fallback counts in the counters
        (not for a retry, counted as such)."""
        from icploc._core import IcpError, icp

        cfg = self._icp_config_for(pts, pred_cov)
        index = self._match_index(pred)
        try:
            res = icp(pts, index, pred, cfg)
        except IcpError:
            return None
        if cfg.metric == "point_to_line" and not res.converged:
            # Point-to-line that does not settle is sliding or oscillating on ambiguous
            # geometry; the paper's point-to-point from the same prediction has the wider
            # basin. Keep whichever explains more of the scan.
            if count:
                self._counters.point_to_point_fallbacks += 1
            try:
                alt = icp(pts, index, pred, self._fallback_config(cfg))
            except IcpError:
                return res
            if alt.inlier_ratio > res.inlier_ratio:
                return alt
        return res

    def _heading_retry(
        self, pts: NDArray[np.float64], pred: Pose, pred_cov: NDArray[np.float64], res: Any
    ) -> Any:
        """A fit from ``pred`` that does not verify, retried from the prediction turned by
        ``heading_retry_sigmas`` of its heading uncertainty either way: after a turn, an
        odometry whose rotation scale is off leaves the prediction's heading out by a
        tenth of a radian, and point-to-line from there settles in a half-fitting minimum
        (half the usual beams on walls) whose heading error the fusion then takes into the
        pose, and the next steps' dead reckoning carries it metres off. The retry that
        verifies and explains clearly more of the scan (``arbitration_margin``) replaces
        the fit; the gates then judge it against the prediction as any fit."""
        lc = self.config.localizer
        k = _HEADING_RETRY_SIGMAS
        m = self._measurement(res)
        if m is None:
            return res
        z = m[0]
        base = self._check(pts, z, z, res)
        if self._verified(base):
            return res
        sth = math.sqrt(max(float(pred_cov[2, 2]), 0.0))
        d = max(k * sth, math.radians(_HEADING_RETRY_MIN_DEG))
        best, best_hit = res, -math.inf
        # the heading-turned seeds must explain clearly more than the fit; a step seed
        # (the odometry's step scaled, :meth:`_step_seeds`) only more, as it is bounded
        # near the prediction and its fit must verify where the prediction's did not
        seeds = [
            ((pred[0], pred[1], wrap_angle(pred[2] + sign * d)), lc.arbitration_margin)
            for sign in (-1.0, 1.0)
        ]
        seeds += [(p, lc.step_retry_margin) for p in self._step_seeds(pred)]
        for seed, margin in seeds:
            alt = self._run_icp(pts, seed, pred_cov, count=False)
            if alt is None:
                continue
            ma = self._measurement(alt)
            if ma is None:
                continue
            at = self._check(pts, ma[0], ma[0], alt)
            if self._verified(at) and at.hit >= max(best_hit, base.hit + margin):
                best, best_hit = alt, at.hit
        if best is not res:
            self._counters.heading_retries += 1
        return best

    def _step_seeds(self, pred: Pose) -> list[Pose]:
        """Retry seeds for a fit that does not verify: the last pose moved on by this
        scan's (calibrated) odometry step scaled by each of ``step_retry_scales``. Real
        odometry is now and then off by a large share of one step (a wheel slipping, a
        stop the encoders did not see: on intel and csail with the bad base single steps
        of 0.49 and 0.52 m where the robot moved 0.09 and 0.34 m), far beyond the motion
        model's sigma; from there the fit settles in a wrong minimum, while a seed at the
        pose the odometry's step scaled down (or up) lies within its basin. The travel is
        scaled, not the turn (a turn on the spot that the odometry also saw as 0.4 m of
        travel; the turn's own error is the heading retry's). Only seeds farther from the
        prediction than the ICP's final correspondence distance and at most
        ``step_retry_max_offset`` from it."""
        lc = self.config.localizer
        if self._step is None or not lc.step_retry_scales:
            return []
        step = self.calibration.apply(self._step)
        if abs(step[2]) < math.radians(lc.step_retry_min_turn_deg):
            return []
        q = self.quality
        far = max(self.config.icp.min_correspondence_distance, 3.0 * q.sigma + 0.5 * q.resolution)
        move = math.hypot(step[0], step[1])
        out: list[Pose] = []
        for f in lc.step_retry_scales:
            dev = abs(1.0 - f)
            if dev * move > lc.step_retry_max_offset or dev * move <= far:
                # too far: another place as often as the right one; too near: the fit's
                continue
            seed = compose(self.pose, (f * step[0], f * step[1], step[2]))
            out.append((seed[0], seed[1], wrap_angle(seed[2])))
        return out

    def _fallback_config(self, cfg: Any) -> Any:
        key = ("p2p", cfg.max_correspondence_distance, cfg.min_correspondence_distance)
        alt = self._icp_configs.get(key)
        if alt is None:
            from icploc._core import IcpConfig

            d = cfg.to_dict()
            d["metric"] = "point_to_point"
            alt = IcpConfig(**d)
            self._icp_configs[key] = alt
        return alt

    def _measurement(self, res: Any) -> tuple[Pose, NDArray[np.float64]] | None:
        """The scan match as a measurement: its pose and calibrated covariance."""
        ix, iy, ith = res.pose
        if not (math.isfinite(ix) and math.isfinite(iy) and math.isfinite(ith)):
            return None
        R = scan_covariance(
            res.information,
            int(res.inliers),
            float(res.mse),
            self.quality.sigma,
            self._independent_beams,
            self.config.localizer.min_axis_beams,
            self.config.localizer.covariance_min_axis_independent,
        )
        return (ix, iy, wrap_angle(ith)), R

    def _verified(self, check: FitCheck) -> bool:
        """The pose's evidence is as good as this map's verified fits usually are. Until the
        map's usual hit share is measured (five fits) the share is held to
        ``verify_unmeasured_hit_ratio``, for a tracking fit as for a recovery's lock: the
        assumed share of 1 would refuse every fit on a map from another pass (the first fits
        there were held to 0.8 x an assumed 1 and none verified), and the absolute floor
        alone let a wrong start pose half fitting the scan verify and then teach its own
        share as the usual one (the map's quality learns the share only from fits at that
        bar until it is measured, :meth:`MapQuality.observe_consistent`)."""
        lc = self.config.localizer
        q = self.quality
        bar = (
            lc.verify_hit_fraction * q.hit_reference
            if q.hit_measured
            else lc.verify_unmeasured_hit_ratio
        )
        return self._explains(check, bar)

    def _explains(self, check: FitCheck, bar: float) -> bool:
        """The fit's evidence clears ``bar`` for its share of beams on walls, and the clauses
        every verified or arbitrating fit shares: enough beams, the absolute floor
        (``verify_min_hit_ratio``), the usual residual and, when the checker looks through
        walls, the usual see-through share."""
        lc = self.config.localizer
        q = self.quality
        return (
            check.beams >= self.config.scan.min_points // 2
            and check.hit >= lc.verify_min_hit_ratio
            and check.hit >= bar
            and check.rms <= lc.verify_max_residual * q.sigma
            and (
                not self.checker.see_through
                or check.see_through
                <= q.see_through_reference + lc.verify_max_see_through
            )
        )

    def _outweighs(self, at_z: FitCheck, at_pred: FitCheck, jump: float) -> bool:
        """The map arbitrates for a fit that fails the chi-square test: the fit explains
        clearly more of the scan than the prediction (``arbitration_margin``), and either
        verifies, or lies at most ``arbitration_ratio_max_jump`` from the prediction
        (``jump``, m) and shows the verification's absolute floor of beams on walls at the
        usual residual and ``arbitration_hit_ratio`` times the prediction's share. In a place
        the map covers by half (another pass, clutter) right fits stay under the usual
        share while a prediction tens of centimetres off explains a fifth of the scan: on
        intel, aces and acapulco such fits (3-5 cm off, 0.46-0.56 of the beams on walls
        against the prediction's 0.17-0.23) were refused scan after scan, the dead
        reckoning ran 35-60 cm off and the pose was lost. Those fits moved the pose at most
        0.54 m; a fit that half explains a scan farther off is as often a wrong place the
        map also covers by half (freiburg-079 on its partial map: fits 1.0 and 1.2 m from
        the reference, 0.78 and 0.69 m from the prediction, turning it by 9 and 5 degrees,
        at 0.63 and 0.61 of the beams on walls against the prediction's 0.24 while the
        reference pose showed 0.27 and 0.62). The pose it takes is not promised
        (``odometry_off`` must settle, :meth:`_settle`)."""
        lc = self.config.localizer
        if at_z.hit < at_pred.hit + lc.arbitration_margin:
            return False
        if self._verified(at_z):
            return True
        ratio = lc.arbitration_hit_ratio
        return ratio > 0.0 and jump <= lc.arbitration_ratio_max_jump and self._explains(
            at_z, ratio * at_pred.hit + lc.arbitration_margin
        )

    def _contradiction_bar(self) -> float:
        """The hit share under which an accepted fit must show more (beats the prediction,
        or fits tightly) to be kept: ``lost_hit_fraction`` x the usual share of verified
        fits (:attr:`MapQuality.verified_hit_reference`). Not the share the verification's
        bar follows, which consistent fits that did not verify teach too (else it
        ratchets): right fits half hitting in a place the map covers poorly would lower
        this bar with it, and a wrong fit hitting less still would be fused (csail 5 cm,
        biased odometry: a fit 24 cm off at a hit share of 0.28)."""
        return self.config.localizer.lost_hit_fraction * self.quality.verified_hit_reference

    def _gate_statistic(
        self, pred: Pose, P: NDArray[np.float64], z: Pose, R: NDArray[np.float64]
    ) -> float:
        """The chi-square gate's statistic (3 dof): ``v' (P + R)^-1 v``, and with
        ``gating.heading_test`` at least the 3-dof value with the same tail as the
        heading's own statistic (1 dof, :func:`icploc.fusion.heading_nis`). A turn grows the
        position covariance (the turn's random walk, the learned gain); jointly tested, a
        heading innovation then passes that the heading variance alone refuses (csail
        10 cm, a fit 10.8 deg off in heading after a 44 deg turn at 4.1 sigma of the
        heading, joint d^2 20.6 under the reject quantile, taken as ``inflated``)."""
        nis = mahalanobis2(pred, P, z, R)
        if self.config.gating.heading_test:
            nis = max(nis, chi2_3_same_tail(heading_nis(pred, P, z, R)))
        return nis

    def _slid(self, res: Any, pred: Pose, z: Pose) -> bool:
        """The fit is weakly constrained along one direction (translational degeneracy
        below ``_SLIDE_DEGENERACY``) and moved the pose along it beyond the ICP's final
        correspondence distance."""
        if not float(res.degeneracy) < _SLIDE_DEGENERACY:
            return False
        q = self.quality
        far = max(self.config.icp.min_correspondence_distance, 3.0 * q.sigma + 0.5 * q.resolution)
        ux, uy = res.degenerate_direction
        return abs((z[0] - pred[0]) * ux + (z[1] - pred[1]) * uy) > far

    def _prediction_better(self, pts: NDArray[np.float64], pred: Pose, z: Pose) -> bool:
        """The prediction verifies and explains the scan better than the fit ``z``."""
        at_pred = self.checker.check(pts, pred)
        return self._verified(at_pred) and at_pred.hit > self.checker.check(pts, z).hit

    def _drift(self) -> float:
        """The sigma (m) of a pose dead-reckoned along a direction the fits left to the
        odometry since the last that measured it: the calibration's scale and skew sigma
        not yet learned (:meth:`OdometryCalibration.uncertainty`) times the travel since.
        The motion model adds that sigma step by step as if each step's error were its own;
        a scale error adds up with the travel, and along a corridor no scan shows it."""
        return math.sqrt(self.calibration.uncertainty((self._coasted_m, 0.0, 0.0))[0])

    def _confident(self, cov: NDArray[np.float64]) -> bool:
        """The covariance is tight enough to promise the pose (``tracking``)."""
        lc = self.config.localizer
        lmax = _largest_position_variance(cov)
        return (
            math.sqrt(max(lmax, 0.0)) <= lc.tracking_max_sigma
            and math.sqrt(max(float(cov[2, 2]), 0.0)) <= math.radians(lc.tracking_max_sigma_theta_deg)
        )

    def verify_pose(
        self, points: NDArray[np.float64], pose: Pose
    ) -> tuple[bool, Any, Pose]:
        """ICP from ``pose``, then the verification tracking uses: ``(ok, IcpResult | None,
        refined pose)``. What a recovery strategy calls before it may lock (see
        :class:`icploc.recovery.RecoveryView`); the localizer then decides how far to trust
        the lock (:meth:`_update_lost`)."""
        if points.shape[0] < self.config.scan.min_points:
            return False, None, pose
        res = self._run_icp(points, pose, None)
        if res is None or res.inlier_ratio < self.config.localizer.recover_inlier_ratio:
            return False, res, pose
        m = self._measurement(res)
        if m is None:
            return False, res, pose
        z, R = m
        return self._verified(self._check(points, z, z, res)), res, z

    def _update_tracking(
        self,
        scan: Scan,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64],
        odom: Pose | None,
        t0: float,
    ) -> Estimate:
        g = self.config.gating
        lc = self.config.localizer
        cnt = self._counters
        n = pts.shape[0]
        P0 = pred_cov  # the prediction's covariance before any arbitration inflates it
        res = self._run_icp(pts, pred, pred_cov) if n >= self.config.scan.min_points else None
        if res is not None:
            res = self._heading_retry(pts, pred, pred_cov, res)
        reason: str = Reason.NONE
        pose, cov = pred, pred_cov
        accepted = False
        inlier_ratio = 0.0
        iterations = 0
        degeneracy = float("nan")
        z: Pose | None = None
        R: NDArray[np.float64] | None = None
        nis = float("nan")
        supported = False  # a rejected fit, but the prediction explains the scan better
        grown = False  # a rejected fit grew the prediction's covariance
        #: the odometry noise to learn from this scan's fit (after the rival had its say:
        #: a scan that goes back to the rival teaches nothing from the fit it abandons)
        learn: tuple[Pose, NDArray[np.float64], Pose, NDArray[np.float64]] | None = None
        overruled = (pred, pred_cov)  # the prediction before any inflation
        if res is None:
            reason = Reason.TOO_FEW_POINTS if n < self.config.scan.min_points else Reason.ICP_FAILED
        else:
            inlier_ratio = float(res.inlier_ratio)
            iterations = int(res.iterations)
            degeneracy = float(res.degeneracy)
            m = self._measurement(res)
            if m is None:
                reason = Reason.ICP_FAILED
            elif inlier_ratio < g.min_inlier_ratio:
                reason = Reason.LOW_INLIER_RATIO
            elif g.require_convergence and not res.converged:
                reason = Reason.NOT_CONVERGED
            else:
                z, R = m
                jump = math.hypot(z[0] - pred[0], z[1] - pred[1])
                turn = abs(wrap_angle(z[2] - pred[2]))
                nis = self._gate_statistic(pred, pred_cov, z, R)
                if jump > g.max_translation_jump or turn > math.radians(g.max_rotation_jump_deg):
                    reason = Reason.JUMP
                elif nis <= self._chi2_accept and not (
                    self._slid(res, pred, z) and self._prediction_better(pts, pred, z)
                ):
                    accepted = True
                elif nis <= self._chi2_accept:
                    # a fit slid far along its weak axis and explains the scan less well
                    # than the prediction: a neighbouring minimum of repetitive structure
                    reason = Reason.INCONSISTENT
                    supported = True
                elif nis <= self._chi2_reject and not self._prediction_better(pts, pred, z):
                    accepted = True
                    reason = Reason.INFLATED
                    R = R * (nis / self._chi2_accept)
                elif nis <= self._chi2_reject:
                    # a doubtful fit (between the quantiles) that explains the scan less
                    # well than the prediction it started from, which verifies: the fit
                    # went astray (a neighbouring minimum of repetitive structure)
                    reason = Reason.INCONSISTENT
                    supported = True
                else:
                    # prediction and scan disagree: the map arbitrates. A scan pose that
                    # explains the scan clearly better than the prediction (and verifies,
                    # or explains several times as much, :meth:`_outweighs`) means the
                    # odometry was off, not the fit: the prediction's covariance
                    # is inflated instead. Otherwise the prediction stands.
                    at_z = self.checker.check(pts, z)
                    at_pred = self.checker.check(pts, pred)
                    if (
                        nis <= lc.arbitration_max_inflation * self._chi2_accept
                        and self._outweighs(at_z, at_pred, jump)
                    ):
                        accepted = True
                        reason = Reason.ODOMETRY_OFF
                        pred_cov = pred_cov * (nis / self._chi2_accept)
                    elif (
                        self._consistent_rejection(z, R, odom) >= lc.consistent_rejections
                        and self._verified(at_z)
                        and at_z.hit >= at_pred.hit
                    ):
                        # the scans keep agreeing with each other against the prediction
                        # (a robot pushed, a pose that drifted while standing still): the
                        # prediction is off
                        accepted = True
                        reason = Reason.ODOMETRY_OFF
                        pred_cov = pred_cov * (nis / self._chi2_accept)
                    else:
                        reason = Reason.INCONSISTENT
                        # the fit went astray from a prediction that explains the scan at
                        # least as well (ICP sliding along a weak axis, a neighbouring
                        # minimum of repetitive structure): no evidence against the pose
                        supported = self._verified(at_pred) and at_pred.hit >= at_z.hit
                        if self._verified(at_z) and at_z.hit >= at_pred.hit:
                            learn = (pred, P0, z, m[1])  # the map backs the fit
                        if (
                            lc.grow_on_rejected_fit
                            and not supported
                            and at_z.hit >= at_pred.hit + lc.arbitration_margin
                        ):
                            # the prediction stands, but the fit explains clearly more of the
                            # scan than it: the chi-square test failed on a prediction whose
                            # covariance is too tight (odometry off beyond its model: a turn
                            # on the spot, a slip), so it is grown until the fit is at the
                            # accept quantile and the next scan's fit can be weighed. Only by
                            # as much as the learned odometry noise may grow
                            # (``noise_gain_max``): a fit farther off than that is another
                            # place, not odometry off beyond its model. The cap holds over
                            # the rejected scans in a row: ``pred_cov`` already carries the
                            # growth of the earlier ones (the motion model's since only adds
                            # to it), so their factors multiply and the product is capped
                            grow = _growth_to_consistent(pred, pred_cov, z, R, self._chi2_accept)
                            if self._growth * grow <= lc.noise_gain_max:
                                cov = pred_cov * grow
                                grown = True
                                self._growth *= grow
                if accepted and self._grown and reason in (Reason.NONE, Reason.INFLATED) and self._apart(pred, z):
                    # the last scan's fit was rejected and grew the covariance: this fit,
                    # farther from the prediction than the map can tell apart, is taken
                    # against the odometry as much as one the map arbitrated
                    reason = Reason.ODOMETRY_OFF
                if (
                    accepted
                    and reason in (Reason.NONE, Reason.INFLATED)
                    and lc.unverified_worse_margin > 0.0
                ):
                    # a fit the chi-square test admits but the map does not back: it does
                    # not verify and explains clearly less of the scan than the prediction
                    # it started from. In a place the map covers by half, with odometry off
                    # by more than its model (csail 10 cm, bad base: a prediction 20 cm
                    # off at 0.45 of the beams on walls, the fit 31 cm off at 0.38), fusing
                    # it moves the pose away from what the scan shows and the next fits
                    # start from there: the prediction stands
                    at_z = self._check(pts, z, z, res)
                    if not self._verified(at_z):
                        at_pred = self.checker.check(pts, pred)
                        if at_z.hit < at_pred.hit - lc.unverified_worse_margin:
                            accepted = False
                            reason = Reason.INCONSISTENT
                            supported = self._verified(at_pred)
                            R = m[1]
                if accepted:
                    self._rejected = None
                    learn = (pred, P0, z, m[1])
                if accepted and R is not None:
                    pose, cov = fuse(pred, pred_cov, z, R)
        check = self._check(pts, pose, z, res)
        if accepted and check.hit < self._contradiction_bar():
            # the fused pose explains far less of the scan than poses here usually do: a
            # place the map barely covers, or a fit that found something else (a local
            # minimum, a crowd). Keep the correction only if it explains more of the scan
            # than the prediction did, or if the few beams that do end on walls fit as
            # tightly as usual: walls hidden by a crowd, not a wrong place (where chance
            # hits scatter over the hit distance). A loose fit to a few chance hits (its
            # own inliers under ``verify_min_hit_ratio``) is no evidence even when it
            # explains a little more than the prediction: fused, its covariance would
            # shrink the pose's for nothing, and on biased odometry in a place the map
            # barely covers the pose then slides off with a covariance that says all is
            # well.
            at_pred = self.checker.check(pts, pred)
            tight = check.rms <= lc.crowd_residual * self.quality.sigma
            weak = float(res.inlier_ratio) < lc.verify_min_hit_ratio if res is not None else True
            if not tight and (weak or check.hit <= at_pred.hit + 0.02):
                accepted = False
                reason = Reason.CONTRADICTED
                pose, cov = pred, pred_cov
                check = at_pred
        verified = accepted and self._verified(check)
        if accepted and not verified and not reason:
            reason = Reason.UNVERIFIED
        # a pose a fit took against the odometry is not promised until it has settled
        # (:meth:`_settle`); the map's quality and the calibration learn as usual (freezing
        # them locked a bad base into its bias and the verification into its first bar:
        # the calibration's bias is what makes the odometry disagree with the fits; only
        # the calibration pair across a jump is dropped)
        # a fit that measures the position along every direction (a full independent
        # measurement along its weakest) after fits that measured one less, and moved the
        # pose by more than the sigma a tracking pose promises, corrected a pose the weak
        # fits held: a jump along a weak axis (on a real corridor the next fits slid on
        # with it), not promised until it has settled
        axis = (
            axis_measurements(res.information, int(res.inliers), self._independent_beams)
            if accepted and res is not None
            else math.nan
        )
        strong = axis >= lc.tracking_min_axis_independent
        # ... or that came after a dead reckoning along it longer than the promise allows:
        # the fit finds the minimum next to the prediction, which along a corridor need not
        # be the place
        weak_jump = (
            strong
            and self._loose
            and max(math.hypot(pose[0] - pred[0], pose[1] - pred[1]), self._drift())
            > lc.tracking_max_sigma
        )
        self._settle(accepted, verified, reason, check, pred, pose, weak_jump)
        self._grown = grown
        if accepted:
            self._growth = 1.0  # the covariance is the fused one: no growth carried
        if strong:
            self._loose = self._unpinned = False
            self._coasted_m = 0.0
        else:
            if accepted:
                self._loose = True
                self._unpinned |= axis < lc.min_axis_independent
            if self._unpinned and self._step is not None:
                self._coasted_m += math.hypot(self._step[0], self._step[1])
        observed = reason  # the fit's own verdict (the map's quality learns by it below)
        # the scan contradicts the pose: no usable fit, a rejected one, or one that explains
        # the scan no better than the prediction while far fewer beams than usual end on
        # walls (people hide walls and unmapped places show none: a consistent, improving
        # fit there is weak evidence, not a contradiction)
        if accepted:
            cnt.bad_in_row = 0
        elif not supported:
            cnt.bad_in_row += 1
        confident = self._confident(cov)
        drift = self._drift()
        coasted = math.sqrt(_largest_position_variance(cov) + drift * drift) > lc.tracking_max_sigma
        # a fit accepted against the odometry (``odometry_off``: the map preferred the scan
        # over a prediction it contradicts beyond the chi-square gate) is the map's word
        # against the odometry's, not agreement: on repetitive structure (doubled walls, a
        # corridor's along axis) the neighbouring minimum also verifies. The correction is
        # kept, the promise is not: ``degraded`` until a scan agrees with its prediction.
        if verified and confident and not coasted and reason in (Reason.NONE, Reason.INFLATED):
            status = Status.TRACKING
        else:
            status = Status.DEGRADED
            if verified and not confident and not reason:
                reason = Reason.UNCERTAIN
            elif verified and coasted and not reason:
                reason = Reason.UNCONSTRAINED
        # a fit weakly constrained along one direction (a corridor) says little about the
        # pose along it: after a stretch not promised it does not make the pose a promise
        # until ``dispute_scans`` such fits in a row agreed with the predictions
        # (never while the fits since have left a direction to the odometry: the pose along
        # it is then the dead-reckoned one that was not promised)
        if (
            status is Status.TRACKING
            and self.status is not Status.TRACKING
            and (
                self._unpinned
                or (degeneracy < _SLIDE_DEGENERACY and self._held < lc.dispute_scans)
            )
        ):
            status, reason = Status.DEGRADED, Reason.UNCONSTRAINED
        self._held = self._held + 1 if reason == Reason.UNCONSTRAINED else 0
        # the prediction such a fit overruled is followed too: while it still explains the
        # scans (a neighbouring minimum verifies as well as the other), neither is promised
        # (before the map's quality, the calibration and the odometry noise learn from this
        # scan's fit: a scan that goes back to the rival abandons the fit, so it teaches none)
        back = None
        if self._rival is not None:
            status, reason, back = self._dispute(pts, pose, check, status, reason)
            if back is not None:
                # the rival explains the scan clearly better than the pose now: the jump
                # it overruled was a neighbouring minimum, the pose goes back to the rival
                pose, cov, check = back
                status, reason = Status.DEGRADED, Reason.REVERTED
                if not self._unsettled:
                    q = self.quality
                    self._settle_hit = q.hit_reference if q.hit_measured else 0.0
                self._unsettled = lc.settle_scans
                self._anchor = None  # no calibration pair spans the jump back
                self._growth = 1.0
        if back is None:
            if learn is not None:
                self._learn_noise(*learn)
            # the residual learned is the ICP's own (at the fit, over its inliers)
            fit_rms = _fit_rms(res)
            if verified:
                self.quality.observe(check, fit_rms)
                if z is not None and R is not None and odom is not None:
                    self._calibrate(odom, z, R, axis)
            elif accepted and observed in (Reason.NONE, Reason.UNVERIFIED):
                self.quality.observe_consistent(check, fit_rms)
                if (
                    lc.calibrate_from_consistent
                    and check.hit >= lc.verify_min_hit_ratio
                    and z is not None
                    and R is not None
                    and odom is not None
                ):
                    self._calibrate(odom, z, R, axis)
        if accepted and reason == Reason.ODOMETRY_OFF:
            # the latest prediction a fit overruled is the rival (an older one disputed a
            # pose the map has since left)
            self._rival = _Rival(*overruled)
        if status is Status.TRACKING and self._unsettled:
            status, reason = Status.DEGRADED, Reason.UNSETTLED
        # the fit contradicted the odometry (taken against a prediction it is beyond what
        # the arbitration accepts: several rejected scans agreed) and explains less of the
        # scan than usual: a place that half fits the old pose
        jumped = (
            accepted
            and reason == Reason.ODOMETRY_OFF
            and nis > lc.arbitration_max_inflation * self._chi2_accept
            and check.hit < self._trigger.doubt_jump * self.quality.hit_reference
        )
        tight = check.rms <= lc.crowd_residual * self.quality.sigma
        status, reason, elsewhere = self._kidnap_step(
            pts, pose, odom, check.hit, accepted, jumped, tight, status, reason
        )
        sig_xy = math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0))
        if elsewhere:
            # a distinct place explains the scans much better (checked twice): the pose
            # says nothing any more, the recovery searches the whole map at once
            status, reason = Status.LOST, Reason.ELSEWHERE
            self.declare_lost()
            cov = _unknown_covariance()
        elif (
            cnt.bad_in_row >= lc.lost_after_bad_scans
            or sig_xy > lc.lost_sigma_xy
        ):
            status = Status.LOST
            reason = reason or Reason.LOST
            self.declare_lost()
        self.pose = pose
        self.covariance = cov
        self.status = status
        return Estimate(
            stamp=scan.stamp,
            pose=pose,
            covariance=cov,
            status=status,
            inlier_ratio=inlier_ratio,
            iterations=iterations,
            time=time.perf_counter() - t0,
            accepted=accepted,
            reason=reason,
            degeneracy=degeneracy,
            prediction=pred,
            odometry=odom,
            num_points=n,
            measurement=z,
            measurement_covariance=R,
            nis=nis,
            hit_ratio=check.hit,
            residual=check.rms,
            calibration=self.calibration.factors,
            calibration_skew=self.calibration.skew,
        )

    def _settle(
        self,
        accepted: bool,
        verified: bool,
        reason: str,
        check: FitCheck,
        pred: Pose,
        pose: Pose,
        weak_jump: bool = False,
    ) -> None:
        """Count a pose taken against the odometry (``odometry_off``, or a fit beyond the
        accept quantile, ``inflated``, that moved it farther than the map can tell apart or
        came right after another such fit, or a ``weak_jump``: a fit that moved it along a
        direction the last fit left to the odometry), or the first verified fit after ``lost_after_bad_scans``
        scans without one, towards settling: ``settle_scans`` verified
        scans that explain the scan at least as well as this map's verified fits usually
        did before the pose was taken (the usual hit share then), not just as well as
        verification allows (a fraction of the share now), with no unverified scan
        between. Until then the pose is not promised (``unsettled``): the odometry, which
        contradicted it, weighs against it, and a neighbouring minimum that half explains
        the scans of a place the map barely covers verifies as readily (the prediction's
        place explains nothing there, so the map's arbitration and the rival lose to it;
        and the usual share the map learns from such fits sinks towards theirs)."""
        lc = self.config.localizer
        inflated = accepted and reason == Reason.INFLATED
        against = weak_jump or reason == Reason.ODOMETRY_OFF or (
            # beyond the accept quantile, and moved the pose farther than the map can tell
            # or the fit before was beyond it too (the fits pull the pose away from the
            # odometry scan after scan, each within the gate)
            inflated and (self._apart(pred, pose) or self._inflated)
        ) or (
            # a correction larger than a tracking pose promises: the pose was that far off
            # or now is (a turn on the spot the odometry got wrong by tens of centimetres,
            # whose fit the grown covariance admits, can land in a neighbouring minimum)
            lc.settle_correction > 0.0
            and math.hypot(pose[0] - pred[0], pose[1] - pred[1]) > lc.settle_correction
        )
        self._inflated = inflated
        q = self.quality
        if self._unsettled and not self._settle_hit and q.hit_measured:
            self._settle_hit = q.hit_reference  # the bar, once the map's share is known
        # back from a stretch without a verified fit (a place the map barely covers, where
        # the prediction drifts and fits follow it): the same holds for the first fit there
        returning = verified and self._untracked >= lc.lost_after_bad_scans and q.hit_measured
        self._untracked = 0 if verified else self._untracked + 1
        if (accepted and against) or returning:
            if not self._unsettled:
                # the bar: the usual share before the pose was taken (before the map's
                # share is measured, on the first scans, it is an assumed 1: then the
                # verification itself)
                self._settle_hit = q.hit_reference if q.hit_measured else 0.0
            self._unsettled = lc.settle_scans
            if reason == Reason.ODOMETRY_OFF:
                self._anchor = None  # no calibration pair spans the jump
            return
        if not self._unsettled:
            return
        if verified and check.hit >= self._settle_hit:
            self._unsettled -= 1
        elif not verified:
            self._unsettled = lc.settle_scans

    def _dispute(
        self,
        pts: NDArray[np.float64],
        pose: Pose,
        check: FitCheck,
        status: Status,
        reason: str,
    ) -> tuple[Status, str, tuple[Pose, NDArray[np.float64], FitCheck] | None]:
        """Follow the rival one scan: the prediction an ``odometry_off`` fit overruled,
        dead-reckoned (fits near it would follow the map's neighbouring minimum as readily
        as the pose did). Its evidence is the share of beams ending on walls at it, or at a
        verified fit from it that did not slide to the pose. While the pose does not explain
        clearly more of the scan (by ``arbitration_margin``) the pose is not promised
        (``disputed``). The rival is dropped once the pose is back where it is (closer than
        the map's hit distance: the map cannot tell them apart), once the pose explained
        clearly more on ``dispute_scans`` scans in a row (the map has decided), or once it
        is as uncertain as a lost pose. Not by the chi-square gate: a dead-reckoned pose's
        covariance soon covers the neighbouring minimum the pose jumped to (and the pose's
        own is so tight that a fit a few centimetres off would count as distinct).

        The third item is where the pose goes back to (pose, covariance, its check), or None:
        the rival's own fit verifies, is consistent with the rival's dead reckoning and
        explains clearly more of the scan (``arbitration_margin``) than the pose — the same
        test by which the jump was taken, now against it (after a jump to a neighbouring
        minimum the pose's fits soon explain little while the rival's explain the scan)."""
        rv = self._rival
        assert rv is not None
        lc = self.config.localizer
        g = self.config.gating
        rp, rP = self._move(rv.pose, rv.covariance, self._step)
        rv.pose, rv.covariance = rp, rP
        vague = math.sqrt(max(float(rP[0, 0] + rP[1, 1]), 0.0)) > lc.lost_sigma_xy
        if vague or not self._apart(pose, rp):
            self._rival = None
            return status, reason, None
        if pts.shape[0] >= self.config.scan.min_points:
            hit = self.checker.check(pts, rp).hit
            res = self._run_icp(pts, rp, rP)
            m = None
            if res is not None and float(res.inlier_ratio) >= g.min_inlier_ratio:
                m = self._measurement(res)
            if m is not None and self._apart(pose, m[0]):
                at = self._check(pts, m[0], m[0], res)
                if self._verified(at):
                    hit = max(hit, at.hit)
                    if (
                        at.hit >= check.hit + lc.arbitration_margin
                        and mahalanobis2(rp, rP, m[0], m[1]) <= self._chi2_reject
                    ):
                        self._rival = None
                        bp, bP = fuse(rp, rP, m[0], m[1])
                        return status, reason, (bp, bP, self._check(pts, bp, m[0], res))
            if check.hit >= hit + lc.arbitration_margin:
                rv.misses += 1
                if rv.misses >= lc.dispute_scans:
                    self._rival = None
                    return status, reason, None
            else:
                rv.misses = 0  # the map cannot tell the two apart
        if status is Status.TRACKING:
            status, reason = Status.DEGRADED, Reason.DISPUTED
        return status, reason, None

    def _apart(self, a: Pose, b: Pose) -> bool:
        """Two poses the map can tell apart: farther than its hit distance, or turned by
        more than the heading a tracking pose promises."""
        lc = self.config.localizer
        return math.hypot(a[0] - b[0], a[1] - b[1]) > self.quality.hit_distance() or abs(
            wrap_angle(a[2] - b[2])
        ) > math.radians(lc.tracking_max_sigma_theta_deg)

    # -- kidnap detection (icploc.kidnap) --------------------------------------------------
    def _run_check(
        self, pts: NDArray[np.float64], pose: Pose, odom: Pose | None, strict: bool
    ) -> CheckVerdict | None:
        """Run the recovery's global check of ``pose``: inline (the verdict), or on the
        worker thread with ``localizer.lost_check: background`` (None; collected by
        :meth:`_collect_check` on a later scan)."""
        fn = getattr(self.recovery, "check_pose", None)
        if fn is None:
            return None
        if self.config.localizer.lost_check != "background":
            try:
                v: CheckVerdict = fn(self.index, pts, pose, strict)
            except Exception:  # noqa: BLE001 - a failed check is no evidence
                return CheckVerdict("unsure")
            return v
        if self._check_executor is None:
            from concurrent.futures import ThreadPoolExecutor

            self._check_executor = ThreadPoolExecutor(1, thread_name_prefix="icploc-kidnap")
        fut = self._check_executor.submit(fn, self.index, np.array(pts), pose, strict)
        self._check_inflight = (fut, odom, strict)
        return None

    def _collect_check(self, odom: Pose | None) -> tuple[CheckVerdict, bool] | None:
        """A finished background check: (its verdict, its pose carried to now by
        odometry; strict)."""
        inflight = self._check_inflight
        if inflight is None or not inflight[0].done():
            return None
        fut, odom_then, strict = inflight
        self._check_inflight = None
        try:
            v: CheckVerdict = fut.result()
        except Exception:  # noqa: BLE001 - a failed check is no evidence
            return CheckVerdict("unsure"), strict
        if v.pose is not None and odom_then is not None and odom is not None:
            v = dataclasses.replace(
                v, pose=compose(v.pose, self.calibration.apply(between(odom_then, odom)))
            )
        return v, strict

    def _kidnap_step(
        self,
        pts: NDArray[np.float64],
        pose: Pose,
        odom: Pose | None,
        hit: float,
        accepted: bool,
        jumped: bool,
        tight: bool,
        status: Status,
        reason: str,
    ) -> tuple[Status, str, bool]:
        """Feed the kidnap trigger, run or collect a global check, act on its verdict.
        Returns (status, reason, elsewhere: declare lost)."""
        fired = self._trigger.observe(hit if hit == hit else 0.0, accepted, jumped, tight)
        pending = self._elsewhere
        if not (fired or pending or self._check_inflight or self._lock_unconfirmed):
            return status, reason, False  # the usual scan: nothing out, nothing to ask
        if getattr(self.recovery, "check_pose", None) is None:
            return status, reason, False
        got = self._collect_check(odom)
        due = (
            pending is not None
            and self._counters.scans - pending[2] >= self._trigger.recheck_scans
        )
        if got is None and self._check_inflight is None and (fired or due):
            v = self._run_check(pts, pose, odom, False)
            got = None if v is None else (v, False)
        elsewhere = False
        if got is not None:
            v, strict = got
            if strict:
                self._lock_unconfirmed = False
                recovering = self._recover_unconfirmed
                self._recover_unconfirmed = False
                if v.verdict == "elsewhere" or (recovering and not self._clear(v)):
                    # a coasting recovery's check must come back clear ("unsure" is not)
                    self._note("refuted")
                    elsewhere = True
                else:
                    self._trigger.confirmed()
            else:
                elsewhere = self._apply_verdict(v, odom)
        if status is Status.TRACKING and not elsewhere:
            # not promised while a check is out or a better pose elsewhere awaits its
            # re-check
            if self._lock_unconfirmed:
                status, reason = Status.DEGRADED, Reason.UNCONFIRMED
            elif self._elsewhere is not None or self._check_inflight is not None:
                status, reason = Status.DEGRADED, Reason.SUSPECT
        return status, reason, elsewhere

    def _apply_verdict(self, v: CheckVerdict, odom: Pose | None) -> bool:
        """A tracking check's verdict; True: lost (a better pose elsewhere, found again
        ``recheck_scans`` later where odometry carried it: a crowd's chance fits do not
        stay put)."""
        pending = self._elsewhere
        if v.verdict == "elsewhere" and v.pose is not None:
            if pending is not None:
                then, odom_then, _ = pending
                moved = (
                    then
                    if odom_then is None or odom is None
                    else compose(then, self.calibration.apply(between(odom_then, odom)))
                )
                t = self._trigger
                if (
                    math.hypot(moved[0] - v.pose[0], moved[1] - v.pose[1]) <= t.recheck_distance
                    and abs(wrap_angle(moved[2] - v.pose[2])) <= t.recheck_angle
                ):
                    self._note("elsewhere")
                    return True
            self._elsewhere = (v.pose, odom, self._counters.scans)
            self._note("suspect")
            return False
        self._elsewhere = None
        self._note(v.verdict)
        if v.verdict == "":
            self._trigger.confirmed()
        else:
            self._trigger.backoff()
        return False

    def _note(self, verdict: str) -> None:
        self.kidnap_verdicts.append(verdict)
        if len(self.kidnap_verdicts) > 100:
            del self.kidnap_verdicts[:-100]

    def _check(
        self, pts: NDArray[np.float64], pose: Pose, z: Pose | None, res: Any
    ) -> FitCheck:
        """The verification evidence at ``pose``: the ICP's own (its inliers within the
        final correspondence distance, its point-to-line residual) when ``pose`` is within
        half a cell and half a degree of the fit, else checked afresh."""
        if pts.shape[0] == 0:
            return FitCheck(0.0, 0.0, math.inf, 0)
        if (
            z is not None
            and res is not None
            and math.hypot(pose[0] - z[0], pose[1] - z[1]) <= 0.5 * self.quality.resolution
            and abs(wrap_angle(pose[2] - z[2])) <= 0.0087
            and not self.checker.see_through
        ):
            mse = float(res.mse)
            return FitCheck(
                float(res.inlier_ratio),
                0.0,
                math.sqrt(mse) if math.isfinite(mse) and res.inliers else math.inf,
                int(res.num_points),
            )
        return self.checker.check(pts, pose)

    def _learn_noise(
        self, pred: Pose, P: NDArray[np.float64], z: Pose, R: NDArray[np.float64]
    ) -> None:
        """Online odometry noise (:class:`icploc.motion.NoiseGain`) from a scan pose the
        map backs: the motion model's alphas scale to make the prediction consistent with
        such fits (never below the configured ones, at most ``noise_gain_max``)."""
        if not self.config.localizer.learn_noise:
            return
        self._noise.observe(pred, P, z, R, self.motion_model.gain)
        gain = self._noise.gain
        if abs(gain - self.motion_model.gain) > 0.05 * self.motion_model.gain:
            self.motion_model = dataclasses.replace(self.motion_model, gain=gain)

    def _consistent_rejection(
        self, z: Pose, R: NDArray[np.float64], odom: Pose | None
    ) -> int:
        """Count the rejected scan poses in a row that agree with each other (the previous
        one moved on by odometry, within both covariances)."""
        prev = self._rejected
        count = 1
        if prev is not None:
            zp, Rp, op, k = prev
            moved = zp if op is None or odom is None else compose(zp, between(op, odom))
            if mahalanobis2(moved, Rp, z, R) <= self._chi2_accept:
                count = k + 1
        self._rejected = (z, R, odom, count)
        return count

    def _calibrate(self, odom: Pose, z: Pose, R: NDArray[np.float64], axis: float) -> None:
        """Feed the odometry calibration with the motion between two verified, well
        constrained scan matches at least ``calibration_baseline`` apart. ``axis``: the
        independent measurements the fit gives along its weakest direction
        (:func:`~icploc.fusion.axis_measurements`)."""
        lc = self.config.localizer
        if not self.calibration.enabled:
            return
        if not axis >= lc.tracking_min_axis_independent:
            # a fit that measures the position along every direction less than fully
            # (``tracking_min_axis_independent``: a corridor's length, held by a door frame
            # or two) is no evidence of the motion along it, whatever its covariance
            # claims: it stays at its prediction (the calibration's own scale, read back)
            # or slides to a neighbouring door. On infinite-corridor 5 cm bad
            # (odometry ~2 % short) such fits slid back and taught a 1.6 % short scale,
            # the dead reckoning then fell 3 m behind along the corridor (at
            # min_axis_independent's 0.5 the bar let a scale 1 % long through there, and a
            # pose 0.55 m ahead was promised). Neither an anchor nor an end: the pair spans
            # it from the last fit that pinned the position.
            return
        a, b, c = float(R[0, 0]), float(R[0, 1]), float(R[1, 1])
        lmax = 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))
        if lmax > lc.calibration_max_sigma**2:
            return  # a corridor: its along-track position is no evidence
        if self._anchor is None:
            self._anchor = (odom, z)
            return
        o0, z0 = self._anchor
        d_odo = between(o0, odom)
        turned = abs(d_odo[2]) >= self.calibration.min_turn
        if math.hypot(d_odo[0], d_odo[1]) < lc.calibration_baseline and not turned:
            return
        self.calibration.observe(d_odo, between(z0, z))
        self._anchor = (odom, z)

    # -- lost / recovery -------------------------------------------------------------------
    def _update_lost(
        self,
        scan: Scan,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64],
        odom: Pose | None,
        t0: float,
    ) -> Estimate:
        self._lost_scans += 1
        motion = None
        if odom is not None and self._lost_odom is not None:
            motion = self.calibration.apply(between(self._lost_odom, odom))
        self._lost_odom = odom
        step = RecoveryStep("searching")
        view = None
        if pts.shape[0] >= self.config.scan.min_points:
            view = RecoveryView(
                pose=pred,
                covariance=pred_cov,
                motion=motion,
                stamp=float(scan.stamp),
                scans_processed=self._counters.scans,
                lost_scans=self._lost_scans,
                index=self.index,
                icp_config=self._icp_config_for(pts, None),
                config=self.config,
                verify=self.verify_pose,
                hit_reference=self.quality.hit_reference,
            )
            step = self.recovery.recover(view, pts)
        res = step.result
        m = self._measurement(res) if step.lock is not None and res is not None else None
        lock_pose: Pose | None = None
        agrees = False
        if m is not None and step.lock is not None:
            R = m[1]
            nis = mahalanobis2(pred, pred_cov, step.lock, R)
            if nis <= self._chi2_reject:
                # a lock where the dead reckoning says we are: one information update (in a
                # corridor the lock says nothing along it, the dead reckoning keeps that)
                lock_pose, R = fuse(pred, pred_cov, step.lock, R)
                agrees = True
            elif self._confident(R):
                lock_pose = step.lock  # elsewhere, and the scan pins it down: jump there
        refuted = False
        strict_pending = False
        unsure_lock = False
        if lock_pose is not None and res is not None:
            # a stricter check of the lock: no distinct pose anywhere explains the scan
            # clearly better (inline on this scan, or on the worker thread: then the
            # pose is not promised until the verdict is back). Locks are rare; a wrong
            # local one after a kidnapping is not (the dead reckoning led there). Not
            # again for a verified lock that the dead reckoning agrees with, where that
            # dead reckoning says something, and that came after a recent whole-map search
            # of this episode (the tracker's rivals: a kidnapping's true place among them;
            # ~0.3-0.7 s a lock on the 5 cm grids). "Says something": the recovery's own
            # window test (its search window is not the whole map); for a recovery without
            # one, the covariance is not the unknown one (a pose refuted or never given)
            win = getattr(self.recovery, "window", None)
            if win is not None and view is not None:
                meant = win(view) is not None
            else:
                meant = float(pred_cov[0, 0] + pred_cov[1, 1]) < 1e-3 * _UNKNOWN_VAR_XY
            skip = agrees and meant and step.verified and step.rivals_searched
            v = None if skip else self._run_check(pts, lock_pose, odom, True)
            strict_pending = not skip and v is None and self._check_inflight is not None
            if v is not None and v.verdict == "elsewhere":
                self._note("refuted")
                refuted = True
                lock_pose = None
            elif v is not None and not self._clear(v):
                # a distinct pose fits as well (a periodic building's next office): the
                # lock is not told from it, no jump and no promise; still lost
                lock_pose = None
            elif v is not None and not self._clear(v, unsure_ok=False):
                # "unsure", the best distinct pose trailing by the lock margin: the jump,
                # but no promise until settle_scans verified scans (as an unverified lock)
                unsure_lock = True
        if lock_pose is not None and res is not None:
            inflight = self._check_inflight
            self.reset(lock_pose, R, Status.TRACKING)
            if strict_pending:
                self._check_inflight = inflight
                self._lock_unconfirmed = True
            status = Status.TRACKING if self._confident(R) else Status.DEGRADED
            if self._lock_unconfirmed or not step.verified or unsure_lock:  # hook (lost2)
                status = Status.DEGRADED
            if not step.verified or unsure_lock:
                # a lock the verification refused: not tracking until settle_scans verified
                # scans explain the scan as well as the map's usual share (as after a jump)
                q = self.quality
                self._unsettled = self.config.localizer.settle_scans
                self._settle_hit = q.hit_reference if q.hit_measured else 0.0
            self.status = status
            return Estimate(
                stamp=scan.stamp,
                pose=self.pose,
                covariance=self.covariance,
                status=status,
                inlier_ratio=float(res.inlier_ratio),
                iterations=int(res.iterations),
                time=time.perf_counter() - t0,
                accepted=True,
                reason=Reason.RELOCALIZED
                if step.verified and not unsure_lock
                else Reason.LOCK_UNVERIFIED,
                degeneracy=float(res.degeneracy),
                prediction=pred,
                odometry=odom,
                num_points=pts.shape[0],
                measurement=step.lock,
                measurement_covariance=R,
                calibration=self.calibration.factors,
                calibration_skew=self.calibration.skew,
                hypotheses=step.hypotheses,
            )
        # no lock: the dead-reckoned continuation of the last pose, its covariance growing
        if refuted:
            # a lock a distinct place beats: the dead reckoning that led there means
            # nothing, search the whole map
            pred_cov = _unknown_covariance()
            self.recovery.reset()
        elif self.config.localizer.lost_coasting:
            pred, pred_cov, fused = self._coast(pts, pred, pred_cov)
            # a weak coasting fit (under the usual share, taken for its tight hits) corrects
            # the dead reckoning but is no step on the way back to tracking: a wing the map
            # does not hold half fits it too (tests/partial_world.py's sudden exit: weak
            # fits in a row led back to tracking 0.5-0.9 m off)
            self._coast_streak = self._coast_streak + 1 if fused and not self._coast_weak else 0
            if fused and self._coast_streak >= self.config.localizer.recover_after:
                # consistent, well-hitting fits from the dead reckoning on several scans
                # in a row: the local search around it has found the way back. Checked
                # like any lock (no distinct pose anywhere clearly better), then the
                # localizer tracks again from there, ``degraded`` until it verifies.
                # Only a clear verdict confirms: "unsure" (the check's search found no
                # pose it could rank) is no evidence the dead reckoning led to the right
                # one of several alike places (a periodic building: the next office)
                v = self._run_check(pts, pred, odom, True)
                if v is not None and not self._clear(v):
                    if v.verdict == "elsewhere":
                        self._note("refuted")
                    self._coast_streak = 0
                else:
                    inflight = self._check_inflight
                    pending = v is None and inflight is not None
                    self.reset(pred, pred_cov, Status.DEGRADED)
                    if pending:
                        self._check_inflight = inflight
                        self._lock_unconfirmed = True
                        self._recover_unconfirmed = True
                    return Estimate(
                        stamp=scan.stamp,
                        pose=self.pose,
                        covariance=self.covariance,
                        status=Status.DEGRADED,
                        inlier_ratio=self._coast_inlier_ratio,
                        iterations=0,
                        time=time.perf_counter() - t0,
                        accepted=True,
                        reason=Reason.RELOCALIZED,
                        prediction=pred,
                        odometry=odom,
                        num_points=pts.shape[0],
                        calibration=self.calibration.factors,
                        calibration_skew=self.calibration.skew,
                        hypotheses=step.hypotheses,
                    )
        self.pose = pred
        self.covariance = pred_cov
        best = step.hypotheses[0] if step.hypotheses else None
        return Estimate(
            stamp=scan.stamp,
            pose=pred,
            covariance=pred_cov,
            status=Status.LOST,
            inlier_ratio=best.inlier_ratio if best is not None else 0.0,
            iterations=0,
            time=time.perf_counter() - t0,
            accepted=False,
            reason=Reason.REFUTED if refuted else (step.state or Reason.LOST),
            prediction=pred,
            odometry=odom,
            num_points=pts.shape[0],
            calibration=self.calibration.factors,
            calibration_skew=self.calibration.skew,
            hypotheses=step.hypotheses,
        )

    def _coast(
        self, pts: NDArray[np.float64], pred: Pose, pred_cov: NDArray[np.float64]
    ) -> tuple[Pose, NDArray[np.float64], bool]:
        """While lost and not locked: the dead reckoning corrected by a scan fit from it
        that is consistent with it (chi-square within the reject quantile, within the jump
        caps) and explains the scan at least as well as the dead-reckoned pose. Biased
        odometry then does not carry the pose off while the verification is still unsure
        (a place the map barely covers); the status stays ``lost`` and the pose jumps only to
        a verified lock (or, after ``recover_after`` such fits in a row, to tracking, see
        :meth:`_update_lost`). A pose that means nothing (unknown covariance) is not corrected:
        coasting stops once the position's sigma passes ``localizer.coast_sigma_xy``, and a
        fit may move the pose by ``coast_jump_sigmas`` of that sigma (at least the jump cap)."""
        lc = self.config.localizer
        sig = math.sqrt(max(float(pred_cov[0, 0] + pred_cov[1, 1]), 0.0))
        if pts.shape[0] < self.config.scan.min_points or not sig <= lc.coast_sigma_xy:
            return pred, pred_cov, False
        # the dead reckoning's own evidence: every seed's fit is judged against it
        at_pred = self.checker.check(pts, pred)
        got = self._coast_fit(pts, pred, pred_cov, pred, sig, at_pred)
        if (got is None or got[5]) and lc.coast_heading_seeds:
            # the dead reckoning's heading is what carries it off while lost (odometry off
            # in a turn: freiburg-campus 10 cm bad, 0.13-0.18 rad, the pose ran 4.5 m off
            # over 20 scans; orebro 5 cm, 0.15-0.22 rad, 1.4-3 m), and from a heading that
            # far off the fit finds too few beams on walls: fits from the dead reckoning
            # turned by multiples of its heading sigma, judged against the dead reckoning
            # as the fit from it is; the one explaining most of the scan
            sth = math.sqrt(max(float(pred_cov[2, 2]), 0.0))
            d = max(_HEADING_RETRY_SIGMAS * sth, math.radians(_HEADING_RETRY_MIN_DEG))
            # (also when the fit from the dead reckoning passed only as a weak one, under
            # the usual share: the minimum next to a wrong dead reckoning can half explain
            # the scan while a turned seed finds the place explaining most of it)
            best = got
            off_map = self.outside is not None and getattr(self.outside, "state", "inside") != "inside"
            for k in range(1, lc.coast_heading_seeds + 1):
                for sign in (-1.0, 1.0):
                    seed = (pred[0], pred[1], wrap_angle(pred[2] + sign * k * d))
                    alt = self._coast_fit(pts, pred, pred_cov, seed, sig, at_pred)
                    # while a stretch outside the map is open (icploc.outside: coasted or
                    # re-entering) a turned seed must pass on the usual share: a weak fit
                    # from a turned heading took a wrong place there (freiburg-079's partial
                    # map: its one stretch never re-locked, revisits 100 -> 87 %)
                    if alt is not None and alt[5] and off_map:
                        continue
                    if alt is not None and (best is None or alt[2].hit > best[2].hit):
                        best = alt
            got = best
        if got is None:
            return pred, pred_cov, False
        pose, cov, at_z, inlier_ratio, z, weak = got
        if math.hypot(z[0] - pred[0], z[1] - pred[1]) > self.config.gating.max_translation_jump and not (
            self._verified(at_z) and self._strict_clear(pts, z)
        ):
            # past the tracking jump cap the reported pose moves only to a fit that
            # verifies and that no distinct pose anywhere rivals (a strict check, inline
            # only: with background checks such a move waits for a recovery's lock)
            return pred, pred_cov, False
        self._coast_inlier_ratio = inlier_ratio
        self._coast_weak = weak
        return pose, cov, True

    def _coast_fit(
        self,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64],
        seed: Pose,
        sig: float,
        at_pred: FitCheck,
    ) -> tuple[Pose, NDArray[np.float64], FitCheck, float, Pose, bool] | None:
        """One coasting fit from ``seed`` judged against the dead reckoning ``pred``
        (:meth:`_coast`; ``at_pred``: its evidence at ``pred``): the fused pose, its covariance, the fit's evidence, its inlier
        ratio, the fit's pose and whether it passed only as a weak fit (under the usual
        share, taken for its tight hits); None when it is not consistent with the dead reckoning
        or explains the scan less well than it (the strict check a move past the jump cap
        needs is the caller's, once for the fit it takes)."""
        lc = self.config.localizer
        g = self.config.gating
        res = self._run_icp(pts, seed, pred_cov)
        if res is None or res.inlier_ratio < min(lc.recover_inlier_ratio, lc.coast_min_hit_ratio):
            return None
        m = self._measurement(res)
        if m is None:
            return None
        z, R = m
        # the dead reckoning's own uncertainty bounds the correction (bad odometry over a
        # long stretch the map barely shows: freiburg-campus 5 cm, a fit 1.7 m from a dead
        # reckoning 1.7 m off was refused by the tracking jump cap and the pose ran 6.7 m off)
        cap = max(g.max_translation_jump, lc.coast_jump_sigmas * sig)
        jump = math.hypot(z[0] - pred[0], z[1] - pred[1])
        if jump > cap or abs(
            wrap_angle(z[2] - pred[2])
        ) > math.radians(g.max_rotation_jump_deg):
            return None
        nis = mahalanobis2(pred, pred_cov, z, R)
        if nis > self._chi2_reject:
            return None
        at_z = self.checker.check(pts, z)
        if at_z.hit < lc.coast_min_hit_ratio:
            return None
        if at_z.hit < at_pred.hit:
            return None
        floor = max(lc.verify_min_hit_ratio, lc.lost_hit_fraction * self.quality.hit_reference)
        weak = at_z.hit < floor or float(res.inlier_ratio) < lc.recover_inlier_ratio
        if weak and not (
            at_z.rms <= lc.verify_max_residual * self.quality.sigma
            and at_z.hit >= at_pred.hit + lc.arbitration_margin
        ):
            # a place the map covers by a third (orebro 5 cm: the right fit 2.5 cm off at
            # 0.30 of the beams on walls, the reference pose itself at 0.31, while the dead
            # reckoning ran 1.4 m off): such a fit corrects the dead reckoning when its
            # hits fit as tightly as usual and it explains clearly more than the dead
            # reckoning (chance hits of a wrong place scatter over the hit distance)
            return None
        if nis > self._chi2_accept:
            R = R * (nis / self._chi2_accept)
        pose, cov = fuse(pred, pred_cov, z, R)
        return pose, cov, at_z, float(res.inlier_ratio), z, weak

    def _strict_clear(self, pts: NDArray[np.float64], pose: Pose) -> bool:
        """An inline strict global check of ``pose`` clears it (:meth:`_clear`: verdict
        ``""`` with no distinct rival, or ``"unsure"`` with the best distinct pose trailing
        by the lock margin); False otherwise, for a recovery without checks, and with
        ``localizer.lost_check: background`` (no verdict now)."""
        fn = getattr(self.recovery, "check_pose", None)
        if fn is None or self.config.localizer.lost_check == "background":
            return False
        try:
            v: CheckVerdict = fn(self.index, pts, pose, True)
        except Exception:  # noqa: BLE001 - a failed check is no evidence
            return False
        return self._clear(v)

    def _clear(self, v: CheckVerdict, unsure_ok: bool = True) -> bool:
        """A strict check's verdict that clears a pose: ``""`` and no distinct rival, or
        every one trailing by the tracker's dominance margin (a periodic building's next
        office fits as well as the right one: a rival not beaten). For a pose the localizer
        reached by itself (``unsure_ok``: a coasting fit, the way back by dead reckoning; a
        recovery's lock it clears only so far: the jump, ``degraded`` until settled, as a
        lock the verification refused; ``tracking`` at once needs ``""``),
        ``"unsure"`` (the best distinct pose the search
        found is no good fit) clears only when that pose trails the checked one by the lead
        the tracker asks of a leader over every rival to lock (its dominance margin at the
        checked pose's score, :meth:`icploc.relocalize.Relocalizer._margin`): a place the
        map covers by half, where the right pose scores 0.48 and the best elsewhere 0.31
        (freiburg-campus 5 cm, bad odometry: the right coasting fit was refused and the
        dead reckoning ran 6.9 m off), not a tie of two poor fits (an unsure check with no
        rival ranked carries no scores and does not clear)."""
        if v.verdict == "unsure":
            if not unsure_ok:
                return False
            c = self.config.relocalize
            margin = c.dominance + c.dominance_slope * max(0.0, c.clean_score - v.here)
            return v.here > 0.0 and v.best < (1.0 - margin) * v.here
        if v.verdict != "":
            return False
        dom = self.config.relocalize.dominance
        return v.pose is None or v.best < (1.0 - dom) * v.here

    # -- start refinement: a thin wrapper of icploc.startrefine (--refine-start) ----------
    def refine_start(self, config: Any = None, **kw: Any) -> Any:
        """Refine the current pose from the next stationary scans, with a verdict
        (:func:`icploc.startrefine.attach`)."""
        from icploc.startrefine import attach

        return attach(self, config, **kw)

    # -- saved state: thin wrappers of icploc.state (icploc run --state) ------------------
    def save_state(self, path: str | os.PathLike[str]) -> Any:
        """Save the last tracking pose and covariance to ``path``, atomically."""
        from icploc.state import save_state

        return save_state(self, os.fspath(path))

    def load_state(self, path: str | os.PathLike[str]) -> Any:
        """Start from the pose saved in ``path``, checked against the map on the first scan."""
        from icploc.state import restore

        return restore(self, os.fspath(path))



def _growth_to_consistent(
    pred: Pose, P: NDArray[np.float64], z: Pose, R: NDArray[np.float64], target: float
) -> float:
    """The smallest factor f (at least 1) that brings ``v'(fP + R)^-1 v`` down to
    ``target`` (bisection in log f; the statistic falls as f grows; inf beyond 1e6 or when
    the statistic is not finite)."""
    d2 = mahalanobis2(pred, P, z, R)
    if not math.isfinite(d2):
        return math.inf  # no statistic (a NaN pose or covariance): no growth
    if d2 <= target:
        return 1.0
    if mahalanobis2(pred, P * 1e6, z, R) > target:
        return math.inf
    lo, hi = 0.0, math.log(1e6)
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if mahalanobis2(pred, P * math.exp(mid), z, R) > target:
            lo = mid
        else:
            hi = mid
    return math.exp(hi)


def _fit_rms(res: Any) -> float | None:
    """The ICP's own RMS residual over its inliers, or None (no fit, no inliers)."""
    if res is None or not int(res.inliers):
        return None
    mse = float(res.mse)
    return math.sqrt(mse) if math.isfinite(mse) and mse >= 0 else None


def _largest_position_variance(cov: NDArray[np.float64]) -> float:
    """The position's variance along its worst direction (m^2)."""
    a, b, c = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    return 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))


#: the position variance (x + y) of a pose that says nothing
_UNKNOWN_VAR_XY = 2e6


def _unknown_covariance() -> NDArray[np.float64]:
    """The covariance of a pose that says nothing (no initial pose, a place refuted)."""
    return np.diag([0.5 * _UNKNOWN_VAR_XY, 0.5 * _UNKNOWN_VAR_XY, math.pi**2])


def _chi2_3(p: float) -> float:
    """The chi-square quantile with 3 degrees of freedom at probability ``p``."""
    if p in CHI2_3:
        return CHI2_3[p]
    # Wilson-Hilferty: chi2_k(p) ~ k (1 - 2/(9k) + z sqrt(2/(9k)))^3
    from statistics import NormalDist

    z = NormalDist().inv_cdf(p)
    k = 3.0
    return k * (1.0 - 2.0 / (9.0 * k) + z * math.sqrt(2.0 / (9.0 * k))) ** 3


def run(
    localizer: Localizer,
    items: Any,
    on_estimate: Callable[[Estimate], None] | None = None,
) -> list[Estimate]:
    """Feed a time-ordered stream of Scan / Odometry items through ``localizer``: odometry
    goes into its buffer; each scan waits for the first odometry sample at or after its
    stamp (exact interpolation, deterministic) or the end of the stream."""
    out: list[Estimate] = []
    pending: list[Scan] = []

    def flush(upto: float | None) -> None:
        while pending and (upto is None or pending[0].stamp <= upto):
            est = localizer.update(pending.pop(0))
            out.append(est)
            if on_estimate is not None:
                on_estimate(est)

    for it in items:
        if isinstance(it, Odometry):
            localizer.add_odometry(it)
            flush(it.stamp)
        elif isinstance(it, Scan):
            last = localizer.odometry.last_stamp
            if last is not None and it.stamp <= last:
                flush(None)
                est = localizer.update(it)
                out.append(est)
                if on_estimate is not None:
                    on_estimate(est)
            else:
                pending.append(it)
    flush(None)
    return out

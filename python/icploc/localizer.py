"""The outer localization loop: odometry predicts, ICP corrects, a gate checks.

Per scan (the paper's Fig. 3, plus its §3.5 "referring to the past value")::

    odometry at the scan stamp ──► predict: pose ⊕ (odom_prev⁻¹ ⊕ odom_now)
    scan ──► prepare: drop no-return / max-range / too-near beams, decimate,
             move into the robot base frame through the laser mounting offset
    ICP (Rust core) from the prediction ──► gate:
        * inlier ratio too low            → reject, keep the prediction
        * degenerate fit (a corridor)     → keep the prediction along the degenerate
                                            direction, ICP across it
        * a jump odometry cannot explain  → reject, keep the prediction
    ──► Estimate(stamp, pose, covariance, status, inlier_ratio, iterations, time)

Status machine: ``tracking`` (the last scan corrected the pose), ``degraded`` (the
pose leans on odometry: a rejected or partially degenerate correction), ``lost``
(inlier ratio collapsed for several scans, or the gate rejected many scans in a row).
While lost the localizer keeps dead-reckoning and calls :meth:`Localizer.relocalize`
every scan; a global search plugs in there (``global_search=`` callable) and returns
candidate poses that are refined with ``icploc.icp_batch``. A whole relocalization
strategy (multi-hypothesis global localization, kidnap detection) plugs in as a
:class:`Relocalization` (``relocalization=``, or :func:`icploc.relocalize.attach`):
:meth:`Localizer.relocalize` then delegates to it, and it observes every estimate.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from icploc.config import LocalizerConfig
from icploc.se2 import Pose, between, compose, wrap_angle
from icploc.types import BEAM_DAZZLE, BEAM_INVALID, BEAM_NO_RETURN, Odometry, Scan

__all__ = [
    "Estimate",
    "GlobalSearch",
    "Localizer",
    "OdometryBuffer",
    "Relocalization",
    "Status",
    "global_search_from",
    "prepare_scan",
    "run",
]


class Status(str, Enum):
    TRACKING = "tracking"
    DEGRADED = "degraded"
    LOST = "lost"

    def __str__(self) -> str:
        return self.value


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
    accepted: bool = False  #: the ICP correction (or part of it) was applied
    reason: str = ""  #: why a correction was rejected / degraded ("" when fully accepted)
    degeneracy: float = float("nan")  #: lambda_min / lambda_max of the fit (nan: no fit)
    prediction: Pose = (0.0, 0.0, 0.0)  #: the odometry prediction for this scan
    odometry: Pose | None = None  #: the (interpolated) odometry pose used
    num_points: int = 0  #: beams used for matching

    @property
    def x(self) -> float:
        return self.pose[0]

    @property
    def y(self) -> float:
        return self.pose[1]

    @property
    def theta(self) -> float:
        return self.pose[2]


class GlobalSearch(Protocol):
    """Produce candidate robot poses for a scan without trusting the current estimate.

    ``points`` are the prepared scan points in the robot base frame, ``prior`` and
    ``covariance`` the dead-reckoned belief (may be ignored by a truly global search).
    """

    def __call__(
        self,
        points: NDArray[np.float64],
        index: Any,
        prior: Pose,
        covariance: NDArray[np.float64],
    ) -> Sequence[Sequence[float]]: ...


class Relocalization(Protocol):
    """A relocalization strategy plugged into a :class:`Localizer` (``relocalization=``).

    While the localizer is ``lost``, :meth:`relocalize` is called on **every** scan (it
    throttles any expensive search itself) with the scan's prepared points; it returns
    ``(pose, IcpResult)`` once the pose is verified — tracking resumes there — or
    ``None``. It may move ``localizer.pose`` to follow its leading hypothesis meanwhile.
    :meth:`observe` sees every estimate (tracking or not) and may call
    :meth:`Localizer.declare_lost` (a kidnapping) or :meth:`Localizer.reset` (a slid pose).
    An optional ``state`` attribute (e.g. ``"ambiguous"``) becomes the ``reason`` of the
    estimates while lost.
    """

    def relocalize(
        self, localizer: Localizer, scan: Scan, points: NDArray[np.float64]
    ) -> tuple[Pose, Any] | None: ...

    def observe(self, localizer: Localizer, scan: Scan, estimate: Estimate) -> None: ...


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


_BAD_FLAGS = np.uint8(BEAM_NO_RETURN | BEAM_DAZZLE | BEAM_INVALID)


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
    r = scan.ranges
    hi = sc.max_range if sc.max_range > 0.0 else scan.max_range
    if hi != math.inf:
        hi = hi * sc.max_range_margin
    lo = sc.min_range if sc.min_range > scan.min_range else scan.min_range
    ok = r < hi  # NaN and inf compare False (inf < inf is False)
    ok &= r > lo
    if scan.flags is not None:
        ok &= (scan.flags & _BAD_FLAGS) == 0
    idx = ok.nonzero()[0]
    if sc.decimation > 1:
        idx = idx[:: sc.decimation]
    if trig is None:
        trig = _TrigCache()
    c, s = trig.get(scan.angles, sc.laser_theta)
    rr = r[idx]
    pts = np.empty((idx.shape[0], 2))
    np.multiply(rr, c[idx], out=pts[:, 0])
    np.multiply(rr, s[idx], out=pts[:, 1])
    if sc.laser_x != 0.0 or sc.laser_y != 0.0:
        pts += (sc.laser_x, sc.laser_y)
    return pts


def _fuse(
    pred: Pose,
    pred_cov: NDArray[np.float64],
    meas: Pose,
    meas_cov: NDArray[np.float64],
) -> tuple[Pose, NDArray[np.float64]]:
    """Kalman update of the odometry prediction with the ICP pose as the measurement:
    K = P (P + R)^-1, x = x_pred + K (z - x_pred), P' = (I - K) P. In floats (3x3, per scan)."""
    P = pred_cov.tolist()
    R = meas_cov.tolist()
    s00, s01, s02 = P[0][0] + R[0][0], P[0][1] + R[0][1], P[0][2] + R[0][2]
    s11, s12, s22 = P[1][1] + R[1][1], P[1][2] + R[1][2], P[2][2] + R[2][2]
    # inverse of the symmetric S by cofactors
    c00 = s11 * s22 - s12 * s12
    c01 = s02 * s12 - s01 * s22
    c02 = s01 * s12 - s02 * s11
    det = s00 * c00 + s01 * c01 + s02 * c02
    if not det > 0.0 or not math.isfinite(det):
        return meas, meas_cov
    c11 = s00 * s22 - s02 * s02
    c12 = s01 * s02 - s00 * s12
    c22 = s00 * s11 - s01 * s01
    inv = 1.0 / det
    Si = (
        (c00 * inv, c01 * inv, c02 * inv),
        (c01 * inv, c11 * inv, c12 * inv),
        (c02 * inv, c12 * inv, c22 * inv),
    )
    (p00, p01, p02), (_, p11, p12), (_, _, p22) = P
    (i00, i01, i02), (_, i11, i12), (_, _, i22) = Si
    k00 = p00 * i00 + p01 * i01 + p02 * i02
    k01 = p00 * i01 + p01 * i11 + p02 * i12
    k02 = p00 * i02 + p01 * i12 + p02 * i22
    k10 = p01 * i00 + p11 * i01 + p12 * i02
    k11 = p01 * i01 + p11 * i11 + p12 * i12
    k12 = p01 * i02 + p11 * i12 + p12 * i22
    k20 = p02 * i00 + p12 * i01 + p22 * i02
    k21 = p02 * i01 + p12 * i11 + p22 * i12
    k22 = p02 * i02 + p12 * i12 + p22 * i22
    v0, v1, v2 = meas[0] - pred[0], meas[1] - pred[1], wrap_angle(meas[2] - pred[2])
    dx = (
        k00 * v0 + k01 * v1 + k02 * v2,
        k10 * v0 + k11 * v1 + k12 * v2,
        k20 * v0 + k21 * v1 + k22 * v2,
    )
    # (I - K) P, symmetric
    q00 = p00 - (k00 * p00 + k01 * p01 + k02 * p02)
    q01 = p01 - (k00 * p01 + k01 * p11 + k02 * p12)
    q02 = p02 - (k00 * p02 + k01 * p12 + k02 * p22)
    q11 = p11 - (k10 * p01 + k11 * p11 + k12 * p12)
    q12 = p12 - (k10 * p02 + k11 * p12 + k12 * p22)
    q22 = p22 - (k20 * p02 + k21 * p12 + k22 * p22)
    cov = np.array([[q00, q01, q02], [q01, q11, q12], [q02, q12, q22]])
    return (pred[0] + dx[0], pred[1] + dx[1], wrap_angle(pred[2] + dx[2])), cov


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
class _Counters:
    scans: int = 0
    rejections_in_row: int = 0
    low_inliers_in_row: int = 0
    good_in_row: int = 0
    point_to_point_fallbacks: int = 0
    status_counts: dict[str, int] = field(default_factory=lambda: {s.value: 0 for s in Status})


class Localizer:
    """ICP localization against a known map, odometry as prior and fallback.

    ``map`` is an ``icploc.Map`` (its ``index(config.map.spacing)`` is used), an
    ``icploc.MapIndex`` or an (N, 2) array of map points. ``initial_pose`` (or
    ``config.localizer.initial_pose``) is the robot's start pose in the map frame; without
    one the localizer starts ``lost`` and waits for :meth:`relocalize` / :meth:`reset`.
    """

    def __init__(
        self,
        map: Any,
        config: LocalizerConfig | None = None,
        initial_pose: Sequence[float] | None = None,
        *,
        global_search: GlobalSearch | None = None,
        relocalization: Relocalization | None = None,
    ) -> None:
        self.config = (config or LocalizerConfig()).validate()
        self.index = _as_index(map, self.config)
        self.map = map
        self.icp_config = self.config.icp.to_icp_config()
        self.global_search = global_search
        #: the plugged-in relocalization strategy (see :class:`Relocalization`), if any;
        #: by default (``localizer.relocalization: global``, no ``global_search``) the global
        #: one of :mod:`icploc.relocalize`, its grids built when first needed
        if (
            relocalization is None
            and global_search is None
            and self.config.localizer.relocalization == "global"
        ):
            from icploc.relocalize import GlobalRelocalization

            relocalization = GlobalRelocalization.deferred(
                background=self.config.localizer.lost_check == "background"
            )
        self.relocalization: Relocalization | None = relocalization
        self.odometry = OdometryBuffer(
            max_extrapolation=min(0.25, self.config.localizer.max_odometry_gap)
        )
        self._trig = _TrigCache()
        self._counters = _Counters()
        self._last_odom: Pose | None = None
        self._since_fix_dist = 0.0
        self._since_fix_rot = 0.0
        self._recover_pose: Pose | None = None
        self._map_points: NDArray[np.float64] | None = None
        self._map_normals: NDArray[np.float64] | None = None
        self.last_estimate: Estimate | None = None
        self._last_reloc_result: Any = None
        self._icp_configs: dict[Any, Any] = {}
        lc0 = self.config.localizer
        self._q_floor = np.diag(
            [lc0.process_sigma_xy**2, lc0.process_sigma_xy**2, lc0.process_sigma_theta**2]
        )
        self._cov_floor = np.diag(
            [lc0.min_sigma_xy**2, lc0.min_sigma_xy**2, lc0.min_sigma_theta**2]
        )
        self._lost_scans = 0
        lc = self.config.localizer
        pose = initial_pose if initial_pose is not None else lc.initial_pose
        if pose is not None:
            self.reset(pose)
        else:
            self.pose: Pose = (0.0, 0.0, 0.0)
            self.covariance = np.diag([1e6, 1e6, math.pi**2])
            self.status = Status.LOST

    # -- state -----------------------------------------------------------------------------
    def reset(
        self,
        pose: Sequence[float],
        covariance: NDArray[np.float64] | None = None,
        status: Status = Status.TRACKING,
    ) -> None:
        """Set the pose (e.g. the initial pose, or after a relocalization)."""
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
        c.rejections_in_row = c.low_inliers_in_row = c.good_in_row = 0
        self._lost_scans = 0
        # a fresh pose is uncertain: open the gate as if we had driven a while
        self._since_fix_dist = lc.initial_sigma_xy / max(
            self.config.gating.translation_jump_per_metre, 1e-9
        )
        self._since_fix_rot = 0.0
        self._recover_pose = None

    def declare_lost(self) -> None:
        """Switch to ``lost`` now (e.g. a kidnapping detected from outside): the pose is
        dead-reckoned and relocalization runs from the next scan on."""
        self.reset(self.pose, self.covariance, Status.LOST)

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
        pred, pred_cov, moved, turned = self._predict(odom)
        self._since_fix_dist += moved
        self._since_fix_rot += turned
        pts = prepare_scan(scan, self.config, self._trig)
        if self.status is Status.LOST:
            est = self._update_lost(scan, pts, pred, pred_cov, odom, t0)
        else:
            est = self._update_tracking(scan, pts, pred, pred_cov, odom, t0)
        self._counters.scans += 1
        self._counters.status_counts[est.status.value] += 1
        self.last_estimate = est
        if self.relocalization is not None:
            self.relocalization.observe(self, scan, est)
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

    def _predict(self, odom: Pose | None) -> tuple[Pose, NDArray[np.float64], float, float]:
        lc = self.config.localizer
        if odom is None or self._last_odom is None:
            if odom is not None:
                self._last_odom = odom
            return self.pose, self.covariance + self._q_floor, 0.0, 0.0
        d = between(self._last_odom, odom)
        self._last_odom = odom
        pose = self.pose
        pred = compose(pose, d)
        dist = math.hypot(d[0], d[1])
        rot = abs(d[2])
        c, s = math.cos(pose[2]), math.sin(pose[2])
        # P' = F P F^T + G Q G^T with F = d(pose ⊕ d)/d(pose); Q is isotropic in x, y so
        # G Q G^T = Q. Written out in floats: this runs for every scan.
        a = -s * d[0] - c * d[1]
        b = c * d[0] - s * d[1]
        (p00, p01, p02), (_, p11, p12), (p20, p21, p22) = self.covariance.tolist()
        r00, r01, r02 = p00 + a * p20, p01 + a * p21, p02 + a * p22
        r11, r12 = p11 + b * p21, p12 + b * p22
        sxy = lc.odom_sigma_per_metre * dist
        sth = lc.odom_sigma_theta_per_radian * rot + lc.odom_sigma_theta_per_metre * dist
        qxy = sxy * sxy + lc.process_sigma_xy**2
        qth = sth * sth + lc.process_sigma_theta**2
        c00 = r00 + a * r02 + qxy
        c01 = r01 + b * r02
        c11 = r11 + b * r12 + qxy
        cov = np.array([[c00, c01, r02], [c01, c11, r12], [r02, r12, p22 + qth]])
        return pred, cov, dist, rot

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

    def _icp_config_for(self, pts: NDArray[np.float64], pred_cov: NDArray[np.float64]) -> Any:
        """The ICP settings for this scan: the first correspondence threshold opens up to
        cover the prediction's uncertainty (``icp.correspondence_sigmas`` standard
        deviations of position plus heading times the median range), capped at
        ``icp.max_correspondence_cap``; quantised so configs are reused."""
        ic = self.config.icp
        if not ic.adaptive_correspondence:
            return self.icp_config
        (p00, _, _), (_, p11, _), (_, _, p22) = pred_cov.tolist()
        sxy = math.sqrt(max(p00 + p11, 0.0))
        sth = math.sqrt(max(p22, 0.0))
        if ic.correspondence_sigmas * (sxy + 30.0 * sth) <= ic.max_correspondence_distance:
            return self.icp_config  # the common case: small steps, checked without the ranges
        if pts.shape[0]:
            r = pts[:: max(1, pts.shape[0] // 16)]
            rng = float(np.median(np.hypot(r[:, 0], r[:, 1])))
        else:
            rng = 0.0
        want = ic.correspondence_sigmas * (sxy + rng * sth)
        if want <= ic.max_correspondence_distance:
            return self.icp_config
        d = min(ic.max_correspondence_cap, math.ceil(want / 0.1) * 0.1)
        cfg = self._icp_configs.get(d)
        if cfg is None:
            cfg = dataclasses.replace(ic, max_correspondence_distance=d).to_icp_config()
            self._icp_configs[d] = cfg
        return cfg

    def _run_icp(
        self, pts: NDArray[np.float64], pred: Pose, pred_cov: NDArray[np.float64] | None = None
    ) -> Any:
        from icploc._core import IcpError, icp

        cfg = self.icp_config if pred_cov is None else self._icp_config_for(pts, pred_cov)
        index = self._match_index(pred)
        try:
            res = icp(pts, index, pred, cfg)
        except IcpError:
            return None
        if cfg.metric == "point_to_line" and not res.converged:
            # Point-to-line that does not settle is sliding or oscillating on ambiguous
            # geometry (measured: it drifted off on the Acapulco log); the paper's
            # point-to-point from the same prediction has the wider basin. Keep whichever
            # explains more of the scan.
            self._counters.point_to_point_fallbacks += 1
            try:
                alt = icp(pts, index, pred, self._fallback_config(cfg))
            except IcpError:
                return res
            if alt.inlier_ratio > res.inlier_ratio:
                return alt
        return res

    def _fallback_config(self, cfg: Any) -> Any:
        key = ("p2p", cfg.max_correspondence_distance)
        alt = self._icp_configs.get(key)
        if alt is None:
            from icploc._core import IcpConfig

            d = cfg.to_dict()
            d["metric"] = "point_to_point"
            alt = IcpConfig(**d)
            self._icp_configs[key] = alt
        return alt

    def _gate_allowance(self) -> tuple[float, float]:
        g = self.config.gating
        tr = min(
            g.max_translation_jump + g.translation_jump_per_metre * self._since_fix_dist,
            g.max_translation_jump_cap,
        )
        rot_deg = min(
            g.max_rotation_jump_deg
            + g.rotation_jump_per_radian_deg * self._since_fix_rot
            + g.rotation_jump_per_metre_deg * self._since_fix_dist,
            g.max_rotation_jump_cap_deg,
        )
        return tr, math.radians(rot_deg)

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
        res = self._run_icp(pts, pred, pred_cov) if n >= self.config.scan.min_points else None
        reason = ""
        pose = pred
        cov = pred_cov
        accepted = False
        inlier_ratio = 0.0
        iterations = 0
        degeneracy = float("nan")
        if res is None:
            reason = "too_few_points" if n < self.config.scan.min_points else "icp_failed"
        else:
            inlier_ratio = float(res.inlier_ratio)
            iterations = int(res.iterations)
            degeneracy = float(res.degeneracy)
            ix, iy, ith = res.pose
            if not (math.isfinite(ix) and math.isfinite(iy) and math.isfinite(ith)):
                reason = "icp_failed"
            elif inlier_ratio < g.min_inlier_ratio:
                reason = "low_inlier_ratio"
            elif g.require_convergence and not res.converged:
                reason = "not_converged"
            else:
                cand = (ix, iy, wrap_angle(ith))
                degenerate = degeneracy < g.degeneracy_threshold
                if degenerate:
                    dx, dy = res.degenerate_direction
                    nrm = math.hypot(dx, dy) or 1.0
                    dx, dy = dx / nrm, dy / nrm
                    along = (ix - pred[0]) * dx + (iy - pred[1]) * dy
                    cand = (ix - along * dx, iy - along * dy, cand[2])
                jx, jy = cand[0] - pred[0], cand[1] - pred[1]
                jth = wrap_angle(cand[2] - pred[2])
                max_tr, max_rot = self._gate_allowance()
                if math.hypot(jx, jy) > max_tr or abs(jth) > max_rot:
                    reason = "jump"
                else:
                    accepted = True
                    pose = cand
                    cov = self._corrected_covariance(res, pred_cov, degenerate)
                    if lc.fuse_odometry:
                        pose, cov = _fuse(pred, pred_cov, cand, cov)
                    # the gate re-tightens after any accepted fix: after a degenerate one the
                    # along-axis part was taken from odometry, so no jump remains there
                    self._since_fix_dist = 0.0
                    self._since_fix_rot = 0.0
                    if degenerate:
                        reason = "degenerate"
        # counters and status
        if inlier_ratio < lc.lost_inlier_ratio:
            cnt.low_inliers_in_row += 1
        else:
            cnt.low_inliers_in_row = 0
        if accepted:
            cnt.rejections_in_row = 0
            status = Status.TRACKING if reason == "" else Status.DEGRADED
        else:
            cnt.rejections_in_row += 1
            status = Status.DEGRADED
        if (
            cnt.low_inliers_in_row >= lc.lost_after_low_inlier_scans
            or cnt.rejections_in_row >= lc.lost_after_rejections
        ):
            status = Status.LOST
            reason = reason or "lost"
            self._lost_scans = 0
            cnt.good_in_row = 0
            self._recover_pose = None
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
        )

    def _corrected_covariance(
        self, res: Any, pred_cov: NDArray[np.float64], degenerate: bool
    ) -> NDArray[np.float64]:
        cov = np.asarray(res.covariance, dtype=np.float64).reshape(3, 3)
        if not np.isfinite(cov).all():
            cov = pred_cov
        # symmetric, and floored: a covariance that is never zero
        cov = (cov + cov.T) * 0.5 + self._cov_floor
        if degenerate:
            dx, dy = res.degenerate_direction
            nrm = math.hypot(dx, dy) or 1.0
            d = np.array([dx / nrm, dy / nrm])
            var_pred = float(d @ pred_cov[:2, :2] @ d)
            # replace the variance along the degenerate direction with the prediction's
            P = np.outer(d, d)
            cross = np.eye(2) - P
            cov[:2, :2] = cross @ cov[:2, :2] @ cross + var_pred * P
            cov[:2, 2] = cross @ cov[:2, 2]
            cov[2, :2] = cov[:2, 2]
        return cov

    # -- lost / relocalization -------------------------------------------------------------
    def _update_lost(
        self,
        scan: Scan,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64],
        odom: Pose | None,
        t0: float,
    ) -> Estimate:
        self.pose = pred
        self.covariance = pred_cov
        self._lost_scans += 1
        every = self.config.localizer.relocalize_every
        try_now = (
            self.relocalization is not None  # a plugged-in strategy throttles itself
            or self._counters.good_in_row > 0
            or (self._lost_scans - 1) % every == 0
        )
        found = (
            self.relocalize(scan, points=pts)
            if try_now and pts.shape[0] >= self.config.scan.min_points
            else None
        )
        if found is not None:
            res_pose, res = found
            self._last_reloc_result = res
            self.reset(res_pose, self._corrected_covariance(res, pred_cov, False), Status.TRACKING)
            self._since_fix_dist = 0.0
            return Estimate(
                stamp=scan.stamp,
                pose=self.pose,
                covariance=self.covariance,
                status=Status.TRACKING,
                inlier_ratio=float(res.inlier_ratio),
                iterations=int(res.iterations),
                time=time.perf_counter() - t0,
                accepted=True,
                reason="relocalized",
                degeneracy=float(res.degeneracy),
                prediction=pred,
                odometry=odom,
                num_points=pts.shape[0],
            )
        last = self._last_reloc_result
        return Estimate(
            stamp=scan.stamp,
            pose=pred,
            covariance=pred_cov,
            status=Status.LOST,
            inlier_ratio=float(last.inlier_ratio) if last is not None else 0.0,
            iterations=int(last.iterations) if last is not None else 0,
            time=time.perf_counter() - t0,
            accepted=False,
            # a plugged-in strategy says what it is doing: "ambiguous" (several places fit
            # the scans equally well), "confirming", "searching"
            reason=str(getattr(self.relocalization, "state", "") or "lost"),
            degeneracy=float(last.degeneracy) if last is not None else float("nan"),
            prediction=pred,
            odometry=odom,
            num_points=pts.shape[0],
        )

    def candidate_poses(self, points: NDArray[np.float64]) -> list[Pose]:
        """Start poses for relocalization: the dead-reckoned pose, a small local spread
        around it, and whatever the plugged-in ``global_search`` proposes."""
        p = self.pose
        out: list[Pose] = [p]
        sig = math.sqrt(max(float(self.covariance[0, 0] + self.covariance[1, 1]), 0.0))
        r = min(max(sig, 0.25), 1.0)
        for dth in (-0.3, 0.0, 0.3):
            for dx, dy in ((0.0, 0.0), (r, 0.0), (-r, 0.0), (0.0, r), (0.0, -r)):
                if dx == 0.0 and dy == 0.0 and dth == 0.0:
                    continue
                out.append((p[0] + dx, p[1] + dy, wrap_angle(p[2] + dth)))
        if self.global_search is not None:
            for c in self.global_search(points, self.index, self.pose, self.covariance):
                out.append((float(c[0]), float(c[1]), wrap_angle(float(c[2]))))
        return out

    def relocalize(
        self, scan: Scan, points: NDArray[np.float64] | None = None
    ) -> tuple[Pose, Any] | None:
        """Try to recover the pose from ``scan`` alone (plus the dead-reckoned prior).

        Refines :meth:`candidate_poses` with ``icploc.icp_batch`` and keeps the best fit by
        inlier ratio; a fit that is good (``recover_inlier_ratio``), not degenerate and
        agrees with itself for ``recover_after`` consecutive scans is returned as
        ``(pose, IcpResult)`` and tracking resumes. Returns ``None`` otherwise.
        This is the hook a global search plugs into (``global_search=``); with a
        :class:`Relocalization` plugged in (``relocalization=``) it delegates to that
        (:meth:`relocalize_locally` is the built-in recovery either way).
        """
        if self.relocalization is not None:
            pts0 = self.prepare(scan) if points is None else points
            return self.relocalization.relocalize(self, scan, pts0)
        return self.relocalize_locally(scan, points)

    def relocalize_locally(
        self, scan: Scan, points: NDArray[np.float64] | None = None
    ) -> tuple[Pose, Any] | None:
        """The built-in recovery of :meth:`relocalize`: multi-start ICP from
        :meth:`candidate_poses` (around the dead-reckoned pose, plus ``global_search``)."""
        from icploc._core import IcpError, icp_batch

        lc = self.config.localizer
        g = self.config.gating
        pts = prepare_scan(scan, self.config, self._trig) if points is None else points
        if pts.shape[0] < self.config.scan.min_points:
            return None
        cands = self.candidate_poses(pts)
        try:
            results = icp_batch(
                [pts], self.index, np.asarray(cands, dtype=np.float64), self.icp_config
            )
        except IcpError:
            return None
        best = None
        for r in results:
            if not all(math.isfinite(v) for v in r.pose):
                continue
            key = (r.inlier_ratio, -r.mse)
            if best is None or key > (best.inlier_ratio, -best.mse):
                best = r
        self._last_reloc_result = best
        cnt = self._counters
        if (
            best is None
            or best.inlier_ratio < lc.recover_inlier_ratio
            or best.degeneracy < g.degeneracy_threshold
        ):
            cnt.good_in_row = 0
            self._recover_pose = None
            return None
        bp: Pose = (best.pose[0], best.pose[1], wrap_angle(best.pose[2]))
        prior = self.pose  # the previous good fit moved on by odometry
        if self._recover_pose is not None and (
            math.hypot(bp[0] - prior[0], bp[1] - prior[1]) > 0.15
            or abs(wrap_angle(bp[2] - prior[2])) > math.radians(5.0)
        ):
            cnt.good_in_row = 0  # a different hypothesis: start confirming afresh
        cnt.good_in_row += 1
        self._recover_pose = bp
        # follow the best hypothesis while confirming it
        self.pose = bp
        if cnt.good_in_row >= lc.recover_after:
            cnt.good_in_row = 0
            self._recover_pose = None
            return bp, best
        return None

    # -- saved state: thin wrappers of icploc.state (icploc run --state) ------------------
    def save_state(self, path: str | os.PathLike[str]) -> Any:
        """Save the last tracking pose and covariance to ``path``, atomically."""
        from icploc.state import save_state

        return save_state(self, os.fspath(path))

    def load_state(self, path: str | os.PathLike[str]) -> Any:
        """Start from the pose saved in ``path``, checked against the map on the first scan."""
        from icploc.state import restore

        return restore(self, os.fspath(path))


def global_search_from(global_localizer: Any, max_candidates: int = 4) -> GlobalSearch:
    """Adapt an ``icploc.GlobalLocalizer`` (branch-and-bound over the whole map) to the
    :class:`Localizer` ``global_search`` hook: its best distinct candidates become start
    poses for the relocalization ICP. The scan points are in the robot base frame, so the
    candidates are base poses."""

    def search(
        points: NDArray[np.float64],
        index: Any,
        prior: Pose,
        covariance: NDArray[np.float64],
    ) -> list[Pose]:
        res = global_localizer.search(points)
        return [tuple(c.pose) for c in list(res.candidates)[:max_candidates]]

    return search


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

"""Refine the start without moving (AMCL's "no-motion update"), with a verdict.

A robot placed by hand, or restarted where an operator says it is, gets an initial pose
that is a few decimetres and degrees off. Tracking from there usually works, but a pose
that is off by more than the ICP's basin locks onto the wrong wall and then reports
``tracking`` confidently. While the robot stands still its first few scans say much more
than one: :class:`StartRefinement` (``Localizer.refine_start()``, ``icploc replay
--refine-start``, ``icploc run --refine-start``) uses them before the pose is promised:

1. **Search the window.** Each stationary scan goes to a multi-hypothesis
   :class:`icploc.relocalize.Relocalizer` restricted to a window around the given pose,
   sized from its covariance (``window_sigmas`` standard deviations per axis, within
   bounds): the branch-and-bound search finds every pose in the window that explains
   the scan, the tracker keeps the distinct ones and locks only when one has dominated
   every rival for ``confirm_scans`` scans (the same rule as global localization).
2. **Combine the scans, then ICP.** The scans are combined into one (the per-beam
   median of the ranges when they share their beams: a person walking past and the
   range noise drop out; else their union) and matched by the localizer's own ICP from
   the lock (:meth:`icploc.localizer.Localizer.verify_pose`), which also runs the
   verification tracking uses. The same ICP started around the result (up to
   ``basin_distance``) must come back to it: a fit that ends elsewhere and explains the
   scan as well means the scans do not single one pose out (a corridor's length, a
   repeated structure closer than the search can tell apart).
3. **Check elsewhere.** One search over the whole map
   (:meth:`icploc.relocalize.GlobalRelocalization.check_pose`, strict): a distinct pose
   outside the window that explains the scans clearly better means the given pose was
   not just imprecise but wrong.

The verdict (:class:`StartVerdict`, also in :attr:`StartRefinement.verdict`) is one of

* ``refined``: the localizer restarts at the refined pose with the combined scan's
  covariance (``change`` says how far it moved);
* ``ambiguous``: distinct poses in the window explain the scans about equally well —
  the localizer is told it is ``lost`` with a covariance covering the window, and its
  recovery decides once the robot moves (never a silent pick);
* ``rejected``: nothing in the window explains the scans, the localizer's verification
  refuses the best, or a distinct place elsewhere fits clearly better — the given pose
  is discarded and the localizer localizes globally;
* ``moved``: the odometry moved (``still_distance`` / ``still_angle``) before the
  refinement converged — it stops and says so; tracking goes on from the given pose as
  it would have without refinement.

Until the verdict the estimates are never ``tracking``: their status is at most
``degraded`` with reason ``refining_start``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from icploc.messages import BEAM_DAZZLE, BEAM_INVALID, BEAM_NO_RETURN, Scan
from icploc.se2 import Pose, between, compose, wrap_angle
from icploc.status import Reason

if TYPE_CHECKING:
    from icploc.localizer import Estimate, Localizer

__all__ = [
    "REFINING",
    "StartRefineConfig",
    "StartRefinement",
    "StartVerdict",
    "attach",
    "combine_scans",
]

#: the reason of the estimates made while the start is being refined
REFINING = Reason.REFINING_START


@dataclass(frozen=True)
class StartRefineConfig:
    """Settings of the start refinement (see the module docstring)."""

    #: stationary scans used at most; the verdict comes at the latest with the last
    scans: int = 5
    #: consecutive dominating scans before the window search locks
    confirm_scans: int = 3
    #: the window: this many standard deviations of the given covariance per axis ...
    window_sigmas: float = 3.0
    #: ... within these bounds (m, rad; half-widths)
    min_window_xy: float = 0.25
    max_window_xy: float = 3.0
    min_window_theta: float = math.radians(10.0)
    max_window_theta: float = math.pi
    #: odometry motion since the first scan beyond either of these: the robot moved
    still_distance: float = 0.02
    still_angle: float = math.radians(1.0)
    #: without odometry: the scans' own fits (the localizer's tracking ICP) may spread at
    #: most this much (m, rad) before the robot counts as moved
    still_fit_distance: float = 0.05
    still_fit_angle: float = math.radians(2.0)
    #: the basin check: fits started up to this far (m) from the refined pose that end
    #: more than ``basin_spread`` m (or 2 deg) away from it with a hit share within
    #: ``basin_margin`` of its own make the start ambiguous
    basin_distance: float = 0.4
    basin_spread: float = 0.1
    basin_margin: float = 0.03
    #: run the strict whole-map check of the refined pose (step 3)
    global_check: bool = True

    def __post_init__(self) -> None:
        for name in ("scans", "confirm_scans"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"startrefine.{name} must be an integer >= 1, got {v!r}")
        if self.confirm_scans > self.scans:
            raise ValueError(
                f"startrefine.confirm_scans ({self.confirm_scans}) must not exceed "
                f"startrefine.scans ({self.scans})"
            )
        for name in (
            "window_sigmas",
            "min_window_xy",
            "max_window_xy",
            "min_window_theta",
            "max_window_theta",
            "still_distance",
            "still_angle",
            "still_fit_distance",
            "still_fit_angle",
            "basin_distance",
            "basin_spread",
            "basin_margin",
        ):
            v = getattr(self, name)
            if (
                isinstance(v, bool)
                or not isinstance(v, (int, float))
                or not (math.isfinite(v) and v > 0)
            ):
                raise ValueError(f"startrefine.{name} must be a finite positive number, got {v!r}")
        if self.min_window_xy > self.max_window_xy:
            raise ValueError("startrefine.min_window_xy must not exceed startrefine.max_window_xy")
        if self.min_window_theta > self.max_window_theta:
            raise ValueError(
                "startrefine.min_window_theta must not exceed startrefine.max_window_theta"
            )


@dataclass(frozen=True)
class StartVerdict:
    """What the start refinement decided (see the module docstring)."""

    verdict: str  #: "refined", "ambiguous", "rejected" or "moved"
    reason: str  #: one sentence: why
    given: Pose  #: the pose the refinement started from
    pose: Pose  #: the pose the localizer goes on from (the refined one when refined)
    covariance: NDArray[np.float64]  #: its covariance (the window's when not refined)
    scans: int  #: stationary scans used
    #: the window searched: half-widths (m in x, m in y, rad)
    window: tuple[float, float, float]
    #: the distinct poses found in the window, best first: (pose, score)
    candidates: tuple[tuple[Pose, float], ...] = ()

    @property
    def refined(self) -> bool:
        return self.verdict == "refined"

    @property
    def change(self) -> Pose:
        """The pose change (dx, dy, dtheta) in the map frame (zero unless refined)."""
        return (
            self.pose[0] - self.given[0],
            self.pose[1] - self.given[1],
            wrap_angle(self.pose[2] - self.given[2]),
        )

    @property
    def distance(self) -> float:
        dx, dy, _ = self.change
        return math.hypot(dx, dy)

    def summary(self) -> str:
        dx, dy, dth = self.change
        line = f"start {self.verdict} after {self.scans} scan(s): {self.reason}"
        if self.refined:
            line += (
                f"; moved the pose by ({dx:+.3f} m, {dy:+.3f} m, {math.degrees(dth):+.2f} deg) to "
                f"({self.pose[0]:.3f}, {self.pose[1]:.3f}, {self.pose[2]:.4f})"
            )
        return line


def combine_scans(scans: list[Scan]) -> Scan | None:
    """One scan from several taken at the same place with the same beams: the per-beam
    median of the ranges that returned (a beam is a no-return when fewer than half of the
    scans saw something along it), so a person walking through some of them and most of
    the range noise drop out. None when the scans do not share their beams."""
    if not scans:
        return None
    first = scans[0]
    if any(
        s.angles.shape != first.angles.shape or not np.array_equal(s.angles, first.angles)
        for s in scans[1:]
    ):
        return None
    bad = np.uint8(BEAM_NO_RETURN | BEAM_DAZZLE | BEAM_INVALID)
    rows = []
    for s in scans:
        r = np.array(s.ranges, dtype=np.float64)
        ok = np.isfinite(r) & (r > 0.0) & (r < s.max_range)
        if s.flags is not None:
            ok &= (s.flags & bad) == 0
        r[~ok] = np.nan
        rows.append(r)
    R = np.vstack(rows)
    seen = np.count_nonzero(np.isfinite(R), axis=0)
    out = np.full(R.shape[1], np.inf)
    enough = 2 * seen >= len(scans)
    if enough.any():
        out[enough] = np.nanmedian(R[:, enough], axis=0)
    return Scan(
        stamp=scans[-1].stamp,
        ranges=out,
        angles=first.angles,
        seq=scans[-1].seq,
        max_range=min(s.max_range for s in scans),
        min_range=max(s.min_range for s in scans),
        frame=first.frame,
    )


@dataclass
class StartRefinement:
    """The refinement of one start, plugged into a Localizer (:func:`attach`). Read
    :attr:`verdict` (None until decided); ``on_verdict`` is called once with it."""

    localizer: Localizer
    config: StartRefineConfig = field(default_factory=StartRefineConfig)
    on_verdict: Callable[[StartVerdict], None] | None = None
    verdict: StartVerdict | None = None
    given: Pose = (0.0, 0.0, 0.0)
    given_covariance: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    _scans: list[Scan] = field(default_factory=list)
    _points: list[NDArray[np.float64]] = field(default_factory=list)
    _odom0: Pose | None = None
    _fits: list[Pose] = field(default_factory=list)
    _window: tuple[float, float, float] = (0.0, 0.0, 0.0)
    _tracker: Any = None
    _last: Any = None

    def __post_init__(self) -> None:
        loc = self.localizer
        self.given = (float(loc.pose[0]), float(loc.pose[1]), float(loc.pose[2]))
        self.given_covariance = np.array(loc.covariance, dtype=np.float64).reshape(3, 3)
        c = self.config
        sx = math.sqrt(max(float(self.given_covariance[0, 0]), 0.0))
        sy = math.sqrt(max(float(self.given_covariance[1, 1]), 0.0))
        st = math.sqrt(max(float(self.given_covariance[2, 2]), 0.0))

        def clamp(v: float, lo: float, hi: float) -> float:
            return min(max(v, lo), hi)

        k = c.window_sigmas
        self._window = (
            clamp(k * sx, c.min_window_xy, c.max_window_xy),
            clamp(k * sy, c.min_window_xy, c.max_window_xy),
            clamp(k * st, c.min_window_theta, c.max_window_theta),
        )

    # -- the hook the localizer calls after each update ---------------------------------
    def __call__(self, scan: Scan, points: NDArray[np.float64], est: Estimate) -> Estimate:
        if self.verdict is not None:
            return est
        odom = est.odometry
        moved = self._moved(odom, est)
        if moved:
            return self._decide_moved(est, moved)
        if points.shape[0] >= self.localizer.config.scan.min_points:
            if self._odom0 is None:
                self._odom0 = odom
            self._scans.append(scan)
            self._points.append(np.array(points, dtype=np.float64))
            if est.measurement is not None:
                self._fits.append(est.measurement)
            self._last = self._search(points)
            done = self._last.status == "locked" or len(self._scans) >= self.config.scans
            if done:
                return self._decide(est)
        return _not_promised(est)

    def detach(self) -> None:
        """Stop refining (no verdict)."""
        if getattr(self.localizer, "review", None) is self:
            self.localizer.review = None

    # -- steps --------------------------------------------------------------------------
    def _moved(self, odom: Pose | None, est: Estimate) -> str:
        """How the robot moved since the first scan ("" while it stands still)."""
        c = self.config
        if not self._scans:
            return ""
        if odom is not None and self._odom0 is not None:
            d = between(self._odom0, odom)
            dist, turn = math.hypot(d[0], d[1]), abs(d[2])
            if dist > c.still_distance or turn > c.still_angle:
                return f"the odometry moved {dist:.3f} m / {math.degrees(turn):.1f} deg"
            return ""
        z = est.measurement
        if z is None or not self._fits:
            return ""
        f = self._fits[0]
        dist, turn = math.hypot(z[0] - f[0], z[1] - f[1]), abs(wrap_angle(z[2] - f[2]))
        if dist > c.still_fit_distance or turn > c.still_fit_angle:
            return f"without odometry, the scans' fits moved {dist:.3f} m / {math.degrees(turn):.1f} deg"
        return ""

    def _glob(self) -> Any:
        """The localizer's global localizer (its grids built once), else a new one."""
        from icploc.relocalize import GlobalRelocalization, global_localizer

        rec = self.localizer.recovery
        inner = getattr(rec, "inner", rec)  # a saved-state check wraps the recovery
        if isinstance(inner, GlobalRelocalization) and inner.ready(self.localizer.index):
            return inner.relocalizer.glob
        return global_localizer(self.localizer.index, 0.05)

    def _search(self, points: NDArray[np.float64]) -> Any:
        from icploc.relocalize import RelocalizeConfig, Relocalizer

        if self._tracker is None:
            x, y, th = self.given
            wx, wy, wt = self._window
            heading = None if wt >= math.pi else (th - wt, th + wt)
            self._tracker = Relocalizer(
                self.localizer.index,
                RelocalizeConfig(confirm_scans=self.config.confirm_scans),
                localizer=self._glob(),
                region=(x - wx, y - wy, x + wx, y + wy),
                heading=heading,
            )
        # standing still: no motion between the scans
        return self._tracker.update(points, (0.0, 0.0, 0.0), search=True)

    def _combined_points(self) -> NDArray[np.float64]:
        scan = combine_scans(self._scans)
        if scan is not None:
            pts = self.localizer.prepare(scan)
            if pts.shape[0] >= self.localizer.config.scan.min_points:
                return pts
        return np.vstack(self._points)

    def _candidates(self) -> tuple[tuple[Pose, float], ...]:
        r = self._last
        if r is None:
            return ()
        return tuple((tuple(h.pose), float(h.score)) for h in r.hypotheses[:5])  # type: ignore[misc]

    def _decide(self, est: Estimate) -> Estimate:
        from icploc.fusion import scan_covariance

        loc = self.localizer
        r = self._last
        n = len(self._scans)
        wx, wy, wt = self._window
        where = f"within +-{wx:.2f} m, +-{wy:.2f} m, +-{math.degrees(wt):.0f} deg of the given pose"
        if r.status == "ambiguous":
            h = r.hypotheses
            return self._finish(
                est,
                "ambiguous",
                f"{len(h)} distinct poses {where} explain the scans about equally well "
                f"(scores {', '.join(f'{q.score:.2f}' for q in h[:3])})",
            )
        if r.status != "locked" or r.pose is None:
            if r.status == "confirming":
                return self._finish(
                    est,
                    "ambiguous",
                    f"no pose {where} dominated for {self.config.confirm_scans} scans",
                )
            best = (
                f" (best score {r.score:.2f}, inlier ratio {r.inlier_ratio:.2f})"
                if r.hypotheses
                else ""
            )
            return self._finish(est, "rejected", f"no pose {where} explains the scans{best}")
        pts = self._combined_points()
        ok, res, z = loc.verify_pose(pts, r.pose)
        if not ok or res is None:
            return self._finish(
                est, "rejected", "the localizer's verification refuses the best pose in the window"
            )
        rival = self._basin_rival(pts, z, res)
        if rival is not None:
            d = math.hypot(rival[0] - z[0], rival[1] - z[1])
            return self._finish(
                est,
                "ambiguous",
                f"fits started around the best pose also end {d:.2f} m / "
                f"{math.degrees(abs(wrap_angle(rival[2] - z[2]))):.1f} deg from it and verify "
                "as well (the scans do not pin the pose down: a corridor, repeated structure)",
            )
        if self.config.global_check:
            from icploc.relocalize import GlobalRelocalization, Relocalizer

            check = GlobalRelocalization(Relocalizer(loc.index, localizer=self._tracker.glob))
            v = check.check_pose(loc.index, pts, z, True)
            if v.verdict == "elsewhere" and v.pose is not None:
                p = v.pose
                return self._finish(
                    est,
                    "rejected",
                    f"a distinct place elsewhere on the map, ({p[0]:.2f}, {p[1]:.2f}, "
                    f"{p[2]:.2f}), explains the scans clearly better (score {v.best:.2f} "
                    f"against {v.here:.2f})",
                )
        R = scan_covariance(
            res.information,
            int(res.inliers),
            float(res.mse),
            loc.quality.sigma,
            loc._independent_beams,  # the localizer's own beam count (its measurement model)
        )
        if not np.all(np.isfinite(R)):
            return self._finish(est, "rejected", "the combined scan's fit has no usable covariance")
        # carried to now by the odometry (within the stillness bounds: a few mm at most)
        now = z
        if self._odom0 is not None and est.odometry is not None:
            now = compose(z, between(self._odom0, est.odometry))
        return self._finish(
            est,
            "refined",
            f"one pose {where} dominated {n} stationary scan(s) and the combined scan verifies",
            pose=now,
            covariance=R,
        )

    def _basin_rival(self, pts: NDArray[np.float64], z: Pose, res: Any) -> Pose | None:
        """A pose the localizer's ICP also converges to from starts around ``z`` (up to
        ``basin_distance`` m and half the heading window away), distinct from ``z``
        (beyond ``basin_spread`` m / 2 deg) and explaining the scan as well (hit share
        within ``basin_margin``): the scans do not single one pose out."""
        loc = self.localizer
        c = self.config
        here = loc.checker.check(pts, z)
        d = min(c.basin_distance, max(self._window[0], self._window[1]))
        dt = 0.5 * self._window[2]
        starts = [
            (z[0] + f * d * ux, z[1] + f * d * uy, z[2])
            for f in (0.5, 1.0)
            for ux, uy in ((1, 0), (-1, 0), (0, 1), (0, -1))
        ]
        starts += [(z[0], z[1], wrap_angle(z[2] + dt)), (z[0], z[1], wrap_angle(z[2] - dt))]
        for p in starts:
            ok, _, q = loc.verify_pose(pts, p)
            if not ok:
                continue
            far = math.hypot(q[0] - z[0], q[1] - z[1]) > c.basin_spread or abs(
                wrap_angle(q[2] - z[2])
            ) > math.radians(2.0)
            if far and loc.checker.check(pts, q).hit >= here.hit - c.basin_margin:
                return q
        return None

    def _decide_moved(self, est: Estimate, how: str) -> Estimate:
        n = len(self._scans)
        v = StartVerdict(
            verdict="moved",
            reason=(
                f"{how} before the refinement converged; the start is not refined "
                "(tracking goes on from the given pose)"
            ),
            given=self.given,
            pose=self.given,
            covariance=self.given_covariance,
            scans=n,
            window=self._window,
            candidates=self._candidates(),
        )
        self._publish(v)
        return est

    def _finish(
        self,
        est: Estimate,
        verdict: str,
        reason: str,
        pose: Pose | None = None,
        covariance: NDArray[np.float64] | None = None,
    ) -> Estimate:
        from icploc.localizer import Status

        loc = self.localizer
        wx, wy, wt = self._window
        if verdict == "refined":
            assert pose is not None and covariance is not None
            loc.reset(pose, covariance, Status.TRACKING)
            cov = covariance
            # the next scan's ordinary checks decide whether the pose is promised
            out = dataclasses.replace(
                est, pose=pose, covariance=cov, status=Status.DEGRADED, reason="start_refined"
            )
        else:
            if verdict == "ambiguous":
                # lost within the window: the recovery resolves it once the robot moves
                cov = np.diag([wx**2, wy**2, wt**2])
            else:
                cov = np.diag([1e6, 1e6, math.pi**2])  # the given pose means nothing
            pose = self.given
            loc.declare_lost()
            loc.pose = pose
            loc.covariance = cov
            out = dataclasses.replace(
                est,
                pose=pose,
                covariance=cov,
                status=Status.LOST,
                reason=f"start_{verdict}",
                accepted=False,
            )
        v = StartVerdict(
            verdict=verdict,
            reason=reason,
            given=self.given,
            pose=pose,
            covariance=np.array(cov, dtype=np.float64),
            scans=len(self._scans),
            window=self._window,
            candidates=self._candidates(),
        )
        self._publish(v)
        return out

    def _publish(self, v: StartVerdict) -> None:
        self.verdict = v
        self.detach()
        if self.on_verdict is not None:
            self.on_verdict(v)


def _not_promised(est: Estimate) -> Estimate:
    """While refining nothing is ``tracking``."""
    from icploc.localizer import Status

    if est.status is Status.TRACKING:
        return dataclasses.replace(est, status=Status.DEGRADED, reason=REFINING)
    return est


def attach(
    localizer: Localizer,
    config: StartRefineConfig | None = None,
    *,
    on_verdict: Callable[[StartVerdict], None] | None = None,
) -> StartRefinement:
    """Refine ``localizer``'s current pose from its next stationary scans (see the module
    docstring). The localizer must have a pose (not be lost)."""
    from icploc.localizer import Status

    if localizer.status is Status.LOST:
        raise ValueError(
            "refine_start: the localizer has no pose to refine (it is lost); give an initial pose"
        )
    r = StartRefinement(localizer, config or StartRefineConfig(), on_verdict)
    localizer.review = r
    return r

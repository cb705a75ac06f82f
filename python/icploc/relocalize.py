"""Global localization and kidnapped-robot recovery.

The Rust :class:`icploc.GlobalLocalizer` finds ranked pose candidates for one scan
anywhere on the map (branch-and-bound over positions and headings, ICP-refined) and says
when the best two are too close to choose (``ambiguous``). One scan is often not enough —
a symmetric room, a building of identical offices — so :class:`Relocalizer` keeps the
plausible candidates as hypotheses, carries each through the odometry increments, refines
and re-scores each on every new scan, adds whatever a fresh search finds, drops those that
fall behind, and declares a lock only when one hypothesis has dominated every other
distinct one (by a relative score margin), with a good fit, for ``confirm_scans``
consecutive scans. While two hypotheses explain the scans equally well it keeps saying
``ambiguous``: never a confident wrong lock.

:class:`GlobalRelocalization` is the Localizer's default recovery strategy
(:class:`icploc.recovery.Recovery`): while the localizer is lost it searches around the
dead-reckoned pose, then with the hypothesis tracker over the whole map; :func:`attach`
plugs one into an existing Localizer. This module does not import the localizer.
:func:`relocalize` is the one-shot form: search (and optionally confirm over the
following scans with odometry).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.config import GlobalSearchSection, LocalizerConfig, RelocalizeSection
from icploc.kidnap import CheckVerdict
from icploc.messages import Scan
from icploc.recovery import Candidate, LocalRecovery, RecoveryStep, RecoveryView
from icploc.scanprep import prepare_scan
from icploc.se2 import Pose, compose, wrap_angle

__all__ = [
    "GlobalRelocalization",
    "Hypothesis",
    "RelocalizeConfig",
    "RelocalizeResult",
    "Relocalizer",
    "attach",
    "global_localizer",
    "relocalize",
]


#: the hypothesis tracker's settings: the ``relocalize:`` section of the config
#: (:class:`icploc.config.RelocalizeSection`, the one source of their defaults and checks)
RelocalizeConfig = RelocalizeSection

#: a kidnap / lock check's coarse floor per unit of the refined score it must reach. The
#: coarse likelihood (``global_search.sigma``, 15 cm, on the grid) of a lattice leaf is
#: well above the fine one (``score_sigma``, 5 cm) of the pose ICP refines it to; measured
#: on the real 5 cm cells' checks (248 refined candidates): coarse / fine >= 1.2 for every
#: one, >= 1.66 below a fine 0.3 (see benches/results/speed.md); kept at 0.8
_COARSE_PER_FINE = 0.8


@dataclass
class Hypothesis:
    """One pose hypothesis followed through the scans."""

    pose: Pose
    score: float
    inlier_ratio: float
    id: int
    see_through: float = 0.0  #: fraction of beams crossing mapped walls (last scan)
    age: int = 1  #: scans this hypothesis has been scored on
    good: int = 0  #: consecutive scans with a good fit (score and inlier ratio)


@dataclass(frozen=True)
class RelocalizeResult:
    """What the tracker thinks after one scan.

    ``status``: ``"locked"`` (``pose`` verified), ``"ambiguous"`` (two or more distinct
    hypotheses explain the scans about equally well), ``"confirming"`` (one dominates but
    not for long enough yet), ``"searching"`` (no good hypothesis)."""

    status: str
    pose: Pose | None
    score: float
    inlier_ratio: float
    hypotheses: tuple[Hypothesis, ...]
    scans: int
    search_time: float = 0.0  #: seconds spent in the global search for this scan
    search_ambiguous: bool = False  #: the global search of this scan reported ambiguity

    @property
    def locked(self) -> bool:
        return self.status == "locked"

    @property
    def ambiguous(self) -> bool:
        return self.status == "ambiguous"


def _index_of(map_: Any, spacing: float = 0.05) -> Any:
    from icploc._core import MapIndex

    if isinstance(map_, MapIndex):
        return map_
    if hasattr(map_, "index") and callable(map_.index):
        return map_.index(spacing)
    pts = np.asarray(map_, dtype=np.float64)
    if pts.ndim == 2 and pts.shape[1] == 4:  # wall segments
        return MapIndex(_sample_segments(pts, spacing))
    return MapIndex(pts.reshape(-1, 2))


def _sample_segments(segs: NDArray[np.float64], spacing: float) -> NDArray[np.float64]:
    out = []
    for x1, y1, x2, y2 in segs:
        n = max(1, int(math.ceil(math.hypot(x2 - x1, y2 - y1) / spacing)))
        t = np.linspace(0.0, 1.0, n + 1)
        out.append(np.column_stack([x1 + t * (x2 - x1), y1 + t * (y2 - y1)]))
    return np.vstack(out)


def global_localizer(map_: Any, resolution: float = 0.05, **kwargs: Any) -> Any:
    """A :class:`icploc.GlobalLocalizer` for ``map_``: a MapIndex, an ``icploc.Map``, an
    (N, 2) array of points or a (K, 4) array of wall segments (sampled every 5 cm)."""
    from icploc.maps.cache import global_localizer as cached  # a cached map's field is kept

    return cached(_index_of(map_), resolution, **kwargs)


def _subsample(points: NDArray[np.float64], n: int) -> NDArray[np.float64]:
    if n <= 0 or points.shape[0] <= n:
        return points
    k = np.linspace(0, points.shape[0] - 1, n).round().astype(np.int64)
    return points[k]


def window_extent(covariance: Any, settings: Any) -> tuple[float, float]:
    """The search window of a dead-reckoned pose with ``covariance``: half its side in
    position (``window_sigmas`` x the position covariance's larger axis + ``window_margin``)
    and in heading (``window_sigmas`` x the heading sigma + ``window_heading_margin``);
    ``settings``: the ``relocalize`` section. One definition for the window searched and the
    window a leader locks in sooner."""
    P = np.asarray(covariance, dtype=np.float64)
    a, b, c = float(P[0, 0]), float(P[0, 1]), float(P[1, 1])
    lmax = 0.5 * (a + c) + math.sqrt(max(0.25 * (a - c) ** 2 + b * b, 0.0))
    half = settings.window_sigmas * math.sqrt(max(lmax, 0.0)) + settings.window_margin
    w = settings.window_sigmas * math.sqrt(max(float(P[2, 2]), 0.0)) + settings.window_heading_margin
    return half, w


class Relocalizer:
    """Multi-hypothesis global localization: :meth:`update` once per scan with the
    odometry motion since the previous call (robot frame, ``between(odom_prev, odom_now)``)
    until the result is ``locked``. ``points`` are scan points in the robot base frame.
    ``region`` / ``heading`` restrict the searches (see :meth:`GlobalLocalizer.search`)."""

    def __init__(
        self,
        map_: Any,
        config: RelocalizeConfig | None = None,
        *,
        localizer: Any = None,
        region: Sequence[float] | None = None,
        heading: tuple[float, float] | None = None,
        **global_kwargs: Any,
    ) -> None:
        self.config = (config or RelocalizeConfig()).validate()
        self.glob = (
            localizer
            if localizer is not None
            else global_localizer(map_, self.config.resolution, **global_kwargs)
        )
        #: candidates a search returns at most (GlobalLocalizer max_candidates): a full
        #: list whose weakest entry is as good as its best was truncated
        self.search_cap = int(global_kwargs.get("max_candidates", 32))
        self.region = tuple(region) if region is not None else None
        self.heading = heading
        self._ids = itertools.count()
        self.reset()

    def reset(self) -> None:
        """Forget every hypothesis (the next :meth:`update` searches afresh)."""
        self.hypotheses: list[Hypothesis] = []
        self.scans = 0
        self._leader: int | None = None
        self._streak = 0
        #: consecutive scans the current leader needs (confirm_scans, or
        #: prior_confirm_scans inside the prior's window)
        self._need = self.config.confirm_scans
        self._prior: tuple[Pose, NDArray[np.float64]] | None = None
        self._verified = False  # the leader dominated a scan that had a fresh search
        self._saturated = False  # the last search (or the cap) may have cut a rival
        self.last: RelocalizeResult | None = None

    @property
    def awaiting_verification(self) -> bool:
        """One hypothesis has dominated for ``confirm_scans - 1`` scans but has not yet
        beaten a fresh global search: a throttled caller should search on the next scan
        (the lock waits for it)."""
        return (
            self._leader is not None
            and not self._verified
            and self._streak >= max(1, self._need - 1)
        )

    def _margin(self, best_score: float) -> float:
        """The relative lead a leader scoring ``best_score`` needs over every rival:
        ``dominance``, more for a mediocre leader, never so much that a rival could
        already have been dropped by ``keep_ratio``."""
        c = self.config
        m = c.dominance + c.dominance_slope * max(0.0, c.clean_score - best_score)
        return min(m, 1.0 - c.keep_ratio)

    def _score(self, cand: Any) -> float:
        """The tracker's score of a GlobalCandidate: its likelihood with a softened
        see-through penalty."""
        st = float(cand.see_through)
        raw = float(cand.score) / (1.0 - st) if st < 1.0 else 0.0
        return raw * (1.0 - self.config.see_through_weight * st)

    def expect(self, share: float) -> None:
        """What a good fit looks like on this map: the inlier share its verified fits show
        (``share``, e.g. the localizer's hit reference times its verification fraction).
        Where that is below ``min_inlier_ratio`` (a coarse or cluttered map, a map from
        another pass) the confirming thresholds follow it down: the inlier ratio to it, the
        score in proportion. Never above the configured ones."""
        c = self.config
        if not (0.0 < share < c.min_inlier_ratio):
            self._min_inlier, self._min_score = c.min_inlier_ratio, c.min_score
            return
        self._min_inlier = share
        self._min_score = c.min_score * share / c.min_inlier_ratio

    def _good(self, score: float, inlier_ratio: float, see_through: float = 0.0) -> bool:
        c = self.config
        return (
            score >= getattr(self, "_min_score", c.min_score)
            and inlier_ratio >= getattr(self, "_min_inlier", c.min_inlier_ratio)
            and see_through <= c.max_see_through
        )

    def update(
        self,
        points: NDArray[np.float64],
        motion: Sequence[float] | None = None,
        search: bool | None = None,
        window: tuple[Sequence[float] | None, tuple[float, float] | None] | None = None,
        prior: tuple[Pose, NDArray[np.float64]] | None = None,
    ) -> RelocalizeResult:
        """``search``: run the global search on this scan (True) or only track the
        hypotheses (False); None: with no hypotheses, else every ``search_every``-th scan.
        ``window``: (region, heading) of this scan's search instead of the tracker's own
        (see :meth:`GlobalLocalizer.search`; a caller with a prior, e.g. the dead-reckoned
        pose while lost, searches where the robot can be). ``prior``: (pose, covariance)
        of where the robot should be (the dead-reckoned pose while lost; None: no idea); a
        leader within ``window_sigmas`` of it (the covariance grown by ``window_margin`` /
        ``window_heading_margin``) locks after ``prior_confirm_scans`` scans instead of
        ``confirm_scans`` (still dominating every rival, still beating a fresh search)."""
        c = self.config
        self._prior = prior
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        pts = pts[np.isfinite(pts).all(axis=1)]
        self.scans += 1
        if pts.shape[0] < 10:
            return self._result("searching", 0.0, False)
        sub = np.ascontiguousarray(_subsample(pts, c.max_points))
        # 1. carry the hypotheses through the odometry motion, refine and re-score them
        hyps = self.hypotheses
        if hyps:
            if motion is not None:
                m = (float(motion[0]), float(motion[1]), float(motion[2]))
                for h in hyps:
                    h.pose = compose(h.pose, m)
            refined = self.glob.refine(sub, np.array([h.pose for h in hyps]))
            for h, r in zip(hyps, refined, strict=True):
                h.pose = (r.pose[0], r.pose[1], wrap_angle(r.pose[2]))
                h.score, h.inlier_ratio = self._score(r), r.inlier_ratio
                h.see_through = r.see_through
                h.age += 1
                h.good = h.good + 1 if self._good(h.score, h.inlier_ratio, h.see_through) else 0
        # 2. a fresh search adds what the hypotheses do not cover yet
        search_time = 0.0
        search_amb = False
        searched = (
            search if search is not None else (not hyps or (self.scans - 1) % c.search_every == 0)
        )
        if searched:
            self._saturated = False
            region, heading = window if window is not None else (self.region, self.heading)
            res = self.glob.search(pts, region, heading)
            search_time = res.coarse_time + res.refine_time
            search_amb = res.ambiguous
            cands = list(res.candidates)
            if len(cands) >= self.search_cap:
                top, last = self._score(cands[0]), self._score(cands[-1])
                self._saturated = last >= (1.0 - self._margin(top)) * top
            for cand in res.candidates:
                p = (cand.pose[0], cand.pose[1], wrap_angle(cand.pose[2]))
                if any(not self.glob.distinct(p, h.pose) for h in hyps):
                    continue
                hyps.append(
                    Hypothesis(
                        pose=p,
                        score=self._score(cand),
                        inlier_ratio=cand.inlier_ratio,
                        see_through=cand.see_through,
                        id=next(self._ids),
                        good=1
                        if self._good(self._score(cand), cand.inlier_ratio, cand.see_through)
                        else 0,
                    )
                )
        # 3. drop hypotheses inside walls or off the map, merge those that converged onto
        # each other, drop the weak ones
        if hyps:
            d = self.glob.distance(np.array([h.pose[:2] for h in hyps], dtype=np.float64))
            hyps = [h for h, dist in zip(hyps, d, strict=True) if dist >= c.min_clearance]
        hyps.sort(key=lambda h: (h.score, h.age), reverse=True)
        merged: list[Hypothesis] = []
        for h in hyps:
            twin = next((q for q in merged if not self.glob.distinct(h.pose, q.pose)), None)
            if twin is None:
                merged.append(h)
            elif h.age > twin.age:  # keep the longer history, the better pose
                twin.age, twin.good, twin.id = h.age, max(h.good, twin.good), h.id
        best = merged[0] if merged else None
        if best is not None:
            merged = [h for h in merged if h.score >= c.keep_ratio * best.score]
        self.hypotheses = merged[: c.max_hypotheses]
        if best is not None and any(
            h.score >= (1.0 - self._margin(best.score)) * best.score
            for h in merged[c.max_hypotheses :]
        ):
            self._saturated = True  # until the next search
        # decide on every hypothesis, not only those kept: a rival cut by the cap (many
        # identical offices) is still a rival; and a search whose weakest returned
        # candidate is as good as its best was truncated: the truth may be among the
        # poses it could not return
        return self._decide(merged, search_time, search_amb, bool(searched))

    def _decide(
        self,
        hyps: list[Hypothesis],
        search_time: float,
        search_amb: bool,
        searched: bool = True,
    ) -> RelocalizeResult:
        c = self.config
        if not hyps or not self._good(hyps[0].score, hyps[0].inlier_ratio, hyps[0].see_through):
            self._leader, self._streak = None, 0
            return self._result("searching", search_time, search_amb)
        best = hyps[0]
        margin = self._margin(best.score)
        rival = next(
            (
                h
                for h in hyps[1:]
                if h.score >= (1.0 - margin) * best.score
                or h.inlier_ratio > best.inlier_ratio + c.inlier_margin
            ),
            None,
        )
        if rival is not None or self._saturated:
            self._leader, self._streak = None, 0
            return self._result("ambiguous", search_time, search_amb)
        need = c.confirm_scans
        if self._prior is not None and self.in_prior(best.pose):
            need = min(need, c.prior_confirm_scans)
        self._need = need
        if self._leader == best.id:
            self._streak += 1
            self._verified = self._verified or searched
        else:
            self._leader, self._streak, self._verified = best.id, 1, searched
        # a lock needs the leader to have beaten a fresh search too (with the search
        # throttled, the scans in between only re-score the hypotheses already held)
        if self._streak >= need and best.good >= need and self._verified:
            return self._result("locked", search_time, search_amb)
        return self._result("confirming", search_time, search_amb)

    @property
    def held_longer_than_needed(self) -> bool:
        """The current leader has dominated one scan more than a lock of it needs."""
        return self._leader is not None and self._streak >= self._need + 1

    def in_prior(self, pose: Pose) -> bool:
        """``pose`` lies inside the window of the prior given to this update (the window
        :meth:`GlobalRelocalization.window` searches: :func:`window_extent`)."""
        if self._prior is None:
            return False
        q, P = self._prior
        half, wth = window_extent(P, self.config)
        if not math.isfinite(half):
            return False
        inside = abs(pose[0] - q[0]) <= half and abs(pose[1] - q[1]) <= half
        return inside and abs(wrap_angle(pose[2] - q[2])) <= wth

    def _result(self, status: str, search_time: float, search_amb: bool) -> RelocalizeResult:
        best = self.hypotheses[0] if self.hypotheses else None
        r = RelocalizeResult(
            status=status,
            pose=best.pose if best is not None else None,
            score=best.score if best is not None else 0.0,
            inlier_ratio=best.inlier_ratio if best is not None else 0.0,
            hypotheses=tuple(replace(h) for h in self.hypotheses),
            scans=self.scans,
            search_time=search_time,
            search_ambiguous=search_amb,
        )
        self.last = r
        return r


def relocalize(
    scan: Any,
    map_: Any,
    *,
    motions: Iterable[Sequence[float]] = (),
    scans: Iterable[Any] = (),
    config: RelocalizeConfig | None = None,
    localizer: Any = None,
    region: Sequence[float] | None = None,
    heading: tuple[float, float] | None = None,
) -> RelocalizeResult:
    """Global localization of ``scan`` ((N, 2) robot-frame points, or an
    :class:`icploc.Scan`) on ``map_`` (see :func:`global_localizer`; pass a prebuilt
    ``localizer=`` to reuse its grids). With ``scans`` and ``motions`` (the odometry motion
    from the previous scan to each of them) the top hypotheses are tracked until one
    dominates; the result of the first scan that locks (or of the last scan) is returned.
    Check ``result.status``: only ``"locked"`` is a verified pose."""
    r = Relocalizer(map_, config, localizer=localizer, region=region, heading=heading)
    res = r.update(_points(scan))
    for s, m in zip(scans, motions, strict=False):
        if res.locked:
            break
        res = r.update(_points(s), m)
    return res


def _points(scan: Any) -> NDArray[np.float64]:
    if isinstance(scan, Scan):
        return prepare_scan(scan, LocalizerConfig())
    return np.asarray(scan, dtype=np.float64).reshape(-1, 2)


# -- Localizer integration ---------------------------------------------------------------------


class GlobalRelocalization:
    """The :class:`icploc.recovery.Recovery` a Localizer uses by default
    (``localizer.relocalization: global``) and :func:`attach` plugs in.

    While the localizer is lost it first searches around the dead-reckoned pose
    (:class:`icploc.recovery.LocalRecovery`, for ``localizer.local_recovery_scans`` scans:
    a short outage, a crowd), then runs the multi-hypothesis :class:`Relocalizer` over the
    whole map with the odometry motion between scans (the global search throttled by
    ``localizer.global_search_every`` / ``global_search_interval``, except to verify a
    dominating leader at once). Its hypotheses are reported every scan; a lock is returned
    only when the Relocalizer has locked **and** the localizer's own verification accepts
    the pose. It never moves the localizer's pose, and detects nothing: the localizer's
    one lost detector decides when it runs. While tracking, :meth:`check_pose` is the
    global kidnap check the localizer's trigger asks for (:mod:`icploc.kidnap`)."""

    def __init__(
        self,
        relocalizer: Relocalizer | None,
        *,
        local: LocalRecovery | None = None,
        background: bool = False,
        config: LocalizerConfig | None = None,
    ) -> None:
        #: None: built from the localizer's map index when first needed (:meth:`deferred`)
        self._relocalizer = relocalizer
        cfg = config or LocalizerConfig()
        #: the ``relocalize:`` settings (the deferred build, the kidnap check) and the
        #: ``global_search:`` settings of the deferred build's GlobalLocalizer
        self.settings: RelocalizeSection = cfg.relocalize
        self.global_search: GlobalSearchSection = cfg.global_search
        self.local = local or LocalRecovery.from_config(config)
        #: run the global searches on a worker thread (``localizer.lost_check: background``):
        #: ``recover`` never waits for one; a search's candidates join the hypotheses when
        #: ready, carried there by odometry
        self.background = bool(background)
        self._executor: Any = None
        self._inflight: Any = None
        self._unavailable = False  #: the map could not be gridded: local recovery only
        #: (localizer scan count, stamp) of the last global search
        self._last_search: tuple[int, float] | None = None
        #: (scan count, stamp) of the last whole-map search
        self._last_full: tuple[int, float] | None = None
        #: the latest relocalizer results (at most 100)
        self.results: list[RelocalizeResult] = []
        self.state = ""
        #: odometry motion since the tracker's last update (robot frame)
        self._motion: Pose = (0.0, 0.0, 0.0)
        self._hyps: tuple[Candidate, ...] = ()
        #: (map index, its checked bounds) of :meth:`map_bounds`
        self._bounds: tuple[Any, tuple[float, float, float, float] | None] | None = None

    @classmethod
    def deferred(
        cls, *, background: bool = False, config: LocalizerConfig | None = None
    ) -> GlobalRelocalization:
        """The Localizer's default: a :class:`Relocalizer` over the localizer's own map
        index, built the first time a global search is needed, with ``config``'s
        ``relocalize:`` and ``recovery:`` settings."""
        return cls(None, background=background, config=config)

    @property
    def relocalizer(self) -> Relocalizer:
        if self._relocalizer is None:
            raise RuntimeError("GlobalRelocalization: not built yet (no global search so far)")
        return self._relocalizer

    def reset(self) -> None:
        fut = self._inflight
        if fut is not None:
            fut.result()  # let a running update finish before its tracker is reset
        self.local.reset()
        if self._relocalizer is not None:
            self._relocalizer.reset()
        self._last_search = None
        self._last_full = None
        self._inflight = None
        self.state = ""
        self._motion = (0.0, 0.0, 0.0)
        self._hyps = ()

    def _ready(self, view: RecoveryView) -> bool:
        return self.ready(view.index)

    def ready(self, index: Any) -> bool:
        """Build the deferred relocalizer from the map ``index`` (at 5 cm, coarser on a map
        larger than ``relocalize.max_cells`` cells at 5 cm). A map the global search cannot grid
        leaves local recovery only (and no kidnap checks), with a warning."""
        if self._relocalizer is not None:
            return True
        if self._unavailable:
            return False
        from icploc._core import GridTooLargeError

        try:
            x0, y0, x1, y1 = index.bounds
            area = max(float(x1 - x0), 1.0) * max(float(y1 - y0), 1.0)
            res0 = max(0.05, math.ceil(math.sqrt(area / self.settings.max_cells) / 0.05) * 0.05)
            for res in (res0, 2 * res0, 4 * res0, 8 * res0):
                try:
                    self._relocalizer = Relocalizer(
                        index,
                        # res > 0 by construction: a copy, no validation (a validator build)
                        self.settings.model_copy(update={"resolution": res}),
                        **self.global_search.to_dict(),
                    )
                    break
                except GridTooLargeError:
                    if res == 8 * res0:
                        raise
        except (ValueError, RuntimeError, MemoryError) as e:
            import warnings

            warnings.warn(
                f"global relocalization unavailable for this map ({e}); "
                "falling back to local recovery",
                RuntimeWarning,
                stacklevel=3,
            )
            self._unavailable = True
            return False
        return True

    def map_bounds(self, index: Any) -> tuple[float, float, float, float] | None:
        """The map ``index``'s extent ``(xmin, ymin, xmax, ymax)``, checked the first time
        this index is seen (the per-scan path then reuses it); None: the index has no
        bounds. Bounds that are not four finite numbers with ``xmin <= xmax`` and
        ``ymin <= ymax`` raise :class:`icploc.maps.MapError` naming the field."""
        got = self._bounds
        if got is not None and got[0] is index:
            return got[1]
        bounds = getattr(index, "bounds", None)
        checked: tuple[float, float, float, float] | None = None
        if bounds is not None:
            from icploc.maps.errors import MapError

            problem = f"map index bounds {bounds!r}: expected (xmin, ymin, xmax, ymax)"
            try:
                x0, y0, x1, y1 = (float(v) for v in bounds)
            except (TypeError, ValueError):
                raise MapError(None, "bounds", problem) from None
            if not (all(map(math.isfinite, (x0, y0, x1, y1))) and x0 <= x1 and y0 <= y1):
                raise MapError(None, "bounds", problem + " with finite xmin <= xmax, ymin <= ymax")
            checked = (x0, y0, x1, y1)
        self._bounds = (index, checked)
        return checked

    def window(
        self, view: RecoveryView
    ) -> tuple[tuple[float, float, float, float], tuple[float, float] | None] | None:
        """Where a global search while lost looks: the dead-reckoned position +-
        ``relocalize.window_sigmas`` sigmas of its covariance (the larger axis) plus
        ``window_margin``, clipped to the map, and its heading +- as many sigmas plus
        ``window_heading_margin`` (None: every heading).

        None (the whole map) for a pose that says nothing, a window that would cover most
        of the map anyway, one that lies off the map, and a map index that has no bounds
        (no ``bounds`` attribute, or ``None``: a stand-in for a :class:`MapIndex`, which
        always has them): without the map's extent the window can neither be clipped to
        the map nor told from one covering most of it, so the whole map is searched, as
        for a pose that says nothing. Bounds that are not four finite numbers
        ``(xmin, ymin, xmax, ymax)`` with ``xmin <= xmax`` and ``ymin <= ymax`` are a
        broken index, not a missing one: :class:`icploc.maps.MapError` (a ``ValueError``),
        raised once per index (:meth:`map_bounds` checks an index's bounds the first time
        it sees it, not on every scan)."""
        P = np.asarray(view.covariance, dtype=np.float64)
        x, y, th = view.pose
        if not (np.isfinite(P).all() and math.isfinite(x) and math.isfinite(y)):
            return None
        half, w = window_extent(P, self.settings)
        b = self.map_bounds(view.index)
        if b is None:
            return None  # no map extent: the whole map (see above)
        x0, y0, x1, y1 = b
        r = (max(x - half, x0), max(y - half, y0), min(x + half, x1), min(y + half, y1))
        if r[0] >= r[2] or r[1] >= r[3]:
            return None  # the dead reckoning left the map: search all of it
        if (r[2] - r[0]) * (r[3] - r[1]) > 0.5 * max(x1 - x0, 1e-9) * max(y1 - y0, 1e-9):
            return None
        heading = None if w >= math.pi else (th - w, th + w)
        return r, heading

    def recover(self, view: RecoveryView, points: NDArray[np.float64]) -> RecoveryStep:
        lc = view.config.localizer
        # 1. around the dead-reckoned pose first, while it means something (and alongside
        # the global search: a verified local lock is the cheapest way back)
        P = view.covariance
        near = math.sqrt(max(float(P[0, 0] + P[1, 1]), 0.0)) <= self.local.max_radius
        local = self.local.recover(view, points) if near else RecoveryStep("searching")
        if local.lock is not None:
            self.reset()
            return local
        # a dead-reckoned pose that means something bounds the global search and backs a
        # leader there; a tracker restricted by its caller (region, heading) keeps its
        # restriction
        rel0 = self._relocalizer
        own = rel0 is not None and (rel0.region is not None or rel0.heading is not None)
        near_window = None if own else self.window(view)
        early = view.lost_scans <= lc.local_recovery_scans
        if (near and early) or not self._ready(view):
            self.state = local.state
            return local
        # 2. the multi-hypothesis tracker over the window or the whole map, throttled
        rel = self.relocalizer
        rel.expect(view.hit_reference * lc.verify_hit_fraction)
        n, stamp = view.scans_processed, view.stamp
        prior = (view.pose, np.asarray(view.covariance)) if near_window is not None else None
        every, interval = lc.global_search_every, lc.global_search_interval

        def due(last: tuple[int, float] | None, scans: float, secs: float) -> bool:
            return last is None or (n - last[0] >= scans and not 0.0 <= stamp - last[1] < secs)

        window = None
        if near_window is None:
            # the whole map, throttled (global_search_every scans, global_search_interval s)
            search = rel.scans == 0 or rel.awaiting_verification or due(
                self._last_search, every, interval
            )
        else:
            # the window, throttled as the whole map is (its coarse search is cheap, but
            # refining its seeds costs about as much as a whole-map search's: a window
            # searched on every scan made a lost stretch slower on freiburg-campus 10 cm
            # and relocked no sooner). The whole map once a window search brought no
            # leader (a robot carried off that the lost detector caught before any kidnap
            # check did: its covariance does not say its dead reckoning means nothing), or
            # a throttle period after the local phase, then once in full_search_every
            # throttle periods
            k = self.settings.full_search_every
            if self._last_full is None:
                fruitless = rel.last is not None and rel.last.status != "confirming"
                full = fruitless or view.lost_scans > lc.local_recovery_scans + every
            else:
                full = due(self._last_full, every * k, interval * k)
            search = (
                full
                or rel.scans == 0
                or rel.awaiting_verification
                or due(self._last_search, every, interval)
            )
            window = None if full else near_window
        # (in the background a search is made only when no update is running: one decided
        # while one runs is not made, not counted)
        if search and not (self.background and self._inflight is not None):
            self._last_search = (n, stamp)
            if window is None:
                self._last_full = (n, stamp)
        if view.motion is not None:
            self._motion = compose(self._motion, view.motion)
        if self.background:
            got = self._background_update(rel, points, search, window, prior)
            if got is None:
                return RecoveryStep(self.state or "searching", self._hyps or local.hypotheses)
            res, carry = got
        else:
            motion = self._motion if rel.hypotheses else None
            self._motion = (0.0, 0.0, 0.0)
            res = rel.update(
                points, motion, search=None if search else False, window=window, prior=prior
            )
            carry = None
        self.results.append(res)
        if len(self.results) > 100:
            del self.results[:-100]
        self.state = res.status
        def now(p: Pose) -> Pose:  # a background result's pose, carried to this scan
            return p if carry is None else compose(p, carry)

        hyps = tuple(
            Candidate(now(h.pose), float(h.score), float(h.inlier_ratio)) for h in res.hypotheses
        )
        self._hyps = hyps
        if not res.locked or res.pose is None:
            return RecoveryStep(res.status, hyps or local.hypotheses)
        ok, fit, pose = view.verify(points, now(res.pose))
        if fit is None:
            return RecoveryStep("confirming", hyps)
        if not ok:
            # the localizer's bar is this map's usual fit; a place the map covers worse
            # (another pass, clutter) never reaches it and the robot stayed lost, dead
            # reckoning metres off while the tracker held the right pose (intel 5 cm, bad
            # odometry: 10 scans locked, 1-5 cm off, the dead reckoning 0.5 -> 2.6 m).
            # A lock held one scan longer than a lock needs, on a fit as good as recovery
            # asks for, resumes there degraded: no promise, no dead reckoning
            if not (rel.held_longer_than_needed and float(fit.inlier_ratio) >= lc.recover_inlier_ratio):
                return RecoveryStep("confirming", hyps)
            self.reset()
            return RecoveryStep("locked", hyps, lock=pose, result=fit, verified=False)
        full = self._last_full
        k = self.settings.full_search_every
        searched = full is not None and n - full[0] <= every * k
        self.reset()
        return RecoveryStep("locked", hyps, lock=pose, result=fit, rivals_searched=searched)


    # -- while tracking: the kidnap check (icploc.kidnap) ---------------------------------
    # "elsewhere" needs the tracked pose's score below (1 - relocalize.lost_margin) x the
    # best's, or, for a clean best fit (relocalize.clean_inlier_ratio, few beams through
    # walls), below the best's minus relocalize.clean_margin: a robot carried along a
    # corridor fits its old place well but not cleanly

    def check_pose(
        self,
        index: Any,
        points: NDArray[np.float64],
        tracked: Pose,
        strict: bool = False,
        floored: bool = True,
    ) -> CheckVerdict:
        """One global search: does a distinct pose elsewhere explain ``points`` (robot
        frame) much better than ``tracked``? ``strict`` (checking a fresh lock): any
        distinct pose clearly better than ``tracked`` (by the tracker's dominance margin)
        counts. Touches no localizer state (it may run on a worker thread).

        ``floored`` (the default): the search looks only for poses that could change the
        verdict, those scoring at least the confirming minimum (``strict``: and above
        the tracked pose); its coarse floor is that score times ``_COARSE_PER_FINE`` (a
        coarse score is, as measured, well above a refined pose's score), so it prunes much of
        the tree where nothing fits well (a crowd, a poorly mapped place). A floored
        tracking check that finds no distinct pose above its floor decides from that one
        search (no second, lower one): ``""`` when ``tracked`` is a good fit or a candidate
        near it refines to the confirming minimum, the only place at that level;
        ``"unsure"`` when no place, the tracked one included, reached it. ``floored=False``: the plain search (and its verdicts: ``""`` for no
        distinct pose among its leaves, within ``accept_ratio`` of its best)."""
        if not self.ready(index):
            return CheckVerdict("unsure")
        rel = self.relocalizer
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        pts = pts[np.isfinite(pts).all(axis=1)]
        if pts.shape[0] < 10:
            return CheckVerdict("unsure")
        sub = np.ascontiguousarray(_subsample(pts, rel.config.max_points))
        here = rel.glob.refine(sub, np.array([tracked], dtype=np.float64))[0]
        s_here = rel._score(here)
        floor = None
        if floored:
            good = float(getattr(rel, "_min_score", rel.config.min_score))
            floor = _COARSE_PER_FINE * (max(good, s_here) if strict else good)
            if floor <= self.global_search.min_score:
                floor = None  # no higher than the search's own floor: the plain search
        found = rel.glob.search(pts, rel.region, rel.heading, min_score=floor).candidates
        cands = [c for c in found if rel.glob.distinct(here.pose, c.pose)]
        if not cands and floor is not None and not strict:
            # nothing elsewhere comes near the confirming minimum, so no verdict can be
            # "elsewhere"; whether the tracked place is the one place at that level (its
            # usual share re-based by the trigger) or none is (the trigger backs off) is
            # told by what this search found near it. (The plain search's leaves, down to
            # accept_ratio x its best, told it before at 2-4x this search's cost on the
            # large held-out maps: benches/results/speed.md.)
            near = max((rel._score(c) for c in found), default=0.0)
            if rel._good(s_here, here.inlier_ratio, here.see_through) or near >= good:
                return CheckVerdict("", here=s_here, best=max(s_here, near))
            # (review: reaching the coarse floor alone is no good fit. Only strict checks'
            # verdicts clear a pose, Localizer._clear: this non-strict one never does)
            return CheckVerdict("unsure", here=s_here, best=near)
        if not cands:
            return CheckVerdict("", here=s_here, best=s_here)
        best = max(cands, key=rel._score)
        s_best = rel._score(best)
        pose = (best.pose[0], best.pose[1], wrap_angle(best.pose[2]))
        if not rel._good(s_best, best.inlier_ratio, best.see_through):
            return CheckVerdict("unsure", here=s_here, best=s_best)
        if strict:
            better = s_here < (1.0 - rel._margin(s_best)) * s_best or (
                best.inlier_ratio > here.inlier_ratio + rel.config.inlier_margin
                and s_here < s_best
            )
            return CheckVerdict("elsewhere" if better else "", pose, s_here, s_best)
        # the better pose must be a convincing fit itself (a crowd's outlines fit walls
        # elsewhere somewhat, never well), or the tracked pose contradicted by beams
        # through its walls where the better pose is not
        convincing = best.inlier_ratio >= 0.85 and best.see_through <= 0.25
        contradicted = here.see_through >= 0.15 and best.see_through <= min(
            0.3, 0.5 * here.see_through
        )
        clean = best.inlier_ratio >= self.settings.clean_inlier_ratio and best.see_through <= 0.1
        if not (convincing or contradicted):
            return CheckVerdict("unsure", here=s_here, best=s_best)
        if s_here < (1.0 - self.settings.lost_margin) * s_best or (
            clean and s_here < s_best - self.settings.clean_margin
        ):
            return CheckVerdict("elsewhere", pose, s_here, s_best)
        return CheckVerdict("", here=s_here, best=s_best)

    def _background_update(
        self,
        rel: Relocalizer,
        points: NDArray[np.float64],
        search: bool,
        window: tuple[Sequence[float] | None, tuple[float, float] | None] | None = None,
        prior: tuple[Pose, NDArray[np.float64]] | None = None,
    ) -> tuple[RelocalizeResult, Pose] | None:
        """Run the tracker's update on the worker thread: submit one when none is running,
        collect it once done. Returns (result, motion since its scan) or None."""
        fut = self._inflight
        if fut is None:
            if self._executor is None:
                from concurrent.futures import ThreadPoolExecutor

                self._executor = ThreadPoolExecutor(1, thread_name_prefix="icploc-recovery")
            motion = self._motion if rel.hypotheses else None
            self._motion = (0.0, 0.0, 0.0)
            self._inflight = self._executor.submit(
                rel.update, np.array(points), motion, None if search else False, window, prior
            )
            return None
        if not fut.done():
            return None
        self._inflight = None
        res = fut.result()
        return res, self._motion

    def __del__(self) -> None:
        ex = getattr(self, "_executor", None)
        if ex is not None:
            ex.shutdown(wait=False)


def attach(
    localizer: Any,
    relocalizer: Relocalizer | None = None,
    *,
    background: bool | None = None,
) -> Relocalizer:
    """Plug global relocalization (a :class:`GlobalRelocalization`) into ``localizer`` (an
    :class:`icploc.localizer.Localizer`) as its ``recovery``: while lost it searches around
    the dead-reckoned pose, then the whole map with the multi-hypothesis
    :class:`Relocalizer` (``relocalizer``, default: one over the localizer's map index).
    ``background`` (None: as ``localizer.lost_check`` says) runs its global searches on a
    worker thread. Returns the relocalizer (its ``last`` result is the latest state)."""
    rel = relocalizer or Relocalizer(localizer.index)
    if background is None:
        lc = getattr(getattr(localizer, "config", None), "localizer", None)
        background = getattr(lc, "lost_check", "inline") == "background"
    cfg = getattr(localizer, "config", None)
    localizer.recovery = GlobalRelocalization(
        rel, background=background, config=cfg if isinstance(cfg, LocalizerConfig) else None
    )
    return rel

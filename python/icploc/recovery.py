"""The seam between the localizer and recovery: one protocol, a narrow view, local recovery.

The :class:`~icploc.localizer.Localizer` owns prediction, correction, fusion and status —
and the one lost detector. While it is ``lost`` it calls its recovery strategy once per
scan with a :class:`RecoveryView` (what a strategy may read: the dead-reckoned belief, the
odometry motion since the last call, the map index, the ICP settings, and the
localizer's own :meth:`~RecoveryView.verify`) and the scan's points. The strategy answers a
:class:`RecoveryStep`: its ranked hypotheses, what it is doing (``state``), and — only when
a hypothesis passed ``verify`` on enough consecutive scans — a ``lock``. The localizer
alone then moves its pose there; nothing else writes it.

:class:`LocalRecovery` (here) searches around the dead-reckoned pose within its
uncertainty; :class:`icploc.relocalize.GlobalRelocalization` tries that first and then the
whole map (the default of ``localizer.relocalization: global``). Plug one in with
``Localizer(..., recovery=...)`` or by setting ``localizer.recovery``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from icploc.config import LocalizerConfig, LocalizerSection, RecoverySection
from icploc.se2 import Pose, compose, wrap_angle

__all__ = ["Candidate", "LocalRecovery", "Recovery", "RecoveryStep", "RecoveryView"]


@dataclass(frozen=True)
class Candidate:
    """A ranked pose hypothesis while lost."""

    pose: Pose
    score: float  #: the strategy's score (higher is better; for local recovery: hit share)
    inlier_ratio: float = 0.0
    verified: bool = False  #: passed the localizer's verification on this scan


@dataclass(frozen=True)
class RecoveryView:
    """What a recovery strategy sees of the localizer (read-only)."""

    pose: Pose  #: the dead-reckoned pose (the last verified pose moved on by odometry)
    covariance: NDArray[np.float64]
    motion: Pose | None  #: odometry motion since the previous lost scan (robot frame)
    stamp: float
    scans_processed: int
    lost_scans: int  #: scans since the localizer declared itself lost (1 on the first)
    index: Any  #: the map's MapIndex
    icp_config: Any  #: the localizer's IcpConfig
    config: Any  #: the LocalizerConfig
    #: ``verify(points, pose) -> (ok, IcpResult | None, pose)``: the localizer's own check
    #: of a pose (ICP from it, then the same verification tracking uses)
    verify: Callable[[NDArray[np.float64], Pose], tuple[bool, Any, Pose]]
    #: the share of beams this map's verified fits usually end on walls with (1: unknown)
    hit_reference: float = 1.0


@dataclass(frozen=True)
class RecoveryStep:
    """A strategy's answer for one lost scan."""

    state: str  #: "searching", "confirming", "ambiguous", "locked"
    hypotheses: tuple[Candidate, ...] = ()
    lock: Pose | None = None  #: a verified pose: tracking resumes there
    result: Any = None  #: the IcpResult of the lock (its covariance, inliers)
    #: False: a lock on the strategy's own evidence (it dominated every rival for longer
    #: than a lock needs) that the localizer's verification did not accept: the localizer
    #: resumes there ``degraded``, never ``tracking``, until its own fits verify
    verified: bool = True
    #: True: a whole-map search ran in this lost episode within
    #: ``relocalize.full_search_every`` throttle periods and the lock's hypothesis leads
    #: the rivals the tracker still carries from it (rivals it pruned since were dropped,
    #: not beaten): a verified lock the dead reckoning agrees with, for a dead-reckoned
    #: pose that says something, then gets no fresh whole-map check (the localizer's
    #: strict check of a lock, :meth:`icploc.localizer.Localizer._update_lost`)
    rivals_searched: bool = False


class Recovery(Protocol):
    """A recovery strategy (see the module docstring)."""

    def recover(self, view: RecoveryView, points: NDArray[np.float64]) -> RecoveryStep: ...

    def reset(self) -> None:
        """Forget the current episode (called when the localizer is lost afresh)."""
        ...


#: the defaults (one source: the config models, ``recovery:`` in a config file)
_R = RecoverySection()


@dataclass
class LocalRecovery:
    """Multi-start ICP around the dead-reckoned pose, within its uncertainty (3 sigma,
    ``min_radius`` .. ``max_radius``); a candidate that the localizer verifies and that
    stays put (by odometry) on ``confirm`` scans locks (one scan between that does not
    verify pauses the count, two in a row end it). The settings are the
    ``recovery:`` section's (:class:`icploc.config.RecoverySection`), ``confirm`` is
    ``localizer.recover_after``."""

    confirm: int = LocalizerSection().recover_after
    min_radius: float = _R.min_radius
    max_radius: float = _R.max_radius
    headings: tuple[float, ...] = _R.headings
    #: candidates kept as hypotheses
    keep: int = _R.keep
    _leader: Pose | None = None
    _streak: int = 0
    _missed: bool = False  #: the leader's last scan did not verify
    _hyps: list[Candidate] = field(default_factory=list)

    @classmethod
    def from_config(cls, config: LocalizerConfig | None) -> LocalRecovery:
        """A local recovery with a config's ``recovery:`` settings (the defaults: None)."""
        if config is None:
            return cls()
        return cls(confirm=config.localizer.recover_after, **config.recovery.__dict__)

    def reset(self) -> None:
        self._leader, self._streak, self._hyps, self._missed = None, 0, [], False

    def starts(self, view: RecoveryView) -> list[Pose]:
        p = view.pose
        P = view.covariance
        sig = math.sqrt(max(float(P[0, 0] + P[1, 1]), 0.0))
        r = min(max(3.0 * sig, self.min_radius), self.max_radius)
        out: list[Pose] = []
        rings = [0.0, 0.5 * r, r] if r > 0.5 else [0.0, r]
        for rad in rings:
            dirs = (
                [(0.0, 0.0)]
                if rad == 0.0
                else [
                    (rad * math.cos(a), rad * math.sin(a))
                    for a in np.linspace(0, 2 * math.pi, 8, endpoint=False)
                ]
            )
            for dx, dy in dirs:
                for dth in self.headings:
                    out.append((p[0] + dx, p[1] + dy, wrap_angle(p[2] + dth)))
        return out

    def recover(self, view: RecoveryView, points: NDArray[np.float64]) -> RecoveryStep:
        from icploc._core import IcpError, icp_batch

        if self._leader is not None and view.motion is not None:
            self._leader = compose(self._leader, view.motion)
        starts = self.starts(view)
        try:
            results = icp_batch(
                [points], view.index, np.asarray(starts, dtype=np.float64), view.icp_config
            )
        except IcpError:
            return RecoveryStep("searching", tuple(self._hyps))
        ranked = sorted(
            (r for r in results if all(math.isfinite(v) for v in r.pose)),
            key=lambda r: (r.inlier_ratio, -r.mse),
            reverse=True,
        )
        hyps: list[Candidate] = []
        for r in ranked:
            pz = (r.pose[0], r.pose[1], wrap_angle(r.pose[2]))
            if any(_close(pz, h.pose) for h in hyps):
                continue
            hyps.append(Candidate(pz, float(r.inlier_ratio), float(r.inlier_ratio)))
            if len(hyps) >= self.keep:
                break
        if not hyps:
            self._leader, self._streak, self._hyps = None, 0, []
            return RecoveryStep("searching")
        ok, res, pose = view.verify(points, hyps[0].pose)
        hyps[0] = Candidate(pose, hyps[0].score, hyps[0].inlier_ratio, ok)
        self._hyps = hyps
        if not ok:
            # one scan that does not verify (a crowd, a poor scan on a map from another
            # pass) pauses the streak; two in a row end it
            if self._missed or self._leader is None:
                self._leader, self._streak, self._missed = None, 0, False
            else:
                self._missed = True
            return RecoveryStep("searching", tuple(hyps))
        if self._leader is not None and _close(pose, self._leader):
            self._streak += 1
        else:
            self._streak = 1
        self._leader = pose
        self._missed = False
        if self._streak >= self.confirm:
            self.reset()
            return RecoveryStep("locked", tuple(hyps), lock=pose, result=res)
        return RecoveryStep("confirming", tuple(hyps))


def _close(a: Pose, b: Pose, dist: float = 0.15, ang: float = math.radians(5.0)) -> bool:
    return math.hypot(a[0] - b[0], a[1] - b[1]) <= dist and abs(wrap_angle(a[2] - b[2])) <= ang

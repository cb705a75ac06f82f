"""Kidnap detection while tracking: a cheap per-scan trigger and a throttled global check.

A robot carried somewhere else (a kidnapping, a bad restart, a wrong lock) usually makes
the scan contradict the pose, and the localizer's lost detector sees it. But a place that
looks a little like the true one (the same corridor further on, the next office) can keep
fitting half well and pass verification. No global search runs on every tracking scan
(real replays must stay fast); instead :class:`KidnapTrigger` watches what the localizer
computes anyway and asks for one global check (one search over the whole map, on the
worker thread with ``localizer.lost_check: background``) when

* the verification's hit share stays below ``doubt`` x this run's usual share (the
  average of its recent ordinary scans), the beams that hit not fitting tightly (a crowd
  hides walls, the rest fit as usual), or the fit is rejected, for ``doubt_scans`` scans
  in a row;
* the fit contradicted the odometry (the scans were taken against the prediction with a
  chi-square statistic beyond the rejection quantile: a jump the odometry cannot have made);
* the localizer has just locked after being lost (a stricter check of the lock).

The check is :meth:`icploc.relocalize.GlobalRelocalization.check_pose` (any recovery with a
``check_pose`` method): does a distinct pose elsewhere explain the scan much better than
the tracked one? A check that finds nothing backs the trigger off (quiet for
``doubt_scans`` x 2^k scans, at most ``backoff_max``); a tracked pose that explains the scan
as well as anything re-bases the usual share. What the localizer does with a verdict is its
own business (:meth:`icploc.localizer.Localizer._kidnap_step`).
"""

from __future__ import annotations

from dataclasses import dataclass

from icploc.config import KidnapSection
from icploc.se2 import Pose

__all__ = ["CheckVerdict", "KidnapTrigger"]


@dataclass(frozen=True)
class CheckVerdict:
    """A global check of a tracked pose.

    ``verdict``: ``""`` (the tracked pose explains the scan as well as any), ``"unsure"`` (no
    convincing pose anywhere: a crowd, an unmapped place) or ``"elsewhere"`` (``pose``, a
    distinct place, explains it much better); ``here`` / ``best``: the scores of the tracked
    pose and of the search's best pose (``"unsure"``: the best the check's floored search
    kept, below the confirming minimum; 0 when no place reached its floor)."""

    verdict: str
    pose: Pose | None = None
    here: float = 0.0
    best: float = 0.0


#: the defaults (one source: the config model, ``kidnap:`` in a config file)
_K = KidnapSection()


@dataclass
class KidnapTrigger:
    """When to run a global check while tracking (see the module docstring); the settings
    are the ``kidnap:`` section's (:class:`icploc.config.KidnapSection`)."""

    doubt: float = _K.doubt
    doubt_scans: int = _K.doubt_scans
    #: a fit taken far against the odometry is checked when its hit share is below this
    #: fraction of the map's usual (verified fits') share
    doubt_jump: float = _K.doubt_jump
    #: a better pose elsewhere is re-checked this many scans later; it must be found
    #: again within ``recheck_distance`` m and ``recheck_angle`` rad of where the odometry
    #: carried it
    recheck_scans: int = _K.recheck_scans
    recheck_distance: float = _K.recheck_distance
    recheck_angle: float = _K.recheck_angle
    #: the usual share: the mean of the ordinary scans, over about this many recent ones
    #: (an exponential average: O(1) per scan); ``history`` calm scans also end a backoff
    history: int = _K.history
    backoff_max: int = _K.backoff_max
    _ref: float = 0.0
    _n: int = 0  #: ordinary scans in the usual share (none: no reference yet)
    _doubtful: int = 0
    _quiet: int = 0
    _backoffs: int = 0
    _calm: int = 0

    @classmethod
    def from_config(cls, settings: KidnapSection) -> KidnapTrigger:
        """A trigger with a config's ``kidnap:`` settings."""
        return cls(**settings.__dict__)

    def reset(self) -> None:
        """Forget the usual share (a new place: after a lock, a reset)."""
        self._n = 0
        self._doubtful = 0
        self._quiet = 0

    def reference(self) -> float | None:
        """The usual hit share of the recent ordinary scans (None: fewer than 3 so far)."""
        return self._ref if self._n >= 3 else None

    def observe(
        self, hit: float, accepted: bool, jumped: bool = False, tight: bool = False
    ) -> bool:
        """One tracking scan: its verification hit share, whether its fit was accepted,
        whether it was taken far against the odometry, whether the beams that hit fit as
        tightly as usual (people hiding walls: a low share is no doubt then). True: run a
        check now."""
        low = self._n >= 3 and hit < self.doubt * self._ref
        if jumped or not accepted or (low and not tight):
            self._doubtful += 1
            self._calm = 0
        else:
            self._doubtful = 0
            self._calm += 1
            if self._calm >= self.history:
                self._backoffs = 0
            self._n += 1
            self._ref += (hit - self._ref) / min(self._n, self.history)
        if self._quiet > 0:
            self._quiet -= 1
            return False
        if jumped or self._doubtful >= self.doubt_scans:
            self._doubtful = 0
            return True
        return False

    def confirmed(self) -> None:
        """The check found the tracked pose as good as any: its share is the new usual
        (and the trigger keeps quiet a while, as after an unsure check: a place the map
        shows poorly keeps looking doubtful)."""
        self._n = 0
        self.backoff()

    def backoff(self) -> None:
        """The check could not tell: keep quiet a while (longer each time)."""
        self._doubtful = 0
        self._quiet = min(self.backoff_max, self.doubt_scans * 2**self._backoffs)
        self._backoffs += 1

"""The localizer's status and the reasons it gives, as string enums.

Both compare equal to their strings (``Status.TRACKING == "tracking"``) and print, format
and write to CSV as them, so code and files that used the plain strings are unchanged.
"""

from __future__ import annotations

import sys
from enum import Enum

__all__ = ["LOCK_REASONS", "Reason", "Status"]

if sys.version_info >= (3, 11):
    from enum import StrEnum as _StrEnum
else:  # pragma: no cover - Python 3.10

    class _StrEnum(str, Enum):
        def __str__(self) -> str:
            return str(self.value)

        def __format__(self, spec: str) -> str:
            return str(self.value).__format__(spec)


class Status(_StrEnum):
    """What an :class:`~icploc.localizer.Estimate` promises."""

    TRACKING = "tracking"  #: the pose is verified and tight: a promise
    DEGRADED = "degraded"  #: a pose, not promised (see the reason)
    LOST = "lost"  #: dead-reckoned while the recovery searches


class Reason(_StrEnum):
    """Why a scan is not ``tracking``, or what happened (``NONE``: tracking on a plain fit).
    While lost the recovery's state (searching, confirming, ambiguous) is the reason."""

    NONE = ""
    TOO_FEW_POINTS = "too_few_points"
    ICP_FAILED = "icp_failed"
    LOW_INLIER_RATIO = "low_inlier_ratio"
    NOT_CONVERGED = "not_converged"
    JUMP = "jump"  #: a correction beyond the hard caps
    INCONSISTENT = "inconsistent"  #: chi-square rejected
    INFLATED = "inflated"  #: chi-square: the measurement inflated until consistent
    #: chi-square failed but the map (or several scans agreeing) prefer the scan pose
    ODOMETRY_OFF = "odometry_off"
    CONTRADICTED = "contradicted"  #: the fused pose explains far less of the scan than usual
    #: the prediction an ``odometry_off`` fit overruled still verifies (a rival pose)
    DISPUTED = "disputed"
    #: the rival (the prediction an ``odometry_off`` fit overruled) explained the scan
    #: clearly better than the pose, its own fit verified: the pose went back to it (then
    #: ``unsettled`` as after any jump)
    REVERTED = "reverted"
    UNVERIFIED = "unverified"
    UNCERTAIN = "uncertain"  #: verified, but the covariance is too wide to promise
    #: a weakly constrained fit (degeneracy below 0.1: a corridor) right after a stretch
    #: that was not ``tracking`` (up to ``dispute_scans`` of them in a row): it does not pin
    #: the pose along its weak direction
    UNCONSTRAINED = "unconstrained"
    #: a pose that has not settled since an ``odometry_off`` jump, an ``inflated`` fit that
    #: moved it farther than the map can tell apart (or came right after another), or the
    #: first verified fit after a stretch without one: ``settle_scans`` verified scans in a
    #: row have not yet explained the scan at least as well as the map's usual hit share
    #: from before
    UNSETTLED = "unsettled"
    RELOCALIZED = "relocalized"
    #: a lock the recovery took on its own evidence (its leader held longer than a lock
    #: needs) that the localizer's verification refused: resumed ``degraded``, then
    #: ``unsettled`` until its own fits verify at the map's usual share
    LOCK_UNVERIFIED = "lock_unverified"
    SUSPECT = "suspect"  #: a kidnap check is out, or found a better pose to re-check
    UNCONFIRMED = "unconfirmed"  #: a lock whose strict check is out
    ELSEWHERE = "elsewhere"  #: the check found the better pose again: lost
    REFUTED = "refuted"  #: a lock a distinct pose beats: still lost
    LOST = "lost"
    SEARCHING = "searching"
    CONFIRMING = "confirming"
    AMBIGUOUS = "ambiguous"
    LOCKED = "locked"
    #: the scan lies outside the mapped area: coasted on odometry (``--partial-map``)
    OUTSIDE_MAP = "outside_map"
    #: back on the map, dead-reckoned while the re-entry search runs
    REENTERING = "reentering"
    #: the scan, matched as usual, still lies mostly outside the mapped area at the pose
    #: found (the scans before a stretch outside it begins: ``outside.enter_scans``, the
    #: sudden exit's wait): not promised (``--partial-map``)
    LEAVING_MAP = "leaving_map"
    #: the start pose is being refined from stationary scans
    REFINING_START = "refining_start"


#: the reasons of a scan the recovery locked on (the re-entry into the map: a stretch
#: outside it ends there), as plain strings so a reason string or a :class:`Reason` matches
LOCK_REASONS: frozenset[str] = frozenset({Reason.RELOCALIZED.value, Reason.LOCK_UNVERIFIED.value})

"""Remember the last verified pose across restarts (``icploc run --state FILE``).

:class:`StateSaver` writes the last *tracking* estimate (pose and covariance) to a small
JSON file, at most every ``every`` seconds of scan time and once more at the end, always
atomically (a temporary file in the same directory, fsync, ``os.replace``): a crash or a
power cut leaves the previous state or the new one, never half a file.

:func:`restore` puts a saved state into a :class:`~icploc.localizer.Localizer` without
trusting it: the localizer starts ``lost`` at the saved pose, and its first usable scan is
matched by one ICP from there (a :class:`SavedStateCheck` plugged in as its
``recovery``). A pose the localizer verifies close to the saved one is taken at once
(tracking from the first scan, reason ``"relocalized"``); anything else hands over to the
strategy the localizer had (global localization by default) on that same scan.

State file (version 1)::

    {"format": "icploc-state", "version": 1, "stamp": 12.3, "saved_at": 1764601234.5,
     "pose": [x, y, theta], "covariance": [[...], [...], [...]], "status": "tracking",
     "map": "lab.yaml"}
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.errors import FileFormatError
from icploc.localizer import Estimate, Localizer, Status
from icploc.recovery import Candidate, RecoveryStep, RecoveryView
from icploc.se2 import Pose, wrap_angle

__all__ = [
    "SavedState",
    "SavedStateCheck",
    "StateError",
    "StateSaver",
    "load_state",
    "restore",
    "save_state",
]

FORMAT = "icploc-state"
VERSION = 1
#: the first scan's ICP from the saved pose must land within this of it to be trusted
#: (m, rad): a robot pushed further while switched off is localized globally instead
MAX_CORRECTION_XY = 0.5
MAX_CORRECTION_THETA = 0.35


class StateError(FileFormatError):
    """A state file that cannot be read (the message names the file and the field)."""

    def __init__(self, message: str, path: str | os.PathLike[str] | None = None) -> None:
        self._where(path, None, message)


@dataclass(frozen=True)
class SavedState:
    pose: Pose
    covariance: NDArray[np.float64]
    stamp: float  #: scan stamp of the estimate saved
    saved_at: float = math.nan  #: wall-clock time of the save (time.time())
    map: str = ""  #: the map's source, when known

    def to_json(self) -> str:
        return json.dumps(
            {
                "format": FORMAT,
                "version": VERSION,
                "stamp": self.stamp,
                "saved_at": self.saved_at,
                "pose": list(self.pose),
                "covariance": np.asarray(self.covariance, dtype=float).tolist(),
                "status": "tracking",
                "map": self.map,
            }
        )


def _map_source(localizer: Localizer) -> str:
    src = getattr(localizer.map, "source", None)
    return str(src) if src else ""


def write_state(path: str | Path, state: SavedState) -> Path:
    """Write ``state`` to ``path`` atomically (temporary file + fsync + ``os.replace``)."""
    p = Path(path)
    d = p.parent if str(p.parent) else Path(".")
    fd, tmp = tempfile.mkstemp(prefix=f".{p.name}.", suffix=".tmp", dir=d)
    try:
        with os.fdopen(fd, "w") as f:
            f.write(state.to_json())
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, p)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise
    return p


def save_state(
    localizer: Localizer, path: str | Path, estimate: Estimate | None = None
) -> SavedState | None:
    """Save ``estimate`` (default: the localizer's last one) if it is ``tracking``;
    returns what was saved, or None (nothing verified to save: the file is left as it was)."""
    e = estimate if estimate is not None else localizer.last_estimate
    if e is None or e.status is not Status.TRACKING:
        return None
    st = SavedState(
        pose=(float(e.pose[0]), float(e.pose[1]), float(e.pose[2])),
        covariance=np.array(e.covariance, dtype=np.float64).reshape(3, 3),
        stamp=float(e.stamp),
        saved_at=time.time(),
        map=_map_source(localizer),
    )
    write_state(path, st)
    return st


def load_state(path: str | Path) -> SavedState:
    """Read a state file; a clear :class:`StateError` naming the file and field otherwise."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text())
    except OSError as e:
        raise StateError(f"{p}: cannot read the state file ({e.strerror or e})") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise StateError(f"{p}: not a state file (invalid JSON: {e})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise StateError(f'{p}: not an icploc state file (no "format": "{FORMAT}")')
    if doc.get("version") != VERSION:
        raise StateError(f"{p}: state file version {doc.get('version')!r}, expected {VERSION}")
    try:
        pose = tuple(float(v) for v in doc["pose"])
    except (KeyError, TypeError, ValueError):
        raise StateError(f"{p}: field 'pose' must be [x, y, theta]") from None
    if len(pose) != 3 or not all(math.isfinite(v) for v in pose):
        raise StateError(f"{p}: field 'pose' must be three finite numbers, got {doc['pose']!r}")
    try:
        cov = np.array(doc["covariance"], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise StateError(f"{p}: field 'covariance' must be a 3x3 matrix of numbers") from None
    if cov.shape != (3, 3) or not np.isfinite(cov).all():
        raise StateError(f"{p}: field 'covariance' must be a finite 3x3 matrix")
    if not np.allclose(cov, cov.T, atol=1e-12) or np.linalg.eigvalsh(cov).min() < -1e-12:
        raise StateError(f"{p}: field 'covariance' is not symmetric positive semi-definite")
    try:
        stamp = float(doc.get("stamp", math.nan))
        saved_at = float(doc.get("saved_at", math.nan))
    except (TypeError, ValueError):
        raise StateError(f"{p}: fields 'stamp' / 'saved_at' must be numbers") from None
    return SavedState(
        pose=(pose[0], pose[1], wrap_angle(pose[2])),
        covariance=cov,
        stamp=stamp,
        saved_at=saved_at,
        map=str(doc.get("map", "")),
    )


class StateSaver:
    """Feed it every estimate (``observe``); it saves the latest tracking one to ``path``
    at most every ``every`` seconds of scan time, and on :meth:`close` (also as a context
    manager). A failed write is reported once through ``on_error`` (default: a warning)
    and retried at the next save: a full disk never stops the localizer."""

    def __init__(
        self,
        localizer: Localizer,
        path: str | Path,
        every: float = 1.0,
        on_error: Any = None,
    ) -> None:
        if not every >= 0.0:
            raise ValueError(f"StateSaver: every must be >= 0 s, got {every}")
        self.localizer = localizer
        self.path = Path(path)
        self.every = float(every)
        self.on_error = on_error
        self.saves = 0
        self._last_saved: float | None = None
        self._pending: Estimate | None = None
        self._error_reported = False

    def _save(self, e: Estimate) -> None:
        try:
            save_state(self.localizer, self.path, e)
        except OSError as err:
            if not self._error_reported:
                self._error_reported = True
                msg = f"{self.path}: cannot save the state ({err.strerror or err})"
                if self.on_error is not None:
                    self.on_error(msg)
                else:
                    import warnings

                    warnings.warn(msg, RuntimeWarning, stacklevel=3)
            return
        self.saves += 1
        self._last_saved = e.stamp
        self._pending = None

    def observe(self, e: Estimate) -> None:
        if e.status is not Status.TRACKING:
            return
        self._pending = e
        if self._last_saved is None or not 0.0 <= e.stamp - self._last_saved < self.every:
            self._save(e)

    def close(self) -> None:
        if self._pending is not None:
            self._save(self._pending)

    def __enter__(self) -> StateSaver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class SavedStateCheck:
    """A :class:`icploc.recovery.Recovery` that checks a restored pose once: the
    localizer's own verification (ICP, then the checks tracking uses) of the first usable
    scan from the saved pose (moved on by odometry), trusted only when it verifies and lands
    close to the saved pose; then (or at once, on a bad fit) the localizer's previous
    strategy takes over, searching as if no pose had been given."""

    def __init__(self, localizer: Localizer, inner: Any) -> None:
        self._loc = localizer
        self.inner = inner
        self.verdict = ""  #: "" (not checked yet), "accepted" or "rejected"
        self.fit: Any = None

    @property
    def state(self) -> str:
        if not self.verdict:
            return "checking saved pose"
        return str(getattr(self.inner, "state", "") or "")

    def reset(self) -> None:
        if self.inner is not None:
            self.inner.reset()

    def _hand_over(self) -> None:
        if self._loc.recovery is self:
            self._loc.recovery = self.inner

    def recover(self, view: RecoveryView, points: NDArray[np.float64]) -> RecoveryStep:
        start = view.pose  # the saved pose, moved on by odometry since the start
        ok, fit, pose = view.verify(points, start)
        self.fit = fit
        ok = (
            ok
            and fit is not None
            and math.hypot(pose[0] - start[0], pose[1] - start[1]) <= MAX_CORRECTION_XY
            and abs(wrap_angle(pose[2] - start[2])) <= MAX_CORRECTION_THETA
        )
        self.verdict = "accepted" if ok else "rejected"
        self._hand_over()
        if ok:
            ratio = float(fit.inlier_ratio)
            hyp = Candidate(pose, score=ratio, inlier_ratio=ratio, verified=True)
            return RecoveryStep("locked", (hyp,), lock=pose, result=fit)
        # not where we saved it: search as if no pose had been given, from this scan on
        wide = dataclasses.replace(view, covariance=np.diag([1e6, 1e6, math.pi**2]))
        if self.inner is not None:
            return self.inner.recover(wide, points)  # type: ignore[no-any-return]
        return RecoveryStep("searching")


def restore(localizer: Localizer, state: SavedState | str | Path) -> SavedStateCheck:
    """Start ``localizer`` from a saved state, to be checked on the first scan (see the
    module doc). Returns the check (its ``verdict`` says what the first scan found)."""
    st = state if isinstance(state, SavedState) else load_state(state)
    # the recovery as the reset leaves it (a reset while re-entering the map gives the
    # localizer its own recovery back: icploc.outside.OutsideMonitor.on_reset)
    localizer.reset(st.pose, st.covariance, Status.LOST)
    inner = localizer.recovery
    if isinstance(inner, SavedStateCheck):
        inner = inner.inner
    check = SavedStateCheck(localizer, inner)
    localizer.recovery = check
    return check

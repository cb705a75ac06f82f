"""Shared pieces of the log readers: the error type, the summary record, the loaded-log
container, and the deterministic timestamp repair every reader applies."""

from __future__ import annotations

import math
import os
import sys
from bisect import bisect_right
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.errors import FileFormatError
from icploc.messages import Odometry, Scan
from icploc.trajectory import Trajectory


class _Log:
    """``logging.getLogger("icploc.logs")``, imported on first use: the readers log a line
    at INFO per log, which nobody can see in a process that has not imported ``logging``
    (no handler set, the default level WARNING), so such a process does not import it
    (~2 ms of a replay's start) for them."""

    def info(self, msg: str, *args: object) -> None:
        if "logging" in sys.modules:
            self._logger().info(msg, *args)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._logger(), name)

    @staticmethod
    def _logger() -> Any:
        import logging

        return logging.getLogger("icploc.logs")


log = _Log()

__all__ = [
    "FORMATS",
    "Damage",
    "LogFormat",
    "LogData",
    "LogFormatError",
    "LogInfo",
    "StampRepair",
    "repair_stamps",
]


class LogFormatError(FileFormatError):
    """A log file is malformed. ``path`` and (for text logs) ``line`` say where."""

    path: str


@dataclass
class LogInfo:
    """What a log holds, and what the reader had to do to it."""

    path: str
    format: str  #: "carmen", "rosbag1", "rosbag2", "recorded"
    n_scans: int = 0
    n_odometry: int = 0
    beams: tuple[int, ...] = ()  #: distinct beam counts
    angle_min: float = math.nan
    angle_max: float = math.nan
    max_range: float = math.inf  #: readings at or beyond this are no-return (inf)
    start: float = math.nan
    end: float = math.nan
    stamps: str = "ok"  #: "ok", "repaired" or "synthetic"
    stamp_note: str = ""  #: human-readable account of what was done to the stamps
    n_repaired_stamps: int = 0
    has_truth: bool = False  #: the log carries a reported (corrected / true) pose per scan
    skipped: dict[str, int] = field(default_factory=dict)  #: unknown message types → count
    #: malformed lines / messages the reader skipped (torn, garbage, wrong counts, NaN poses)
    n_dropped: int = 0
    #: the first :data:`MAX_REPORTED` of them: (line number or None, reason)
    dropped: list[tuple[int | None, str]] = field(default_factory=list)
    #: impossible readings turned into invalid beams, by kind ("NaN", "negative", ...)
    invalid_readings: dict[str, int] = field(default_factory=dict)
    topics: dict[str, str] = field(default_factory=dict)  #: bag topics used → message type
    notes: list[str] = field(default_factory=list)

    @property
    def duration(self) -> float:
        return self.end - self.start if self.n_scans else 0.0

    def summary(self) -> str:
        beams = "/".join(str(b) for b in self.beams) or "-"
        lines = [
            f"{self.path} [{self.format}]",
            f"  scans {self.n_scans} × {beams} beams, "
            f"angles {math.degrees(self.angle_min):.2f}°..{math.degrees(self.angle_max):.2f}°, "
            f"max range {self.max_range:g} m",
            f"  odometry {self.n_odometry}, truth {'yes' if self.has_truth else 'no'}",
            f"  time {self.start:.3f} .. {self.end:.3f} ({self.duration:.1f} s), stamps {self.stamps}"
            + (f": {self.stamp_note}" if self.stamp_note else ""),
        ]
        if self.topics:
            lines.append("  topics " + ", ".join(f"{k} ({v})" for k, v in self.topics.items()))
        if self.skipped:
            lines.append(
                "  skipped " + ", ".join(f"{k}×{v}" for k, v in sorted(self.skipped.items()))
            )
        lines.extend(self.damage_lines())
        lines.extend(f"  note: {n}" for n in self.notes)
        return "\n".join(lines)

    def damage_lines(self) -> list[str]:
        """What the reader dropped or repaired, one line per kind ([] for a clean log)."""
        out = []
        if self.n_dropped:
            first = "; ".join(
                (f"line {ln}: {why}" if ln is not None else why) for ln, why in self.dropped
            )
            more = f" (first {len(self.dropped)}: {first})" if self.dropped else ""
            out.append(f"  dropped {self.n_dropped} malformed line(s){more}")
        if self.invalid_readings:
            out.append(
                "  invalid readings (beams not used): "
                + ", ".join(f"{k} {v}" for k, v in sorted(self.invalid_readings.items()))
            )
        if self.n_repaired_stamps and self.stamps == "repaired":
            out.append(f"  repaired {self.n_repaired_stamps} stamp(s): {self.stamp_note}")
        return out


#: how many dropped lines a :class:`LogInfo` keeps (with their line numbers) for the summary
MAX_REPORTED = 10


class Damage:
    """Collects what a reader could not use. Lenient (default): a malformed line is
    skipped and counted, an impossible reading becomes an invalid beam and is counted.
    ``strict``: the first of either raises :class:`LogFormatError` instead."""

    def __init__(self, path: str | os.PathLike[str], strict: bool = False) -> None:
        self.path = os.fspath(path)
        self.strict = strict
        self.n_dropped = 0
        self.dropped: list[tuple[int | None, str]] = []
        self.invalid: dict[str, int] = {}

    def drop(self, err: LogFormatError) -> None:
        """A malformed line or message: raise when strict, else count it."""
        if self.strict:
            raise err
        self.n_dropped += 1
        if len(self.dropped) < 100_000:  # sorted by line, then cut to MAX_REPORTED
            self.dropped.append((err.line, err.reason))

    def readings(self, kind: str, n: int, line: int | None, example: float) -> None:
        """``n`` impossible readings of ``kind`` (first on ``line``)."""
        if n <= 0:
            return
        if self.strict:
            raise LogFormatError(self.path, f"{kind} range reading {example!r}", line)
        self.invalid[kind] = self.invalid.get(kind, 0) + n

    def fill(self, info: LogInfo) -> LogInfo:
        info.n_dropped = self.n_dropped
        info.dropped = sorted(self.dropped, key=lambda d: (d[0] is None, d[0] or 0))[:MAX_REPORTED]
        info.invalid_readings = dict(self.invalid)
        if self.n_dropped:
            log.info("%s: dropped %d malformed line(s)", self.path, self.n_dropped)
        return info


@dataclass
class LogData:
    """A whole log in memory: scans, odometry, optional reported poses, and the summary.

    ``truth_stamps`` / ``truth_poses`` (N, 3) are the pose the log reports with each scan
    (CARMEN's corrected laser pose); they are empty when the log has none. ``scan_odometry``
    (N, 3) is the odometry the log writes with each scan, if any. Iterating yields
    the scans and odometry merged in time order (odometry first on equal stamps).
    """

    info: LogInfo
    scans: list[Scan]
    odometry: list[Odometry]
    truth_stamps: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))
    truth_poses: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    #: the odometry pose written with each scan (CARMEN FLASER ``odom_*`` / ROBOTLASER1
    #: robot pose), (N, 3) aligned with ``scans``; empty when the format has none
    scan_odometry: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))

    def __iter__(self) -> Iterator[Scan | Odometry]:
        return merge_in_time(self.scans, self.odometry)

    def __len__(self) -> int:
        return len(self.scans) + len(self.odometry)

    def truth(self) -> Trajectory | None:
        """The pose the log reports with each scan, as a trajectory (None if it has none)."""
        if len(self.truth_stamps) == 0:
            return None
        return Trajectory(self.truth_stamps, self.truth_poses)

    def odometry_trajectory(self) -> Trajectory:
        """The odometry stream as a trajectory (in the odometry frame)."""
        st, ps = self.odometry_arrays()
        return Trajectory(st, ps)

    def odometry_arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Odometry as (stamps (M,), poses (M, 3))."""
        if not self.odometry:
            return np.zeros(0), np.zeros((0, 3))
        st = np.fromiter((o.stamp for o in self.odometry), np.float64, len(self.odometry))
        ps = np.array([o.pose for o in self.odometry], dtype=np.float64)
        return st, ps


def merge_in_time(scans: list[Scan], odometry: list[Odometry]) -> Iterator[Scan | Odometry]:
    """Stable merge of two time-sorted lists; odometry goes first on equal stamps."""
    i = j = 0
    ns, no = len(scans), len(odometry)
    while i < ns or j < no:
        if j < no and (i >= ns or odometry[j].stamp <= scans[i].stamp):
            yield odometry[j]
            j += 1
        else:
            yield scans[i]
            i += 1


@dataclass(frozen=True)
class StampRepair:
    stamps: NDArray[np.float64]
    status: str  #: "ok", "repaired", "synthetic"
    note: str
    n_changed: int


def _longest_nondecreasing(t: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Mask of one longest non-decreasing subsequence (deterministic: patience sorting)."""
    n = len(t)
    tails: list[float] = []
    tail_idx: list[int] = []
    prev = np.full(n, -1, dtype=np.int64)
    for i in range(n):
        v = float(t[i])
        k = bisect_right(tails, v)
        if k == len(tails):
            tails.append(v)
            tail_idx.append(i)
        else:
            tails[k] = v
            tail_idx[k] = i
        prev[i] = tail_idx[k - 1] if k > 0 else -1
    keep = np.zeros(n, dtype=bool)
    i = tail_idx[-1] if tail_idx else -1
    while i >= 0:
        keep[i] = True
        i = int(prev[i])
    return keep


def _count_distinct(a: NDArray[np.float64]) -> int:
    """``len(np.unique(a))`` (NaNs count as one value) without ``np.unique``, whose check
    for a masked array imports ``numpy.ma`` (~25 ms of a replay's start)."""
    nan = np.isnan(a)
    s = np.sort(a[~nan])
    distinct = int(np.count_nonzero(s[1:] != s[:-1])) + 1 if len(s) else 0
    return distinct + int(nan.any())


def repair_stamps(
    stamps: NDArray[np.float64],
    is_scan: NDArray[np.bool_],
    *,
    mode: str = "auto",
    period: float = 0.1,
    min_kept: float = 0.9,
    min_distinct: float = 0.9,
) -> StampRepair:
    """Make the stamps of all messages of a log (in file order) usable, deterministically.

    ``mode``: ``"raw"`` keeps them as they are; ``"index"`` always uses scan index ×
    ``period``; ``"auto"``:

    * a stamp that is exactly 0 or not finite is *missing*;
    * of the scans with a stamp, the longest non-decreasing run (in file order) is kept and
      the others are *out of order*;
    * if fewer than ``min_kept`` of the scans keep a stamp, or the kept scan stamps have
      fewer than ``min_distinct`` distinct values (rounded or frozen clocks), the stamps are
      unusable and every message gets a *synthetic* stamp: scan k at k × ``period``, the
      other messages spread evenly by file position between the scans around them;
    * otherwise missing and out-of-order scan stamps, and missing odometry stamps, are
      replaced by linear interpolation over file position between the good neighbours
      (held constant beyond the ends). Odometry stamps that are present are kept even when
      they are not in file order (odometry often arrives with jitter): the caller sorts.

    Scan stamps come out non-decreasing in file order in all modes but ``raw``.
    """
    t = np.asarray(stamps, dtype=np.float64)
    sc = np.asarray(is_scan, dtype=bool)
    n = len(t)
    n_scans = int(sc.sum())
    if n == 0:
        return StampRepair(t.copy(), "ok", "", 0)
    if mode == "raw":
        return StampRepair(t.copy(), "ok", "raw stamps, not checked", 0)
    if mode not in ("auto", "index"):
        raise ValueError(f"timestamps mode must be 'auto', 'raw' or 'index', got {mode!r}")

    reason = ""
    if mode == "index":
        reason = "index stamps requested"
    else:
        present = np.isfinite(t) & (t != 0.0)
        scan_idx = np.flatnonzero(sc & present)
        keep = present & ~sc  # odometry with a stamp is good as it is
        keep[scan_idx[_longest_nondecreasing(t[scan_idx])]] = True
        kept_scans = keep & sc
        n_kept_scans = int(kept_scans.sum())
        n_missing_scans = int((~present & sc).sum())
        if n_scans and n_kept_scans < min_kept * n_scans:
            if n_missing_scans >= 0.5 * n_scans:
                reason = f"{n_missing_scans} of {n_scans} scan stamps are zero or missing"
            else:
                reason = f"{n_scans - n_kept_scans} of {n_scans} scan stamps are out of order"
        elif n_scans > 1:
            n_distinct = _count_distinct(t[kept_scans])
            if n_distinct < min_distinct * n_kept_scans:
                reason = (
                    f"only {n_distinct} distinct stamps for {n_kept_scans} scans "
                    f"(rounded or frozen clock)"
                )
        elif n_scans == 0 and not present.any():
            reason = "no message has a stamp"
        if not reason:
            bad = ~keep
            n_bad = int(bad.sum())
            if n_bad == 0:
                return StampRepair(t.copy(), "ok", "", 0)
            pos = np.arange(n, dtype=np.float64)
            good = np.flatnonzero(keep)
            out = t.copy()
            # interpolate scans from scans only, so they stay monotone
            bad_sc = bad & sc
            if bad_sc.any():
                gs = np.flatnonzero(kept_scans)
                out[bad_sc] = np.interp(pos[bad_sc], pos[gs], t[gs])
            bad_od = bad & ~sc
            if bad_od.any():
                out[bad_od] = np.interp(pos[bad_od], pos[good], t[good])
            parts = []
            if n_missing_scans:
                parts.append(f"{n_missing_scans} missing scan")
            if n_scans - n_kept_scans - n_missing_scans:
                parts.append(f"{n_scans - n_kept_scans - n_missing_scans} out-of-order scan")
            if int(bad_od.sum()):
                parts.append(f"{int(bad_od.sum())} missing odometry")
            note = ", ".join(parts) + " stamps interpolated by file position"
            log.info("timestamps repaired: %s", note)
            return StampRepair(out, "repaired", note, n_bad)

    # synthetic: scans at k * period, everything else spread between them by file position
    pos = np.arange(n, dtype=np.float64)
    scan_pos = np.flatnonzero(sc).astype(np.float64)
    if len(scan_pos) == 0:
        out = pos * period
    elif len(scan_pos) == 1:
        out = (pos - scan_pos[0]) * period / max(n, 1)
    else:
        k = np.arange(len(scan_pos), dtype=np.float64) * period
        out = np.interp(pos, scan_pos, k)
        # linear extrapolation at the ends, with the slope of the nearest scan interval
        lo = pos < scan_pos[0]
        out[lo] = (pos[lo] - scan_pos[0]) * period / (scan_pos[1] - scan_pos[0])
        hi = pos > scan_pos[-1]
        out[hi] = k[-1] + (pos[hi] - scan_pos[-1]) * period / (scan_pos[-1] - scan_pos[-2])
    note = f"{reason}; synthetic stamps: scan index × {period:g} s"
    log.info("timestamps unusable: %s", note)
    return StampRepair(out, "synthetic", note, n)


def scan_span(scans: list[Scan]) -> dict[str, Any]:
    """The :class:`LogInfo` fields that summarise time-sorted ``scans``: beam counts,
    angle span, max range, first and last stamp."""
    return {
        "n_scans": len(scans),
        "beams": tuple(sorted({len(s) for s in scans})),
        "angle_min": min((float(s.angles[0]) for s in scans if len(s)), default=math.nan),
        "angle_max": max((float(s.angles[-1]) for s in scans if len(s)), default=math.nan),
        "max_range": min((s.max_range for s in scans), default=math.inf),
        "start": scans[0].stamp if scans else math.nan,
        "end": scans[-1].stamp if scans else math.nan,
    }


# -- the reader registry: every reader module registers itself (icploc.logs finds them) ----


@dataclass(frozen=True)
class LogFormat:
    """One log format: ``sniff(path) -> bool`` claims a file by content, ``load(path,
    **opts) -> LogData`` reads it; ``extensions`` are the fallback when no sniffer claims a
    file; formats are sniffed by ``order`` (cheap, dependency-free checks first)."""

    name: str
    sniff: Callable[[str], bool]
    load: Callable[..., LogData]
    extensions: tuple[str, ...] = ()
    order: int = 50


#: format name -> format (filled by the reader modules as they are imported)
FORMATS: dict[str, LogFormat] = {}


def register_format(
    name: str,
    sniff: Callable[[str], bool],
    load: Callable[..., LogData],
    extensions: Iterable[str] = (),
    order: int = 50,
) -> LogFormat:
    """Add (or replace) a format (a reader module calls this at import)."""
    f = LogFormat(name, sniff, load, tuple(e.lower() for e in extensions), order)
    FORMATS[name] = f
    items = sorted(FORMATS.values(), key=lambda x: x.order)
    FORMATS.clear()
    FORMATS.update((x.name, x) for x in items)
    return f

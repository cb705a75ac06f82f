"""Log readers: one module per format, picked by content (then extension) by :func:`open_log`.

>>> log = open_log("intel-corrected.log.gz")        # doctest: +SKIP
>>> print(log.info.summary())                        # doctest: +SKIP
>>> for msg in log:                                  # Scan and Odometry, in time order
...     ...                                          # doctest: +SKIP

Formats: ``carmen`` (:mod:`icploc.logs.carmen`), ``rosbag1`` / ``rosbag2``
(:mod:`icploc.logs.rosbag`) and ``recorded`` (our raw-byte recordings,
:mod:`icploc.logs.recorded`, imported only when used).
"""

from __future__ import annotations

import errno
import importlib
import importlib.util
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from icploc.logs._base import LogData, LogFormatError, LogInfo, merge_in_time, repair_stamps
from icploc.logs.carmen import is_carmen, read_carmen, write_carmen
from icploc.types import Odometry, Scan

__all__ = [
    "FORMATS",
    "LogData",
    "LogFormatError",
    "LogInfo",
    "detect_format",
    "is_carmen",
    "load_log",
    "log_info",
    "merge_in_time",
    "open_log",
    "read_carmen",
    "register_format",
    "repair_stamps",
    "write_carmen",
]


@dataclass(frozen=True)
class _Format:
    name: str
    sniff: Callable[[str], bool]
    load: Callable[..., LogData]
    extensions: tuple[str, ...]


FORMATS: dict[str, _Format] = {}


def register_format(
    name: str,
    sniff: Callable[[str], bool],
    load: Callable[..., LogData],
    extensions: Iterable[str] = (),
) -> None:
    """Add (or replace) a format: ``sniff(path) -> bool`` and ``load(path, **opts) -> LogData``.

    Formats are tried in registration order; ``extensions`` are the fallback when no
    sniffer claims a file.
    """
    FORMATS[name] = _Format(name, sniff, load, tuple(e.lower() for e in extensions))


# -- recorded raw bytes (another module; imported lazily, only if it exists) ------------

_RECORDED = "icploc.logs.recorded"


def _recorded_available() -> bool:
    return importlib.util.find_spec(_RECORDED) is not None


def _sniff_recorded(path: str) -> bool:
    if not _recorded_available():
        return False
    mod = importlib.import_module(_RECORDED)
    return bool(mod.is_recorded(path))


def _load_recorded(path: str, **opts: Any) -> LogData:
    if not _recorded_available():
        raise LogFormatError(
            path, "recorded-session reader (icploc.logs.recorded) is not installed"
        )
    mod = importlib.import_module(_RECORDED)
    opts.pop("strict", None)  # the recording reader checks every frame's checksum itself
    scans: list[Scan] = []
    odoms: list[Odometry] = []
    try:
        for msg in mod.read_recorded(path, **opts):
            (scans if isinstance(msg, Scan) else odoms).append(msg)
    except LogFormatError:
        raise
    except ValueError as exc:  # RecordingFormatError and the protocol errors are ValueErrors
        raise LogFormatError(path, f"bad recording: {exc}") from exc
    scans.sort(key=lambda s: s.stamp)
    odoms.sort(key=lambda o: o.stamp)
    return LogData(info=_info_from(path, "recorded", scans, odoms), scans=scans, odometry=odoms)


def _info_from(path: str, fmt: str, scans: list[Scan], odoms: list[Odometry]) -> LogInfo:
    import math

    return LogInfo(
        path=path,
        format=fmt,
        n_scans=len(scans),
        n_odometry=len(odoms),
        beams=tuple(sorted({len(s) for s in scans})),
        angle_min=min((float(s.angles[0]) for s in scans if len(s)), default=math.nan),
        angle_max=max((float(s.angles[-1]) for s in scans if len(s)), default=math.nan),
        max_range=min((s.max_range for s in scans), default=math.inf),
        start=scans[0].stamp if scans else math.nan,
        end=scans[-1].stamp if scans else math.nan,
    )


# -- rosbag (rosbags imported lazily by the module) -------------------------------------


def _sniff_rosbag(path: str) -> bool:
    from icploc.logs.rosbag import is_rosbag

    return is_rosbag(path)


def _load_rosbag(path: str, **opts: Any) -> LogData:
    from icploc.logs.rosbag import read_rosbag

    return read_rosbag(path, **opts)


# sniffing order: the cheap, dependency-free checks first
register_format("rosbag", _sniff_rosbag, _load_rosbag, (".bag", ".db3", ".mcap"))
register_format("carmen", is_carmen, read_carmen, (".log", ".log.gz", ".clf", ".clf.gz", ".gz"))
register_format("recorded", _sniff_recorded, _load_recorded, (".icpraw",))


def detect_format(path: str | os.PathLike[str]) -> str:
    """Name of the registered format that reads ``path`` (by content, then by extension)."""
    p = os.fspath(path)
    if not os.path.exists(p):
        raise FileNotFoundError(errno.ENOENT, "no such log file", p)
    for f in FORMATS.values():
        if f.sniff(p):
            return f.name
    name = Path(p).name.lower()
    for f in FORMATS.values():
        if f.extensions and name.endswith(f.extensions):
            return f.name
    raise LogFormatError(p, f"unknown log format (known: {', '.join(FORMATS)})")


def load_log(path: str | os.PathLike[str], *, format: str | None = None, **opts: Any) -> LogData:
    """Read a whole log: scans, odometry (time-sorted), reported poses and a :class:`LogInfo`."""
    p = os.fspath(path)
    name = format or detect_format(p)
    if name not in FORMATS:
        raise ValueError(f"unknown log format {name!r} (known: {', '.join(FORMATS)})")
    return FORMATS[name].load(p, **opts)


def open_log(path: str | os.PathLike[str], *, format: str | None = None, **opts: Any) -> LogData:
    """Open a log; iterating the result yields :class:`Scan` and :class:`Odometry` in time
    order (odometry first on equal stamps). ``.info`` summarises it; ``.truth_poses`` holds
    the pose the log reports with each scan, if any. ``opts`` go to the format's reader."""
    return load_log(path, format=format, **opts)


def log_info(path: str | os.PathLike[str], **opts: Any) -> LogInfo:
    """The :class:`LogInfo` of a log (reads it)."""
    return load_log(path, **opts).info

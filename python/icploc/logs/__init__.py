"""Log readers: one module per format, picked by content (then extension) by :func:`open_log`.

>>> log = open_log("intel-corrected.log.gz")        # doctest: +SKIP
>>> print(log.info.summary())                        # doctest: +SKIP
>>> for msg in log:                                  # Scan and Odometry, in time order
...     ...                                          # doctest: +SKIP

Formats: ``carmen`` (:mod:`icploc.logs.carmen`), ``rosbag1`` / ``rosbag2``
(:mod:`icploc.logs.rosbag`) and ``recorded`` (our raw-byte recordings,
:mod:`icploc.logs.recorded`). Every reader module registers itself
(:func:`register_format`); the package imports its reader modules the first time a log
is opened (a new reader is a new module here), and no reader imports its heavy dependency
(``rosbags``) before it reads.
"""

from __future__ import annotations

import errno
import importlib
import os
import pkgutil
from pathlib import Path
from typing import Any

from icploc.logs import _base
from icploc.logs._base import (
    LogData,
    LogFormat,
    LogFormatError,
    LogInfo,
    merge_in_time,
    register_format,
    repair_stamps,
)
from icploc.logs.carmen import is_carmen, read_carmen, write_carmen

__all__ = [
    "FORMATS",
    "LogData",
    "LogFormat",
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

_found = False


def _formats() -> dict[str, LogFormat]:
    """The registry, after importing every reader module of this package once (each
    registers itself; none imports its heavy dependency, e.g. rosbags, until it reads)."""
    global _found
    if not _found:
        _found = True
        for mod in pkgutil.iter_modules(__path__):
            if not mod.name.startswith("_"):
                importlib.import_module(f"{__name__}.{mod.name}")
    return _base.FORMATS


def __getattr__(name: str) -> Any:
    if name == "FORMATS":  # the full registry, its reader modules imported on first use
        return _formats()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def detect_format(path: str | os.PathLike[str]) -> str:
    """Name of the registered format that reads ``path`` (by content, then by extension)."""
    p = os.fspath(path)
    if not os.path.exists(p):
        raise FileNotFoundError(errno.ENOENT, "no such log file", p)
    formats = _formats()
    for f in formats.values():
        if f.sniff(p):
            return f.name
    name = Path(p).name.lower()
    for f in formats.values():
        if f.extensions and name.endswith(f.extensions):
            return f.name
    raise LogFormatError(p, f"unknown log format (known: {', '.join(formats)})")


def load_log(path: str | os.PathLike[str], *, format: str | None = None, **opts: Any) -> LogData:
    """Read a whole log: scans, odometry (time-sorted), reported poses and a :class:`LogInfo`."""
    p = os.fspath(path)
    name = format or detect_format(p)
    formats = _formats()
    if name not in formats:
        raise ValueError(f"unknown log format {name!r} (known: {', '.join(formats)})")
    return formats[name].load(p, **opts)


def open_log(path: str | os.PathLike[str], *, format: str | None = None, **opts: Any) -> LogData:
    """Open a log; iterating the result yields :class:`Scan` and :class:`Odometry` in time
    order (odometry first on equal stamps). ``.info`` summarises it; ``.truth_poses`` holds
    the pose the log reports with each scan, if any. ``opts`` go to the format's reader."""
    return load_log(path, format=format, **opts)


def log_info(path: str | os.PathLike[str], **opts: Any) -> LogInfo:
    """The :class:`LogInfo` of a log (reads it)."""
    return load_log(path, **opts).info

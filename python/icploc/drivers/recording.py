"""Raw-byte recording of driver sessions (format: ``docs/recording-format.md``).

A recording is a small header followed by records ``(stamp, device, kind, bytes)``:
the bytes a driver received (and sent) over its serial line, stamped on
:func:`icploc.clock.now`. Replaying them through the same parsers reproduces a session
without hardware (:mod:`icploc.logs.recorded`). ``icploc run`` writes the laser mounting
the run used into the header (:func:`mounting_header`), so that a replay puts the scans
where the run did (:func:`recorded_mounting`).
"""

from __future__ import annotations

import json
import math
import os
import struct
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from icploc.errors import FileFormatError
from icploc.se2 import Pose

MAGIC = b"ICPLRAW1"
VERSION = 1
RECORD = struct.Struct("<dBBI")  # stamp, device, kind, length

KIND_META = 0  #: JSON object describing the device / a settings change
KIND_RX = 1  #: bytes received from the device; stamp = when the read returned
KIND_TX = 2  #: bytes sent to the device; stamp = just before the write

#: Largest record payload a reader accepts (guards against a corrupt length field).
MAX_RECORD = 1 << 24

#: header key: the laser mounting of the run, ``[x m, y m, yaw rad]`` of the laser in the
#: robot frame (``scan.laser_x``, ``laser_y``, ``laser_theta`` of the config)
MOUNTING = "laser_mounting"


class RecordingFormatError(FileFormatError):
    """The file is not a raw-byte recording, or it is corrupt. Raised with the message
    alone (``RecordingFormatError(message)``, which names the file) or as
    ``RecordingFormatError(message, path=..., line=...)``."""

    def __init__(
        self, message: str, path: str | os.PathLike[str] | None = None, line: int | None = None
    ) -> None:
        self._where(path, line, message)


@dataclass(frozen=True)
class Record:
    stamp: float
    device: int
    kind: int
    data: bytes

    def meta(self) -> dict[str, Any]:
        obj = json.loads(self.data.decode("utf-8"))
        if not isinstance(obj, dict):
            raise RecordingFormatError("META record is not a JSON object")
        return obj


class Recorder:
    """Thread-safe writer shared by any number of drivers. Every record is flushed to
    the file as it is written, so a crash or Ctrl-C leaves a complete recording up to
    the last record. A write error (disk full, file system gone) stops the recording
    instead of the drivers: it is kept in :attr:`error` and nothing more is written.

    >>> rec = Recorder("session.icpraw")            # doctest: +SKIP
    >>> laser = PLS(port, recorder=rec)              # doctest: +SKIP
    """

    def __init__(
        self, path: str | os.PathLike[str], *, header: dict[str, Any] | None = None
    ) -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._f: BinaryIO | None = open(self.path, "wb")  # noqa: SIM115
        hdr = {"format": "icploc-raw", "version": VERSION, "clock": "time.monotonic"}
        if header:
            hdr.update(header)
        blob = json.dumps(hdr, sort_keys=True).encode("utf-8")
        self._f.write(MAGIC + struct.pack("<I", len(blob)) + blob)
        self._f.flush()
        self._devices: dict[str, int] = {}
        self._owners = 0
        #: the write error that stopped the recording (None while it records)
        self.error: OSError | None = None
        self.records = 0

    def device(self, name: str, meta: dict[str, Any], stamp: float) -> int:
        """Register (or re-describe) a device; returns its id for later records."""
        with self._lock:
            dev = self._devices.get(name)
            if dev is None:
                dev = len(self._devices) + 1
                if dev > 255:
                    raise ValueError("too many devices in one recording")
                self._devices[name] = dev
        self.meta(dev, stamp, {"name": name, **meta})
        return dev

    def meta(self, device: int, stamp: float, meta: dict[str, Any]) -> None:
        self._write(stamp, device, KIND_META, json.dumps(meta, sort_keys=True).encode("utf-8"))

    def rx(self, device: int, stamp: float, data: bytes) -> None:
        if data:
            self._write(stamp, device, KIND_RX, data)

    def tx(self, device: int, stamp: float, data: bytes) -> None:
        if data:
            self._write(stamp, device, KIND_TX, data)

    def _write(self, stamp: float, device: int, kind: int, data: bytes) -> None:
        with self._lock:
            if self._f is None:
                return
            try:
                self._f.write(RECORD.pack(stamp, device, kind, len(data)) + data)
                self._f.flush()
            except OSError as e:
                self.error = e
                try:
                    self._f.close()
                except OSError:
                    pass
                self._f = None
                return
            self.records += 1

    def rename(self, path: str | os.PathLike[str]) -> None:
        """Move the file being written to ``path`` (replacing it); writing continues
        there. ``icploc run`` records the handshake into a temporary file and moves it
        over ``--record`` only once the devices answered."""
        with self._lock:
            os.replace(self.path, path)
            self.path = Path(path)

    def flush(self) -> None:
        with self._lock:
            if self._f is not None:
                self._f.flush()

    def close(self) -> None:
        with self._lock:
            if self._f is not None:
                try:
                    self._f.close()
                except OSError as e:
                    self.error = self.error or e
                self._f = None

    @property
    def closed(self) -> bool:
        return self._f is None

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def is_recording(path: str | os.PathLike[str]) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(MAGIC)) == MAGIC
    except (OSError, IsADirectoryError):
        return False


def read_header(f: BinaryIO) -> dict[str, Any]:
    if f.read(len(MAGIC)) != MAGIC:
        raise RecordingFormatError("not an icploc raw-byte recording (bad magic)")
    raw = f.read(4)
    if len(raw) != 4:
        raise RecordingFormatError("truncated header")
    (n,) = struct.unpack("<I", raw)
    if n > MAX_RECORD:
        raise RecordingFormatError("header length implausible")
    blob = f.read(n)
    if len(blob) != n:
        raise RecordingFormatError("truncated header")
    try:
        hdr = json.loads(blob.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise RecordingFormatError(f"header is not JSON: {e}") from e
    if not isinstance(hdr, dict) or hdr.get("version") != VERSION:
        raise RecordingFormatError(f"unsupported recording header {hdr!r}")
    return hdr


def iter_records(path: str | os.PathLike[str]) -> Iterator[Record]:
    """All records in file order. A record cut short at the end of the file (a crash
    while recording) ends the iteration quietly; anything else malformed raises
    :class:`RecordingFormatError`."""
    with open(path, "rb") as f:
        read_header(f)
        while True:
            head = f.read(RECORD.size)
            if len(head) < RECORD.size:
                return
            stamp, dev, kind, n = RECORD.unpack(head)
            if kind not in (KIND_META, KIND_RX, KIND_TX) or n > MAX_RECORD:
                raise RecordingFormatError(
                    f"corrupt record header at offset {f.tell() - RECORD.size}"
                )
            data = f.read(n)
            if len(data) < n:
                return
            yield Record(stamp, dev, kind, data)


def mounting_header(mounting: Sequence[float]) -> dict[str, Any]:
    """The header entry that records the laser mounting (x m, y m, yaw rad)."""
    return {MOUNTING: [float(v) for v in mounting]}


def recorded_mounting(path: str | os.PathLike[str]) -> Pose | None:
    """The laser mounting (x m, y m, yaw rad) the recording's header carries; None for a
    recording made before recordings carried it. A malformed value is a
    :class:`RecordingFormatError` naming the file."""
    with open(path, "rb") as f:
        try:
            hdr = read_header(f)
        except RecordingFormatError as e:
            raise RecordingFormatError(f"{path}: {e}") from None
    if MOUNTING not in hdr:
        return None
    v = hdr[MOUNTING]
    if (
        not isinstance(v, list)
        or len(v) != 3
        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
        or not all(math.isfinite(x) for x in v)
    ):
        raise RecordingFormatError(
            f"{path}: header field {MOUNTING!r} must be three finite numbers [x, y, yaw], got {v!r}"
        )
    return (float(v[0]), float(v[1]), float(v[2]))

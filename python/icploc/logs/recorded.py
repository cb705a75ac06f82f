"""Replay of raw-byte recordings made by the drivers (``docs/recording-format.md``).

The bytes each driver received are fed, with their recorded stamps, through the same
parsers the live drivers use (:mod:`icploc.drivers.sick_protocol`,
:mod:`icploc.drivers.arcos_protocol`), so a real session re-runs without hardware and
produces the same :class:`~icploc.messages.Scan` and :class:`~icploc.messages.Odometry`
objects, merged in time order. :func:`replay_config` puts the scans where the run did:
at the laser mounting the recording carries.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
import os
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from icploc.logs._base import LogData, LogFormatError, LogInfo, register_format, scan_span
from icploc.messages import Odometry, Scan
from icploc.se2 import Pose, compose

if TYPE_CHECKING:
    from icploc.drivers.recording import RecordingFormatError

__all__ = ["RecordingFormatError", "is_recorded", "load_recorded", "read_recorded", "replay_config"]

# icploc.drivers.recording is imported where a recording is sniffed or read: a process that
# reads another format (a CARMEN replay) imports this module, for the registry, but not it


def __getattr__(name: str) -> Any:
    if name == "RecordingFormatError":
        from icploc.drivers.recording import RecordingFormatError

        return RecordingFormatError
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def is_recorded(path: str | os.PathLike[str]) -> bool:
    """True if ``path`` is an icploc raw-byte recording (checks the magic bytes)."""
    from icploc.drivers.recording import is_recording

    return os.path.isfile(path) and is_recording(path)


def _devices(path: str | os.PathLike[str]) -> dict[int, dict[str, Any]]:
    from icploc.drivers.recording import KIND_META, iter_records

    devs: dict[int, dict[str, Any]] = {}
    for rec in iter_records(path):
        if rec.kind == KIND_META and rec.device not in devs:
            devs[rec.device] = rec.meta()
    return devs


def _sick_stream(path: str | os.PathLike[str], dev: int, meta: dict[str, Any]) -> Iterator[Scan]:
    variant = str(meta.get("variant", "pls"))
    flipped = bool(meta.get("flipped", False))
    bits = int(meta.get("bits_per_byte", 11 if variant == "pls" else 10))
    max_range = meta.get("max_range")
    from icploc.drivers import sick_protocol as sp  # on reading one (~8 ms to import)
    from icploc.drivers.recording import KIND_META, KIND_RX, iter_records

    parser = sp.TelegramParser(addresses=frozenset(range(0x80, 0x85)))
    seq = 0
    for rec in iter_records(path):
        if rec.device != dev:
            continue
        if rec.kind == KIND_META:
            m = rec.meta()
            if "baudrate" in m:
                parser.byte_time = bits / float(m["baudrate"])
            continue
        if rec.kind != KIND_RX:
            continue
        for ev in parser.feed(rec.data, rec.stamp):
            if isinstance(ev, sp.Telegram) and ev.cmd == sp.REPLY_MEASURED:
                try:
                    scan = sp.decode_scan(ev, variant=variant, seq=seq + 1, flipped=flipped,
                                          max_range=None if max_range is None else float(max_range))  # fmt: skip
                except sp.SickProtocolError:
                    continue
                seq += 1
                yield scan


def _powerbot_stream(
    path: str | os.PathLike[str], dev: int, meta: dict[str, Any]
) -> Iterator[Odometry]:
    from icploc.drivers import arcos_protocol as ap  # on reading one (~5 ms to import)
    from icploc.drivers.recording import KIND_META, KIND_RX, iter_records

    parser = ap.PacketParser(byte_time=10.0 / float(meta.get("baudrate", 9600)))
    decoder = ap.SipDecoder(ap.POWERBOT)
    forced = False
    # the driver re-anchors a power-cycled controller's odometry (it restarts at 0, 0, 0) by
    # a rigid offset and records it as a META right after the SIP that revealed it: that SIP
    # and every later one are re-anchored the same way here (one SIP is held back for it)
    offset: tuple[float, float, float] | None = None
    held: Any = None

    def anchored(sip: Any) -> Odometry:
        odo = sip.to_odometry()
        if offset is None:
            return odo  # type: ignore[no-any-return]
        return dataclasses.replace(odo, pose=compose(offset, odo.pose))

    for rec in iter_records(path):
        if rec.device != dev:
            continue
        if rec.kind == KIND_META:
            m = rec.meta()
            if "baudrate" in m:
                parser.byte_time = 10.0 / float(m["baudrate"])
            if "subtype" in m:
                decoder.set_params(ap.params_for(str(m["subtype"])))
                forced = True
            if "odometry_offset" in m:
                o = m["odometry_offset"]
                offset = (float(o[0]), float(o[1]), float(o[2]))
            continue
        if rec.kind != KIND_RX:
            continue
        for pkt in parser.feed(rec.data, rec.stamp):
            if pkt.type == ap.SYNC2 and not forced:
                try:
                    decoder.set_params(ap.params_for(ap.parse_sync2(pkt.payload)[2]))
                except ap.ArcosProtocolError:
                    pass
                continue
            sip = decoder.decode(pkt)
            if sip is not None:
                if held is not None:
                    yield anchored(held)
                held = sip
    if held is not None:
        yield anchored(held)


def read_recorded(path: str | os.PathLike[str]) -> Iterator[Scan | Odometry]:
    """Scans and odometry decoded from a recording, in stamp order.

    Raises :class:`~icploc.drivers.recording.RecordingFormatError` if the file is not a
    recording or is corrupt (a record cut short at the very end is tolerated)."""
    from icploc.drivers.recording import RecordingFormatError

    devs = _devices(path)
    streams: list[Iterator[Scan | Odometry]] = []
    for dev, meta in sorted(devs.items()):
        driver = meta.get("driver")
        if driver == "sick":
            streams.append(_sick_stream(path, dev, meta))
        elif driver == "powerbot":
            streams.append(_powerbot_stream(path, dev, meta))
        else:
            raise RecordingFormatError(f"device {dev} has unknown driver {driver!r}")
    yield from heapq.merge(*streams, key=lambda item: item.stamp)


def load_recorded(path: str | os.PathLike[str], **opts: Any) -> LogData:
    """A recording as :class:`~icploc.logs.LogData` (the log registry's reader)."""
    p = os.fspath(path)
    opts.pop("strict", None)  # the recording reader checks every frame's checksum itself
    if opts:
        raise TypeError(f"load_recorded: unexpected option(s) {sorted(opts)}")
    scans: list[Scan] = []
    odoms: list[Odometry] = []
    try:
        for msg in read_recorded(p):
            if isinstance(msg, Scan):
                scans.append(msg)
            else:
                odoms.append(msg)
    except LogFormatError:
        raise
    except ValueError as exc:  # RecordingFormatError and the protocol errors are ValueErrors
        raise LogFormatError(p, f"bad recording: {exc}") from exc
    scans.sort(key=lambda s: s.stamp)
    odoms.sort(key=lambda o: o.stamp)
    return LogData(info=_info_from(p, scans, odoms), scans=scans, odometry=odoms)


def _info_from(path: str, scans: list[Scan], odoms: list[Odometry]) -> LogInfo:
    return LogInfo(path=path, format="recorded", n_odometry=len(odoms), **scan_span(scans))


register_format("recorded", is_recorded, load_recorded, (".icpraw",), order=30)
def _mm(p: Pose) -> str:
    return f"x {p[0]:+.3f} m, y {p[1]:+.3f} m, yaw {math.degrees(p[2]):+.1f} deg"


def replay_config(path: str | os.PathLike[str], config: Any, config_given: bool) -> tuple[Any, str]:
    """The config to replay the recording ``path`` with, and a note for the summary that
    says where the laser mounting came from. The mounting the recording carries is used
    unless ``config_given`` (a config file) sets another, non-zero one, which then wins; a
    recording made before recordings carried the mounting keeps the config's, and the note
    says so (not silently: a laser 0.25 m ahead of the centre shifts every scan)."""
    from icploc.drivers.recording import recorded_mounting

    configured: Pose = tuple(config.scan.mounting)  # type: ignore[assignment]
    rec = recorded_mounting(path)
    if rec is None:
        how = "the config's" if any(configured) else "none (the laser at the robot's centre)"
        return config, (
            f"the recording holds no laser mounting (made before recordings carried it): "
            f"using {how}, {_mm(configured)}; if the laser sat elsewhere, give it in --config "
            "(scan.laser_x, scan.laser_y, scan.laser_theta)"
        )
    if config_given and any(configured) and configured != rec:
        return config, (
            f"laser mounting from the config, {_mm(configured)}; the recording says {_mm(rec)}"
        )
    cfg = config.replace(scan={"laser_x": rec[0], "laser_y": rec[1], "laser_theta": rec[2]})
    return cfg, f"laser mounting from the recording: {_mm(rec)}"

"""ROS 1 and ROS 2 bags (via ``rosbags``): ``sensor_msgs/LaserScan`` and ``nav_msgs/Odometry``.

Topics are auto-detected (the LaserScan / Odometry topic; ``/scan`` and ``/odom`` win when
there are several, else the busiest) or chosen with ``scan_topic`` / ``odom_topic``.

Beams follow REP 117: ``+inf`` or ≥ ``range_max`` is no return (``inf`` +
``BEAM_NO_RETURN``); NaN, ``-inf`` and readings below ``range_min`` are invalid (``inf`` +
``BEAM_INVALID``). Stamps are the message header stamps; a message with a zero header stamp
takes the bag's record time, and the whole log goes through the same stamp repair as the
CARMEN reader.

A ROS 1 bag whose index ``rosbags`` rejects (e.g. ``AssertionError`` on an inconsistent
index section) is read by scanning its chunks sequentially instead (:func:`iter_ros1_raw`),
which needs no index.
"""

from __future__ import annotations

import bz2
import math
import os
import struct
from collections.abc import Iterator, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.errors import UsageError
from icploc.logs._base import (
    Damage,
    LogData,
    LogFormatError,
    LogInfo,
    log,
    register_format,
    repair_stamps,
    scan_span,
)
from icploc.messages import BEAM_INVALID, BEAM_NO_RETURN, Odometry, Scan

__all__ = ["TopicError", "is_rosbag", "iter_ros1_raw", "read_rosbag", "write_rosbag"]

SCAN_TYPE = "sensor_msgs/msg/LaserScan"
ODOM_TYPE = "nav_msgs/msg/Odometry"
_ROS1_MAGIC = b"#ROSBAG V2.0\n"


def is_rosbag(path: str | os.PathLike[str]) -> bool:
    """A ROS 1 bag (magic line), or a ROS 2 bag (directory with metadata.yaml, .db3, .mcap)."""
    p = Path(path)
    if p.is_dir():
        return (p / "metadata.yaml").is_file()
    if p.suffix in (".db3", ".mcap") and (p.parent / "metadata.yaml").is_file():
        return True
    try:
        with open(p, "rb") as fh:
            head = fh.read(len(_ROS1_MAGIC))
    except OSError:
        return False
    return head == _ROS1_MAGIC


# ----------------------------------------------------------------------------- raw ROS 1


def _fields(path: str, buf: bytes, where: int) -> dict[str, bytes]:
    out: dict[str, bytes] = {}
    i = 0
    while i < len(buf):
        if i + 4 > len(buf):
            raise LogFormatError(path, f"bag record header truncated at byte {where + i}")
        (n,) = struct.unpack_from("<I", buf, i)
        i += 4
        field = buf[i : i + n]
        i += n
        if len(field) != n or b"=" not in field:
            raise LogFormatError(path, f"bad bag record header field at byte {where + i}")
        k, v = field.split(b"=", 1)
        out[k.decode("ascii", "replace")] = v
    return out


def _records(
    path: str, data: bytes | memoryview, base: int
) -> Iterator[tuple[dict[str, bytes], bytes, int]]:
    i = 0
    n = len(data)
    while i < n:
        if i + 4 > n:
            raise LogFormatError(path, f"truncated record at byte {base + i}")
        (hl,) = struct.unpack_from("<I", data, i)
        hdr = bytes(data[i + 4 : i + 4 + hl])
        j = i + 4 + hl
        if j + 4 > n:
            raise LogFormatError(path, f"truncated record at byte {base + i}")
        (dl,) = struct.unpack_from("<I", data, j)
        fields = _fields(path, hdr, base + i)
        if (
            fields.get("op") == b"\x04"
            and "count" in fields
            and fields.get("ver", b"\x01\0\0\0")[0] == 1
        ):
            # index data: its length is fixed by its count (12 bytes per entry); some
            # writers put a wrong data length here, which would derail the scan
            dl = 12 * struct.unpack("<I", fields["count"])[0]
        body = bytes(data[j + 4 : j + 4 + dl])
        if len(body) != dl:
            raise LogFormatError(path, f"truncated record data at byte {base + j}")
        yield fields, body, base + i
        i = j + 4 + dl


class TopicError(UsageError):
    """The requested topic is missing or has the wrong type."""


def iter_ros1_raw(path: str | os.PathLike[str]) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, msgtype, record time ns, serialized message) for every message of a ROS 1
    bag, read chunk by chunk in file order without using its index. Any inconsistency is a
    :class:`LogFormatError` naming the file."""
    spath = os.fspath(path)
    try:
        yield from _iter_ros1_raw(spath)
    except LogFormatError:
        raise
    except (KeyError, IndexError, struct.error, ValueError, OSError, EOFError, ImportError) as exc:
        raise LogFormatError(spath, f"corrupt ROS 1 bag: {type(exc).__name__}: {exc}") from exc


def _iter_ros1_raw(spath: str) -> Iterator[tuple[str, str, int, bytes]]:
    with open(spath, "rb") as fh:
        data = fh.read()
    if not data.startswith(_ROS1_MAGIC):
        raise LogFormatError(spath, "not a ROS 1 bag (no '#ROSBAG V2.0' line)")
    conns: dict[int, tuple[str, str]] = {}

    def conn_of(h: dict[str, bytes], body: bytes, at: int) -> None:
        cid = struct.unpack("<I", h["conn"])[0]
        inner = _fields(spath, body, at)
        topic = h.get("topic", inner.get("topic", b"")).decode()
        mtype = inner.get("type", b"").decode()
        if "/msg/" not in mtype and "/" in mtype:
            pkg, name = mtype.split("/", 1)
            mtype = f"{pkg}/msg/{name}"
        conns[cid] = (topic, mtype)

    def messages(
        recs: Iterator[tuple[dict[str, bytes], bytes, int]],
    ) -> Iterator[tuple[str, str, int, bytes]]:
        for h, body, at in recs:
            op = h.get("op", b"\xff")[0]
            if op == 0x07:
                conn_of(h, body, at)
            elif op == 0x02:
                cid = struct.unpack("<I", h["conn"])[0]
                sec, nsec = struct.unpack("<II", h["time"])
                if cid not in conns:
                    raise LogFormatError(spath, f"message on unknown connection {cid} at byte {at}")
                topic, mtype = conns[cid]
                yield topic, mtype, sec * 1_000_000_000 + nsec, body

    for h, body, at in _records(spath, memoryview(data)[len(_ROS1_MAGIC) :], len(_ROS1_MAGIC)):
        op = h.get("op", b"\xff")[0]
        if op == 0x05:
            comp = h.get("compression", b"none").decode()
            size = struct.unpack("<I", h["size"])[0]
            if comp == "none":
                raw = body
            elif comp == "bz2":
                raw = bz2.decompress(body)
            elif comp == "lz4":
                import lz4.frame  # type: ignore[import-not-found]

                raw = lz4.frame.decompress(body)
            else:
                raise LogFormatError(spath, f"unknown chunk compression {comp!r} at byte {at}")
            if len(raw) != size:
                raise LogFormatError(
                    spath, f"chunk at byte {at}: {len(raw)} bytes, header says {size}"
                )
            yield from messages(_records(spath, raw, at))
        elif op == 0x07:
            conn_of(h, body, at)
        elif op == 0x02:
            yield from messages(iter([(h, body, at)]))
        # 0x03 bag header, 0x04 index data, 0x06 chunk info: not needed


# ----------------------------------------------------------------------------- reading


def _choose(
    topics: dict[str, tuple[str, int]], mtype: str, want: str | None, default: str
) -> str | None:
    cands = {t: c for t, (m, c) in topics.items() if m == mtype}
    if want is not None:
        if want not in topics:
            raise TopicError(
                f"topic {want!r} not in bag (topics: {', '.join(sorted(topics)) or 'none'})"
            )
        if topics[want][0] != mtype:
            raise TopicError(f"topic {want!r} has type {topics[want][0]}, expected {mtype}")
        return want
    if not cands:
        return None
    if default in cands:
        return default
    return sorted(cands, key=lambda t: (-cands[t], t))[0]


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _scan_arrays(msg: Any) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.uint8]]:
    with np.errstate(invalid="ignore"):  # a damaged float32 can be a signalling NaN
        r = np.asarray(msg.ranges, dtype=np.float64)
    n = r.shape[0]
    a = float(msg.angle_min) + np.arange(n, dtype=np.float64) * float(msg.angle_increment)
    rmin, rmax = float(msg.range_min), float(msg.range_max)
    flags = np.zeros(n, dtype=np.uint8)
    with np.errstate(invalid="ignore"):
        invalid = np.isnan(r) | (r < rmin) | (r == -np.inf)
        noret = ~invalid & ((r == np.inf) | ((r >= rmax) if rmax > 0 else False))
    flags[noret] |= BEAM_NO_RETURN
    flags[invalid] |= BEAM_INVALID
    r = np.where(noret | invalid, np.inf, r)
    return r, a, flags


def read_rosbag(
    path: str | os.PathLike[str],
    *,
    scan_topic: str | None = None,
    odom_topic: str | None = None,
    timestamps: str = "auto",
    period: float = 0.1,
    strict: bool = False,
) -> LogData:
    """Read the LaserScan and Odometry messages of a ROS 1 or ROS 2 bag.

    Damage: a message that cannot be decoded, a scan with non-finite angles and an odometry
    message with a non-finite pose are skipped and counted (:attr:`LogInfo.n_dropped`);
    NaN and out-of-limits readings are invalid beams (REP 117). ``strict=True`` raises
    :class:`LogFormatError` at the first skipped message instead."""
    spath = os.fspath(path)
    damage = Damage(spath, strict)
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    notes: list[str] = []
    entries: list[tuple[str, str, int, Any]] = []  # topic, type, bag time ns, message
    fmt = (
        "rosbag1" if Path(spath).is_file() and not spath.endswith((".db3", ".mcap")) else "rosbag2"
    )
    bag_path = Path(spath).parent if spath.endswith((".db3", ".mcap")) else Path(spath)
    topics: dict[str, tuple[str, int]] = {}
    try:
        with AnyReader([bag_path]) as reader:
            for c in reader.connections:
                m, cnt = topics.get(c.topic, (c.msgtype, 0))
                topics[c.topic] = (c.msgtype, cnt + c.msgcount)
            st = _choose(topics, SCAN_TYPE, scan_topic, "/scan")
            ot = _choose(topics, ODOM_TYPE, odom_topic, "/odom")
            conns = [c for c in reader.connections if c.topic in (st, ot)]
            for c, t, raw in reader.messages(connections=conns):
                entries.append((c.topic, c.msgtype, t, reader.deserialize(raw, c.msgtype)))
    except (TopicError, LogFormatError):
        raise
    except Exception as exc:  # noqa: BLE001 - rosbags raises AssertionError, ReaderError, ...
        if fmt != "rosbag1" or not is_rosbag(spath):
            raise LogFormatError(spath, f"cannot read bag: {type(exc).__name__}: {exc}") from exc
        reason = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        notes.append(f"rosbags could not open the index ({reason}); chunks read sequentially")
        log.info("%s: %s", spath, notes[-1])
        ts = get_typestore(Stores.ROS1_NOETIC)
        raw_msgs = list(iter_ros1_raw(spath))
        topics = {}
        for topic, mtype, _, _ in raw_msgs:
            m, cnt = topics.get(topic, (mtype, 0))
            topics[topic] = (mtype, cnt + 1)
        st = _choose(topics, SCAN_TYPE, scan_topic, "/scan")
        ot = _choose(topics, ODOM_TYPE, odom_topic, "/odom")
        entries = []
        for topic, mtype, t, raw in raw_msgs:
            if topic in (st, ot):
                try:
                    msg = ts.deserialize_ros1(raw, mtype)
                except Exception as exc2:  # noqa: BLE001
                    damage.drop(
                        LogFormatError(
                            spath,
                            f"cannot decode a {mtype} message on {topic} at {t * 1e-9:.3f} s: {exc2}",
                        )
                    )
                    continue
                entries.append((topic, mtype, t, msg))
        entries.sort(key=lambda e: e[2])

    if st is None and ot is None:
        raise LogFormatError(
            spath,
            "no sensor_msgs/LaserScan or nav_msgs/Odometry topic "
            f"(topics: {', '.join(f'{k} [{v[0]}]' for k, v in sorted(topics.items())) or 'none'})",
        )

    kept = []
    for e in entries:
        why = _unusable(e[3], e[0] == st)
        if why:
            damage.drop(LogFormatError(spath, f"{e[0]} message at {e[2] * 1e-9:.3f} s: {why}"))
        else:
            kept.append(e)
    entries = kept
    stamps = np.empty(len(entries))
    is_scan = np.zeros(len(entries), dtype=bool)
    n_bagtime = 0
    for k, (topic, _, tns, msg) in enumerate(entries):
        hs = _stamp(msg.header)
        if hs == 0.0:
            hs = tns * 1e-9
            n_bagtime += 1
        stamps[k] = hs
        is_scan[k] = topic == st
    if n_bagtime:
        notes.append(f"{n_bagtime} messages had a zero header stamp: bag record time used")
    rep = repair_stamps(stamps, is_scan, mode=timestamps, period=period)

    scans: list[tuple[float, int, Scan]] = []
    odoms: list[tuple[float, int, Odometry]] = []
    for k, (topic, _, _, msg) in enumerate(entries):
        tk = float(rep.stamps[k])
        if topic == st:
            r, a, f = _scan_arrays(msg)
            scans.append(
                (
                    tk,
                    k,
                    Scan(
                        stamp=tk,
                        ranges=r,
                        angles=a,
                        flags=f,
                        max_range=float(msg.range_max) if msg.range_max > 0 else math.inf,
                        min_range=max(float(msg.range_min), 0.0),
                        frame=str(msg.header.frame_id) or "laser",
                    ),
                )
            )
        else:
            p = msg.pose.pose
            v = msg.twist.twist
            odoms.append(
                (
                    tk,
                    k,
                    Odometry(
                        stamp=tk,
                        pose=(float(p.position.x), float(p.position.y), _yaw(p.orientation)),
                        velocity=(float(v.linear.x), float(v.angular.z)),
                        extra={"source": topic, "frame": str(msg.header.frame_id)},
                    ),
                )
            )
    scans.sort(key=lambda e: (e[0], e[1]))
    odoms.sort(key=lambda e: (e[0], e[1]))
    scan_list = [replace(sc, seq=seq) for seq, (_, _, sc) in enumerate(scans)]
    odom_list = [o for _, _, o in odoms]
    used = {}
    if st is not None:
        used[st] = SCAN_TYPE
    if ot is not None:
        used[ot] = ODOM_TYPE
    others = sorted(t for t in topics if t not in used)
    if others:
        notes.append("other topics ignored: " + ", ".join(others))
    info = LogInfo(
        path=spath,
        format=fmt,
        n_odometry=len(odom_list),
        **scan_span(scan_list),
        stamps=rep.status,
        stamp_note=rep.note,
        n_repaired_stamps=rep.n_changed,
        topics=used,
        notes=notes,
    )
    damage.fill(info)
    return LogData(info=info, scans=scan_list, odometry=odom_list)


def _unusable(msg: Any, is_scan: bool) -> str:
    """Why a LaserScan / Odometry message cannot be used ("" when it can)."""
    vals: tuple[Any, ...]
    try:
        if is_scan:
            vals = (msg.angle_min, msg.angle_increment)
            what = "non-finite angles"
        else:
            p = msg.pose.pose
            vals = (p.position.x, p.position.y, p.orientation.z, p.orientation.w)
            what = "non-finite pose"
        hs = float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)
    except (AttributeError, TypeError, ValueError) as e:
        return f"malformed message ({e})"
    if not all(math.isfinite(float(v)) for v in vals):
        return what
    if not math.isfinite(hs):
        return "non-finite stamp"
    return ""


# ----------------------------------------------------------------------------- writing


def _quat(th: float) -> tuple[float, float, float, float]:
    return 0.0, 0.0, math.sin(th / 2.0), math.cos(th / 2.0)


def write_rosbag(
    path: str | os.PathLike[str],
    scans: Sequence[Scan],
    odoms: Sequence[Odometry] = (),
    *,
    version: int = 1,
    scan_topic: str = "/scan",
    odom_topic: str = "/odom",
    scan_frame: str = "laser",
    odom_frame: str = "odom",
) -> None:
    """Write scans as LaserScan and odometry as Odometry into a ROS 1 (``version=1``, a
    ``.bag`` file) or ROS 2 (``version=2``, a bag directory) bag. Scan angles must be evenly
    spaced; no-return beams are written as +inf."""
    from rosbags.typesys import Stores, get_typestore

    if version not in (1, 2):
        raise ValueError("version must be 1 or 2")
    ts = get_typestore(Stores.ROS1_NOETIC if version == 1 else Stores.ROS2_HUMBLE)
    T = ts.types
    Time = T["builtin_interfaces/msg/Time"]

    def header(stamp: float, frame: str, seq: int) -> Any:
        sec = math.floor(stamp)
        nsec = min(int(round((stamp - sec) * 1e9)), 999_999_999)
        if version == 1:
            return T["std_msgs/msg/Header"](
                seq=seq, stamp=Time(sec=sec, nanosec=nsec), frame_id=frame
            )
        return T["std_msgs/msg/Header"](stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    msgs: list[tuple[int, int, str, Any]] = []
    for k, s in enumerate(scans):
        n = len(s)
        inc = float(s.angles[1] - s.angles[0]) if n > 1 else 0.0
        if n > 2 and not np.allclose(np.diff(s.angles), inc, atol=1e-9):
            raise ValueError(f"scan {k}: LaserScan needs evenly spaced angles")
        r = np.asarray(s.ranges, dtype=np.float64).copy()
        if s.flags is not None:
            r[(s.flags & (BEAM_NO_RETURN | BEAM_INVALID)) != 0] = np.inf
        m = T[SCAN_TYPE](
            header=header(s.stamp, scan_frame, k),
            angle_min=float(s.angles[0]) if n else 0.0,
            angle_max=float(s.angles[-1]) if n else 0.0,
            angle_increment=inc,
            time_increment=0.0,
            scan_time=0.0,
            range_min=float(s.min_range),
            range_max=float(s.max_range) if math.isfinite(s.max_range) else 1e3,
            ranges=r.astype(np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        msgs.append((int(round(s.stamp * 1e9)), 1, scan_topic, m))
    P = T["geometry_msgs/msg/Pose"]
    PT = T["geometry_msgs/msg/Point"]
    Q = T["geometry_msgs/msg/Quaternion"]
    V3 = T["geometry_msgs/msg/Vector3"]
    for k, o in enumerate(odoms):
        qx, qy, qz, qw = _quat(o.pose[2])
        v = o.velocity or (0.0, 0.0)
        m = T[ODOM_TYPE](
            header=header(o.stamp, odom_frame, k),
            child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](
                pose=P(
                    position=PT(x=float(o.pose[0]), y=float(o.pose[1]), z=0.0),
                    orientation=Q(x=qx, y=qy, z=qz, w=qw),
                ),
                covariance=np.zeros(36),
            ),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](
                    linear=V3(x=float(v[0]), y=0.0, z=0.0), angular=V3(x=0.0, y=0.0, z=float(v[1]))
                ),
                covariance=np.zeros(36),
            ),
        )
        msgs.append((int(round(o.stamp * 1e9)), 0, odom_topic, m))
    msgs.sort(key=lambda e: (e[0], e[1]))
    if version == 1:
        from rosbags.rosbag1 import Writer as Writer1

        with Writer1(Path(path)) as w:
            c1 = {scan_topic: w.add_connection(scan_topic, SCAN_TYPE, typestore=ts)}
            if odoms:
                c1[odom_topic] = w.add_connection(odom_topic, ODOM_TYPE, typestore=ts)
            for t, _, topic, m in msgs:
                w.write(c1[topic], t, ts.serialize_ros1(m, m.__msgtype__))
    else:
        from rosbags.rosbag2 import Writer as Writer2

        with Writer2(Path(path), version=9) as w2:
            c2 = {scan_topic: w2.add_connection(scan_topic, SCAN_TYPE, typestore=ts)}
            if odoms:
                c2[odom_topic] = w2.add_connection(odom_topic, ODOM_TYPE, typestore=ts)
            for t, _, topic, m in msgs:
                w2.write(c2[topic], t, ts.serialize_cdr(m, m.__msgtype__))


# sniffed first: a magic line or a metadata.yaml, no parsing (rosbags itself is imported
# only when a bag is read or written)
register_format("rosbag", is_rosbag, read_rosbag, (".bag", ".db3", ".mcap"), order=10)

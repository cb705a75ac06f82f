"""Fast protobuf encoding of the few planar Foxglove messages a localization run logs
(``foxglove.LaserScan``, ``PoseInFrame``, ``PosesInFrame``, ``FrameTransforms``), byte for
byte what ``foxglove-sdk``'s own ``message.encode()`` produces (proto3: zero scalars left
out, sub-messages always present; tests compare the two).

Building the SDK's message objects costs ~10-25 us per message in Python, several times a
localization step; these encoders build the same bytes with ``struct`` (a scan's ranges
are one ``tobytes``). The schemas themselves (``get_schema()``) and the MCAP writing are
the SDK's (:mod:`icploc.mcap_export`).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "frame_transforms",
    "laser_scan",
    "pose",
    "pose_in_frame",
    "poses_in_frame",
    "timestamp",
]

_pack_d = struct.Struct("<d").pack


def _varint(n: int) -> bytes:
    if n < 0:
        n += 1 << 64  # int64 as protobuf encodes it
    out = bytearray()
    while n > 0x7F:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _ld(tag: int, payload: bytes) -> bytes:
    """A length-delimited field (``tag`` is the whole tag byte: field << 3 | 2)."""
    n = len(payload)
    if n < 0x80:
        return bytes((tag, n)) + payload
    return bytes((tag,)) + _varint(n) + payload


_TAG = [bytes((t,)) for t in range(128)]


def _d(tag: int, v: float) -> bytes:
    """A double field (``tag``: field << 3 | 1), left out when zero (proto3)."""
    return _TAG[tag] + _pack_d(v) if v != 0.0 else b""


_strings: dict[int, dict[str, bytes]] = {0x12: {}, 0x1A: {}}


def _string(tag: int, s: str) -> bytes:
    """A string field; the few frame names are encoded once."""
    cache = _strings.get(tag)
    f = cache.get(s) if cache is not None else None
    if f is None:
        f = _ld(tag, s.encode()) if s else b""
        if cache is not None and len(cache) < 64:
            cache[s] = f
    return f


def timestamp(ns: int) -> bytes:
    """``google.protobuf.Timestamp`` of ``ns`` nanoseconds (the message body)."""
    sec, nsec = divmod(int(ns), 1_000_000_000)
    return (b"\x08" + _varint(sec) if sec else b"") + (b"\x10" + _varint(nsec) if nsec else b"")


_last_stamp: list[tuple[int, bytes]] = [(-1, b"")]


def _stamp_field(ns: int) -> bytes:
    """Field 1 = ``timestamp(ns)`` (the messages of one scan share it: cached)."""
    last = _last_stamp[0]
    if last[0] == ns:
        return last[1]
    f = _ld(0x0A, timestamp(ns))
    _last_stamp[0] = (ns, f)
    return f


def _vector3(x: float, y: float) -> bytes:
    return _d(0x09, x) + _d(0x11, y)


# a Pose with x, y, sin(theta/2), cos(theta/2) all non-zero (almost always): one pack
_POSE_FULL = struct.Struct("<3BdBd3BdBd")


def pose(p: Sequence[float]) -> bytes:
    """``foxglove.Pose`` of a planar pose (x, y, theta)."""
    x, y = p[0], p[1]
    h = 0.5 * p[2]
    qz, qw = math.sin(h), math.cos(h)
    if x != 0.0 and y != 0.0 and qz != 0.0 and qw != 0.0:
        return _POSE_FULL.pack(0x0A, 18, 0x09, x, 0x11, y, 0x12, 18, 0x19, qz, 0x21, qw)
    return _ld(0x0A, _vector3(x, y)) + _ld(0x12, _d(0x19, qz) + _d(0x21, qw))


_ORIGIN = pose((0.0, 0.0, 0.0))


def pose_in_frame(ns: int, frame: str, p: Sequence[float]) -> bytes:
    return _stamp_field(ns) + _string(0x12, frame) + _ld(0x1A, pose(p))


def poses_in_frame(ns: int, frame: str, poses: Sequence[Sequence[float]]) -> bytes:
    return _stamp_field(ns) + _string(0x12, frame) + b"".join(_ld(0x1A, pose(p)) for p in poses)


def _translation_rotation(x: float, y: float, theta: float) -> bytes:
    """FrameTransform fields 4 (translation) and 5 (rotation) of a planar pose."""
    h = 0.5 * theta
    qz, qw = math.sin(h), math.cos(h)
    if x != 0.0 and y != 0.0 and qz != 0.0 and qw != 0.0:
        return _POSE_FULL.pack(0x22, 18, 0x09, x, 0x11, y, 0x2A, 18, 0x19, qz, 0x21, qw)
    return _ld(0x22, _vector3(x, y)) + _ld(0x2A, _d(0x19, qz) + _d(0x21, qw))


def frame_transforms(ns: int, transforms: Sequence[tuple[str, str, Sequence[float]]]) -> bytes:
    """``foxglove.FrameTransforms`` of (parent, child, planar pose) triples, all at ``ns``."""
    ts = timestamp(ns)
    return b"".join(_ld(0x0A, _frame_transform(ts, a, b, p)) for a, b, p in transforms)


def _frame_transform(ts: bytes, parent: str, child: str, p: Sequence[float]) -> bytes:
    return (
        _ld(0x0A, ts)
        + _string(0x12, parent)
        + _string(0x1A, child)
        + _translation_rotation(p[0], p[1], p[2])
    )


def laser_scan(
    ns: int,
    frame: str,
    start_angle: float,
    end_angle: float,
    ranges: NDArray[np.float64] | bytes,
) -> bytes:
    """``foxglove.LaserScan`` at the frame's origin (ranges packed as doubles; given as
    an array, or already as little-endian float64 bytes)."""
    r = ranges if isinstance(ranges, bytes) else np.ascontiguousarray(ranges, "<f8").tobytes()
    return (
        _stamp_field(ns)
        + _string(0x12, frame)
        + _ld(0x1A, _ORIGIN)
        + _d(0x21, start_angle)
        + _d(0x29, end_angle)
        + (_ld(0x32, r) if r else b"")
    )

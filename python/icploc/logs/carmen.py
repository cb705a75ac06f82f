"""CARMEN text logs (``.log`` or ``.log.gz``): ``FLASER``, ``RLASER``, ``ROBOTLASER1``, ``RAWLASER1``, ``ODOM``.

Message layouts (whitespace separated; the last three tokens of every message are
``ipc_timestamp ipc_hostname logger_timestamp``; we use ``ipc_timestamp``)::

    FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ts host logger_ts
    RLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ts host logger_ts
    ROBOTLASER1 type start fov res max_range accuracy remission_mode n r_1 .. r_n
                m rem_1 .. rem_m laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis ts host logger_ts
    RAWLASER1 type start fov res max_range accuracy remission_mode n r_1 .. r_n
              m rem_1 .. rem_m ts host logger_ts
    ODOM x y theta tv rv accel ts host logger_ts

``FLASER`` carries no angles: n readings cover 180°; n = 180 / 360 (any even n) step
180°/n from −90°, n = 181 / 361 (any odd n) span −90°..+90° inclusive. Its ``x y theta``
is the pose the log reports for the laser (the SLAM-corrected pose in the Radish
"corrected" logs) and ``odom_*`` the odometry; ``ROBOTLASER1`` gives the laser pose and
the robot pose. Both are kept: :attr:`LogData.truth_poses` holds the reported pose per scan.

``RLASER`` is the rear laser, laid out as ``FLASER`` (its readings in its own frame, its
``x y theta`` the pose the log reports for it). It is read with ``rear_laser=True`` (a
replay with several lasers configured, :mod:`icploc.multilaser`); by default its lines
are skipped and counted, and a note says so. Scans carry their source in
:attr:`~icploc.messages.Scan.frame`: ``front_laser`` (``FLASER``), ``rear_laser``
(``RLASER``), ``laser`` (``ROBOTLASER1`` / ``RAWLASER1``); the ``PARAM``s
``robot_frontlaser_offset`` / ``robot_rearlaser_offset`` (m along the robot's x axis)
are reported in :attr:`LogInfo.notes` when a rear laser is read.

Parsing is whole-file and vectorised: lines are grouped by message type and beam count and
each group is converted to one float matrix at once (pandas' C parser when pandas is
installed, else ``numpy.fromstring``). When a group does not convert cleanly, it is parsed
line by line to find and report the first malformed line exactly.

Broken stamps (all zero, rounded, frozen, out of order) are handled by
:func:`icploc.logs._base.repair_stamps`; :attr:`LogInfo.stamps` / ``stamp_note`` say what
was done.
"""

from __future__ import annotations

import io
import math
import os
import re
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.logs._base import (
    Damage,
    LogData,
    LogFormatError,
    LogInfo,
    log,
    register_format,
    repair_stamps,
)
from icploc.messages import BEAM_INVALID, BEAM_NO_RETURN, Odometry, Scan

__all__ = [
    "CARMEN_TYPES",
    "flaser_angles",
    "is_carmen",
    "read_carmen",
    "write_carmen",
]

#: message types this reader understands; any other type is skipped (and counted)
CARMEN_TYPES = ("FLASER", "ROBOTLASER1", "RAWLASER1", "ODOM")
_KNOWN_OTHER = ("PARAM", "SYNC", "NEFF", "RLASER", "TRUEPOS", "ROBOTLASER2", "RAWLASER2")

#: PARAM written by :func:`write_carmen` so FLASER max range survives a round trip
MAX_RANGE_PARAM = "icploc_flaser_max_range"

_SENTINEL_WINDOW = 0.25  # m below the largest reading treated as the no-return sentinel
_STUCK_MIN_SCANS = 50


def flaser_angles(n: int, fov: float = math.pi) -> NDArray[np.float64]:
    """Beam angles of an n-reading FLASER (CARMEN convention, see the module doc)."""
    if n <= 0:
        raise ValueError(f"beam count must be positive, got {n}")
    if n % 2 == 1:
        if n == 1:
            return np.zeros(1)
        return np.linspace(-fov / 2, fov / 2, n)
    return -fov / 2 + np.arange(n, dtype=np.float64) * (fov / n)


#: default bound on a log's (decompressed) size; a bigger file is refused with a clear error
MAX_LOG_BYTES = 1 << 30


def _open_text(path: str | os.PathLike[str], max_bytes: int, damage: Damage) -> str:
    """The file as text, gunzipped when it is gzip, decompressed in bounded steps up to
    ``max_bytes`` (a gzip bomb is stopped there). A gzip stream cut short or corrupted
    part-way keeps what it held before (lenient; ``strict`` refuses it)."""
    limit = int(max_bytes)
    # unbuffered: a buffered reader's read() after a seek copies the file twice (10x slower)
    with open(path, "rb", buffering=0) as fh:
        if fh.read(2) != b"\x1f\x8b":
            size = os.fstat(fh.fileno()).st_size
            if size > limit:
                raise LogFormatError(path, f"is {size:,} bytes, more than the {limit:,} allowed")
            fh.seek(0)
            return fh.read().decode("latin-1")
        fh.seek(0)
        chunks: list[bytes] = []
        size = 0
        d = zlib.decompressobj(31)
        broken = ""
        fed = False  # the current member has been given input
        try:
            while comp := fh.read(1 << 20):
                while comp:
                    fed = True
                    out = d.decompress(comp, 1 << 22)
                    size += len(out)
                    if size > limit:
                        raise LogFormatError(
                            path,
                            f"decompresses to more than {limit:,} bytes; refusing to read it "
                            "whole (raise the bound with max_bytes= if the log is genuine)",
                        )
                    chunks.append(out)
                    comp = d.unconsumed_tail
                    if d.eof:  # a multi-member gzip: the next member follows
                        comp = d.unused_data
                        d = zlib.decompressobj(31)
                        fed = False
            if fed and not d.eof:
                broken = "the gzip stream ends before its end marker"
        except zlib.error as exc:
            broken = f"corrupt gzip data: {exc}"
    if broken:
        if damage.strict or not chunks:
            raise LogFormatError(path, f"broken gzip stream: {broken}")
        damage.drop(LogFormatError(path, f"{broken} (after {size:,} bytes)"))
    return b"".join(chunks).decode("latin-1")


def is_carmen(path: str | os.PathLike[str]) -> bool:
    """Sniff: the first non-comment lines of the (possibly gzipped) file are CARMEN messages."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(2)
        if head == b"\x1f\x8b":  # gzip only for a gzipped log (its import: ~1.5 ms of a start)
            import gzip

            opener: Callable[..., io.IOBase] = gzip.open  # type: ignore[assignment]
        else:
            opener = open  # type: ignore[assignment]
        with opener(path, "rb") as fh:
            chunk = fh.read(65536)
    except (OSError, EOFError):
        return False
    for line in chunk.decode("latin-1").split("\n")[:500]:
        toks = line.split(None, 1)
        if not toks or toks[0].startswith("#"):
            continue
        if toks[0] in CARMEN_TYPES:
            return True
        if "\x00" in line or not _is_type_word(toks[0]):
            return False
    name = os.fspath(path).lower()
    return name.endswith((".log", ".log.gz", ".clf", ".clf.gz"))


#: a character no CARMEN text line holds (anything but tab, CR and printable ASCII): binary
#: garbage that happens to start with an upper-case word is still garbage
_BINARY = re.compile(r"[^\t\r\x20-\x7e]")
#: control characters: no text line, not even a comment in some 8-bit encoding, holds them
_CONTROL = re.compile(r"[\x00-\x08\x0b\x0c\x0e-\x1f\x7f]")


def _cut_type(tok: str) -> str | None:
    """The message type this reader reads that ``tok`` is the start of, cut short (a line torn
    inside its first word, ``ROBOTLASE``), or None."""
    return next((k for k in CARMEN_TYPES if k != tok and k.startswith(tok)), None)


def _is_type_word(tok: str) -> bool:
    """A CARMEN message type: an upper-case ASCII word (``FLASER``, ``GPS_NMEA`` ...)."""
    return tok.isascii() and tok.replace("_", "").isalnum() and tok.isupper()


# ----------------------------------------------------------------------------- parsing


def _fast_matrix(heads: list[str], ncols: int) -> NDArray[np.float64] | None:
    """All rows as one (rows, ncols) matrix, or None when they do not convert cleanly (the
    caller then parses line by line, naming the bad line).

    The one float parser: the core's ``parse_floats`` (Rust; whitespace-separated decimal /
    exponent / ``nan`` / ``inf`` tokens, exact round-trip conversion, ``ValueError`` on any
    other token). NaN and inf come back as such; the readers check finiteness afterwards."""
    if not heads:
        return np.zeros((0, ncols))
    from icploc._core import parse_floats

    try:
        flat = np.asarray(parse_floats("\n".join(heads)), dtype=np.float64)
    except ValueError:
        return None
    return flat.reshape(len(heads), ncols) if flat.size == len(heads) * ncols else None


def _num(path: str, lineno: int, what: str, tok: str) -> float:
    try:
        return float(tok)
    except ValueError:
        raise LogFormatError(path, f"{what}: {tok!r} is not a number", lineno) from None


def _count(path: str, lineno: int, what: str, tok: str) -> int:
    try:
        v = int(tok)
    except ValueError:
        raise LogFormatError(path, f"{what}: {tok!r} is not an integer count", lineno) from None
    if v < 0 or v > 100_000:
        raise LogFormatError(path, f"{what}: count {v} out of range", lineno)
    return v


def _exact_flaser(path: str, lineno: int, line: str, kind: str = "FLASER") -> list[float]:
    t = line.split()
    if len(t) < 2:
        raise LogFormatError(path, f"{kind}: truncated line (no beam count)", lineno)
    n = _count(path, lineno, f"{kind} beam count", t[1])
    if n == 0:
        raise LogFormatError(path, f"{kind}: zero beams", lineno)
    need = 2 + n + 6 + 1
    if len(t) < need:
        raise LogFormatError(
            path,
            f"{kind}: truncated line: {n} readings + 6 pose values + timestamp need "
            f"{need} tokens, got {len(t)}",
            lineno,
        )
    if len(t) > need + 2:
        raise LogFormatError(
            path, f"{kind}: {len(t)} tokens, expected {need + 2} for {n} readings", lineno
        )
    _check_tail(path, lineno, kind, t, need)
    _check_not_short(
        path, lineno, kind, t, 2, need, f"{n} readings, 6 pose values and a timestamp"
    )
    vals = [float(n)]
    for k in range(2, need):
        what = f"{kind} reading {k - 1}" if k < 2 + n else f"{kind} pose/timestamp"
        vals.append(_num(path, lineno, what, t[k]))
    return vals


def _is_num(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return False
    return True


def _check_not_short(
    path: str, lineno: int, kind: str, t: list[str], start: int, need: int, what: str
) -> None:
    """A line whose hostname shows up where numbers are still expected is truncated."""
    for k in range(start, min(need, len(t))):
        if not _is_num(t[k]):
            if len(t) - k <= 2:  # only 'hostname [logger_ts]' left: values are missing
                raise LogFormatError(
                    path,
                    f"{kind}: truncated line: expected {what} ({need - start} numbers) before "
                    f"the hostname, found {k - start}",
                    lineno,
                )
            return


def _check_tail(path: str, lineno: int, kind: str, t: list[str], need: int) -> None:
    """Every message ends ``timestamp hostname logger_timestamp``: a line that stops at the
    timestamp (or the hostname) was cut off, and its last number may be cut too."""
    if len(t) < need + 2:
        raise LogFormatError(
            path,
            f"{kind}: truncated line: it ends before the hostname and logger timestamp",
            lineno,
        )


def _exact_odom(path: str, lineno: int, line: str) -> list[float]:
    t = line.split()
    if len(t) < 8:
        raise LogFormatError(
            path,
            f"ODOM: truncated line: need x y theta tv rv accel timestamp, got {len(t) - 1} values",
            lineno,
        )
    if len(t) > 10:
        raise LogFormatError(path, f"ODOM: {len(t)} tokens, expected 10", lineno)
    _check_tail(path, lineno, "ODOM", t, 8)
    _check_not_short(path, lineno, "ODOM", t, 1, 8, "x y theta tv rv accel timestamp")
    return [_num(path, lineno, "ODOM value", t[k]) for k in range(1, 8)]


def _exact_rawlaser(path: str, lineno: int, line: str, robot: bool) -> list[float]:
    kind = "ROBOTLASER1" if robot else "RAWLASER1"
    t = line.split()
    if len(t) < 9:
        raise LogFormatError(path, f"{kind}: truncated line", lineno)
    _check_not_short(path, lineno, kind, t, 1, 9, "a 7-value header and a beam count")
    vals = [_num(path, lineno, f"{kind} header", t[k]) for k in range(1, 8)]
    n = _count(path, lineno, f"{kind} beam count", t[8])
    if n == 0:
        raise LogFormatError(path, f"{kind}: zero beams", lineno)
    vals.append(float(n))
    if len(t) < 9 + n + 1:
        raise LogFormatError(path, f"{kind}: truncated line inside the {n} readings", lineno)
    vals.extend(_num(path, lineno, f"{kind} reading {k - 8}", t[k]) for k in range(9, 9 + n))
    m = _count(path, lineno, f"{kind} remission count", t[9 + n])
    vals.append(float(m))
    tail = 11 if robot else 0
    need = 9 + n + 1 + m + tail + 1
    if len(t) < need:
        raise LogFormatError(
            path,
            f"{kind}: truncated line: need {need} tokens for {n} readings, got {len(t)}",
            lineno,
        )
    if len(t) > need + 2:
        raise LogFormatError(path, f"{kind}: {len(t)} tokens, expected {need + 2}", lineno)
    _check_tail(path, lineno, kind, t, need)
    _check_not_short(path, lineno, kind, t, 10 + n, need, f"{m} remissions, poses and a timestamp")
    vals.extend(_num(path, lineno, f"{kind} value", t[k]) for k in range(10 + n, need))
    return vals


def _head(line: str) -> str:
    """The numeric part of a message: drop the type word, hostname and logger stamp."""
    return line.rsplit(None, 2)[0].split(None, 1)[1]


def _parse_group(
    path: str,
    lines: list[str],
    idx: list[int],
    ncols: int,
    exact: Callable[[str, int, str], list[float]],
    damage: Damage,
) -> tuple[NDArray[np.float64], list[int]]:
    """The rows of ``idx`` as one (rows, ncols) matrix and the line indices it holds.

    The whole group is converted at once; when it does not convert, it is halved until
    the pieces that do are found, and the lines left over are parsed exactly: a malformed
    one goes to ``damage`` (skipped and counted, or raised when strict)."""
    heads: list[str | None]
    try:
        heads = [_head(lines[i]) for i in idx]
    except IndexError:
        heads = []
        for i in idx:
            try:
                heads.append(_head(lines[i]))
            except IndexError:
                heads.append(None)
    mats: list[NDArray[np.float64]] = []
    kept: list[int] = []
    # halve a piece until it converts; small leftovers are parsed line by line (no
    # recursion, no closures: nothing here outlives the call in a reference cycle)
    todo = [(0, len(idx))]
    while todo:
        lo, hi = todo.pop()
        if lo >= hi:
            continue
        hs = heads[lo:hi]
        m = None if any(h is None for h in hs) else _fast_matrix(hs, ncols)  # type: ignore[arg-type]
        if m is not None:
            mats.append(m)
            kept.extend(idx[lo:hi])
        elif hi - lo > 16:
            mid = (lo + hi) // 2
            todo.append((mid, hi))  # popped after the first half: file order is kept
            todo.append((lo, mid))
        else:
            rows, got = [], []
            for k in range(lo, hi):
                i = idx[k]
                try:
                    r = exact(path, i + 1, lines[i])
                    if len(r) != ncols:
                        raise LogFormatError(path, f"expected {ncols} values, got {len(r)}", i + 1)
                except LogFormatError as e:
                    damage.drop(e)
                    continue
                rows.append(r)
                got.append(i)
            if rows:
                mats.append(np.array(rows, dtype=np.float64).reshape(len(rows), ncols))
                kept.extend(got)
    if not mats:
        return np.zeros((0, ncols)), []
    return (mats[0] if len(mats) == 1 else np.concatenate(mats)), kept


def _drop_rows(
    path: str,
    m: NDArray[np.float64],
    idx: list[int],
    flags: ArrayLike,
    why: str,
    damage: Damage,
) -> tuple[NDArray[np.float64], list[int]]:
    """Remove the rows flagged ``bad`` (each a malformed line: ``why``) from ``m`` / ``idx``."""
    bad = np.asarray(flags, dtype=bool).reshape(len(idx))
    if not bad.any():
        return m, idx
    for r in np.flatnonzero(bad):
        damage.drop(LogFormatError(path, why, idx[int(r)] + 1))
    ok = ~bad
    return m[ok], [i for i, k in zip(idx, ok, strict=True) if k]


def _check_finite(
    path: str, m: NDArray[np.float64], cols: Sequence[int] | slice, idx: list[int], what: str
) -> None:
    sub = m[:, cols]
    bad = ~np.isfinite(sub)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise LogFormatError(path, f"{what} is not finite ({sub[r, c]!r})", idx[int(r)] + 1)


@dataclass
class _LaserBlock:
    """One group of laser messages with the same layout."""

    idx: list[int]  # line indices
    ranges: NDArray[np.float64]  # (rows, n)
    angles: NDArray[np.float64]  # (n,)
    stamps: NDArray[np.float64]
    reported: NDArray[np.float64]  # (rows, 3) laser pose reported by the log
    odom: NDArray[np.float64]  # (rows, 3) odometry / robot pose
    velocity: NDArray[np.float64] | None  # (rows, 2)
    max_range: float  # nan: unknown (FLASER), decided later
    frame: str = "laser"  # the Scan.frame of its scans


def _flaser_block(
    path: str, lines: list[str], n: int, idx: list[int], fov: float, damage: Damage,
    kind: str = "FLASER",
) -> _LaserBlock:  # fmt: skip
    def exact(p: str, ln: int, line: str) -> list[float]:
        return _exact_flaser(p, ln, line, kind)

    m, idx = _parse_group(path, lines, idx, n + 8, exact, damage)
    bad = m[:, 0] != n
    if bad.any() and damage.strict:
        r = int(np.flatnonzero(bad)[0])
        exact(path, idx[r] + 1, lines[idx[r]])
        raise LogFormatError(path, f"{kind}: beam count and values disagree", idx[r] + 1)
    m, idx = _drop_rows(path, m, idx, bad, f"{kind}: beam count and values disagree", damage)
    if damage.strict:
        _check_finite(path, m, slice(n + 1, n + 8), idx, f"{kind} pose or timestamp")
    m, idx = _drop_rows(
        path, m, idx, ~np.isfinite(m[:, n + 1 : n + 7]).all(axis=1),
        f"{kind} pose or odometry is not finite", damage,
    )  # fmt: skip
    return _LaserBlock(
        idx=idx,
        ranges=m[:, 1 : n + 1],
        angles=flaser_angles(n, fov),
        stamps=m[:, n + 7].copy(),
        reported=m[:, n + 1 : n + 4].copy(),
        odom=m[:, n + 4 : n + 7].copy(),
        velocity=None,
        max_range=math.nan,
        frame="rear_laser" if kind == "RLASER" else "front_laser",
    )


def _rawlaser_blocks(
    path: str, lines: list[str], idx: list[int], robot: bool, damage: Damage
) -> list[_LaserBlock]:
    kind = "ROBOTLASER1" if robot else "RAWLASER1"
    # group by (n, m) read from the line itself; a line that cannot be grouped is parsed exactly
    groups: dict[tuple[int, int], list[int]] = {}
    for i in idx:
        t = lines[i].split(None, 9)
        try:
            n = int(t[8])
            rest = t[9].split(None, n + 1)
            mm = int(rest[n])
            if not (0 < n <= 100_000 and 0 <= mm <= 100_000):
                raise ValueError
        except (IndexError, ValueError):
            try:
                _exact_rawlaser(path, i + 1, lines[i], robot)
                raise LogFormatError(path, f"{kind}: malformed line", i + 1) from None
            except LogFormatError as e:
                damage.drop(e)
            continue
        groups.setdefault((n, mm), []).append(i)
    blocks = []
    tail = 11 if robot else 0
    for (n, mm), gidx in groups.items():
        ncols = 8 + n + 1 + mm + tail + 1
        mat, gidx = _parse_group(
            path, lines, gidx, ncols, lambda p, ln, s: _exact_rawlaser(p, ln, s, robot), damage
        )
        bad = (mat[:, 7] != n) | (mat[:, 8 + n] != mm)
        if bad.any() and damage.strict:
            r = int(np.flatnonzero(bad)[0])
            _exact_rawlaser(path, gidx[r] + 1, lines[gidx[r]], robot)
            raise LogFormatError(path, f"{kind}: counts and values disagree", gidx[r] + 1)
        mat, gidx = _drop_rows(path, mat, gidx, bad, f"{kind}: counts and values disagree", damage)
        base = 9 + n + mm
        if damage.strict:
            _check_finite(path, mat, slice(0, 7), gidx, f"{kind} header")
            _check_finite(path, mat, slice(base, ncols), gidx, f"{kind} pose or timestamp")
        mat, gidx = _drop_rows(
            path, mat, gidx, ~np.isfinite(mat[:, 0:7]).all(axis=1), f"{kind} header is not finite",
            damage,
        )  # fmt: skip
        if robot:
            mat, gidx = _drop_rows(
                path, mat, gidx, ~np.isfinite(mat[:, base : ncols - 1]).all(axis=1),
                f"{kind} pose or odometry is not finite", damage,
            )  # fmt: skip
        if not gidx:
            continue
        start, res, maxr = mat[:, 1], mat[:, 3], mat[:, 4]
        if not (np.all(start == start[0]) and np.all(res == res[0]) and np.all(maxr == maxr[0])):
            # geometry changes within the group: one block per line (rare)
            for r, i in enumerate(gidx):
                blocks.append(_rawlaser_row_block(mat[r], i, robot, n, mm))
            continue
        angles = start[0] + np.arange(n, dtype=np.float64) * res[0]
        rows = len(gidx)
        if robot:
            reported = mat[:, base : base + 3].copy()
            odom = mat[:, base + 3 : base + 6].copy()
            vel: NDArray[np.float64] | None = mat[:, base + 6 : base + 8].copy()
        else:
            reported = np.full((rows, 3), np.nan)
            odom = np.full((rows, 3), np.nan)
            vel = None
        blocks.append(
            _LaserBlock(
                idx=gidx,
                ranges=mat[:, 8 : 8 + n],
                angles=angles,
                stamps=mat[:, ncols - 1].copy(),
                reported=reported,
                odom=odom,
                velocity=vel,
                max_range=float(maxr[0]) if maxr[0] > 0 else math.inf,
            )
        )
    return blocks


def _rawlaser_row_block(
    v: NDArray[np.float64], i: int, robot: bool, n: int, mm: int
) -> _LaserBlock:
    """One parsed RAWLASER1 / ROBOTLASER1 row (``v``: its values after the type word)."""
    base = 9 + n + mm
    return _LaserBlock(
        idx=[i],
        ranges=v[None, 8 : 8 + n],
        angles=v[1] + np.arange(n) * v[3],
        stamps=v[-1:].copy(),
        reported=v[None, base : base + 3] if robot else np.full((1, 3), np.nan),
        odom=v[None, base + 3 : base + 6] if robot else np.full((1, 3), np.nan),
        velocity=v[None, base + 6 : base + 8] if robot else None,
        max_range=float(v[4]) if v[4] > 0 else math.inf,
    )


#: no planar laser measures this far (m): a larger reading is impossible, whatever the log says
ABSURD_RANGE = 1000.0


def beyond_limit(max_range: float) -> float:
    """Readings above this are impossible for a scanner of ``max_range`` (m): more than
    5 % (at least 0.5 m) beyond it, or beyond :data:`ABSURD_RANGE` when it is unknown."""
    if not math.isfinite(max_range) or max_range <= 0:
        return ABSURD_RANGE
    return min(ABSURD_RANGE, max_range + max(0.5, 0.05 * max_range))


def _detect_sentinel(ranges: list[NDArray[np.float64]]) -> float:
    """Threshold at and above which FLASER readings are the sensor's no-return value.

    SICK scanners report "no echo" as a saturated value (81.91, 81.83, 32.767, 51.x, 50.0 …)
    that then repeats across the log. If the largest reading, within 25 cm, is such a repeated
    value, everything from 25 cm below it up is no-return. A thin tail of impossible readings
    above the saturation value (at most 0.5 % of the readings, none repeated) does not hide
    it. Else the max range is unknown (inf).
    """
    if not ranges:
        return math.inf
    v = np.concatenate([r.ravel() for r in ranges])
    v = v[np.isfinite(v) & (v > 0) & (v <= ABSURD_RANGE)]
    if v.size == 0:
        return math.inf
    top = float(v.max())
    near = v[v >= top - _SENTINEL_WINDOW]
    _, counts = np.unique(np.round(near * 1000.0), return_counts=True)
    need = max(20, 0.001 * v.size)
    if counts.max() >= need:
        return top - _SENTINEL_WINDOW
    # the top is not repeated: the largest saturation value (repeated, and most of the
    # readings within 25 cm below it) with only a thin tail above it
    u, c = np.unique(np.round(v * 1000.0), return_counts=True)
    cum = np.cumsum(c)
    above = cum[-1] - cum  # readings above each value
    lo = np.searchsorted(u, u - _SENTINEL_WINDOW * 1000.0, side="left")
    window = cum - np.where(lo > 0, cum[np.maximum(lo - 1, 0)], 0)
    cand = np.flatnonzero((c >= need) & (above <= 0.005 * v.size) & (2 * c >= window))
    if cand.size:
        return float(u[cand[-1]]) / 1000.0 - _SENTINEL_WINDOW
    return math.inf


def read_carmen(
    path: str | os.PathLike[str],
    *,
    timestamps: str = "auto",
    period: float = 0.1,
    max_range: float | None = None,
    odometry: str = "auto",
    nan_ranges: str = "invalid",
    fov: float = math.pi,
    stuck_beams: bool = True,
    strict: bool = False,
    max_bytes: int = MAX_LOG_BYTES,
    rear_laser: bool = False,
) -> LogData:
    """Read a CARMEN log into memory.

    ``timestamps``: ``"auto"`` (repair, or fall back to scan index × ``period`` when the
    stamps are unusable), ``"raw"`` or ``"index"``; see :func:`~icploc.logs._base.repair_stamps`.
    ``max_range``: FLASER no-return threshold; default: ``PARAM icploc_flaser_max_range`` if
    present, else detected from the repeated saturation value. ``odometry``: ``"auto"`` (the
    ``ODOM`` lines if there are any, else the odometry embedded in the laser messages),
    ``"odom"``, ``"laser"`` or ``"none"``. ``nan_ranges``: ``"invalid"`` (a NaN reading
    becomes an inf beam flagged ``BEAM_INVALID``) or ``"error"``. ``fov``: FLASER coverage.
    ``stuck_beams``: flag as invalid a beam whose reading never changes over ≥ 50 scans.

    Damage: a malformed line (torn, binary garbage, a beam count that disagrees with the
    readings, a non-finite pose or odometry) is skipped and counted with its line number
    (:attr:`LogInfo.n_dropped`, the first ten in :attr:`LogInfo.dropped`); an impossible
    reading (NaN, negative, beyond the max range: :func:`beyond_limit`) becomes an invalid
    beam, counted in :attr:`LogInfo.invalid_readings`; a non-finite stamp is repaired like a
    missing one. ``strict=True`` raises :class:`LogFormatError` at the first of these
    instead. ``max_bytes``: the file (decompressed) may hold at most this many bytes.
    ``rear_laser``: also read the ``RLASER`` scans (frame ``rear_laser``; see the module
    docstring); else they are skipped and counted.
    """
    spath = os.fspath(path)
    if odometry not in ("auto", "odom", "laser", "none"):
        raise ValueError(f"odometry must be 'auto', 'odom', 'laser' or 'none', got {odometry!r}")
    if nan_ranges not in ("invalid", "error"):
        raise ValueError(f"nan_ranges must be 'invalid' or 'error', got {nan_ranges!r}")
    damage = Damage(spath, strict)
    text = _open_text(spath, max_bytes, damage)
    lines = text.split("\n")  # not splitlines(): \x85, \x0c ... in garbage are no line breaks

    flaser: dict[int, list[int]] = {}
    rlaser: dict[int, list[int]] = {}
    robot: list[int] = []
    raw: list[int] = []
    odom_idx: list[int] = []
    skipped: dict[str, int] = {}
    params: dict[str, str] = {}
    for i, line in enumerate(lines):
        t = line.split(None, 2)
        if not t or (t[0][0] == "#" and not _CONTROL.search(line)):
            continue  # a comment (one holding control characters is garbage: dropped below)
        kind = t[0]
        if kind == "FLASER" or (kind == "RLASER" and rear_laser):
            try:
                if len(t) < 2:
                    raise LogFormatError(spath, f"{kind}: truncated line (no beam count)", i + 1)
                n = _count(spath, i + 1, f"{kind} beam count", t[1])
                if n == 0:
                    raise LogFormatError(spath, f"{kind}: zero beams", i + 1)
            except LogFormatError as e:
                damage.drop(e)
                continue
            (flaser if kind == "FLASER" else rlaser).setdefault(n, []).append(i)
        elif kind == "ODOM":
            odom_idx.append(i)
        elif kind == "ROBOTLASER1":
            robot.append(i)
        elif kind == "RAWLASER1":
            raw.append(i)
        elif not _is_type_word(kind) or _BINARY.search(line):
            damage.drop(LogFormatError(spath, "not a CARMEN message (unreadable line)", i + 1))
        elif len(t) == 1 and (whole := _cut_type(kind)):
            damage.drop(LogFormatError(spath, f"torn line: {kind!r} is a cut-off {whole}", i + 1))
        else:
            if kind == "PARAM" and len(t) == 3:
                params[t[1]] = t[2].split(None, 1)[0] if t[2].split() else ""
            skipped[kind] = skipped.get(kind, 0) + 1

    blocks: list[_LaserBlock] = []
    for n, idx in sorted(flaser.items()):
        fb = _flaser_block(spath, lines, n, idx, fov, damage)
        if fb.idx:
            blocks.append(fb)
    for n, idx in sorted(rlaser.items()):  # the rear laser: a FLASER of its own
        fb = _flaser_block(spath, lines, n, idx, fov, damage, "RLASER")
        if fb.idx:
            blocks.append(fb)
    flaser_blocks = list(blocks)
    if robot:
        blocks.extend(_rawlaser_blocks(spath, lines, robot, True, damage))
    if raw:
        blocks.extend(_rawlaser_blocks(spath, lines, raw, False, damage))

    notes: list[str] = []
    if rlaser:
        offs = [f"{k} {params[k]}" for k in ("robot_frontlaser_offset", "robot_rearlaser_offset") if k in params]
        notes.append(
            f"{sum(len(v) for v in rlaser.values())} RLASER (rear laser) scans read, frame 'rear_laser'"
            + (f" (PARAM {', '.join(offs)})" if offs else "")
        )
    elif skipped.get("RLASER"):
        notes.append(
            f"{skipped['RLASER']} RLASER (rear laser) scans not read; configure scan.lasers "
            "to use them (icploc.multilaser)"
        )
    rb = [b for b in blocks[len(flaser_blocks) :] if b.velocity is not None]
    if rb:
        lp = np.concatenate([b.reported for b in rb])
        rp = np.concatenate([b.odom for b in rb])
        c, s_ = np.cos(rp[:, 2]), np.sin(rp[:, 2])
        dx, dy = lp[:, 0] - rp[:, 0], lp[:, 1] - rp[:, 1]
        off = np.median(
            np.column_stack(
                (
                    c * dx + s_ * dy,
                    -s_ * dx + c * dy,
                    np.remainder(lp[:, 2] - rp[:, 2] + np.pi, 2 * np.pi) - np.pi,
                )
            ),
            axis=0,
        )
        if np.any(np.abs(off) > 1e-6):
            notes.append(
                f"ROBOTLASER1 laser pose is offset from the robot pose by "
                f"({off[0]:.3f} m, {off[1]:.3f} m, {math.degrees(off[2]):.2f}°) (median)"
            )
    # FLASER max range
    if flaser_blocks:
        if max_range is not None:
            fl_max = float(max_range)
        elif MAX_RANGE_PARAM in params:
            try:
                fl_max = float(params[MAX_RANGE_PARAM])
            except ValueError:
                fl_max = math.nan
            if not fl_max > 0:
                raise LogFormatError(
                    spath,
                    f"PARAM {MAX_RANGE_PARAM} {params[MAX_RANGE_PARAM]!r} is not a positive number",
                )
        else:
            fl_max = _detect_sentinel([b.ranges for b in flaser_blocks])
            if math.isfinite(fl_max):
                notes.append(
                    f"FLASER readings >= {fl_max:.3f} m are taken as no-return (saturation value)"
                )
        for b in flaser_blocks:
            b.max_range = fl_max
    elif max_range is not None:
        for b in blocks:
            b.max_range = float(max_range)

    odo = np.zeros((0, 7))
    if odom_idx:
        odo, odom_idx = _parse_group(spath, lines, odom_idx, 7, _exact_odom, damage)
        if damage.strict:
            _check_finite(spath, odo, slice(0, 7), odom_idx, "ODOM value")
        odo, odom_idx = _drop_rows(
            spath, odo, odom_idx, ~np.isfinite(odo).all(axis=1), "ODOM value is not finite", damage
        )

    # ---- flags, per block (vectorised)
    flags_blocks: list[NDArray[np.uint8]] = []
    ranges_blocks: list[NDArray[np.float64]] = []
    for b in blocks:
        r = np.ascontiguousarray(b.ranges)
        nan = np.isnan(r)
        n_nan = int(np.count_nonzero(nan))
        if n_nan and nan_ranges == "error":
            row = int(np.argwhere(nan)[0][0])
            raise LogFormatError(spath, "NaN range reading", b.idx[row] + 1)
        mr = b.max_range if math.isfinite(b.max_range) else math.inf
        # impossible readings: negative, or far beyond what the scanner measures
        detected = max_range is None and any(b is fb for fb in flaser_blocks)
        limit = beyond_limit(mr + _SENTINEL_WINDOW if detected else mr)
        impossible = (r < 0) | (r > limit)  # NaN compares False
        noret = (r == 0) | (r >= mr)
        if impossible.any():
            for what, sel in (("negative", r < 0), ("beyond max range", r > limit)):
                if sel.any():
                    row = int(np.argwhere(sel)[0][0])
                    damage.readings(
                        what, int(np.count_nonzero(sel)), b.idx[row] + 1, float(r[sel][0])
                    )
            noret &= ~impossible
        if n_nan:
            row = int(np.argwhere(nan)[0][0])
            damage.readings("NaN", n_nan, b.idx[row] + 1, math.nan)
        fl = noret.view(np.uint8) * np.uint8(BEAM_NO_RETURN)
        bad = noret
        if n_nan or impossible.any():
            inval = nan | impossible
            fl |= inval.view(np.uint8) * np.uint8(BEAM_INVALID)
            bad = noret | inval
        if stuck_beams and r.shape[0] >= _STUCK_MIN_SCANS:
            const = np.all(r == r[0], axis=0) & ~bad[0]
            if 0 < const.sum() < 0.1 * r.shape[1]:
                fl[:, const] |= np.uint8(BEAM_INVALID)
                bad = bad.copy()
                bad[:, const] = True
                notes.append(
                    f"{int(const.sum())} beam(s) of {r.shape[1]} never change "
                    f"(index {', '.join(map(str, np.flatnonzero(const)[:5]))}): flagged invalid"
                )
        if bad.any():
            r[bad] = np.inf  # r is a copy of, or the parsed matrix itself: ours to change
        flags_blocks.append(fl)
        ranges_blocks.append(r)

    # ---- one timeline in file order
    scan_line = (
        np.concatenate([np.asarray(b.idx, dtype=np.int64) for b in blocks])
        if blocks
        else np.zeros(0, np.int64)
    )
    scan_stamp = np.concatenate([b.stamps for b in blocks]) if blocks else np.zeros(0)
    n_sc = len(scan_line)
    all_line = np.concatenate([scan_line, np.asarray(odom_idx, dtype=np.int64)])
    all_stamp = np.concatenate([scan_stamp, odo[:, 6] if len(odo) else np.zeros(0)])
    is_scan = np.concatenate([np.ones(n_sc, bool), np.zeros(len(odom_idx), bool)])
    order = np.argsort(all_line, kind="stable")
    rep = repair_stamps(all_stamp[order], is_scan[order], mode=timestamps, period=period)
    fixed = np.empty_like(all_stamp)
    fixed[order] = rep.stamps
    scan_t = fixed[:n_sc]
    odom_t = fixed[n_sc:]

    # corrected logs (Radish) follow each laser message with an unstamped ODOM line that
    # repeats the laser's reported pose: say so, the ODOM stream is then not raw odometry
    if len(odo) and n_sc:
        so = np.argsort(scan_line)
        sl = scan_line[so]
        rep_pose = np.concatenate([b.reported for b in blocks])[so]
        oi = np.asarray(odom_idx, dtype=np.int64)
        prev = np.searchsorted(sl, oi) - 1
        has = (prev >= 0) & (odo[:, 6] == 0.0)
        same = np.zeros(len(oi), dtype=bool)
        same[has] = np.all(odo[has, :3] == rep_pose[prev[has]], axis=1)
        if int(same.sum()):
            notes.append(
                f"{int(same.sum())} unstamped ODOM lines repeat the preceding laser pose "
                "(a corrected log: its ODOM stream follows the corrected path, it is not raw odometry)"
            )

    # ---- build objects (time order; file order on equal stamps)
    rows: list[tuple[float, int, int, int]] = []  # stamp, line, block, row
    k = 0
    for bi, b in enumerate(blocks):
        b.angles.setflags(write=False)
        for j in range(len(b.idx)):
            rows.append((float(scan_t[k]), b.idx[j], bi, j))
            k += 1
    rows.sort()
    scans: list[Scan] = []
    for seq, (st, _, bi, j) in enumerate(rows):
        b = blocks[bi]
        scans.append(
            Scan(
                stamp=st,
                ranges=ranges_blocks[bi][j],
                angles=b.angles,
                flags=flags_blocks[bi][j],
                seq=seq,
                max_range=b.max_range if math.isfinite(b.max_range) else math.inf,
                frame=b.frame,
            )
        )
    truth_st = np.array([r[0] for r in rows], dtype=np.float64)
    truth_ps = np.array([blocks[r[2]].reported[r[3]] for r in rows], dtype=np.float64).reshape(
        -1, 3
    )
    has_truth = bool(len(truth_ps)) and bool(np.all(np.isfinite(truth_ps)))
    scan_odo = np.array([blocks[r[2]].odom[r[3]] for r in rows], dtype=np.float64).reshape(-1, 3)
    if not np.all(np.isfinite(scan_odo)):
        scan_odo = np.zeros((0, 3))

    use = odometry
    if use == "auto":
        use = "odom" if odom_idx else "laser"
    odoms: list[Odometry] = []
    if use == "odom":
        oo = np.argsort(odom_t, kind="stable")
        for j in oo:
            odoms.append(
                Odometry(
                    stamp=float(odom_t[j]),
                    pose=(float(odo[j, 0]), float(odo[j, 1]), float(odo[j, 2])),
                    velocity=(float(odo[j, 3]), float(odo[j, 4])),
                    extra={"source": "ODOM", "line": int(odom_idx[j]) + 1},
                )
            )
    elif use == "laser":
        # each block's rows as floats once (not three numpy scalars and a reduction a scan)
        finite: list[list[bool]] = [np.isfinite(b.odom).all(axis=1).tolist() for b in blocks]  # type: ignore[misc]
        odom_rows = [b.odom.tolist() for b in blocks]
        vel_rows = [None if b.velocity is None else b.velocity.tolist() for b in blocks]
        for st, li, bi, j in rows:
            if finite[bi][j]:
                od = odom_rows[bi][j]
                vr = vel_rows[bi]
                vel = None if vr is None else (vr[j][0], vr[j][1])
                odoms.append(
                    Odometry(
                        stamp=st,
                        pose=(od[0], od[1], od[2]),
                        velocity=vel,
                        extra={"source": lines[li].split(None, 1)[0], "line": li + 1},
                    )
                )

    beams = tuple(sorted({len(b.angles) for b in blocks}))
    info = LogInfo(
        path=spath,
        format="carmen",
        n_scans=len(scans),
        n_odometry=len(odoms),
        beams=beams,
        angle_min=min((float(b.angles[0]) for b in blocks), default=math.nan),
        angle_max=max((float(b.angles[-1]) for b in blocks), default=math.nan),
        max_range=min((b.max_range for b in blocks), default=math.inf) if blocks else math.inf,
        start=float(scans[0].stamp) if scans else math.nan,
        end=float(scans[-1].stamp) if scans else math.nan,
        stamps=rep.status,
        stamp_note=rep.note,
        n_repaired_stamps=rep.n_changed,
        has_truth=has_truth,
        skipped=skipped,
        notes=notes,
    )
    damage.fill(info)
    if not scans and not odoms:
        why = "; ".join(d.strip() for d in info.damage_lines())
        raise LogFormatError(
            spath,
            "no FLASER, ROBOTLASER1, RAWLASER1 or ODOM message found"
            + (f" ({why})" if why else ""),
        )
    log.info("read %s: %d scans, %d odometry, stamps %s", spath, len(scans), len(odoms), rep.status)
    return LogData(
        info=info,
        scans=scans,
        odometry=odoms,
        truth_stamps=truth_st if has_truth else np.zeros(0),
        truth_poses=truth_ps if has_truth else np.zeros((0, 3)),
        scan_odometry=scan_odo,
    )


# ----------------------------------------------------------------------------- writing


def _fmt(v: float, precision: int | None) -> str:
    if precision is None:
        return repr(float(v))
    return f"{v:.{precision}f}"


def write_carmen(
    path: str | os.PathLike[str],
    scans: Sequence[Scan],
    odoms: Iterable[Odometry] = (),
    *,
    poses: ArrayLike | None = None,
    scan_odometry: ArrayLike | None = None,
    fmt: str = "FLASER",
    no_return: float | None = None,
    precision: int | None = None,
    hostname: str = "icploc",
) -> None:
    """Write scans and odometry as a CARMEN log (gzip if ``path`` ends in ``.gz``).

    ``poses`` (N, 3): the pose reported with each scan (FLASER ``x y theta`` /
    ROBOTLASER1 laser pose), zeros by default; ``scan_odometry`` (N, 3): the odometry
    written with each scan, ``poses`` by default. ``fmt``: ``"FLASER"`` (the scan angles
    must follow the FLASER convention for their beam count; a scan of frame ``rear_laser``
    is written as ``RLASER``) or ``"ROBOTLASER1"`` (evenly
    spaced angles of any span). No-return beams are written as ``no_return`` (default: the
    scan's finite max range, else 81.91). ``precision``: decimals for readings (None: exact).
    Lines are written in time order (odometry first on equal stamps).
    """
    if fmt not in ("FLASER", "ROBOTLASER1"):
        raise ValueError(f"fmt must be 'FLASER' or 'ROBOTLASER1', got {fmt!r}")
    ns = len(scans)
    P = np.zeros((ns, 3)) if poses is None else np.asarray(poses, dtype=np.float64).reshape(ns, 3)
    Q = P if scan_odometry is None else np.asarray(scan_odometry, dtype=np.float64).reshape(ns, 3)
    entries: list[tuple[float, int, str]] = []
    flaser_max: float | None = None
    for k, s in enumerate(scans):
        n = len(s)
        mr = s.max_range if math.isfinite(s.max_range) else 81.91
        nr = float(no_return) if no_return is not None else mr
        r = np.where(np.isfinite(s.ranges), s.ranges, nr)
        if s.flags is not None:
            r = np.where((s.flags & (BEAM_NO_RETURN | BEAM_INVALID)) != 0, nr, r)
        rs = " ".join(_fmt(v, precision) for v in r)
        ps = " ".join(_fmt(v, None) for v in P[k])
        os_ = " ".join(_fmt(v, None) for v in Q[k])
        st = repr(float(s.stamp))
        if fmt == "FLASER":
            if not np.allclose(s.angles, flaser_angles(n), atol=1e-9):
                raise ValueError(
                    f"scan {k}: angles do not follow the FLASER convention for {n} beams; "
                    "use fmt='ROBOTLASER1'"
                )
            flaser_max = nr if flaser_max is None else min(flaser_max, nr)
            kind = "RLASER" if s.frame == "rear_laser" else "FLASER"  # the rear laser's own
            line = f"{kind} {n} {rs} {ps} {os_} {st} {hostname} {st}"
        else:
            a0 = float(s.angles[0])
            res = float(s.angles[1] - s.angles[0]) if n > 1 else 0.0
            if n > 2 and not np.allclose(np.diff(s.angles), res, atol=1e-9):
                raise ValueError(f"scan {k}: ROBOTLASER1 needs evenly spaced angles")
            fov = res * (n - 1) if n > 1 else 0.0
            line = (
                f"ROBOTLASER1 0 {a0!r} {fov!r} {res!r} {mr!r} 0.01 0 {n} {rs} 0 {ps} {os_} "
                f"0 0 0 0 0 {st} {hostname} {st}"
            )
        entries.append((float(s.stamp), 1, line))
    for o in odoms:
        v = o.velocity or (0.0, 0.0)
        st = repr(float(o.stamp))
        pose = " ".join(_fmt(x, None) for x in o.pose)
        entries.append(
            (
                float(o.stamp),
                0,
                f"ODOM {pose} {float(v[0])!r} {float(v[1])!r} 0 {st} {hostname} {st}",
            )
        )
    entries.sort(key=lambda e: (e[0], e[1]))
    out = [
        "# CARMEN log written by icploc",
        "# message formats defined: PARAM ODOM FLASER RLASER ROBOTLASER1",
    ]
    if flaser_max is not None:
        out.append(f"PARAM {MAX_RANGE_PARAM} {flaser_max!r} {hostname} 0")
    out.extend(e[2] for e in entries)
    data = ("\n".join(out) + "\n").encode("ascii")
    if os.fspath(path).endswith(".gz"):
        import gzip

        data = gzip.compress(data, mtime=0)
    with open(path, "wb") as fh:
        fh.write(data)


register_format("carmen", is_carmen, read_carmen, (".log", ".log.gz", ".clf", ".clf.gz", ".gz"), 20)

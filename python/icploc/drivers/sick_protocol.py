"""SICK PLS / LMS 2xx telegram protocol: framing, CRC, encoding, a resynchronising
stream parser and the decoding of measured-value (0xB0) telegrams into :class:`Scan`.

Everything here is pure (no I/O) so the driver, the device simulator and the replay of
recorded bytes share one implementation. Spec: ``../shared/protocols/PROTOCOLS.md`` §A.

Frame (§A.2)::

    STX(02) ADR LEN(word LE) CMD DATA... [STATUS] CRC(word LE)

``LEN`` counts CMD .. STATUS; the CRC covers STX .. the byte before the CRC.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.drivers.byteclock import ByteClock
from icploc.errors import DeviceError
from icploc.messages import (
    BEAM_DAZZLE,
    BEAM_FIELD_A,
    BEAM_FIELD_B,
    BEAM_FIELD_C,
    BEAM_INVALID,
    BEAM_NO_RETURN,
    Scan,
)

STX = 0x02
ACK = 0x06
NAK = 0x15

#: Largest LEN we accept (LMS listing: 812 data bytes per telegram).
MAX_LEN = 812
#: Largest whole telegram (LEN + STX, ADR, 2 LEN bytes, 2 CRC bytes).
MAX_TELEGRAM = MAX_LEN + 6

# Commands (host -> device) and replies (device -> host), §A.6.
CMD_RESET = 0x10
CMD_MODE = 0x20
CMD_MEASURED = 0x30
CMD_STATUS = 0x31
CMD_ERRORS = 0x32
CMD_TYPE = 0x3A
CMD_VARIANT = 0x3B
REPLY_POWER_ON = 0x90
REPLY_RESET = 0x91
REPLY_NOT_ACK = 0x92
REPLY_MODE = 0xA0
REPLY_MEASURED = 0xB0

# Sub-modes of command 0x20 (first data byte).
MODE_INSTALL = 0x00
MODE_DIAGNOSTIC = 0x10
MODE_STREAM_MIN = 0x20
MODE_STREAM_ALL = 0x24
MODE_ON_REQUEST = 0x25
MODE_BAUD = {38400: 0x40, 19200: 0x41, 9600: 0x42, 500000: 0x48}
BAUD_OF_MODE = {v: k for k, v in MODE_BAUD.items()}

PASSWORD_PLS = b"SICK_PLS"
PASSWORD_LMS = b"SICK_LMS"

# Distance special codes in 13-bit modes (§A.7): values >= 0x1FF7 are not distances.
CODE_VALUE_TOO_LARGE = 0x1FF7
CODE_SN_TOO_SMALL = 0x1FFB
CODE_DAZZLED = 0x1FFE
CODE_NO_ECHO = 0x1FFF

UNIT_METRES = {0: 0.01, 1: 0.001, 2: 0.1}  # count-word bits 14..15 (2 = 10 cm per ARIA)


class SickProtocolError(DeviceError, ValueError):
    """A telegram could not be built or decoded (bad length, wrong reply, bad CRC).

    The stream parser never raises: it counts and skips bad input. Only the explicit
    decode functions raise this, and only this.
    """


def crc16(data: bytes | bytearray | memoryview) -> int:
    """SICK ``CreateCRC`` exactly as in §A.3 (generator 0x8005, sliding 16-bit window)."""
    crc = 0
    prev = 0
    for b in bytes(data):
        if crc & 0x8000:
            crc = ((crc & 0x7FFF) << 1) ^ 0x8005
        else:
            crc = (crc << 1) & 0xFFFF
        crc ^= b | (prev << 8)
        prev = b
    return crc


def build_telegram(
    cmd: int, data: bytes = b"", *, address: int = 0x00, status: int | None = None
) -> bytes:
    """Encode one telegram. Host telegrams have no status; device replies do
    (pass ``address=0x80`` and a ``status`` byte)."""
    body = bytes([cmd & 0xFF]) + bytes(data) + (b"" if status is None else bytes([status & 0xFF]))
    if len(body) > MAX_LEN:
        raise SickProtocolError(f"telegram body of {len(body)} bytes exceeds {MAX_LEN}")
    head = bytes([STX, address & 0xFF, len(body) & 0xFF, len(body) >> 8])
    frame = head + body
    crc = crc16(frame)
    return frame + bytes([crc & 0xFF, crc >> 8])


def check_telegram(frame: bytes) -> bool:
    """True if ``frame`` is one complete telegram with a consistent LEN and a good CRC."""
    if len(frame) < 7 or frame[0] != STX:
        return False
    n = frame[2] | (frame[3] << 8)
    if n + 6 != len(frame):
        return False
    return crc16(frame[:-2]) == (frame[-2] | (frame[-1] << 8))


@dataclass(frozen=True)
class Telegram:
    """One framed telegram. ``status`` is None for host->device telegrams."""

    address: int
    cmd: int
    data: bytes
    status: int | None
    stamp: float = 0.0  #: arrival time of the STX byte (parser clock)
    raw: bytes = b""


@dataclass(frozen=True)
class ByteEvent:
    """A single ACK (0x06) or NAK (0x15) byte seen between telegrams."""

    value: int
    stamp: float = 0.0


@dataclass
class ParserStats:
    telegrams: int = 0
    crc_errors: int = 0
    length_errors: int = 0
    resyncs: int = 0
    dropped_bytes: int = 0
    acks: int = 0
    naks: int = 0
    bytes_in: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class TelegramParser:
    """Incremental telegram finder for an arbitrary byte stream (§A.4).

    * syncs on STX followed by an accepted address byte;
    * bounds-checks LEN (``min_len`` .. :data:`MAX_LEN`), else drops the STX;
    * verifies the CRC; on a bad CRC drops **only** the STX byte and resynchronises
      (so a real telegram hidden inside a false start is still found);
    * reports stray ACK/NAK bytes between telegrams as :class:`ByteEvent`;
    * counts everything in :attr:`stats`.

    Memory is bounded: after :meth:`feed` returns at most ``MAX_TELEGRAM - 1`` bytes are
    kept. :meth:`feed` never raises on any input.

    ``device_side=False`` (default) parses device->host replies (address 0x80..0x84,
    with a status byte); ``device_side=True`` parses host->device telegrams (any
    address below 0x80, no status byte), which is what the simulator needs.
    """

    device_side: bool = False
    addresses: frozenset[int] | None = None
    byte_time: float = 0.0  #: seconds per byte on the line, to back-date stamps
    stats: ParserStats = field(default_factory=ParserStats)

    def __post_init__(self) -> None:
        if self.addresses is None:
            self.addresses = (
                frozenset(range(0x00, 0x80)) if self.device_side else frozenset(range(0x80, 0x85))
            )
        self._buf = bytearray()
        self._clock = ByteClock()
        self._min_len = 1 if self.device_side else 2

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def reset(self) -> None:
        self._buf.clear()
        self._clock.clear()

    def feed(self, data: bytes, stamp: float = 0.0) -> list[Telegram | ByteEvent]:
        """Add bytes that arrived by ``stamp`` (arrival of the last byte) and return every
        telegram / ACK / NAK completed by them, in stream order."""
        out: list[Telegram | ByteEvent] = []
        if not data:
            return out
        st = self.stats
        st.bytes_in += len(data)
        buf = self._buf
        buf += data
        clock = self._clock
        clock.add(len(buf), stamp, self.byte_time)
        t_of = clock.time_of
        addresses = self.addresses
        assert addresses is not None
        pos = 0
        end = len(buf)
        while pos < end:
            b = buf[pos]
            if b != STX:
                # skip to the next STX, classifying what we skip
                nxt = buf.find(STX, pos)
                stop = end if nxt < 0 else nxt
                for j in range(pos, stop):
                    c = buf[j]
                    if c == ACK:
                        st.acks += 1
                        out.append(ByteEvent(ACK, t_of(j)))
                    elif c == NAK:
                        st.naks += 1
                        out.append(ByteEvent(NAK, t_of(j)))
                    else:
                        st.dropped_bytes += 1
                pos = stop
                continue
            if pos + 1 >= end:
                break  # need the address byte
            if buf[pos + 1] not in addresses:
                st.dropped_bytes += 1
                pos += 1
                continue
            if pos + 4 > end:
                break
            n = buf[pos + 2] | (buf[pos + 3] << 8)
            if n < self._min_len or n > MAX_LEN:
                st.length_errors += 1
                st.resyncs += 1
                st.dropped_bytes += 1
                pos += 1
                continue
            total = n + 6
            if pos + total > end:
                break  # wait for the rest
            frame = bytes(buf[pos : pos + total])
            if crc16(frame[:-2]) != (frame[-2] | (frame[-1] << 8)):
                st.crc_errors += 1
                st.resyncs += 1
                st.dropped_bytes += 1
                pos += 1  # drop only the STX and hunt again
                continue
            body = frame[4:-2]
            if self.device_side:
                tel = Telegram(frame[1], body[0], body[1:], None, t_of(pos), frame)
            else:
                tel = Telegram(frame[1], body[0], body[1:-1], body[-1], t_of(pos), frame)
            st.telegrams += 1
            out.append(tel)
            pos += total
        if pos:
            del buf[:pos]
            clock.consume(pos)
        return out


# --------------------------------------------------------------------------- decoding


@dataclass(frozen=True)
class ScanGeometry:
    """How value index maps to beam angle."""

    fov_deg: float = 180.0
    flipped: bool = False  #: scanner mounted upside down: reverse the index->angle map

    def angles(self, n: int) -> NDArray[np.float64]:
        return _beam_angles(self.fov_deg, self.flipped, n).copy()


@functools.lru_cache(maxsize=32)
def _beam_angles(fov_deg: float, flipped: bool, n: int) -> NDArray[np.float64]:
    if n < 2:
        return np.zeros(n)
    half = math.radians(fov_deg) / 2.0
    a = np.linspace(-half, half, n)
    return a[::-1].copy() if flipped else a


def geometry_for_count(n: int, flipped: bool = False) -> ScanGeometry:
    """Field of view implied by the number of values (§A.7): 361/181 → 180°,
    401/201/101 → 100°."""
    if n in (401, 201, 101):
        return ScanGeometry(100.0, flipped)
    return ScanGeometry(180.0, flipped)


# flag bits 13..15 of a value word -> Scan flags
_PLS_FLAGS = np.array(
    [
        (BEAM_DAZZLE if k & 1 else 0)
        | (BEAM_FIELD_B if k & 2 else 0)
        | (BEAM_FIELD_A if k & 4 else 0)
        for k in range(8)
    ],
    dtype=np.uint8,
)
_LMS_FLAGS = np.array(
    [
        (BEAM_FIELD_A if k & 1 else 0)
        | (BEAM_FIELD_B if k & 2 else 0)
        | (BEAM_FIELD_C if k & 4 else 0)
        for k in range(8)
    ],
    dtype=np.uint8,
)


@dataclass(frozen=True)
class MeasuredValues:
    """Raw content of a 0xB0 reply."""

    count: int
    unit_m: float
    partial: bool
    partial_index: int
    values: NDArray[np.uint16]
    status: int | None


def parse_measured(data: bytes, status: int | None = None) -> MeasuredValues:
    """Split a 0xB0 data field into count word and value words (§A.7)."""
    if len(data) < 2:
        raise SickProtocolError("B0 telegram shorter than its count word")
    cw = data[0] | (data[1] << 8)
    n = cw & 0x03FF
    unit_code = (cw >> 14) & 0x3
    if unit_code not in UNIT_METRES:
        raise SickProtocolError(f"B0 telegram with reserved unit code {unit_code}")
    if len(data) < 2 + 2 * n:
        raise SickProtocolError(
            f"B0 telegram announces {n} values but holds {(len(data) - 2) // 2}"
        )
    vals = np.frombuffer(data, dtype="<u2", count=n, offset=2).astype(np.uint16)
    return MeasuredValues(
        n, UNIT_METRES[unit_code], bool(cw & 0x2000), (cw >> 11) & 0x3, vals, status
    )


def decode_scan(
    tel: Telegram,
    *,
    variant: str = "pls",
    seq: int = 0,
    flipped: bool = False,
    geometry: ScanGeometry | None = None,
    max_range: float | None = None,
) -> Scan:
    """Decode a 0xB0 telegram into a :class:`Scan` (13-bit distance modes).

    Ranges in metres; codes >= 0x1FF7 and zero become ``inf`` with ``BEAM_NO_RETURN``
    (plus ``BEAM_DAZZLE`` for 0x1FFE, ``BEAM_INVALID`` for the error codes).
    Flag bits 13..15: PLS → dazzle, warning field (B), protective field (A) [CARMEN,
    unverified]; LMS → field A, B, C.
    """
    if tel.cmd != REPLY_MEASURED:
        raise SickProtocolError(f"not a measured-values telegram: reply 0x{tel.cmd:02X}")
    mv = parse_measured(tel.data, tel.status)
    if mv.partial:
        raise SickProtocolError("interlaced partial scans are not supported")
    v = mv.values
    dist = v & 0x1FFF
    flags = (_PLS_FLAGS if variant == "pls" else _LMS_FLAGS)[v >> 13]
    special = dist >= CODE_VALUE_TOO_LARGE
    no_ret = special | (dist == 0)
    if no_ret.any():
        flags[no_ret] |= BEAM_NO_RETURN
        flags[dist == CODE_DAZZLED] |= BEAM_DAZZLE
        err = (
            special
            & (dist != CODE_NO_ECHO)
            & (dist != CODE_VALUE_TOO_LARGE)
            & (dist != CODE_DAZZLED)
        )
        flags[err] |= BEAM_INVALID
    ranges = dist.astype(np.float64) * mv.unit_m
    ranges[no_ret] = np.inf
    geom = geometry or geometry_for_count(mv.count, flipped)
    angles = geom.angles(mv.count)
    if max_range is None:
        max_range = (CODE_VALUE_TOO_LARGE - 1) * mv.unit_m
        if variant == "pls":
            max_range = min(max_range, 50.0)
    return Scan(
        stamp=tel.stamp, ranges=ranges, angles=angles, flags=flags, seq=seq, max_range=max_range
    )


def encode_measured(
    ranges_m: ArrayLike,
    *,
    unit_m: float = 0.01,
    status: int = 0x00,
    flag_bits: NDArray[np.uint16] | None = None,
    address: int = 0x80,
) -> bytes:
    """Build a 0xB0 telegram from ranges in metres (inf / nan / out of range → 0x1FFF).
    ``flag_bits`` (values 0..7) go to bits 13..15 of each word."""
    r = np.asarray(ranges_m, dtype=np.float64)
    n = r.shape[0]
    if n > 0x3FF:
        raise SickProtocolError(f"{n} values do not fit the count word")
    unit_code = {0.01: 0, 0.001: 1, 0.1: 2}.get(unit_m)
    if unit_code is None:
        raise SickProtocolError(f"unsupported unit {unit_m} m")
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(r) & (r >= 0)
        q = np.where(ok, np.rint(np.where(ok, r, 0.0) / unit_m), CODE_NO_ECHO)
    q = np.where(q >= CODE_VALUE_TOO_LARGE, CODE_NO_ECHO, q).astype(np.uint16)
    if flag_bits is not None:
        q = q | ((np.asarray(flag_bits, dtype=np.uint16) & 0x7) << 13).astype(np.uint16)
    cw = n | (unit_code << 14)
    data = bytes([cw & 0xFF, cw >> 8]) + q.astype("<u2").tobytes()
    return build_telegram(REPLY_MEASURED, data, address=address, status=status)


def mode_telegram(mode: int, args: bytes = b"", address: int = 0x00) -> bytes:
    """Host telegram ``20 <mode> [args]``."""
    return build_telegram(CMD_MODE, bytes([mode]) + args, address=address)

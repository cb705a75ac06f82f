"""PowerBot / Pioneer client-server protocol (PSOS/P2OS/AROS/ARCOS): packet framing,
checksum, command encoding, a resynchronising packet parser, standard SIP parsing and
odometry unwrapping. Pure, no I/O. Spec: ``../shared/protocols/PROTOCOLS.md`` §B.

Packet (§B.2)::

    FA FB COUNT PAYLOAD... CHK_HI CHK_LO     COUNT = len(PAYLOAD) + 2
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from icploc.drivers.byteclock import ByteClock
from icploc.errors import DeviceError
from icploc.messages import Odometry

HEADER = b"\xfa\xfb"
#: Largest COUNT accepted on input (§B.2: "maximum of 249").
MAX_COUNT = 249
#: Largest payload we send (ARIA's 200-byte limit + room for the command byte).
MAX_CLIENT_PAYLOAD = 202

ARG_INT = 0x3B
ARG_NINT = 0x1B
ARG_STR = 0x2B

# Command numbers (§B.5).
SYNC0 = PULSE = 0
SYNC1 = OPEN = 1
SYNC2 = CLOSE = 2
POLLING = 3
ENABLE = 4
SETA = 5
SETV = 6
SETO = 7
MOVE = 8
ROTATE = 9
SETRV = 10
VEL = 11
HEAD = 12
DHEAD = 13
CONFIG = 18
RVEL = 21
SETRA = 23
SONAR = 28
STOP = 29
VEL2 = 32
HOSTBAUD = 50
E_STOP = 55

# Server packet types.
SIP_STOPPED = 0x32
SIP_MOVING = 0x33
SIP_TYPES = frozenset({0x30, 0x31, 0x32, 0x33, 0x34})
CONFIGPAC = 0x20

HOSTBAUD_CODES = {9600: 0, 19200: 1, 38400: 2, 57600: 3, 115200: 4}

POSE_MOD = 1 << 15  # XPOS / YPOS are 15-bit counters
HEADING_MOD = 4096  # THPOS units per turn


class ArcosProtocolError(DeviceError, ValueError):
    """A packet could not be built or decoded. The stream parser never raises."""


def checksum(payload: bytes | bytearray) -> int:
    """§B.3: sum of big-endian byte pairs, odd last byte XORed into the low byte."""
    c = 0
    n = len(payload)
    i = 0
    while n - i >= 2:
        c = (c + ((payload[i] << 8) | payload[i + 1])) & 0xFFFF
        i += 2
    if n & 1:
        c ^= payload[n - 1]
    return c


def build_packet(payload: bytes) -> bytes:
    """Frame a payload (command or packet type first)."""
    if not payload:
        raise ArcosProtocolError("empty payload")
    if len(payload) + 2 > MAX_COUNT:
        raise ArcosProtocolError(f"payload of {len(payload)} bytes too long")
    c = checksum(payload)
    return HEADER + bytes([len(payload) + 2]) + bytes(payload) + bytes([c >> 8, c & 0xFF])


def encode_command(cmd: int, arg: int | bytes | str | None = None) -> bytes:
    """Client command packet (§B.4): no argument, a signed int (0x3B / 0x1B with the
    magnitude) or a string (0x2B, length byte, bytes)."""
    if not 0 <= cmd <= 255:
        raise ArcosProtocolError(f"command {cmd} out of range")
    if arg is None:
        payload = bytes([cmd])
    elif isinstance(arg, int):
        mag = abs(arg)
        if mag > 0xFFFF:
            raise ArcosProtocolError(f"integer argument {arg} out of range")
        payload = bytes([cmd, ARG_INT if arg >= 0 else ARG_NINT, mag & 0xFF, mag >> 8])
    else:
        s = arg.encode("latin-1") if isinstance(arg, str) else bytes(arg)
        if len(s) > 200:
            raise ArcosProtocolError("string argument longer than 200 bytes")
        payload = bytes([cmd, ARG_STR, len(s)]) + s
    return build_packet(payload)


def vel2_argument(left_mm_s: float, right_mm_s: float, divisor: float = 20.0) -> int:
    """VEL2 integer: high byte left, low byte right, each a signed byte in units of
    ``divisor`` mm/s (built as ARIA does: ``(left << 8) + (right & 0xFF)``)."""
    lb = max(-128, min(127, int(round(left_mm_s / divisor))))
    rb = max(-128, min(127, int(round(right_mm_s / divisor))))
    v = (lb << 8) + (rb & 0xFF)
    return v


def decode_vel2(value: int, divisor: float = 20.0) -> tuple[float, float]:
    """Inverse of :func:`vel2_argument` on the server side: rebuild the signed 16-bit
    value, then split into (left, right) mm/s."""
    u = value & 0xFFFF
    left = (u >> 8) & 0xFF
    right = u & 0xFF
    left = left - 256 if left >= 128 else left
    right = right - 256 if right >= 128 else right
    return left * divisor, right * divisor


@dataclass(frozen=True)
class Packet:
    """One framed packet: ``payload[0]`` is the command / type."""

    payload: bytes
    stamp: float = 0.0  #: arrival of the first header byte

    @property
    def type(self) -> int:
        return self.payload[0]


@dataclass(frozen=True)
class Command:
    """A decoded client command (server side)."""

    cmd: int
    arg: int | bytes | None


def decode_command(payload: bytes) -> Command:
    """Decode a client payload (§B.4); raises :class:`ArcosProtocolError` on a malformed one."""
    if not payload:
        raise ArcosProtocolError("empty payload")
    cmd = payload[0]
    if len(payload) == 1:
        return Command(cmd, None)
    t = payload[1]
    if t in (ARG_INT, ARG_NINT):
        if len(payload) < 4:
            raise ArcosProtocolError("integer argument truncated")
        v = payload[2] | (payload[3] << 8)
        return Command(cmd, v if t == ARG_INT else -v)
    if t == ARG_STR:
        if len(payload) < 3 or len(payload) < 3 + payload[2]:
            raise ArcosProtocolError("string argument truncated")
        return Command(cmd, bytes(payload[3 : 3 + payload[2]]))
    raise ArcosProtocolError(f"unknown argument type 0x{t:02X}")


@dataclass
class PacketStats:
    packets: int = 0
    checksum_errors: int = 0
    length_errors: int = 0
    resyncs: int = 0
    dropped_bytes: int = 0
    bytes_in: int = 0

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class PacketParser:
    """Incremental packet finder for an arbitrary byte stream.

    Syncs on ``FA FB``, bounds-checks COUNT (3..249), verifies the checksum and on any
    failure drops only the first header byte and hunts again. Never raises; keeps at
    most ``MAX_COUNT + 2`` bytes between calls.
    """

    def __init__(self, byte_time: float = 0.0) -> None:
        self.byte_time = byte_time
        self.stats = PacketStats()
        self._buf = bytearray()
        self._clock = ByteClock()

    @property
    def buffered(self) -> int:
        return len(self._buf)

    def reset(self) -> None:
        self._buf.clear()
        self._clock.clear()

    def feed(self, data: bytes, stamp: float = 0.0) -> list[Packet]:
        out: list[Packet] = []
        if not data:
            return out
        st = self.stats
        st.bytes_in += len(data)
        buf = self._buf
        buf += data
        self._clock.add(len(buf), stamp, self.byte_time)
        pos = 0
        end = len(buf)
        while pos < end:
            k = buf.find(HEADER, pos)
            if k < 0:
                keep = end - 1 if buf[end - 1] == 0xFA else end
                st.dropped_bytes += keep - pos
                pos = keep
                break
            if k > pos:
                st.dropped_bytes += k - pos
                pos = k
            if pos + 3 > end:
                break
            count = buf[pos + 2]
            if count < 3 or count > MAX_COUNT:
                st.length_errors += 1
                st.resyncs += 1
                st.dropped_bytes += 1
                pos += 1
                continue
            total = count + 3
            if pos + total > end:
                break
            payload = bytes(buf[pos + 3 : pos + total - 2])
            chk = (buf[pos + total - 2] << 8) | buf[pos + total - 1]
            if checksum(payload) != chk:
                st.checksum_errors += 1
                st.resyncs += 1
                st.dropped_bytes += 1
                pos += 1
                continue
            st.packets += 1
            out.append(Packet(payload, self._clock.time_of(pos)))
            pos += total
        if pos:
            del buf[:pos]
            self._clock.consume(pos)
        return out


# --------------------------------------------------------------------------- parameters


@dataclass(frozen=True)
class RobotParams:
    """Unit conversion factors (§B.8)."""

    name: str = "powerbot"
    angle_conv: float = 0.001534  #: rad per THPOS unit
    dist_conv: float = 0.5813  #: mm per XPOS/YPOS unit
    vel_conv: float = 1.0  #: mm/s per wheel-velocity unit
    range_conv: float = 1.0  #: mm per sonar unit
    diff_conv: float = 0.00373  #: (R-L)/2 * diff_conv = rad/s
    vel2_divisor: float = 20.0
    switch_to_baud: int = 38400
    max_velocity: float = 2000.0  #: mm/s
    max_rot_velocity: float = 360.0  #: deg/s
    radius_mm: float = 550.0
    width_mm: float = 680.0
    length_mm: float = 911.0
    laser_x_mm: float = 251.0
    laser_flipped: bool = True


POWERBOT = RobotParams()
POWERBOT_SH = RobotParams(name="powerbot-sh", dist_conv=1.0)
#: Generic ARCOS robots report mm directly.
ARCOS_GENERIC = RobotParams(
    name="generic-arcos", dist_conv=1.0, laser_flipped=False, laser_x_mm=0.0
)

PARAMS_BY_SUBTYPE = {"powerbot": POWERBOT, "powerbot-sh": POWERBOT_SH}


def params_for(subtype: str) -> RobotParams:
    """Conversion factors for a SYNC2 subtype string (case-insensitive). Unknown
    ``*-sh`` subtypes get ARCOS (mm) units, anything else the AROS PowerBot set."""
    key = subtype.strip().lower()
    if key in PARAMS_BY_SUBTYPE:
        return PARAMS_BY_SUBTYPE[key]
    if key.endswith("-sh"):
        return ARCOS_GENERIC
    return POWERBOT


def parse_sync2(payload: bytes) -> tuple[str, str, str]:
    """SYNC2 reply: type byte 0x02 then name, type, subtype, NUL-terminated."""
    if not payload or payload[0] != SYNC2:
        raise ArcosProtocolError("not a SYNC2 reply")
    parts = payload[1:].split(b"\x00")
    if len(parts) < 4:
        raise ArcosProtocolError("SYNC2 reply lacks three NUL-terminated strings")
    name, typ, sub = (p.decode("latin-1") for p in parts[:3])
    return name, typ, sub


def build_sync2_reply(name: str, typ: str, subtype: str) -> bytes:
    body = b"".join(s.encode("latin-1") + b"\x00" for s in (name, typ, subtype))
    return build_packet(bytes([SYNC2]) + body)


# --------------------------------------------------------------------------- SIP


@dataclass(frozen=True)
class RawSip:
    """A standard SIP's fields as integers, straight off the wire (§B.7)."""

    type: int
    xpos: int  #: 15-bit
    ypos: int
    thpos: int  #: signed
    lvel: int
    rvel: int
    battery: int  #: 0.1 V
    stall_bumpers: int
    control: int
    flags: int
    compass: int
    sonar: tuple[tuple[int, int], ...]
    grip_state: int | None = None
    anport: int | None = None
    analog: int | None = None
    digin: int | None = None
    digout: int | None = None
    battery_x10: int | None = None
    charge_state: int | None = None
    rotvel: int | None = None
    fault_flags: int | None = None
    latvel: int | None = None
    temperature: int | None = None
    state_of_charge: int | None = None


def _s16(v: int) -> int:
    return v - 0x10000 if v >= 0x8000 else v


def parse_sip(payload: bytes) -> RawSip:
    """Parse a standard SIP payload (type byte first). Length-driven: the optional tail
    after DIGOUT is parsed only as far as bytes remain (§B.7)."""
    if len(payload) < 20 or payload[0] not in SIP_TYPES:
        raise ArcosProtocolError("not a standard SIP")
    p = payload

    def u16(o: int) -> int:
        return p[o] | (p[o + 1] << 8)

    n_sonar = p[19]
    o = 20
    if len(p) < o + 3 * n_sonar:
        raise ArcosProtocolError("SIP sonar block truncated")
    sonar = tuple((p[o + 3 * i], u16(o + 3 * i + 1)) for i in range(n_sonar))
    o += 3 * n_sonar
    rest = len(p) - o
    opt: dict[str, int] = {}
    layout = [
        ("grip_state", 1, False), ("anport", 1, False), ("analog", 1, False),
        ("digin", 1, False), ("digout", 1, False), ("battery_x10", 2, True),
        ("charge_state", 1, True), ("rotvel", 2, True), ("fault_flags", 2, False),
        ("latvel", 2, True), ("temperature", 1, True), ("state_of_charge", 1, False),
    ]  # fmt: skip
    for name, size, signed in layout:
        if rest < size:
            break
        v = p[o] if size == 1 else u16(o)
        if signed:
            v = (v - 256 if v >= 128 else v) if size == 1 else _s16(v)
        opt[name] = v
        o += size
        rest -= size
    return RawSip(
        type=p[0], xpos=u16(1) & 0x7FFF, ypos=u16(3) & 0x7FFF, thpos=_s16(u16(5)),
        lvel=_s16(u16(7)), rvel=_s16(u16(9)), battery=p[11], stall_bumpers=u16(12),
        control=_s16(u16(14)), flags=u16(16), compass=p[18], sonar=sonar, **opt,
    )  # fmt: skip


def build_sip(sip: RawSip) -> bytes:
    """Encode a :class:`RawSip` as a packet (AROS layout up to DIGOUT, then whatever
    optional tail fields are set, in order, stopping at the first unset one)."""

    def w(v: int) -> bytes:
        v &= 0xFFFF
        return bytes([v & 0xFF, v >> 8])

    out = bytearray([sip.type])
    out += w(sip.xpos & 0x7FFF) + w(sip.ypos & 0x7FFF) + w(sip.thpos) + w(sip.lvel) + w(sip.rvel)
    out.append(sip.battery & 0xFF)
    out += w(sip.stall_bumpers) + w(sip.control) + w(sip.flags)
    out.append(sip.compass & 0xFF)
    out.append(len(sip.sonar))
    for num, rng in sip.sonar:
        out.append(num & 0xFF)
        out += w(rng)
    tail = [
        (sip.grip_state, 1), (sip.anport, 1), (sip.analog, 1), (sip.digin, 1),
        (sip.digout, 1), (sip.battery_x10, 2), (sip.charge_state, 1), (sip.rotvel, 2),
        (sip.fault_flags, 2), (sip.latvel, 2), (sip.temperature, 1), (sip.state_of_charge, 1),
    ]  # fmt: skip
    for v, size in tail:
        if v is None:
            break
        out += bytes([v & 0xFF]) if size == 1 else w(v)
    return build_packet(bytes(out))


@dataclass(frozen=True)
class Sip:
    """A standard SIP converted to SI units, with the unwrapped odometry pose."""

    stamp: float
    pose: tuple[float, float, float]  #: (x m, y m, theta rad), continuous in x, y
    v: float  #: m/s, (L+R)/2
    w: float  #: rad/s
    left_velocity: float  #: m/s
    right_velocity: float
    battery_volts: float
    moving: bool
    motors_enabled: bool
    estop: bool
    left_stall: bool
    right_stall: bool
    front_bumpers: int  #: bitmask, bit 0 = first segment
    rear_bumpers: int
    sonar: dict[int, float]  #: disc number -> range in metres (new readings only)
    raw: RawSip
    seq: int = 0

    @property
    def stall(self) -> bool:
        return self.left_stall or self.right_stall

    def to_odometry(self) -> Odometry:
        return Odometry(
            stamp=self.stamp,
            pose=self.pose,
            velocity=(self.v, self.w),
            extra={
                "battery_volts": self.battery_volts,
                "stall": self.stall,
                "front_bumpers": self.front_bumpers,
                "rear_bumpers": self.rear_bumpers,
                "motors_enabled": self.motors_enabled,
                "sonar": dict(self.sonar),
            },
        )


def wrap_delta(new: int, old: int, modulus: int) -> int:
    """Smallest signed difference new - old modulo ``modulus``, in [-m/2, m/2)."""
    d = (new - old) % modulus
    if d >= modulus // 2:
        d -= modulus
    return d


@dataclass
class OdometryUnwrapper:
    """Integrates 15-bit XPOS/YPOS and 12-bit-per-turn THPOS deltas into a continuous pose.

    The first SIP is the reference: its values (taken as signed 15-bit) are the start
    pose, so a fresh controller reporting (0,0,0) starts the odometry at the origin.
    """

    params: RobotParams = POWERBOT
    _last: tuple[int, int, int] | None = field(default=None, repr=False)
    x_units: int = 0
    y_units: int = 0
    th_units: int = 0

    def reset(self) -> None:
        self._last = None

    def update(self, xpos: int, ypos: int, thpos: int) -> tuple[float, float, float]:
        if self._last is None:
            self.x_units = xpos - POSE_MOD if xpos >= POSE_MOD // 2 else xpos
            self.y_units = ypos - POSE_MOD if ypos >= POSE_MOD // 2 else ypos
            self.th_units = thpos
        else:
            lx, ly, lt = self._last
            self.x_units += wrap_delta(xpos, lx, POSE_MOD)
            self.y_units += wrap_delta(ypos, ly, POSE_MOD)
            self.th_units += wrap_delta(thpos, lt, HEADING_MOD)
        self._last = (xpos, ypos, thpos)
        return self.pose

    @property
    def pose(self) -> tuple[float, float, float]:
        k = self.params.dist_conv / 1000.0
        th = math.remainder(self.th_units * self.params.angle_conv, 2.0 * math.pi)
        return (self.x_units * k, self.y_units * k, th)


def convert_sip(
    raw: RawSip, pose: tuple[float, float, float], params: RobotParams, stamp: float, seq: int = 0
) -> Sip:
    """SI units for a parsed SIP (pose comes from an :class:`OdometryUnwrapper`)."""
    lv = raw.lvel * params.vel_conv / 1000.0
    rv = raw.rvel * params.vel_conv / 1000.0
    if raw.rotvel is not None:
        w = math.radians(raw.rotvel / 10.0)
    else:
        w = (raw.rvel - raw.lvel) / 2.0 * params.vel_conv * params.diff_conv
    volts = raw.battery_x10 / 10.0 if raw.battery_x10 is not None else raw.battery / 10.0
    sb = raw.stall_bumpers
    return Sip(
        stamp=stamp,
        pose=pose,
        v=(lv + rv) / 2.0,
        w=w,
        left_velocity=lv,
        right_velocity=rv,
        battery_volts=volts,
        moving=raw.type == SIP_MOVING,
        motors_enabled=bool(raw.flags & 0x1),
        estop=bool(raw.flags & 0x20),
        left_stall=bool(sb & 0x1),
        right_stall=bool(sb & 0x100),
        front_bumpers=(sb >> 9) & 0x7F,
        rear_bumpers=(sb >> 1) & 0x7F,
        sonar={num: rng * params.range_conv / 1000.0 for num, rng in raw.sonar},
        raw=raw,
        seq=seq,
    )


class SipDecoder:
    """Stateful SIP decoding: packets in, :class:`Sip` (unwrapped pose) out."""

    def __init__(self, params: RobotParams = POWERBOT) -> None:
        self.unwrapper = OdometryUnwrapper(params)
        self.params = params
        self.seq = 0
        self.bad_sips = 0

    def set_params(self, params: RobotParams) -> None:
        self.params = params
        self.unwrapper.params = params

    def decode(self, pkt: Packet) -> Sip | None:
        if pkt.type not in SIP_TYPES:
            return None
        try:
            raw = parse_sip(pkt.payload)
        except ArcosProtocolError:
            self.bad_sips += 1
            return None
        pose = self.unwrapper.update(raw.xpos, raw.ypos, raw.thpos)
        self.seq += 1
        return convert_sip(raw, pose, self.params, pkt.stamp, self.seq)

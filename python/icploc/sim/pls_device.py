"""A SICK PLS / LMS 2xx that speaks the telegram protocol byte for byte (PROTOCOLS.md
§A.10), fed by a scan source (e.g. a :class:`~icploc.sim.world.World` and a robot).

Behaviour: power-on at 9600 Bd (PLS 8E1, LMS 8N1), request mode (0x25). Host
telegrams with the wrong address are ignored; a bad CRC is answered with NAK (0x15);
a good one with ACK (0x06) and then the reply (reply code = cmd | 0x80, status byte,
CRC). Mode 0x24 streams 0xB0 telegrams back to back (at most one per scan period;
the line time of a 732-byte telegram bounds the rate in real-time mode). A baud-rate
change is answered at the old rate and takes effect after that reply; the PLS refuses
it (0x92, configurable) outside installation mode (password ``SICK_PLS``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from icploc.drivers import sick_protocol as sp
from icploc.sim.device import Faults, OutputSchedule, PeriodicStream, StreamingEngine, stream_alias
from icploc.sim.robot import DiffDriveRobot

#: ranges (m) at the scan's beam angles, given simulated time (s)
ScanSource = Callable[[float], NDArray[np.float64]]


@dataclass
class B0Record:
    """Ground truth about one measured-values telegram the device sent."""

    index: int
    sim_time: float
    intact: bool
    sent_at: float
    frame: bytes = b""  #: the telegram as built, before fault injection


@dataclass
class PLSDevice(StreamingEngine):
    """Protocol engine of a PLS (``variant="pls"``) or LMS 2xx (``variant="lms"``)."""

    source: ScanSource | None = None
    variant: str = "pls"
    address: int = 0x00
    realtime: bool = False
    scan_period: float = 0.04  #: s between scans (PLS mirror ~25 Hz); the line may be slower
    flipped: bool = False  #: mounted upside down: send values in mirrored order
    faults: Faults = field(default_factory=Faults)
    ack_delay: float = 0.002
    reply_delay: float = 0.010
    mode_reply_delay: float = 0.030
    reset_delay: float = 0.5  #: after 0x91, before the 0x90 power-on telegram
    refuse_baud_outside_install: bool = True
    type_string: str = ""
    max_range: float = 50.0
    keep_b0_log: bool = True
    #: the robot carrying the laser: moved to each scan's time before ``source`` samples it
    robot: DiffDriveRobot | None = None

    def __post_init__(self) -> None:
        self.password = sp.PASSWORD_PLS if self.variant == "pls" else sp.PASSWORD_LMS
        if not self.type_string:
            self.type_string = "PLS101-312" if self.variant == "pls" else "LMS200;301063;V02.10 "
        self.status = 0x00 if self.variant == "pls" else 0x10
        self.parser = sp.TelegramParser(device_side=True)
        self.schedule = OutputSchedule()
        self.stream = PeriodicStream(self.scan_period, self.realtime)
        self.b0_log: list[B0Record] = []
        self.host_telegrams: list[sp.Telegram] = []
        self.naks_sent = 0
        self.power_on()

    # -- state

    def power_on(self) -> None:
        self._baud = 9600
        self.installation = False
        self.mode = sp.MODE_ON_REQUEST
        self.fov_deg = 180
        self.resolution_cdeg = 50
        self.stream.reset()
        self.schedule.clear()
        self.parser.reset()

    streaming = stream_alias("on", "Streaming measured values (mode 0x24).")
    scan_index = stream_alias("index", "Scans built so far (streamed or on request).")

    @property
    def parity(self) -> str:
        return "E" if self.variant == "pls" else "N"

    @property
    def bits_per_byte(self) -> int:
        return 11 if self.variant == "pls" else 10

    def n_values(self) -> int:
        return int(round(self.fov_deg * 100 / self.resolution_cdeg)) + 1

    def beam_angles(self) -> NDArray[np.float64]:
        """Beam angles (sensor frame, CCW, 0 ahead) in the order the driver reports."""
        half = math.radians(self.fov_deg) / 2
        return np.linspace(-half, half, self.n_values())

    # -- engine interface

    def receive(self, data: bytes, now: float) -> None:
        if self.faults.vanished:
            return
        crc_before = self.parser.stats.crc_errors
        events = self.parser.feed(data, now)
        if self.parser.stats.crc_errors > crc_before:
            # a telegram to us with a bad CRC: NAK it (once per burst)
            self._send(now, self.ack_delay, bytes([sp.NAK]))
            self.naks_sent += 1
        for ev in events:
            if isinstance(ev, sp.Telegram):
                self._handle(ev, now)

    # -- internals

    def _stream_frame(self, now: float) -> bytes:
        return self._b0_frame(now)

    def _mark(self, intact: bool) -> None:
        if self.keep_b0_log:
            self.b0_log[-1].intact = intact

    def _sample(self, now: float, t: float) -> NDArray[np.float64]:
        assert self.source is not None
        if self.robot is None:
            return np.asarray(self.source(t), dtype=np.float64)
        with self.robot.lock:  # the base thread moves the robot too
            self.robot.advance_to(self.stream.robot_time(self.robot, now, t))
            return np.asarray(self.source(t), dtype=np.float64)

    def _b0_frame(self, now: float) -> bytes:
        t = self.sim_time(now)
        n = self.n_values()
        if self.source is not None:
            r = self._sample(now, t)
            if r.shape != (n,):
                raise ValueError(f"scan source returned {r.shape}, expected ({n},)")
        else:
            r = np.full(n, np.inf)
        r = np.where(r > self.max_range, np.inf, r)
        if self.flipped:
            r = r[::-1]
        unit = 0.01 if self.variant == "pls" else 0.001
        if self.variant == "lms" and self.max_range > 8.18:
            unit = 0.01
        frame = sp.encode_measured(r, unit_m=unit, status=self.status, address=0x80 | self.address)
        if self.keep_b0_log:
            self.b0_log.append(B0Record(self.scan_index, t, True, now, frame))
        self.scan_index += 1
        return frame

    def _reply(self, now: float, delay: float, code: int, data: bytes = b"",
               action: Callable[[], None] | None = None) -> None:  # fmt: skip
        tel = sp.build_telegram(code, data, address=0x80 | self.address, status=self.status)
        self._send(now, delay, tel, action)

    def _handle(self, tel: sp.Telegram, now: float) -> None:
        if tel.address not in (0x00, self.address):
            return  # not for us: silence
        self.host_telegrams.append(tel)
        f = self.faults
        if f.nak_storm > 0:
            f.nak_storm -= 1
            self._send(now, self.ack_delay, bytes([sp.NAK]))
            self.naks_sent += 1
            return
        if f.ignore_rate and f.rng.random() < f.ignore_rate:
            return
        self._send(now, self.ack_delay, bytes([sp.ACK]))
        cmd, data = tel.cmd, tel.data
        if cmd == sp.CMD_MODE and data:
            self._mode(data[0], data[1:], now)
        elif cmd == sp.CMD_MEASURED and data[:1] == b"\x01":
            self._send(now, self.reply_delay, self._mangled(self._b0_frame(now)))
        elif cmd == sp.CMD_RESET:
            self.streaming = False

            def _reset() -> None:
                self.power_on()
                self.schedule.add(self._last_now + (self.reset_delay if self.realtime else 0.0),
                                  sp.build_telegram(sp.REPLY_POWER_ON, self.type_string.encode(),
                                                    address=0x80 | self.address, status=self.status))  # fmt: skip

            self._last_now = now
            self._reply(now, self.reply_delay, sp.REPLY_RESET, b"", _reset)
        elif cmd == sp.CMD_ERRORS:
            self._reply(now, self.reply_delay, sp.CMD_ERRORS | 0x80, b"")
        elif cmd == sp.CMD_TYPE and self.variant == "lms":
            self._reply(now, self.reply_delay, 0xBA, self.type_string.encode("latin-1"))
        elif cmd == sp.CMD_VARIANT and self.variant == "lms" and len(data) == 4:
            fov = data[0] | data[1] << 8
            res = data[2] | data[3] << 8
            ok = (fov, res) in {(180, 50), (180, 100), (100, 25), (100, 50), (100, 100)}
            if ok:
                self.fov_deg, self.resolution_cdeg = fov, res
            self._reply(now, self.reply_delay, 0xBB, bytes([1 if ok else 0]) + bytes(data))
        else:
            self._reply(now, self.reply_delay, sp.REPLY_NOT_ACK)

    def _mode(self, mode: int, args: bytes, now: float) -> None:
        delay = self.mode_reply_delay
        if mode == sp.MODE_INSTALL:
            if args[:8] == self.password:
                self.installation = True
                self._reply(now, delay, sp.REPLY_MODE, b"\x00")
            else:
                self._reply(now, delay, sp.REPLY_MODE, b"\x01")
            return
        if mode in sp.BAUD_OF_MODE:
            if self.variant == "pls" and self.refuse_baud_outside_install and not self.installation:
                self._reply(now, delay, sp.REPLY_NOT_ACK)
                return
            new = sp.BAUD_OF_MODE[mode]

            def _switch() -> None:
                self._baud = new

            self._reply(now, delay, sp.REPLY_MODE, b"\x00", _switch)
            return
        if mode == sp.MODE_STREAM_ALL:
            self.installation = False

            def _go() -> None:
                self.stream.on = True
                self.stream.restart_clock()

            self.mode = mode
            self._reply(now, delay, sp.REPLY_MODE, b"\x00", _go)
            return
        if mode == sp.MODE_ON_REQUEST:
            self.installation = False
            self.streaming = False
            self.mode = mode
            self._reply(now, delay, sp.REPLY_MODE, b"\x00")
            return
        self._reply(now, delay, sp.REPLY_NOT_ACK)


def ramp_source(n: int = 361, base: float = 1.0, step: float = 0.01) -> ScanSource:
    """A trivial source: value i = base + i * step metres (for tests)."""
    r = base + step * np.arange(n, dtype=np.float64)
    return lambda t: r

"""ActivMedia PowerBot / Pioneer (AROS, ARCOS) driver over pyserial.

>>> from icploc.drivers.powerbot import PowerBot
>>> with PowerBot("/dev/ttyS0") as bot:                       # doctest: +SKIP
...     bot.set_velocity(0.3, 0.0)
...     for sip in bot.sips():
...         print(sip.stamp, sip.pose)

Connecting (PROTOCOLS.md §B.6): SYNC0, SYNC1 (each echoed), SYNC2 (answered with name,
type and subtype, which select the conversion factors, §B.8), with retries and a CLOSE
if the robot turns out to be still connected from an earlier session; then OPEN,
PULSE and ENABLE 1. A heartbeat thread sends PULSE every ``heartbeat`` seconds (well
inside the 2 s watchdog) unless another command went out meanwhile; a reader thread
parses SIPs into :class:`~icploc.drivers.arcos_protocol.Sip` objects with the 15-bit
pose counters unwrapped into a continuous odometry pose (m, rad), stamped on
:func:`icploc.clock.now` at the arrival of the packet's first byte.

On exit (also on Ctrl-C and exceptions inside the ``with`` block, and at interpreter
exit) the driver sends STOP, ENABLE 0 and CLOSE.
"""

from __future__ import annotations

import atexit
import dataclasses
import math
import queue
import threading
import time
import weakref
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import serial

from icploc import clock
from icploc.drivers import arcos_protocol as ap
from icploc.drivers._link import close_quietly, retry_with_backoff
from icploc.drivers._queues import put_dropping_oldest
from icploc.drivers.arcos_protocol import Sip
from icploc.drivers.recording import Recorder
from icploc.errors import DeviceError
from icploc.messages import Odometry
from icploc.se2 import between, compose, inverse

__all__ = ["PowerBot", "PowerBotError", "PowerBotTimeout", "Sip"]


class PowerBotError(DeviceError, RuntimeError):
    """The robot could not be reached, or the line failed."""


class PowerBotTimeout(PowerBotError):
    """No answer to the handshake, or no SIP within the stall timeout."""


_STOP = object()
#: the controller's watchdog (PROTOCOLS.md §B.6): no command for this long stops the robot
WATCHDOG_S = 2.0
_open_bots: weakref.WeakSet[PowerBot] = weakref.WeakSet()


@atexit.register
def _close_all() -> None:  # pragma: no cover - exercised at interpreter exit
    for bot in list(_open_bots):
        try:
            bot.close()
        except Exception:
            pass


class PowerBot:
    """PowerBot client. ``port`` is any pyserial URL or device path."""

    def __init__(
        self,
        port: str,
        *,
        baudrate: int = 9600,
        switch_baudrate: int | None = None,
        params: ap.RobotParams | None = None,
        sync_tries: int = 10,
        sync_timeout: float = 0.5,
        heartbeat: float = 0.5,
        enable_motors: bool = True,
        stall_timeout: float = 2.0,
        auto_reconnect: bool = False,
        reconnect_timeout: float = 30.0,
        reconnect_backoff: float = 0.2,
        reconnect_backoff_max: float = 5.0,
        recorder: Recorder | str | Path | None = None,
        queue_size: int = 256,
    ) -> None:
        self.port = port
        self.baudrate = baudrate
        self.switch_baudrate = switch_baudrate
        self._forced_params = params
        self.params: ap.RobotParams = params or ap.POWERBOT
        self.sync_tries = sync_tries
        self.sync_timeout = sync_timeout
        self.heartbeat = heartbeat
        self.enable_motors = enable_motors
        self.stall_timeout = stall_timeout
        self.auto_reconnect = auto_reconnect
        self.watchdog_s = WATCHDOG_S
        self.reconnect_timeout = reconnect_timeout
        self.reconnect_backoff = reconnect_backoff
        self.reconnect_backoff_max = reconnect_backoff_max
        self._own_recorder = isinstance(recorder, (str, Path))
        self.recorder: Recorder | None = (
            Recorder(recorder) if isinstance(recorder, (str, Path)) else recorder
        )
        self._rec_dev = 0
        self.ser: serial.SerialBase | None = None
        self.parser = ap.PacketParser()
        self.decoder = ap.SipDecoder(self.params)
        self.name = self.robot_type = self.subtype = ""
        self.last_sip: Sip | None = None
        self.counters = {"sips": 0, "sync_retries": 0, "dropped_sips": 0, "commands": 0, "read_errors": 0,
                         "other_packets": 0, "reconnects": 0, "odometry_rebases": 0}  # fmt: skip
        self._sips: queue.Queue[Any] = queue.Queue(maxsize=max(1, queue_size))
        self._write_lock = threading.RLock()
        self._last_write = 0.0
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._error: BaseException | None = None
        self._connected = False
        self._last_sip_time = 0.0
        self._link_up = False
        #: set by a reconnect: the next SIP's pose is checked against the last one
        self._relinked_at: float | None = None
        #: re-anchors the controller's odometry frame after a reconnect (None: identity)
        self._odom_offset: tuple[float, float, float] | None = None

    # ------------------------------------------------------------------ lifecycle

    def __enter__(self) -> PowerBot:
        self.connect()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _open_port(self) -> None:
        self.ser = serial.serial_for_url(self.port, baudrate=self.baudrate, bytesize=8, parity=serial.PARITY_NONE,
                                         stopbits=1, timeout=0.02, write_timeout=5.0)  # fmt: skip
        self.parser.reset()
        self.parser.byte_time = 10.0 / self.baudrate
        if self.recorder is not None and self.counters["reconnects"]:
            # back at the connect rate (the first META of the device says it already)
            self.recorder.meta(self._rec_dev, clock.now(), {"baudrate": self.baudrate})

    def connect(self) -> None:
        """Open the port, handshake, OPEN, ENABLE, start the reader and heartbeat."""
        if self.recorder is not None and not self._rec_dev:
            self._rec_dev = self.recorder.device("powerbot", {"driver": "powerbot", "port": str(self.port),
                                                             "baudrate": self.baudrate}, clock.now())  # fmt: skip
        self._stop.clear()  # close() sets it; a handshake in progress watches it
        self._link()
        self._connected = True
        self._last_sip_time = clock.now()
        _open_bots.add(self)
        self._threads = [
            threading.Thread(target=self._reader, name="powerbot-reader", daemon=True),
            threading.Thread(target=self._heartbeat, name="powerbot-heartbeat", daemon=True),
        ]
        for th in self._threads:
            th.start()

    def _link(self) -> None:
        """Open the port and run the handshake, OPEN, PULSE, (HOSTBAUD), ENABLE."""
        self._open_port()
        try:
            self._handshake()
            self._send(ap.OPEN)
            self._send(ap.PULSE)
            if self.switch_baudrate and self.switch_baudrate != self.baudrate:
                self._switch_baud(self.switch_baudrate)
            if self.enable_motors:
                self._send(ap.ENABLE, 1)
        except BaseException:
            self._close_port()
            raise
        self._link_up = True

    def _relink(self, why: BaseException) -> None:
        """In the reader thread, after the line failed or SIPs stopped: close the port
        and connect again (handshake per PROTOCOLS.md §B.6) with an exponential back-off,
        for at most ``reconnect_timeout`` s, then :class:`PowerBotTimeout`."""
        self._link_up = False
        self.counters["reconnects"] += 1
        if self.recorder is not None:
            self.recorder.meta(self._rec_dev, clock.now(), {"event": "reconnect", "why": str(why)})
        linked, last = retry_with_backoff(
            self._link,
            close=self._close_port,
            failures=(OSError, serial.SerialException, PowerBotError),
            stop=self._stop,
            timeout=self.reconnect_timeout,
            backoff=self.reconnect_backoff,
            backoff_max=self.reconnect_backoff_max,
        )
        if linked:
            self._relinked_at = self._last_sip_time
            self._last_sip_time = clock.now()
            return
        if self._stop.is_set():
            return
        raise PowerBotTimeout(
            f"robot on {self.port} did not come back within {self.reconnect_timeout:g} s "
            f"(last error: {last if last is not None else why})"
        )

    def _continue_odometry(self, sip: Sip) -> Sip:
        """SIPs in the output frame: after a reconnect, the first SIP is checked against
        the last one; if its pose moved further than the robot could have driven in the
        gap (a controller that was power cycled starts again at 0, 0, 0), the odometry
        continues from the last pose (a rigid re-anchoring of the controller's frame; the
        robot is assumed to have stood still, the watchdog stops it within 2 s)."""
        since = self._relinked_at
        if since is not None:
            self._relinked_at = None
            prev = self.last_sip
            if prev is not None:
                out = (
                    sip.pose if self._odom_offset is None else compose(self._odom_offset, sip.pose)
                )
                drive = min(max(0.0, sip.stamp - since), self.watchdog_s)
                reach = 1.5 * abs(prev.v) * drive + 0.1
                turn = 1.5 * abs(prev.w) * drive + 0.1
                d = between(prev.pose, out)
                if math.hypot(d[0], d[1]) > reach or abs(d[2]) > turn:
                    self._odom_offset = compose(prev.pose, inverse(sip.pose))
                    self.counters["odometry_rebases"] += 1
                    if self.recorder is not None:  # a replay can re-anchor the same way
                        self.recorder.meta(self._rec_dev, sip.stamp,
                                           {"odometry_offset": list(self._odom_offset)})  # fmt: skip
        if self._odom_offset is None:
            return sip
        return dataclasses.replace(sip, pose=compose(self._odom_offset, sip.pose))

    def _close_port(self) -> None:
        close_quietly(self.ser)
        self.ser = None

    def close(self) -> None:
        """STOP, ENABLE 0, CLOSE; stop the threads; close the port. Idempotent."""
        with self._write_lock:  # no heartbeat PULSE after this (it would be a SYNC0)
            link_was_up, self._link_up = self._link_up, False
        if self.ser is not None and self._connected and link_was_up:
            for cmd, arg in ((ap.STOP, None), (ap.ENABLE, 0), (ap.CLOSE, None)):
                try:
                    self._send(cmd, arg)
                except (OSError, serial.SerialException, PowerBotError):
                    break
            time.sleep(0.01)
        self._connected = False
        self._link_up = False
        self._stop.set()
        for th in self._threads:
            if th is not threading.current_thread():
                th.join(timeout=5.0)
        self._threads = []
        self._close_port()
        _open_bots.discard(self)
        if self.recorder is not None and self._own_recorder:
            self.recorder.close()

    def reconnect(self) -> None:
        """Close (best effort) and connect again. The odometry stays continuous: the
        unwrapper keeps its last counters, so if the controller kept its pose the next
        SIP continues where the last one ended."""
        self.close()
        self.connect()

    @property
    def connected(self) -> bool:
        return self._connected

    @property
    def link_up(self) -> bool:
        """Connected and talking to the robot; False while a reconnect is under way."""
        return self._connected and self._link_up

    @property
    def stats(self) -> dict[str, int]:
        return {
            **self.counters,
            **{f"parser_{k}": v for k, v in self.parser.stats.as_dict().items()},
        }

    # ------------------------------------------------------------------ handshake

    def _read_packets(self, deadline: float) -> list[ap.Packet]:
        """The packets that arrive until ``deadline``; what arrived meanwhile is read at
        least once, also by a thread that wakes up after the deadline (a loaded host)."""
        ser = self.ser
        assert ser is not None
        while True:
            data = ser.read(max(1, ser.in_waiting))
            if data:
                t = clock.now()
                if self.recorder is not None:
                    self.recorder.rx(self._rec_dev, t, data)
                pkts = self.parser.feed(data, t)
                if pkts:
                    return pkts
            if clock.now() >= deadline:
                return []

    def _await(self, want: int, timeout: float) -> ap.Packet | None:
        """Wait for a packet of type ``want``; a SIP means "still connected"."""
        deadline = clock.now() + timeout
        while True:
            pkts = self._read_packets(deadline)
            if not pkts:
                return None
            for p in pkts:
                if p.type == want:
                    return p
                if p.type in ap.SIP_TYPES:
                    raise _StillConnected()

    def _handshake(self) -> None:
        """SYNC0, SYNC1, SYNC2 with retries. A try that got no SYNC0 echo or no SYNC2 reply
        is followed by a CLOSE: the controller may sit connected (it took our SYNC2 and its
        reply was lost, or an earlier client connected without OPEN), sends no SIPs then,
        and takes every SYNC0 for a PULSE; CLOSE puts it back in its wait state (ARIA sends
        CLOSE to a silent robot, PROTOCOLS.md §B.1). Not after a missing SYNC1 echo: a
        controller waiting for SYNC2 would take that CLOSE for it."""
        assert self.ser is not None
        for attempt in range(self.sync_tries):
            if self._stop.is_set():
                raise PowerBotError("closed while connecting")
            if attempt:
                self.counters["sync_retries"] += 1
                time.sleep(min(0.05 * attempt, 0.5))
            self.ser.reset_input_buffer()
            self.parser.reset()
            try:
                for n in (ap.SYNC0, ap.SYNC1):
                    self._send(n)
                    if self._await(n, self.sync_timeout) is None:
                        raise _Retry(close=n == ap.SYNC0)
                self._send(ap.SYNC2)
                reply = self._await(ap.SYNC2, self.sync_timeout)
                if reply is None:
                    raise _Retry(close=True)
                self.name, self.robot_type, self.subtype = ap.parse_sync2(reply.payload)
            except _StillConnected:
                self._send(ap.CLOSE)
                time.sleep(0.05)
                continue
            except _Retry as r:
                if r.close:
                    self._send(ap.CLOSE)
                continue
            except ap.ArcosProtocolError:
                continue
            if self._forced_params is None:
                self.params = ap.params_for(self.subtype)
            self.decoder.set_params(self.params)
            if self.recorder is not None:
                self.recorder.meta(self._rec_dev, clock.now(), {"name": self.name, "type": self.robot_type,
                                                                "subtype": self.subtype,
                                                                "params": self.params.name})  # fmt: skip
            return
        raise PowerBotTimeout(
            f"no SYNC handshake with the robot on {self.port} after {self.sync_tries} tries"
        )

    #: packets that must arrive at the new rate before a HOSTBAUD switch counts: one
    #: intact packet may be a SIP the robot sent at the old rate before it saw HOSTBAUD,
    #: held in the serial adapter's FIFO across the host's switch and flush (a USB adapter
    #: buffers some milliseconds of bytes); at the wrong rate no second one comes through
    SWITCH_EVIDENCE = 2

    def _switch_baud(self, baud: int, tries: int = 4, verify: float = 0.9) -> None:
        """HOSTBAUD, wait 10 ms, switch the host UART, PULSE; then
        :attr:`SWITCH_EVIDENCE` packets must arrive at the new rate within ``verify`` s,
        else back to the old rate and again, waiting five times longer before the switch
        each time (ARIA's fallback, PROTOCOLS.md §B.6; a controller busy when HOSTBAUD
        came in gets the time it needs)."""
        code = ap.HOSTBAUD_CODES[baud]
        assert self.ser is not None
        old = self.ser.baudrate
        for attempt in range(tries):
            self._send(ap.HOSTBAUD, code)
            time.sleep(0.01 * 5**attempt)
            self._set_line(baud)
            self._send(ap.PULSE)
            if self._packets_arrive(self.SWITCH_EVIDENCE, clock.now() + verify):
                return
            self._set_line(old)  # nothing at the new rate: the robot did not switch
            self._send(ap.PULSE)
            self._read_packets(clock.now() + verify)  # back in step at the old rate
        raise PowerBotError(f"the robot on {self.port} did not answer at {baud} Bd after HOSTBAUD")

    def _packets_arrive(self, n: int, deadline: float) -> bool:
        """``n`` valid packets arrive before ``deadline``."""
        got = 0
        while got < n:
            pkts = self._read_packets(deadline)
            if not pkts:
                return False
            got += len(pkts)
        return True

    def _set_line(self, baud: int) -> None:
        assert self.ser is not None
        self.ser.baudrate = baud
        self.ser.reset_input_buffer()  # what arrived at the old rate is noise at the new
        self.parser.reset()
        self.parser.byte_time = 10.0 / baud
        if self.recorder is not None:
            self.recorder.meta(self._rec_dev, clock.now(), {"baudrate": baud})

    # ------------------------------------------------------------------ commands

    def _send(self, cmd: int, arg: int | bytes | str | None = None) -> None:
        pkt = ap.encode_command(cmd, arg)
        ser = self.ser
        if ser is None:
            raise PowerBotError("not connected")
        with self._write_lock:
            t = clock.now()
            if self.recorder is not None:
                self.recorder.tx(self._rec_dev, t, pkt)
            ser.write(pkt)
            ser.flush()
            self._last_write = t
            self.counters["commands"] += 1

    def command(self, cmd: int, arg: int | bytes | str | None = None) -> None:
        """Send any client command (number per §B.5)."""
        self._send(cmd, arg)

    def set_velocity(self, v: float, w: float) -> None:
        """Translational ``v`` (m/s) and rotational ``w`` (rad/s) via VEL and RVEL.
        RVEL has a resolution of 1 °/s; use :meth:`set_wheel_velocities` (VEL2) for
        direct wheel control."""
        p = self.params
        vmm = int(round(max(-p.max_velocity, min(p.max_velocity, v * 1000.0))))
        wdeg = int(round(max(-p.max_rot_velocity, min(p.max_rot_velocity, math.degrees(w)))))
        self._send(ap.VEL, vmm)
        self._send(ap.RVEL, wdeg)

    def set_wheel_velocities(self, left: float, right: float) -> None:
        """Wheel speeds in m/s via VEL2 (resolution ``Vel2Divisor`` = 20 mm/s)."""
        self._send(
            ap.VEL2, ap.vel2_argument(left * 1000.0, right * 1000.0, self.params.vel2_divisor)
        )

    def stop(self) -> None:
        self._send(ap.STOP)

    def e_stop(self) -> None:
        self._send(ap.E_STOP)

    def enable_motors_cmd(self, on: bool = True) -> None:
        self._send(ap.ENABLE, 1 if on else 0)

    def reset_odometry(self) -> None:
        """SETO: the controller's pose becomes (0, 0, 0); our unwrapped pose follows."""
        self._send(ap.SETO)
        self.decoder.unwrapper.reset()
        self._odom_offset = None

    # ------------------------------------------------------------------ threads

    def _heartbeat(self) -> None:
        while not self._stop.wait(self.heartbeat / 4.0):
            with self._write_lock:
                if not self._link_up:
                    continue  # reconnecting (the reader) or closing
                if clock.now() - self._last_write < self.heartbeat:
                    continue
                try:
                    self._send(ap.PULSE)
                except (OSError, serial.SerialException, PowerBotError):
                    if not self.auto_reconnect:
                        return
                    # the reader notices the failed line and reconnects

    def _reader(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    self._read_once()
                except (OSError, serial.SerialException, PowerBotError) as e:
                    if isinstance(e, (OSError, serial.SerialException)):
                        self.counters["read_errors"] += 1
                        e = PowerBotError(f"serial line to the robot on {self.port} failed: {e}")
                    if not self.auto_reconnect or self._stop.is_set():
                        raise e from None
                    self._relink(e)
        except BaseException as e:
            if not self._stop.is_set():
                self._error = e
            self._put(_STOP)

    def _read_once(self) -> None:
        ser = self.ser
        if ser is None:
            raise PowerBotError("port is closed")
        data = ser.read(max(1, ser.in_waiting))
        if not data:
            if clock.now() - self._last_sip_time > self.stall_timeout:
                raise PowerBotTimeout(
                    f"no SIP from the robot on {self.port} for {self.stall_timeout:g} s"
                )
            return
        t = clock.now()
        if self.recorder is not None:
            self.recorder.rx(self._rec_dev, t, data)
        for pkt in self.parser.feed(data, t):
            sip = self.decoder.decode(pkt)
            if sip is None:
                self.counters["other_packets"] += 1
                continue
            sip = self._continue_odometry(sip)
            self.counters["sips"] += 1
            self.last_sip = sip
            self._last_sip_time = t
            self._put(sip)

    def _put(self, item: object) -> None:
        self.counters["dropped_sips"] += put_dropping_oldest(self._sips, item)

    def get(self, timeout: float | None = None) -> Sip | None:
        """Next SIP (None on timeout or after close). Raises the reader's error."""
        try:
            item = self._sips.get(timeout=timeout)
        except queue.Empty:
            return None
        if item is _STOP:
            err, self._error = self._error, None
            if err is not None:
                raise err
            return None
        assert isinstance(item, Sip)
        return item

    def sips(self, limit: int | None = None) -> Iterator[Sip]:
        """Yield SIPs as they arrive (forever, or ``limit`` of them). Ends when the
        driver is closed; raises :class:`PowerBotTimeout` if SIPs stop coming."""
        n = 0
        while limit is None or n < limit:
            sip = self.get(timeout=0.1)
            if sip is None:
                if not self._connected and self._sips.empty():
                    return
                if self._threads and not self._threads[0].is_alive() and self._sips.empty():
                    if self._error is not None:
                        err, self._error = self._error, None
                        raise err
                    return
                continue
            n += 1
            yield sip

    def odometry(self, limit: int | None = None) -> Iterator[Odometry]:
        """:meth:`sips` converted to :class:`icploc.messages.Odometry`."""
        for sip in self.sips(limit):
            yield sip.to_odometry()


class _Retry(Exception):
    def __init__(self, close: bool = False) -> None:
        super().__init__()
        self.close = close  #: send CLOSE before the next try


class _StillConnected(Exception):
    pass

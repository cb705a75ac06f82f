"""Shared machinery of the device simulators: fault settings, an output schedule, and
the runner thread that moves bytes between a device engine and a transport (a
pseudo-terminal or any pair of byte streams).

An *engine* (:class:`~icploc.sim.pls_device.PLSDevice`,
:class:`~icploc.sim.powerbot_device.PowerBotDevice`) is protocol logic only:
``receive(data, now)`` takes bytes from the host, ``output(now, line_idle)`` returns the
bytes due on the line now. The :class:`DeviceRunner` owns time: in real-time mode it
paces writes at the byte time of the engine's current baud rate and sleeps until the
next scheduled output; in test mode it writes as fast as the host reads.

Both engines send a periodic stream (the PLS its measured values in streaming mode, the
PowerBot its SIPs once opened): :class:`PeriodicStream` times it, and
:class:`StreamingEngine` is the engine half they share (replies and stream frames on the
line, fault injection, vanishing, the device's simulated time).
"""

from __future__ import annotations

import os
import random
import shutil
import tempfile
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol

from icploc import clock
from icploc.sim.pty import LineSettings, PtyPair

if TYPE_CHECKING:
    from icploc.sim.robot import DiffDriveRobot


#: :meth:`DeviceRunner._host_baud` when the host's line speed cannot be read (not a pty)
UNCHECKED = -1


@dataclass
class Faults:
    """Fault injection on the device->host side (probabilities per telegram / packet).

    * ``corrupt_rate``: flip one byte (so the CRC / checksum no longer matches);
    * ``drop_rate``: delete one byte from the telegram;
    * ``garbage_rate``: insert 1..``garbage_max`` random bytes before it;
    * ``late_reply``: extra seconds before every ACK / reply;
    * ``nak_storm``: answer the next N valid host telegrams with NAK (SICK) or ignore
      them (ARCOS, which has no NAK);
    * ``ignore_rate``: silently miss a valid host telegram (mirror revolution);
    * ``vanished``: the device is gone (reads nothing, sends nothing).
    """

    corrupt_rate: float = 0.0
    drop_rate: float = 0.0
    garbage_rate: float = 0.0
    garbage_max: int = 40
    late_reply: float = 0.0
    nak_storm: int = 0
    ignore_rate: float = 0.0
    vanished: bool = False
    seed: int = 0

    def __post_init__(self) -> None:
        self.rng = random.Random(self.seed)

    def mangle(self, frame: bytes) -> tuple[bytes, bool]:
        """Apply the per-telegram faults; returns (bytes to send, intact?)."""
        rng = self.rng
        intact = True
        out = bytearray(frame)
        if self.corrupt_rate and rng.random() < self.corrupt_rate:
            i = rng.randrange(len(out))
            out[i] ^= rng.randrange(1, 256)
            intact = False
        if self.drop_rate and rng.random() < self.drop_rate and len(out) > 1:
            del out[rng.randrange(len(out))]
            intact = False
        if self.garbage_rate and rng.random() < self.garbage_rate:
            n = rng.randint(1, max(1, self.garbage_max))
            out[:0] = bytes(rng.randrange(256) for _ in range(n))
        return bytes(out), intact


@dataclass
class _Item:
    due: float
    data: bytes
    action: Callable[[], None] | None = None


class OutputSchedule:
    """Bytes to send, each no earlier than its due time, in order."""

    def __init__(self) -> None:
        self._items: list[_Item] = []

    def add(self, due: float, data: bytes, action: Callable[[], None] | None = None) -> None:
        # keep order: an item is never sent before one queued earlier
        if self._items:
            due = max(due, self._items[-1].due)
        self._items.append(_Item(due, data, action))

    def pop_due(self, now: float) -> bytes:
        out = bytearray()
        while self._items and self._items[0].due <= now:
            it = self._items.pop(0)
            out += it.data
            if it.action is not None:
                it.action()
        return bytes(out)

    def next_due(self) -> float | None:
        return self._items[0].due if self._items else None

    def clear(self) -> None:
        self._items.clear()

    def __len__(self) -> int:
        return len(self._items)


class Engine(Protocol):
    faults: Faults

    @property
    def baudrate(self) -> int: ...
    @property
    def parity(self) -> str: ...
    @property
    def bits_per_byte(self) -> int: ...
    def receive(self, data: bytes, now: float) -> None: ...
    def output(self, now: float, line_idle: bool) -> bytes: ...
    def next_due(self, now: float) -> float | None: ...


class PeriodicStream:
    """The timing of a device's periodic stream: while :attr:`on`, a frame every
    ``period`` s in real-time mode (never more than one at a time on the line), or one
    each time the line is idle in test mode; and the device's simulated time."""

    def __init__(self, period: float, realtime: bool) -> None:
        self.period = period
        self.realtime = realtime
        self.reset()

    def reset(self) -> None:
        """Power-on: off, nothing sent, the clock not started."""
        self.on = False
        self.index = 0  #: frames built so far (in test mode they count simulated time)
        self._t0: float | None = None  # host time of the first frame after (re)starting
        self._next = 0.0  # real-time mode: when the next frame is due
        self._robot_offset: float | None = None  # test mode: robot time - sim time

    def restart_clock(self) -> None:
        """The next frame starts the simulated time afresh (real-time mode)."""
        self._t0 = None

    def due(self, now: float, line_idle: bool, pending: bool) -> bool:
        """True if a frame goes out now: the stream is on, the line idle, no reply
        ``pending``, and (real time) its time has come. The caller builds it and then
        calls :meth:`sent`."""
        if not (self.on and line_idle and not pending):
            return False
        if self._t0 is None:
            self._t0 = now
            self._next = now
        return not self.realtime or now >= self._next

    def sent(self, now: float) -> None:
        if self.realtime:
            self._next = max(self._next + self.period, now)

    def next_due(self, scheduled: float | None) -> float | None:
        """The earlier of ``scheduled`` (the next reply) and the next frame."""
        if self.on and self.realtime:
            return self._next if scheduled is None else min(scheduled, self._next)
        return scheduled

    def sim_time(self, now: float) -> float:
        """Simulated time (s): since the stream (re)started in real-time mode; the frame
        count times the period in test mode."""
        if self.realtime:
            return 0.0 if self._t0 is None else now - self._t0
        return self.index * self.period

    def robot_time(self, robot: DiffDriveRobot, now: float, t: float) -> float:
        """The robot's simulated time at ``now`` (sim time ``t``): the shared host clock in
        real-time mode; in test mode the device's own sim time, offset to where the robot
        was when this device started streaming."""
        if self.realtime:
            return robot.clock_time(now)
        if self._robot_offset is None:
            self._robot_offset = robot.time - t
        return t + self._robot_offset


def stream_alias(attr: str, doc: str) -> Any:
    """An engine attribute that is its stream's ``attr`` (``PLSDevice.streaming`` is
    ``stream.on``), readable and settable."""

    def get(self: Any) -> Any:
        return getattr(self.stream, attr)

    def put(self: Any, value: Any) -> None:
        setattr(self.stream, attr, value)

    return property(get, put, doc=doc)


class StreamingEngine(ABC):
    """The engine half both device simulators share: replies queued on an
    :class:`OutputSchedule`, a :class:`PeriodicStream`, fault injection on every frame,
    vanishing and coming back. A subclass provides ``faults``, ``realtime``,
    ``schedule``, ``stream``, ``_baud``, :meth:`power_on`, :meth:`_stream_frame` (the next
    stream frame, as built) and :meth:`_mark` (whether the frame it logged last went out
    intact)."""

    faults: Faults
    realtime: bool
    schedule: OutputSchedule
    stream: PeriodicStream
    _baud: int

    @abstractmethod
    def power_on(self) -> None:
        """Reset to the device's power-on state."""

    @abstractmethod
    def _stream_frame(self, now: float) -> bytes:
        """The next stream frame, as built (before fault injection)."""

    @abstractmethod
    def _mark(self, intact: bool) -> None:
        """Record whether the frame logged last went out intact."""

    def _tick(self, now: float) -> None:  # noqa: B027 (an optional hook: nothing by default)
        """Called before every output poll (the PowerBot's watchdog)."""

    @property
    def baudrate(self) -> int:
        return self._baud

    def vanish(self) -> None:
        self.faults.vanished = True

    def revive(self, power_cycle: bool = True) -> None:
        """Come back; with ``power_cycle`` in the power-on state."""
        if power_cycle:
            self.power_on()
        self.faults.vanished = False

    def sim_time(self, now: float) -> float:
        return self.stream.sim_time(now)

    def output(self, now: float, line_idle: bool) -> bytes:
        if self.faults.vanished:
            return b""
        self._tick(now)
        out = self.schedule.pop_due(now)
        if out:
            return out
        if self.stream.due(now, line_idle, len(self.schedule) > 0):
            data = self._mangled(self._stream_frame(now))
            self.stream.sent(now)
            return data
        return b""

    def next_due(self, now: float) -> float | None:
        return self.stream.next_due(self.schedule.next_due())

    def _mangled(self, frame: bytes) -> bytes:
        """``frame`` after fault injection (the log notes whether it went out intact)."""
        mangled, intact = self.faults.mangle(frame)
        self._mark(intact)
        return mangled

    def _send(self, now: float, delay: float, data: bytes, action: Callable[[], None] | None = None) -> None:
        """Queue ``data`` ``delay`` s from now (real-time mode; plus any late-reply fault)."""
        d = (delay if self.realtime else 0.0) + self.faults.late_reply
        self.schedule.add(now + d, data, action)


class Transport(Protocol):
    def read(self, n: int = 65536) -> bytes: ...
    def write(self, data: bytes) -> int: ...
    def wait(self, timeout: float, want_write: bool) -> tuple[bool, bool]: ...
    def close(self) -> None: ...


class DeviceRunner:
    """Runs an engine against a transport in a background thread.

    ``realtime=True`` honours the byte time at the engine's baud rate (and whatever
    periods the engine schedules); ``realtime=False`` moves bytes as fast as possible.
    ``check_line=True`` (pty transports only) compares the host's configured baud rate
    with the device's (a Linux pty does not keep the parity bit, so parity cannot be
    checked this way) and, when they differ, discards the host's bytes and
    sends line noise instead of the device's bytes.
    """

    def __init__(self, engine: Engine, transport: Transport | None = None, *, realtime: bool = False,
                 check_line: bool = True, name: str = "device", unpluggable: bool = False) -> None:  # fmt: skip
        self.engine = engine
        self.transport: Transport = transport if transport is not None else PtyPair()
        #: ``unpluggable``: the port is a symlink (like ``/dev/serial/by-id/...``) to the pty,
        #: so :meth:`unplug` / :meth:`replug` can remove the device node and bring it back
        self._link_dir: str | None = None
        self._link: str | None = None
        self._unplugged = False
        self._swap = threading.Lock()
        if unpluggable:
            if not isinstance(self.transport, PtyPair):
                raise ValueError("unpluggable needs a pty transport")
            self._link_dir = tempfile.mkdtemp(prefix="icploc-sim-")
            self._link = os.path.join(self._link_dir, f"tty-{name}")
            os.symlink(self.transport.port, self._link)
        self.realtime = realtime
        self.check_line = check_line and isinstance(self.transport, PtyPair)
        self.name = name
        self.bytes_in = 0
        self.bytes_out = 0
        self.line_mismatch_bytes = 0
        self.steps = 0  #: turns of the device thread's loop begun (tests wait on it)
        #: the host's line speed sampled just before the last read of its bytes
        self._host_baud_since: int | None = None
        self._pending = bytearray()
        self._pending_baud = 0  #: the device's line speed when the pending bytes were due
        self._line_free_at = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._noise = random.Random(0xC0FFEE)
        self.error: BaseException | None = None

    @property
    def port(self) -> str:
        """Path the driver should open (pty transports)."""
        if self._link is not None:
            return self._link
        if isinstance(self.transport, PtyPair):
            return self.transport.port
        raise AttributeError("transport has no port path")

    @property
    def unplugged(self) -> bool:
        return self._unplugged

    @contextmanager
    def paused(self) -> Iterator[None]:
        """Hold the device thread between two turns of its loop (a device late to read
        the host's bytes, e.g. on a loaded machine)."""
        with self._swap:
            yield

    def unplug(self) -> None:
        """The USB adapter is pulled: the pty closes (the host's reads fail) and the
        device node disappears. Needs ``unpluggable=True``."""
        if self._link is None:
            raise RuntimeError("unplug() needs DeviceRunner(..., unpluggable=True)")
        with self._swap:
            self._unplugged = True
            self.transport.close()
            self._pending.clear()
            try:
                os.unlink(self._link)
            except FileNotFoundError:
                pass

    def replug(self, power_cycle: bool = True) -> None:
        """The adapter is back (a new pty behind the same device node); with
        ``power_cycle`` the device restarts in its power-on state."""
        if self._link is None:
            raise RuntimeError("replug() needs DeviceRunner(..., unpluggable=True)")
        with self._swap:
            tr = PtyPair()
            revive = getattr(self.engine, "revive", None)
            if power_cycle and revive is not None:
                revive(power_cycle=True)
            self.transport = tr
            self._line_free_at = 0.0
            self._host_baud_since = None
            tmp = self._link + ".new"
            os.symlink(tr.port, tmp)
            os.replace(tmp, self._link)
            self._unplugged = False

    def start(self) -> DeviceRunner:
        self._thread = threading.Thread(target=self._run, name=f"sim-{self.name}", daemon=True)
        self._thread.start()
        return self

    def stop(self, close: bool = True) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if close:
            self.transport.close()
            if self._link_dir is not None:
                shutil.rmtree(self._link_dir, ignore_errors=True)
                self._link_dir = None

    def __enter__(self) -> DeviceRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _host_baud(self) -> int | None:
        """The host's configured line speed: :data:`UNCHECKED` when it cannot be read,
        None when it is not a standard speed (it matches no device)."""
        if not self.check_line:
            return UNCHECKED
        assert isinstance(self.transport, PtyPair)
        try:
            s: LineSettings = self.transport.host_settings()
        except OSError:
            return UNCHECKED
        # Linux ptys keep the speed but refuse PARENB, so only the baud rate can be checked.
        return s.baudrate

    def _line_ok(self, baud: int | None = None) -> bool:
        """The host's line speed is the device's (or ``baud``)."""
        host = self._host_baud()
        return host == UNCHECKED or host == (self.engine.baudrate if baud is None else baud)

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as e:  # surfaced through .error for tests
            self.error = e

    def _loop(self) -> None:
        while not self._stop.is_set():
            with self._swap:
                idle = self._unplugged or self._step()
            if idle:
                time.sleep(0.005)

    def _receive(self, deliver: bool = True) -> None:
        """Read what the host wrote and hand it to the engine if it went out at the
        device's line speed. A pty keeps no speed per byte, and this thread may read long
        after the host wrote (a loaded machine): the bytes of this read were written after
        the previous read, at a speed the host had between the sample taken just before
        that read and the one after this read. If the host switched in between (it sent
        HOSTBAUD, or the OPEN and PULSE before it, at 9600 Bd and changed its UART 10 ms
        later, before this thread woke), they count at either speed: judged at read time
        alone, a late device would lose bytes that went out at the right speed."""
        before = self._host_baud()
        data = self.transport.read()
        after = self._host_baud()
        speeds = {after} if self._host_baud_since is None else {after, self._host_baud_since}
        self._host_baud_since = before
        if not data or not deliver:
            return
        self.bytes_in += len(data)
        if UNCHECKED in speeds or self.engine.baudrate in speeds:
            self.engine.receive(data, clock.now())
        else:
            self.line_mismatch_bytes += len(data)

    def _step(self) -> bool:
        """One turn of the loop; True when the device is idle (vanished)."""
        self.steps += 1
        eng = self.engine
        tr = self.transport
        now = clock.now()
        if eng.faults.vanished:
            # bytes already in the pty buffer still reach the host, like bytes in a
            # UART FIFO (flushing them here would race with the host's select/read)
            self._receive(deliver=False)
            self._pending.clear()
            return True
        # what the host has written already arrived: the engine sees it before it decides
        # its output (a late wake-up of this thread must not trip the device's watchdog)
        self._receive()
        byte_time = eng.bits_per_byte / float(eng.baudrate)
        line_idle = not self._pending and (not self.realtime or now >= self._line_free_at)
        line_ok = self._line_ok()  # before output(): a baud switch takes effect after its reply
        baud = eng.baudrate
        out = eng.output(now, line_idle)
        if out:
            if not line_ok:
                out = bytes(self._noise.randrange(256) for _ in range(len(out)))
            self._pending += out
            self._pending_baud = baud
        # how long may we sleep?
        timeout = 0.05
        nd = eng.next_due(now)
        if nd is not None:
            timeout = min(timeout, max(0.0, nd - now))
        if self._pending and self.realtime:
            timeout = min(timeout, max(0.0, self._line_free_at - now))
        readable, writable = tr.wait(
            timeout,
            bool(self._pending) and (not self.realtime or now >= self._line_free_at - 0.002),
        )
        if readable:
            self._receive()
        if writable and self._pending:
            now = clock.now()
            chunk = self._pending
            # while the line stays busy, keep the byte clock running from where it is
            # (late wake-ups must not stretch the line time); after a pause, restart
            base = self._line_free_at if now - self._line_free_at < 0.02 else now
            if self.realtime:
                # write what the line carries up to ~5 ms from now
                n = max(1, int((now + 0.005 - base) / byte_time))
                chunk = self._pending[:n]
            out = bytes(chunk)
            if not self._line_ok(self._pending_baud):
                # the host changed its line since these bytes were due: it reads noise
                out = bytes(self._noise.randrange(256) for _ in range(len(out)))
            k = tr.write(out)
            if k:
                del self._pending[:k]
                self.bytes_out += k
                self._line_free_at = base + k * byte_time
        return False

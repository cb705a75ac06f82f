"""Shared machinery of the device simulators: fault settings, an output schedule, and
the runner thread that moves bytes between a device engine and a transport (a
pseudo-terminal or any pair of byte streams).

An *engine* (:class:`~icploc.sim.pls_device.PLSDevice`,
:class:`~icploc.sim.powerbot_device.PowerBotDevice`) is protocol logic only:
``receive(data, now)`` takes bytes from the host, ``output(now, line_idle)`` returns the
bytes due on the line now. The :class:`DeviceRunner` owns time: in real-time mode it
paces writes at the byte time of the engine's current baud rate and sleeps until the
next scheduled output; in test mode it writes as fast as the host reads.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from icploc import clock
from icploc.sim.pty import LineSettings, PtyPair


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
                 check_line: bool = True, name: str = "device") -> None:  # fmt: skip
        self.engine = engine
        self.transport: Transport = transport if transport is not None else PtyPair()
        self.realtime = realtime
        self.check_line = check_line and isinstance(self.transport, PtyPair)
        self.name = name
        self.bytes_in = 0
        self.bytes_out = 0
        self.line_mismatch_bytes = 0
        self._pending = bytearray()
        self._line_free_at = 0.0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._noise = random.Random(0xC0FFEE)
        self.error: BaseException | None = None

    @property
    def port(self) -> str:
        """Path the driver should open (pty transports)."""
        if isinstance(self.transport, PtyPair):
            return self.transport.port
        raise AttributeError("transport has no port path")

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

    def __enter__(self) -> DeviceRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _line_ok(self) -> bool:
        if not self.check_line:
            return True
        assert isinstance(self.transport, PtyPair)
        try:
            s: LineSettings = self.transport.host_settings()
        except OSError:
            return True
        # Linux ptys keep the speed but refuse PARENB, so only the baud rate can be checked.
        return s.baudrate == self.engine.baudrate

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as e:  # surfaced through .error for tests
            self.error = e

    def _loop(self) -> None:
        eng = self.engine
        tr = self.transport
        while not self._stop.is_set():
            now = clock.now()
            if eng.faults.vanished:
                # bytes already in the pty buffer still reach the host, like bytes in a
                # UART FIFO (flushing them here would race with the host's select/read)
                tr.read()
                self._pending.clear()
                time.sleep(0.005)
                continue
            byte_time = eng.bits_per_byte / float(eng.baudrate)
            line_idle = not self._pending and (not self.realtime or now >= self._line_free_at)
            line_ok = self._line_ok()  # before output(): a baud switch takes effect after its reply
            out = eng.output(now, line_idle)
            if out:
                if not line_ok:
                    out = bytes(self._noise.randrange(256) for _ in range(len(out)))
                self._pending += out
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
                data = tr.read()
                if data:
                    self.bytes_in += len(data)
                    if self._line_ok():
                        eng.receive(data, clock.now())
                    else:
                        self.line_mismatch_bytes += len(data)
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
                k = tr.write(bytes(chunk))
                if k:
                    del self._pending[:k]
                    self.bytes_out += k
                    self._line_free_at = base + k * byte_time

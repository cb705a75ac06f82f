"""SICK PLS 101/201 and LMS 2xx laser scanner driver over pyserial.

>>> from icploc.drivers.sick import PLS
>>> with PLS("/dev/ttyUSB0", baudrate=38400) as laser:          # doctest: +SKIP
...     for scan in laser.scans():
...         print(scan.stamp, scan.ranges.min())

Connection (PROTOCOLS.md §A.8): open the line (PLS 8E1, LMS 8N1), find the device by
probing ``20 25`` at each candidate baud rate, switch to the working baud rate (the PLS
first needs installation mode with the password ``SICK_PLS``), then request continuous
output (``20 24``). Every command is retried with exponential back-off on NAK and on
timeouts. ``close()`` sends ``20 25`` so the scanner stops streaming.

Scans are stamped with the arrival time of the telegram's first byte on
:func:`icploc.clock.now`, back-dated from the read by the line's byte time.

``scans()`` reads in the calling thread; :meth:`SickLaser.start` runs a background
reader thread that fills a bounded queue (and calls an optional callback) instead, and
``scans()`` / :meth:`SickLaser.get` then drain that queue.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import serial

from icploc import clock
from icploc.drivers import sick_protocol as sp
from icploc.drivers._link import close_quietly, retry_with_backoff
from icploc.drivers._queues import put_dropping_oldest
from icploc.drivers.recording import Recorder
from icploc.errors import DeviceError
from icploc.messages import Scan

ScanCallback = Callable[[Scan], None]


class SickError(DeviceError, RuntimeError):
    """The laser could not be reached or configured, or the line failed."""


class SickTimeout(SickError):
    """No (valid) answer within the retries / no scans within the stall timeout."""


class SickRefused(SickError):
    """The device answered 0x92 (command not allowed) or an error result byte."""


_STOP = object()


class SickLaser:
    """Common driver for the PLS and the LMS 2xx; use :class:`PLS` or :class:`LMS2xx`."""

    variant = "lms"
    parity = serial.PARITY_NONE
    password = sp.PASSWORD_LMS
    #: the PLS refuses a baud change outside installation mode (§A.6)
    install_mode_for_baud = False
    default_max_range = 8.18

    def __init__(
        self,
        port: str,
        baudrate: int = 38400,
        *,
        address: int = 0x00,
        flipped: bool = False,
        connect_baudrates: tuple[int, ...] | None = None,
        mode: str = "stream",
        retries: int = 4,
        backoff: float = 0.03,
        ack_timeout: float | None = None,
        reply_timeout: float = 3.0,
        stall_timeout: float = 2.0,
        auto_reconnect: bool = False,
        reconnect_timeout: float = 30.0,
        reconnect_backoff: float = 0.2,
        reconnect_backoff_max: float = 5.0,
        baud_settle: float = 0.25,
        recorder: Recorder | str | Path | None = None,
        queue_size: int = 64,
        read_chunk: int = 4096,
        max_range: float | None = None,
    ) -> None:
        if baudrate not in sp.MODE_BAUD:
            raise ValueError(
                f"unsupported baud rate {baudrate}; choose one of {sorted(sp.MODE_BAUD)}"
            )
        if mode not in ("stream", "poll"):
            raise ValueError("mode must be 'stream' or 'poll'")
        self.port = port
        self.baudrate = baudrate
        self.address = address
        self.flipped = flipped
        order = connect_baudrates or (9600, baudrate, 38400, 19200, 500000)
        self.connect_baudrates = tuple(dict.fromkeys(order))
        self.mode = mode
        self.retries = retries
        self.backoff = backoff
        self._ack_timeout = ack_timeout
        self.reply_timeout = reply_timeout
        self.stall_timeout = stall_timeout
        self.auto_reconnect = auto_reconnect
        self.reconnect_timeout = reconnect_timeout
        self.reconnect_backoff = reconnect_backoff
        self.reconnect_backoff_max = reconnect_backoff_max
        self.baud_settle = baud_settle
        self.read_chunk = read_chunk
        self.max_range = self.default_max_range if max_range is None else max_range
        self._own_recorder = isinstance(recorder, (str, Path))
        self.recorder: Recorder | None = (
            Recorder(recorder) if isinstance(recorder, (str, Path)) else recorder
        )
        self._rec_dev = 0

        self.ser: serial.SerialBase | None = None
        self.parser = sp.TelegramParser(addresses=frozenset({0x80 | address}))
        self.device_type: str | None = None
        self.current_baud = 0
        self.streaming = False
        self.seq = 0
        self.counters: dict[str, int] = {
            "scans": 0, "bad_scans": 0, "naks": 0, "timeouts": 0, "retries": 0,
            "refused": 0, "reconnects": 0, "dropped_scans": 0, "read_errors": 0,
        }  # fmt: skip
        self._control: queue.Queue[sp.Telegram | sp.ByteEvent] = queue.Queue()
        self._scans: queue.Queue[Any] = queue.Queue(maxsize=max(1, queue_size))
        self._callback: ScanCallback | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._io_lock = threading.RLock()
        self._last_scan = 0.0
        self._error: BaseException | None = None
        self._reconnecting = False

    # ------------------------------------------------------------------ lifecycle

    @property
    def bits_per_byte(self) -> int:
        return 11 if self.parity != serial.PARITY_NONE else 10

    def byte_time(self, baud: int | None = None) -> float:
        return self.bits_per_byte / float(baud or self.current_baud or 9600)

    @property
    def ack_timeout(self) -> float:
        """ACK latency (60 ms) plus one maximal telegram in flight at the current baud."""
        if self._ack_timeout is not None:
            return self._ack_timeout
        return 0.06 + 1.2 * sp.MAX_TELEGRAM * self.byte_time()

    def __enter__(self) -> SickLaser:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self) -> None:
        """Open the port, find the device, switch baud rate, start output."""
        if self.recorder is not None and not self._rec_dev:
            self._rec_dev = self.recorder.device(
                f"sick-{self.variant}",
                {"driver": "sick", "variant": self.variant, "flipped": self.flipped, "port": str(self.port),
                 "bits_per_byte": self.bits_per_byte, "max_range": self.max_range},
                clock.now(),
            )  # fmt: skip
        self._open_port()
        try:
            self._configure()
        except BaseException:
            self._close_port()
            raise

    def _open_port(self) -> None:
        first = self.connect_baudrates[0]
        self.ser = serial.serial_for_url(
            self.port,
            baudrate=first,
            bytesize=serial.EIGHTBITS,
            parity=self.parity,
            stopbits=serial.STOPBITS_ONE,
            timeout=0.02,
            write_timeout=5.0,
            xonxoff=False,
            rtscts=False,
        )
        self._set_host_baud(first)
        self.parser.reset()

    def _close_port(self) -> None:
        close_quietly(self.ser)
        self.ser = None

    def _set_host_baud(self, baud: int) -> None:
        assert self.ser is not None
        if self.ser.baudrate != baud:
            self.ser.baudrate = baud
        self.current_baud = baud
        self.parser.byte_time = self.byte_time(baud)
        if self.recorder is not None:
            self.recorder.meta(self._rec_dev, clock.now(), {"baudrate": baud})

    def _configure(self) -> None:
        self.streaming = False
        found = None
        for baud in self.connect_baudrates:
            if self._reconnecting and self._stop.is_set():
                raise SickError("closed while reconnecting")
            try:
                self._set_host_baud(baud)
            except (ValueError, OSError, serial.SerialException):
                continue  # e.g. 500 kBd not settable on this line
            self._flush_input()
            naks = self.counters["naks"]
            try:
                self._mode(sp.MODE_ON_REQUEST, retries=1)
            except SickTimeout:
                if self.counters["naks"] == naks:
                    continue
                # NAKs prove a device at this baud rate: keep trying here
                try:
                    self._mode(sp.MODE_ON_REQUEST)
                except SickTimeout:
                    continue
            found = baud
            break
        if found is None:
            raise SickTimeout(
                f"no answer from the {self.variant.upper()} at any of {self.connect_baudrates} Bd"
            )
        self._identify()
        if found != self.baudrate:
            if self.install_mode_for_baud:
                self._mode(sp.MODE_INSTALL, self.password)
            self._mode(sp.MODE_BAUD[self.baudrate])
            time.sleep(0.02)
            self._set_host_baud(self.baudrate)
            time.sleep(self.baud_settle)
            self._flush_input()
            self._mode(sp.MODE_ON_REQUEST)
        self._setup_variant()
        if self.mode == "stream":
            self._mode(sp.MODE_STREAM_ALL)
            self.streaming = True
        self._last_scan = clock.now()

    def _identify(self) -> None:
        """LMS: read the type string (0x3A). The PLS's support for 0x3A is unverified."""

    def _setup_variant(self) -> None:
        """LMS: set angular range / resolution (0x3B). Fixed on the PLS."""

    def close(self) -> None:
        """Stop the output (``20 25``), stop the reader thread, close the port."""
        if self.ser is not None and self.streaming:
            try:
                self._mode(sp.MODE_ON_REQUEST, retries=2)
            except (SickError, OSError, serial.SerialException):
                pass
            self.streaming = False
        self._stop_thread()
        self._close_port()
        if self.recorder is not None and self._own_recorder:
            self.recorder.close()

    def reconnect(self) -> None:
        """Re-open the line and run the whole connection sequence again (probe every
        connect baud rate, installation mode, baud switch, start output: a power-cycled
        scanner is back at 9600 Bd). Attempts are spaced by an exponential back-off
        (``reconnect_backoff`` doubling up to ``reconnect_backoff_max``) and end after
        ``reconnect_timeout`` s with :class:`SickTimeout`. A device node that vanished
        (USB adapter unplugged) is retried until it reappears."""
        self.counters["reconnects"] += 1
        self._reconnecting = True
        self.streaming = False
        if self.recorder is not None:
            self.recorder.meta(self._rec_dev, clock.now(), {"event": "reconnect"})

        def attempt() -> None:
            self._open_port()
            self._configure()

        try:
            configured, last = retry_with_backoff(
                attempt,
                close=self._close_port,
                failures=(SickError, OSError, serial.SerialException),
                stop=self._stop,
                timeout=self.reconnect_timeout,
                backoff=self.reconnect_backoff,
                backoff_max=self.reconnect_backoff_max,
            )
            if configured:
                return
            if self._stop.is_set():
                raise SickError("closed while reconnecting")
            raise SickTimeout(
                f"{self.variant.upper()} on {self.port} did not come back within "
                f"{self.reconnect_timeout:g} s (last error: {last})"
            )
        finally:
            self._reconnecting = False

    @property
    def link_up(self) -> bool:
        """The port is open and the device configured (and streaming, in stream mode);
        False while a reconnect is under way or after the line failed."""
        if self.ser is None or self._reconnecting:
            return False
        return self.streaming or self.mode == "poll"

    @property
    def reconnecting(self) -> bool:
        return self._reconnecting

    @property
    def stats(self) -> dict[str, int]:
        """Driver counters plus the parser's (CRC errors, resyncs, dropped bytes, ...)."""
        return {
            **self.counters,
            **{f"parser_{k}": v for k, v in self.parser.stats.as_dict().items()},
        }

    # ------------------------------------------------------------------ I/O

    def _write(self, data: bytes) -> None:
        assert self.ser is not None
        if self.recorder is not None:
            self.recorder.tx(self._rec_dev, clock.now(), data)
        self.ser.write(data)
        self.ser.flush()

    def _flush_input(self) -> None:
        assert self.ser is not None
        time.sleep(0.005)
        self.ser.reset_input_buffer()
        self.parser.reset()
        while not self._control.empty():
            self._control.get_nowait()

    def _pump(self) -> int:
        """Read what is there (waiting up to the port timeout for the first byte),
        parse it and dispatch the results. Returns the number of bytes read."""
        ser = self.ser
        if ser is None:
            raise SickError("port is closed")
        with self._io_lock:
            n = ser.in_waiting
            data = ser.read(min(max(n, 1), self.read_chunk))
        if not data:
            return 0
        t = clock.now()
        if self.recorder is not None:
            self.recorder.rx(self._rec_dev, t, data)
        for ev in self.parser.feed(data, t):
            if isinstance(ev, sp.Telegram) and ev.cmd == sp.REPLY_MEASURED:
                self._deliver_scan(ev)
            else:
                self._control.put(ev)
        return len(data)

    def _deliver_scan(self, tel: sp.Telegram) -> None:
        try:
            scan = sp.decode_scan(tel, variant=self.variant, seq=self.seq + 1, flipped=self.flipped,
                                  max_range=self.max_range)  # fmt: skip
        except sp.SickProtocolError:
            self.counters["bad_scans"] += 1
            return
        self.seq += 1
        self.counters["scans"] += 1
        self._last_scan = clock.now()
        if self._callback is not None:
            self._callback(scan)
        self.counters["dropped_scans"] += put_dropping_oldest(self._scans, scan)

    def _next_control(self, deadline: float) -> sp.Telegram | sp.ByteEvent | None:
        in_thread = (
            self._thread is not None
            and self._thread.is_alive()
            and threading.current_thread() is not self._thread
        )
        late = False
        while True:
            try:
                return self._control.get_nowait()
            except queue.Empty:
                pass
            remaining = deadline - clock.now()
            if remaining <= 0:
                if in_thread or late:
                    return None
                # what arrived while this thread slept past the deadline (a loaded host)
                # still counts: read it once
                late = True
                self._pump()
                continue
            if in_thread:
                try:
                    return self._control.get(timeout=min(remaining, 0.05))
                except queue.Empty:
                    continue
            self._pump()

    def transact(
        self,
        cmd: int,
        data: bytes = b"",
        *,
        expect: int | None = None,
        retries: int | None = None,
        reply_timeout: float | None = None,
        ack_only: bool = False,
    ) -> sp.Telegram | None:
        """Send a telegram and return the reply telegram (code ``cmd | 0x80`` unless
        ``expect`` says otherwise). Retries with doubling back-off on NAK / timeout.
        Raises :class:`SickRefused` on a 0x92 reply, :class:`SickTimeout` when out of
        retries."""
        if self.ser is None:
            raise SickError("port is closed")
        tel = sp.build_telegram(cmd, data, address=self.address)
        expect = (cmd | 0x80) if expect is None else expect
        reply_timeout = self.reply_timeout if reply_timeout is None else reply_timeout
        tries = (self.retries if retries is None else retries) + 1
        delay = max(self.backoff, 0.03)  # >= 30 ms after a NAK (§A.4)
        for attempt in range(tries):
            if attempt:
                self.counters["retries"] += 1
                time.sleep(delay)
                delay = min(delay * 2.0, 2.0)
            while not self._control.empty():
                self._control.get_nowait()
            self._write(tel)
            deadline = clock.now() + self.ack_timeout
            acked = False
            reply: sp.Telegram | None = None
            nak = False
            while True:
                ev = self._next_control(deadline)
                if ev is None:
                    break
                if isinstance(ev, sp.ByteEvent):
                    if ev.value == sp.NAK and not acked:
                        nak = True
                        break
                    if ev.value == sp.ACK and not acked:
                        acked = True
                        if ack_only:
                            return None
                        deadline = clock.now() + reply_timeout
                    continue
                if ev.cmd == sp.REPLY_NOT_ACK:
                    self.counters["refused"] += 1
                    raise SickRefused(f"command 0x{cmd:02X} {data.hex()} refused (0x92)")
                if ev.cmd == expect:
                    reply = ev
                    break
            if reply is not None:
                return reply
            if nak:
                self.counters["naks"] += 1
            else:
                self.counters["timeouts"] += 1
        raise SickTimeout(f"no reply to command 0x{cmd:02X} {data.hex()} after {tries} tries")

    def _mode(self, mode: int, args: bytes = b"", retries: int | None = None) -> None:
        reply = self.transact(sp.CMD_MODE, bytes([mode]) + args, retries=retries)
        assert reply is not None
        result = reply.data[0] if reply.data else 0xFF
        if result != 0:
            self.counters["refused"] += 1
            why = {1: "wrong password", 2: "device fault"}.get(result, f"result 0x{result:02X}")
            raise SickRefused(f"mode 0x{mode:02X} refused: {why}")

    # ------------------------------------------------------------------ scans

    def start(self, callback: ScanCallback | None = None) -> None:
        """Run a background reader thread. Scans go to a bounded queue (oldest dropped
        when full, counted in ``dropped_scans``) and to ``callback`` if given (called
        in the reader thread; keep it short)."""
        if self._thread is not None:
            return
        self._callback = callback
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._reader, name=f"sick-{self.variant}-reader", daemon=True
        )
        self._thread.start()

    def _reader(self) -> None:
        try:
            while not self._stop.is_set():
                try:
                    self._pump()
                    self._check_stall()
                except (OSError, serial.SerialException) as e:
                    self.counters["read_errors"] += 1
                    if not self.auto_reconnect or self._stop.is_set():
                        raise SickError(f"serial line failed: {e}") from e
                    self.reconnect()
        except BaseException as e:  # handed to the consumer
            self._error = e
            self._put_marker()

    def _put_marker(self) -> None:
        while True:
            try:
                self._scans.put_nowait(_STOP)
                return
            except queue.Full:
                try:
                    self._scans.get_nowait()
                except queue.Empty:
                    pass

    def _stop_thread(self) -> None:
        th = self._thread
        if th is None:
            return
        self._stop.set()
        if th is not threading.current_thread():
            th.join(timeout=5.0)
        self._thread = None
        self._callback = None

    def _check_stall(self) -> None:
        if self.mode != "stream" or not self.streaming:
            return
        if clock.now() - self._last_scan > self.stall_timeout:
            if self.auto_reconnect:
                self.reconnect()
            else:
                raise SickTimeout(f"no scan for {self.stall_timeout} s")

    def get(self, timeout: float | None = None) -> Scan | None:
        """Next scan from the background reader (None on timeout)."""
        try:
            item = self._scans.get(timeout=timeout)
        except queue.Empty:
            return None
        if item is _STOP:
            err = self._error
            self._error = None
            if err is not None:
                raise err
            return None
        assert isinstance(item, Scan)
        return item

    def scans(self, limit: int | None = None) -> Iterator[Scan]:
        """Yield scans as they arrive (forever, or ``limit`` of them)."""
        n = 0
        while limit is None or n < limit:
            if self._thread is not None:
                scan = self.get(timeout=0.1)
                if scan is None:
                    if self._thread is None or not self._thread.is_alive():
                        if self._error is not None:
                            raise self._error
                        return
                    continue
            else:
                scan = self._read_one()
            n += 1
            yield scan

    def _read_one(self) -> Scan:
        while True:
            try:
                item = self._scans.get_nowait()
                assert isinstance(item, Scan)
                return item
            except queue.Empty:
                pass
            if self.mode == "poll":
                self.transact(sp.CMD_MEASURED, b"\x01", ack_only=True)
                deadline = clock.now() + self.reply_timeout
                while self._scans.empty() and clock.now() < deadline:
                    self._pump_guarded()
                if self._scans.empty():
                    self.counters["timeouts"] += 1
                    if not self.auto_reconnect:
                        raise SickTimeout("no B0 reply to 30 01")
                    self.reconnect()
                continue
            self._pump_guarded()
            if self._scans.empty():
                self._check_stall()

    def _pump_guarded(self) -> None:
        try:
            self._pump()
        except (OSError, serial.SerialException) as e:
            self.counters["read_errors"] += 1
            if not self.auto_reconnect:
                raise SickError(f"serial line failed: {e}") from e
            self.reconnect()


class PLS(SickLaser):
    """SICK PLS 101/201: 8E1, installation mode (``SICK_PLS``) before a baud change,
    always 180° / 0.5° / cm (361 values), about 50 m usable range."""

    variant = "pls"
    parity = serial.PARITY_EVEN
    password = sp.PASSWORD_PLS
    install_mode_for_baud = True
    default_max_range = 50.0


class LMS2xx(SickLaser):
    """SICK LMS 200/211/220/221/291: 8N1, type string via 0x3A, optional angular
    range / resolution via 0x3B (``fov_deg`` 100 or 180, ``resolution_deg`` 0.25/0.5/1)."""

    variant = "lms"
    parity = serial.PARITY_NONE
    password = sp.PASSWORD_LMS
    install_mode_for_baud = False
    default_max_range = 8.18

    def __init__(self, port: str, baudrate: int = 38400, *, fov_deg: int | None = None,
                 resolution_deg: float | None = None, **kw: Any) -> None:  # fmt: skip
        super().__init__(port, baudrate, **kw)
        self.fov_deg = fov_deg
        self.resolution_deg = resolution_deg

    def _identify(self) -> None:
        try:
            reply = self.transact(sp.CMD_TYPE, retries=1)
        except SickError:
            return
        if reply is not None:
            self.device_type = reply.data.decode("latin-1", "replace").strip()

    def _setup_variant(self) -> None:
        if self.fov_deg is None and self.resolution_deg is None:
            return
        fov = int(self.fov_deg or 180)
        res = int(round((self.resolution_deg or 0.5) * 100))
        data = bytes([fov & 0xFF, fov >> 8, res & 0xFF, res >> 8])
        reply = self.transact(sp.CMD_VARIANT, data)
        if reply is None or not reply.data or reply.data[0] != 1:
            raise SickRefused(f"variant {fov} deg / {res / 100} deg refused")

"""Pseudo-terminal pairs for device simulators.

The simulator owns the master side; a driver opens :attr:`PtyPair.port` (the slave's
``/dev/pts/N`` path) with pyserial exactly like a real serial port. The simulator keeps
its own handle on the slave open so the pair survives the driver closing and
re-opening the port, and reads the line settings the driver configured (baud rate,
parity) with ``tcgetattr`` — a pty does not enforce them, so the simulator checks them
itself and garbles the line on a mismatch, as a real UART would.
"""

from __future__ import annotations

import errno
import os
import select
import termios
import tty
from dataclasses import dataclass

_SPEEDS = {
    getattr(termios, f"B{b}"): b
    for b in (50, 75, 110, 134, 150, 200, 300, 600, 1200, 1800, 2400, 4800, 9600, 19200, 38400, 57600,
              115200, 230400, 460800, 500000, 576000, 921600, 1000000)
    if hasattr(termios, f"B{b}")
}  # fmt: skip


@dataclass(frozen=True)
class LineSettings:
    """What the host side configured on the line."""

    baudrate: int | None  #: None when the speed is not a standard constant
    parity: str  #: "N", "E" or "O"
    bytesize: int


class PtyPair:
    """An ``os.openpty()`` pair with the slave in raw mode."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self.slave)
        self._closed = False

    def host_settings(self) -> LineSettings:
        """Line settings as last set by whoever opened the slave (the driver)."""
        attrs = termios.tcgetattr(self.slave)
        cflag = attrs[2]
        speed = _SPEEDS.get(attrs[5])
        if cflag & termios.PARENB:
            parity = "O" if cflag & termios.PARODD else "E"
        else:
            parity = "N"
        size = {termios.CS5: 5, termios.CS6: 6, termios.CS7: 7, termios.CS8: 8}.get(
            cflag & termios.CSIZE, 8
        )
        return LineSettings(speed, parity, size)

    def read(self, n: int = 65536) -> bytes:
        """Non-blocking read of what the host wrote (b"" if nothing)."""
        try:
            return os.read(self.master, n)
        except BlockingIOError:
            return b""
        except OSError as e:  # EIO: no slave open (cannot happen while we hold it)
            if e.errno == errno.EIO:
                return b""
            raise

    def write(self, data: bytes) -> int:
        """Non-blocking write towards the host; returns bytes accepted."""
        if not data:
            return 0
        try:
            return os.write(self.master, data)
        except BlockingIOError:
            return 0

    def wait(self, timeout: float, want_write: bool) -> tuple[bool, bool]:
        """Wait until readable / writable (if asked) or timeout."""
        r, w, _ = select.select(
            [self.master], [self.master] if want_write else [], [], max(0.0, timeout)
        )
        return bool(r), bool(w)

    def discard_host_input(self) -> None:
        """Drop whatever is queued towards the host (a device power-cycle / vanish)."""
        try:
            termios.tcflush(self.slave, termios.TCIFLUSH)
        except termios.error:
            pass

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> PtyPair:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

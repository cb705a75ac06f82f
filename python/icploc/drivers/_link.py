"""The serial-line helpers both drivers share: closing a port quietly, and reconnecting
with an exponential back-off until a deadline."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import serial

from icploc import clock


def close_quietly(ser: Any) -> None:
    """Close a serial port (None: nothing open); a line that is already gone is not an error."""
    if ser is not None:
        try:
            ser.close()
        except (OSError, serial.SerialException):
            pass


def retry_with_backoff(
    attempt: Callable[[], None],
    *,
    close: Callable[[], None],
    failures: tuple[type[BaseException], ...],
    stop: threading.Event,
    timeout: float,
    backoff: float,
    backoff_max: float,
) -> tuple[bool, BaseException | None]:
    """Call ``close`` then ``attempt`` until ``attempt`` returns without raising one of
    ``failures``; attempts are spaced by a back-off of ``backoff`` s doubling up to
    ``backoff_max``, for at most ``timeout`` s (on :mod:`icploc.clock`) or until ``stop``
    is set. Returns ``(True, None)`` when an attempt succeeded; else ``close`` has run once
    more and it returns ``(False, the last failure)`` (None: ``stop`` was set before any
    attempt failed)."""
    deadline = clock.now() + timeout
    delay = backoff
    last: BaseException | None = None
    while not stop.is_set():
        close()
        try:
            attempt()
        except failures as e:
            last = e
        else:
            return True, None
        left = deadline - clock.now()
        if left <= 0:
            break
        stop.wait(min(delay, left))
        delay = min(delay * 2.0, backoff_max)
    close()
    return False, last

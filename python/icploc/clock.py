"""The one clock every icploc component stamps data with.

Laser scans, odometry, recordings and the simulators all use :func:`now`, which is
``time.monotonic()``: seconds, never jumps backwards, unrelated to wall-clock time.
"""

from __future__ import annotations

import time


def now() -> float:
    """Seconds on the shared monotonic clock."""
    return time.monotonic()


def sleep_until(t: float) -> None:
    """Sleep until :func:`now` reaches ``t`` (returns at once if it already has)."""
    dt = t - time.monotonic()
    if dt > 0:
        time.sleep(dt)

"""Arrival times of the bytes in a parser's buffer.

Reads return chunks; we only know when a read returned (the arrival of its last byte).
Earlier bytes of the chunk are back-dated by the line's byte time, but never before the
previous chunk's stamp, so stamps stay monotonic even when the line was faster than
its nominal rate (a pty) or the reader fell behind.
"""

from __future__ import annotations

import bisect
import math


class ByteClock:
    """Arrival time of each buffered byte, from chunk stamps (time of a chunk's last
    byte), back-dated by the byte time but never before the previous chunk's stamp."""

    def __init__(self) -> None:
        self._ends: list[int] = []
        self._stamps: list[float] = []
        self._floors: list[float] = []
        self._byte_times: list[float] = []
        self._last = -math.inf  # stamp of the latest chunk, survives consume()

    def clear(self) -> None:
        # keep self._last: stamps come from one monotonic clock, the floor stays valid
        self._ends.clear()
        self._stamps.clear()
        self._floors.clear()
        self._byte_times.clear()

    def add(self, end: int, stamp: float, byte_time: float) -> None:
        floor = self._last
        self._last = max(self._last, stamp)
        self._ends.append(end)
        self._stamps.append(stamp)
        self._floors.append(floor)
        self._byte_times.append(byte_time)

    def time_of(self, i: int) -> float:
        k = bisect.bisect_right(self._ends, i)
        if k >= len(self._ends):
            k = len(self._ends) - 1
        t = self._stamps[k] - self._byte_times[k] * (self._ends[k] - 1 - i)
        return max(t, self._floors[k]) if self._floors[k] > -math.inf else t

    def consume(self, n: int) -> None:
        ends = [e - n for e in self._ends]
        k = 0
        while k < len(ends) and ends[k] <= 0:
            k += 1
        self._ends = ends[k:]
        self._stamps = self._stamps[k:]
        self._floors = self._floors[k:]
        self._byte_times = self._byte_times[k:]

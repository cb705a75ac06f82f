"""Queue helpers shared by the drivers."""

from __future__ import annotations

import queue
from typing import Any


def put_dropping_oldest(q: queue.Queue[Any], item: object) -> int:
    """Put ``item`` without blocking; when ``q`` is full, drop the oldest entries to make
    room (a consumer that falls behind gets the latest data). Returns how many were dropped."""
    dropped = 0
    while True:
        try:
            q.put_nowait(item)
            return dropped
        except queue.Full:
            try:
                q.get_nowait()
                dropped += 1
            except queue.Empty:
                pass

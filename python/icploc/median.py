"""The median of a few numbers, as :func:`statistics.median` computes it (the middle value of
the sorted numbers, or the mean of the two middle ones), without importing :mod:`statistics`
(which pulls in fractions, decimal and random: ~10 ms of every process's start)."""

from __future__ import annotations

from collections.abc import Iterable


def median(values: Iterable[float]) -> float:
    """The median of ``values``; ``ValueError`` when there are none."""
    data = sorted(values)
    n = len(data)
    if n == 0:
        raise ValueError("median of no values")
    if n % 2 == 1:
        return data[n // 2]
    i = n // 2
    return (data[i - 1] + data[i]) / 2

"""A MapIndex of a simulated world's wall segments sampled every 5 cm, with each segment's
normal: the exact map the recovery and localizer tests localize in."""

from __future__ import annotations

import math
from collections.abc import Iterable

import numpy as np
from icploc import MapIndex


def walls_index(lines: Iterable[tuple[float, float, float, float]] | np.ndarray, spacing: float = 0.05) -> MapIndex:
    pts, nrm = [], []
    for x1, y1, x2, y2 in np.asarray(lines, dtype=float):
        length = math.hypot(x2 - x1, y2 - y1)
        n = max(int(length / spacing), 1)
        t = (np.arange(n) + 0.5) / n
        pts.append(np.column_stack([x1 + t * (x2 - x1), y1 + t * (y2 - y1)]))
        nrm.append(np.tile([-(y2 - y1) / length, (x2 - x1) / length], (n, 1)))
    return MapIndex(np.vstack(pts), np.vstack(nrm))

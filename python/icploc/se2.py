"""SE(2) helpers on (x, y, theta) tuples / arrays (numpy side; the Rust core has its own)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

Pose = tuple[float, float, float]


def wrap_angle(a: float) -> float:
    """Wrap an angle to (-pi, pi]."""
    w = math.remainder(a, 2.0 * math.pi)
    return math.pi if w == -math.pi else w


def compose(a: Sequence[float], b: Sequence[float]) -> Pose:
    """a ⊕ b: the pose b expressed in a's frame, mapped to the world."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], wrap_angle(a[2] + b[2]))


def inverse(a: Sequence[float]) -> Pose:
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-c * a[0] - s * a[1], s * a[0] - c * a[1], wrap_angle(-a[2]))


def between(a: Sequence[float], b: Sequence[float]) -> Pose:
    """The relative motion from a to b: inverse(a) ⊕ b."""
    return compose(inverse(a), b)


def interpolate(a: Sequence[float], b: Sequence[float], t: float) -> Pose:
    """Pose a fraction t of the way from a to b (linear in x, y; shortest way in theta)."""
    dth = wrap_angle(b[2] - a[2])
    return (a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), wrap_angle(a[2] + t * dth))


def transform_points(pose: Sequence[float], pts: NDArray[np.float64]) -> NDArray[np.float64]:
    """Map (N, 2) points from the frame of ``pose`` into the world."""
    c, s = math.cos(pose[2]), math.sin(pose[2])
    p = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    out = np.empty_like(p)
    out[:, 0] = pose[0] + c * p[:, 0] - s * p[:, 1]
    out[:, 1] = pose[1] + s * p[:, 0] + c * p[:, 1]
    return out

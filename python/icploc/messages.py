"""The sensor messages shared by drivers, log readers, the simulator and the localizer.

Every producer of laser data (the SICK driver, the CARMEN / rosbag / recorded-bytes
readers, the simulator) yields :class:`Scan`; every producer of odometry (the PowerBot
driver, the readers) yields :class:`Odometry`. Stamps are seconds on one clock.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "BEAM_DAZZLE",
    "BEAM_FIELD_A",
    "BEAM_FIELD_B",
    "BEAM_FIELD_C",
    "BEAM_INVALID",
    "BEAM_NO_RETURN",
    "Odometry",
    "Scan",
]

# Per-beam flag bits (Scan.flags, uint8).
BEAM_NO_RETURN = 0x01  #: no echo / max range (range is inf)
BEAM_DAZZLE = 0x02  #: sensor reports dazzling (SICK)
BEAM_FIELD_A = 0x04  #: protective/warning field bits where the device reports them
BEAM_FIELD_B = 0x08
BEAM_FIELD_C = 0x10
BEAM_INVALID = 0x20  #: any other reason the reading must not be used


@dataclass(frozen=True)
class Scan:
    """One planar laser scan in the sensor frame.

    ``angles`` are radians, counter-clockwise, 0 straight ahead. ``ranges`` are metres;
    beams without a return are ``inf`` (and carry ``BEAM_NO_RETURN`` in ``flags``).
    """

    stamp: float
    ranges: NDArray[np.float64]
    angles: NDArray[np.float64]
    flags: NDArray[np.uint8] | None = None
    seq: int = 0
    max_range: float = float("inf")
    min_range: float = 0.0
    frame: str = "laser"

    def __post_init__(self) -> None:
        r = np.asarray(self.ranges, dtype=np.float64)
        a = np.asarray(self.angles, dtype=np.float64)
        if r.ndim != 1 or a.ndim != 1 or r.shape != a.shape:
            raise ValueError(
                f"Scan: ranges and angles must be 1-D arrays of equal length, got {r.shape} and {a.shape}"
            )
        object.__setattr__(self, "ranges", r)
        object.__setattr__(self, "angles", a)
        if self.flags is not None:
            f = np.asarray(self.flags, dtype=np.uint8)
            if f.shape != r.shape:
                raise ValueError(f"Scan: flags shape {f.shape} != ranges shape {r.shape}")
            object.__setattr__(self, "flags", f)

    def __len__(self) -> int:
        return int(self.ranges.shape[0])

    def valid_mask(self, min_range: float | None = None, max_range: float | None = None) -> NDArray[np.bool_]:
        """Beams with a usable return: finite, within [min_range, max_range), no bad flags."""
        lo = self.min_range if min_range is None else min_range
        hi = self.max_range if max_range is None else max_range
        r = self.ranges
        ok = np.isfinite(r) & (r >= lo) & (r < hi) & (r > 0.0)
        if self.flags is not None:
            ok &= (self.flags & (BEAM_NO_RETURN | BEAM_DAZZLE | BEAM_INVALID)) == 0
        return ok

    def points(self, min_range: float | None = None, max_range: float | None = None) -> NDArray[np.float64]:
        """Valid beams as an (M, 2) float64 array of x, y in the sensor frame."""
        ok = self.valid_mask(min_range, max_range)
        r = self.ranges[ok]
        a = self.angles[ok]
        return np.column_stack((r * np.cos(a), r * np.sin(a)))


@dataclass(frozen=True)
class Odometry:
    """Odometry pose (x, y, theta) in metres and radians in the odometry frame."""

    stamp: float
    pose: tuple[float, float, float]
    velocity: tuple[float, float] | None = None  #: (v m/s, omega rad/s) when known
    extra: dict[str, object] = field(default_factory=dict)

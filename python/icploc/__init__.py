"""icploc: real-time, robust 2D self-localization by ICP matching of laser scans to a map."""

from __future__ import annotations

from icploc._core import (
    EmptyMapError,
    GlobalLocalizer,
    IcpConfig,
    IcpError,
    IcpResult,
    InvalidConfigError,
    InvalidInputError,
    MapIndex,
    __version__,
    icp,
    icp_batch,
    raycast,
)
from icploc.types import Odometry, Scan

__all__ = [
    "EmptyMapError",
    "GlobalLocalizer",
    "IcpConfig",
    "IcpError",
    "IcpResult",
    "InvalidConfigError",
    "InvalidInputError",
    "MapIndex",
    "Odometry",
    "Scan",
    "__version__",
    "icp",
    "icp_batch",
    "raycast",
]

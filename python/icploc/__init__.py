"""icploc: real-time, robust 2D self-localization by ICP matching of laser scans to a map."""

from __future__ import annotations

from typing import TYPE_CHECKING

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

if TYPE_CHECKING:
    from icploc.config import LocalizerConfig
    from icploc.localizer import Estimate, Localizer
    from icploc.maps import Map, MapError

# Heavier parts load on first use, so ``import icploc`` stays fast.
_LAZY = {
    "Map": ("icploc.maps", "Map"),
    "MapError": ("icploc.maps", "MapError"),
    "Localizer": ("icploc.localizer", "Localizer"),
    "Estimate": ("icploc.localizer", "Estimate"),
    "LocalizerConfig": ("icploc.config", "LocalizerConfig"),
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        module, attr = _LAZY[name]
        value = getattr(importlib.import_module(module), attr)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'icploc' has no attribute {name!r}")

__all__ = [
    "EmptyMapError",
    "Estimate",
    "Localizer",
    "LocalizerConfig",
    "Map",
    "MapError",
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

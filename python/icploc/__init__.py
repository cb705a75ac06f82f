"""icploc: real-time, robust 2D self-localization by ICP matching of laser scans to a map.

The package is built in five layers; a module imports only from its own layer or a lower
one, and the module-level imports have no circle (tests/test_layers.py holds the table,
docs/ARCHITECTURE.md describes it):

1. basics: the binding (``icploc._core``), :mod:`icploc.errors`, :mod:`icploc.se2`,
   :mod:`icploc.messages` (Scan, Odometry), :mod:`icploc.clock`, :mod:`icploc.config`, ...
2. formats and devices: :mod:`icploc.maps`, :mod:`icploc.logs`, :mod:`icploc.trajectory`,
   :mod:`icploc.drivers`, the simulated world and devices (:mod:`icploc.sim`)
3. localization: :mod:`icploc.localizer` and what it is made of (scan preparation, motion,
   fusion, calibration, recovery, relocalization, ...)
4. applications: :mod:`icploc.replay`, :mod:`icploc.live`, :mod:`icploc.demo`,
   :mod:`icploc.batch`, plotting, the simulation harness
5. CLI: :mod:`icploc.cli` and the typer sub-commands

This module re-exports the main API: the Rust core's types and functions, the sensor
messages, the error root, and (loaded on first use, so ``import icploc`` stays fast)
``Map``, ``Localizer``, ``Estimate``, ``LocalizerConfig``, ``open_log`` and the
trajectory evaluation (``Trajectory``, ``read_tum``, ``evaluate``).
"""

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
from icploc.errors import ConfigError, DeviceError, FileFormatError, IcplocError, UsageError
from icploc.status import Reason, Status

if TYPE_CHECKING:
    from icploc.config import LocalizerConfig
    from icploc.localizer import Estimate, Localizer
    from icploc.logs import open_log
    from icploc.maps import Map, MapError
    from icploc.messages import Odometry, Scan
    from icploc.trajectory import Trajectory, evaluate, read_tum

# Heavier parts load on first use, so ``import icploc`` stays fast (it imports no numpy:
# the ``icploc`` command can still choose how numpy starts, see icploc.cli.main).
_LAZY = {
    "Scan": ("icploc.messages", "Scan"),
    "Odometry": ("icploc.messages", "Odometry"),
    "Map": ("icploc.maps", "Map"),
    "MapError": ("icploc.maps", "MapError"),
    "Localizer": ("icploc.localizer", "Localizer"),
    "Estimate": ("icploc.localizer", "Estimate"),
    "LocalizerConfig": ("icploc.config", "LocalizerConfig"),
    "open_log": ("icploc.logs", "open_log"),
    "Trajectory": ("icploc.trajectory", "Trajectory"),
    "read_tum": ("icploc.trajectory", "read_tum"),
    "evaluate": ("icploc.trajectory", "evaluate"),
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
    "ConfigError",
    "DeviceError",
    "EmptyMapError",
    "Estimate",
    "FileFormatError",
    "IcplocError",
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
    "Reason",
    "Scan",
    "Status",
    "Trajectory",
    "UsageError",
    "__version__",
    "evaluate",
    "icp",
    "icp_batch",
    "open_log",
    "raycast",
    "read_tum",
]

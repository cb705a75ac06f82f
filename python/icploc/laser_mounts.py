"""Where each laser sits on the robot: :class:`LaserMount` and the ``scan.lasers`` check.

The ``scan.lasers`` list of the config (see :mod:`icploc.multilaser`, which merges the
lasers' scans) holds one mapping per laser; :func:`check_lasers` validates it with errors
naming the entry and the key, :func:`parse_mount` turns one entry into a
:class:`LaserMount`. These sit below the config (basics) so that the config models can
validate the list without importing the localization layer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from icploc.errors import ConfigError
from icploc.se2 import Pose

__all__ = ["LaserMount", "check_lasers", "parse_mount"]

_KEYS = ("name", "frame", "x", "y", "yaw", "upside_down", "time_offset", "port", "baud")


@dataclass(frozen=True)
class LaserMount:
    """One laser source (see the module docstring)."""

    name: str
    frame: str
    x: float = 0.0
    y: float = 0.0
    yaw: float = 0.0
    upside_down: bool = False
    time_offset: float = 0.0
    port: str | None = None
    baud: int | None = None

    @property
    def mounting(self) -> Pose:
        return (self.x, self.y, self.yaw)

    def to_dict(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in _KEYS}


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ConfigError(f"{where}: expected a number, got {v!r}")
    f = float(v)
    if not math.isfinite(f):
        raise ConfigError(f"{where}: must be a finite number, got {v!r}")
    return f


def parse_mount(entry: Any, i: int, where: str = "scan.lasers") -> LaserMount:
    """Entry ``i`` of the ``where`` list as a :class:`LaserMount` (ConfigError naming the
    entry and the key)."""
    w = f"{where}[{i}]"
    if isinstance(entry, LaserMount):
        entry = entry.to_dict()
    if not isinstance(entry, dict):
        raise ConfigError(
            f"{w}: expected a mapping like {{name: front_laser, x: 0.2, yaw: 0}}, got {entry!r}"
        )
    for k in entry:
        if k not in _KEYS:
            raise ConfigError(f"{w}: unknown key {k!r}; valid keys: {', '.join(_KEYS)}")
    name = entry.get("name", f"laser{i}")
    if not isinstance(name, str) or not name.strip():
        raise ConfigError(f"{w}.name: expected a non-empty name, got {name!r}")
    frame = entry.get("frame", name)
    if frame is None:
        frame = name
    if not isinstance(frame, str) or not frame.strip():
        raise ConfigError(f"{w}.frame: expected a frame name, got {frame!r}")
    ud = entry.get("upside_down", False)
    if not isinstance(ud, bool):
        raise ConfigError(f"{w}.upside_down: expected true/false, got {ud!r}")
    port = entry.get("port")
    if port is not None and (not isinstance(port, str) or not port):
        raise ConfigError(f"{w}.port: expected a serial port path, got {port!r}")
    baud = entry.get("baud")
    if baud is not None and (isinstance(baud, bool) or baud not in (9600, 19200, 38400, 500000)):
        raise ConfigError(f"{w}.baud: expected one of 9600, 19200, 38400, 500000, got {baud!r}")
    off = _number(entry.get("time_offset", 0.0), f"{w}.time_offset")
    if abs(off) > 1.0:
        raise ConfigError(f"{w}.time_offset: {off!r} s is not a scanner latency (at most 1 s)")
    return LaserMount(
        name=name,
        frame=frame,
        x=_number(entry.get("x", 0.0), f"{w}.x"),
        y=_number(entry.get("y", 0.0), f"{w}.y"),
        yaw=_number(entry.get("yaw", 0.0), f"{w}.yaw"),
        upside_down=ud,
        time_offset=off,
        port=port,
        baud=baud,
    )


def check_lasers(
    value: Any, single: Pose = (0.0, 0.0, 0.0), where: str = "scan.lasers"
) -> tuple[dict[str, Any], ...]:
    """Validate the ``scan.lasers`` list: every entry complete (defaults filled), errors
    naming the entry and the key. ``single``: ``scan.laser_x, laser_y, laser_theta``,
    which must stay 0 beside a list. Returns the entries as plain mappings (what the
    config holds and dumps)."""
    if value is None:
        return ()
    if isinstance(value, dict) or isinstance(value, str) or not isinstance(value, Iterable):
        raise ConfigError(f"{where}: expected a list of lasers, got {value!r}")
    out = [parse_mount(e, i, where) for i, e in enumerate(value)]
    if not out:
        return ()
    for name, v in zip(("laser_x", "laser_y", "laser_theta"), single, strict=True):
        if v != 0.0:
            raise ConfigError(
                f"scan.{name}: with {where} every laser gives its own mounting; leave "
                f"scan.{name} at 0 (got {v!r})"
            )
    seen: dict[str, int] = {}
    for i, m in enumerate(out):
        for what, key in (("name", m.name), ("frame", m.frame)):
            k = f"{what}:{key}"
            if k in seen:
                raise ConfigError(
                    f"{where}[{i}].{what}: {key!r} is already {where}[{seen[k]}].{what}"
                )
            seen[k] = i
        if m.port is not None:
            k = f"port:{m.port}"
            if k in seen:
                raise ConfigError(
                    f"{where}[{i}].port: {m.port!r} is already {where}[{seen[k]}].port"
                )
            seen[k] = i
    return tuple(m.to_dict() for m in out)

"""The registry of map file formats: each :class:`MapFormat` says its name, its file
suffixes, how to load one and (when it can) how to save one. :meth:`icploc.Map.load`
picks the format by suffix here; ``icploc map convert`` saves through it. The built-in
formats (ROS map_server, GeoJSON, DXF, point lists, prepared ``.npz``) register
themselves in :mod:`icploc.maps.map`; a new format is one :func:`register` call."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import MapError

if TYPE_CHECKING:
    from .map import Map

__all__ = ["FORMATS", "MapFormat", "format_for", "register"]


@dataclass(frozen=True)
class MapFormat:
    """One map file format.

    ``load(path, cache, options)`` returns a :class:`~icploc.maps.Map` (``cache``: the
    prepared-map cache setting of :meth:`Map.load`; ``options``: the caller's reader /
    line-fit options); ``save(map, path, options)`` writes one (None: read-only format)."""

    name: str
    suffixes: tuple[str, ...]
    load: Callable[[Path, bool | None, dict[str, Any]], Map]
    save: Callable[[Map, Path, dict[str, Any]], Path] | None = None
    description: str = ""


#: format name -> format, in registration order
FORMATS: dict[str, MapFormat] = {}


def register(fmt: MapFormat) -> MapFormat:
    """Add (or replace) a format; its suffixes are matched case-insensitively."""
    fmt = MapFormat(
        fmt.name, tuple(s.lower() for s in fmt.suffixes), fmt.load, fmt.save, fmt.description
    )
    for other in FORMATS.values():
        clash = set(other.suffixes) & set(fmt.suffixes)
        if other.name != fmt.name and clash:
            raise ValueError(
                f"map format {fmt.name!r}: suffix {sorted(clash)[0]!r} is {other.name!r}'s"
            )
    FORMATS[fmt.name] = fmt
    return fmt


def suffixes(*, writable: bool = False) -> list[str]:
    """Every registered suffix (only those of formats that can save: ``writable``)."""
    return sorted(s for f in FORMATS.values() if f.save or not writable for s in f.suffixes)


def format_for(path: str | Path, *, writing: bool = False) -> MapFormat:
    """The format of ``path`` by its suffix; a :class:`MapError` naming the file when no
    format (that can save, with ``writing``) has it."""
    p = Path(path)
    suffix = p.suffix.lower()
    for f in FORMATS.values():
        if suffix in f.suffixes and (f.save is not None or not writing):
            return f
    what = "writable map format" if writing else "map format"
    raise MapError(
        p,
        None,
        f"unknown {what} {p.suffix!r} (expected one of {', '.join(suffixes(writable=writing))})",
    )

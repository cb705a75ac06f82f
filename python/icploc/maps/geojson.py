"""Line-segment floor plans in GeoJSON (our documented subset; see docs/map-formats.md).

Walls are ``LineString``/``MultiLineString`` (each pair of consecutive positions is a wall)
and ``Polygon``/``MultiPolygon`` rings (every edge is a wall, rings must be closed), inside a
``FeatureCollection``, a ``Feature``, a ``GeometryCollection`` or a bare geometry.
Coordinates are planar ``[x, y]`` in the map frame (a third value is ignored), in metres
unless the top-level member ``"units"`` says ``"cm"``, ``"mm"``, ``"in"`` or ``"ft"``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import MapError

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}


#: deepest nesting of GeometryCollections read
MAX_NESTING = 32


class _Reader:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.segments: list[tuple[float, float, float, float]] = []

    def err(self, field: str, problem: str) -> MapError:
        return MapError(self.path, field, problem)

    def position(self, p: Any, field: str) -> tuple[float, float]:
        if not isinstance(p, list) or len(p) < 2:
            raise self.err(field, f"a position must be an array [x, y], got {p!r}")
        out = []
        for i, v in enumerate(p[:2]):
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise self.err(f"{field}[{i}]", f"must be a finite number, got {v!r}")
            out.append(float(v))
        return out[0], out[1]

    def chain(self, coords: Any, field: str, closed: bool) -> None:
        if not isinstance(coords, list):
            raise self.err(field, f"must be an array of positions, got {type(coords).__name__}")
        need = 4 if closed else 2
        if len(coords) < need:
            kind = "a Polygon ring" if closed else "a LineString"
            raise self.err(field, f"{kind} needs at least {need} positions, got {len(coords)}")
        pts = [self.position(p, f"{field}[{i}]") for i, p in enumerate(coords)]
        if closed and pts[0] != pts[-1]:
            raise self.err(field, "Polygon ring is not closed (first position != last)")
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            if a != b:
                self.segments.append((a[0], a[1], b[0], b[1]))

    def geometry(self, g: Any, field: str) -> None:
        if g is None:
            return
        if not isinstance(g, dict):
            raise self.err(field, f"geometry must be an object, got {type(g).__name__}")
        kind = g.get("type")
        if kind == "GeometryCollection":
            if field.count(".geometries[") >= MAX_NESTING:
                raise self.err(field, f"GeometryCollections nested more than {MAX_NESTING} deep")
            geoms = g.get("geometries")
            if not isinstance(geoms, list):
                raise self.err(f"{field}.geometries", "must be an array")
            for i, gg in enumerate(geoms):
                self.geometry(gg, f"{field}.geometries[{i}]")
            return
        if kind not in ("LineString", "MultiLineString", "Polygon", "MultiPolygon"):
            raise self.err(
                f"{field}.type",
                f"unsupported geometry type {kind!r} (use LineString, MultiLineString, Polygon, "
                "MultiPolygon or GeometryCollection)",
            )
        if "coordinates" not in g:
            raise self.err(f"{field}.coordinates", "missing")
        c = g["coordinates"]
        cf = f"{field}.coordinates"
        if kind == "LineString":
            self.chain(c, cf, closed=False)
        elif kind in ("MultiLineString", "Polygon"):
            if not isinstance(c, list):
                raise self.err(cf, "must be an array")
            for i, part in enumerate(c):
                self.chain(part, f"{cf}[{i}]", closed=kind == "Polygon")
        else:  # MultiPolygon
            if not isinstance(c, list):
                raise self.err(cf, "must be an array")
            for i, poly in enumerate(c):
                if not isinstance(poly, list):
                    raise self.err(f"{cf}[{i}]", "must be an array of rings")
                for j, ring in enumerate(poly):
                    self.chain(ring, f"{cf}[{i}][{j}]", closed=True)

    def document(self, doc: Any) -> None:
        if not isinstance(doc, dict):
            raise self.err("type", "top level must be a GeoJSON object")
        kind = doc.get("type")
        if kind == "FeatureCollection":
            feats = doc.get("features")
            if not isinstance(feats, list):
                raise self.err("features", "must be an array")
            for i, f in enumerate(feats):
                self.feature(f, f"features[{i}]")
        elif kind == "Feature":
            self.feature(doc, "feature")
        elif isinstance(kind, str):
            self.geometry(doc, "geometry")
        else:
            raise self.err("type", f"missing or invalid GeoJSON type {kind!r}")

    def feature(self, f: Any, field: str) -> None:
        if not isinstance(f, dict) or f.get("type") != "Feature":
            raise self.err(f"{field}.type", "must be a Feature object")
        if "geometry" not in f:
            raise self.err(f"{field}.geometry", "missing (use null for no geometry)")
        self.geometry(f["geometry"], f"{field}.geometry")


def load_geojson(path: str | Path) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Read wall segments (K, 4) in metres, and metadata (units, name)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except OSError as e:
        raise MapError(path, None, f"cannot read file: {e.strerror or e}") from e
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise MapError(path, None, f"not valid JSON: {e}") from e
    except RecursionError as e:
        raise MapError(path, None, "JSON nested too deeply to be a map") from e
    units = doc.get("units", "m") if isinstance(doc, dict) else "m"
    if units not in UNITS:
        raise MapError(path, "units", f"must be one of {', '.join(UNITS)}, got {units!r}")
    r = _Reader(path)
    r.document(doc)
    if not r.segments:
        raise MapError(path, "features", "no wall segments (no LineString or Polygon with length)")
    lines = np.asarray(r.segments, dtype=np.float64) * UNITS[units]
    meta: dict[str, Any] = {"units": units}
    if isinstance(doc, dict) and isinstance(doc.get("name"), str):
        meta["name"] = doc["name"]
    return lines, meta


def save_geojson(path: str | Path, lines: NDArray[np.float64], name: str | None = None) -> None:
    """Write segments as a FeatureCollection of two-point LineStrings (metres)."""
    lines = np.asarray(lines, dtype=np.float64).reshape(-1, 4)
    doc: dict[str, Any] = {"type": "FeatureCollection", "units": "m"}
    if name:
        doc["name"] = name
    doc["features"] = [
        {
            "type": "Feature",
            "properties": {"wall": i},
            "geometry": {"type": "LineString", "coordinates": [[s[0], s[1]], [s[2], s[3]]]},
        }
        for i, s in enumerate(lines.tolist())
    ]
    Path(path).write_text(json.dumps(doc, indent=1))

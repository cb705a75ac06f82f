"""CAD floor plans in DXF (via ezdxf): LINE, LWPOLYLINE and POLYLINE walls (arcs, circles,
ellipses and splines are flattened to chords), including those inside block references.

Drawing units come from the header variable ``$INSUNITS``; a unitless drawing (0) is taken
as metres unless ``units`` is given. Only x, y are used (the drawing is projected onto the
WCS xy plane).
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import MapError

#: names accepted for ``units`` and their size in metres
UNIT_NAMES = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "in": 0.0254,
    "ft": 0.3048,
    "dm": 0.1,
    "km": 1000.0,
    "yd": 0.9144,
}
WALL_TYPES = ("LINE", "LWPOLYLINE", "POLYLINE", "ARC", "CIRCLE", "ELLIPSE", "SPLINE")


def _entities(entities: Iterable[Any], depth: int = 0) -> Iterable[Any]:
    for e in entities:
        t = e.dxftype()
        if t == "INSERT" and depth < 8:
            try:
                yield from _entities(e.virtual_entities(), depth + 1)
            except Exception:  # noqa: BLE001 - non-uniform scaling etc.: skip the block
                continue
        elif t in WALL_TYPES:
            yield e


def load_dxf(
    path: str | Path,
    units: str | None = None,
    layers: Iterable[str] | None = None,
    chord: float = 0.01,
) -> tuple[NDArray[np.float64], dict[str, Any]]:
    """Read wall segments (K, 4) in metres from a DXF file's model space.

    ``units`` overrides the drawing units; ``layers`` restricts to those layer names
    (case-insensitive); ``chord`` (metres) is the maximum sagitta when flattening curves.
    """
    import ezdxf
    from ezdxf import path as ezpath
    from ezdxf import units as ezunits

    path = Path(path)
    if not path.is_file():
        raise MapError(path, None, "file not found")
    try:
        doc = ezdxf.readfile(str(path))
    except (OSError, ezdxf.DXFError, UnicodeDecodeError, ValueError) as e:
        raise MapError(path, None, f"not a readable DXF file: {e}") from e

    insunits = int(doc.header.get("$INSUNITS", 0) or 0)
    if units is not None:
        if units not in UNIT_NAMES:
            raise MapError(path, "units", f"must be one of {', '.join(UNIT_NAMES)}, got {units!r}")
        scale = UNIT_NAMES[units]
        unit_label = units
    elif insunits == 0:
        scale, unit_label = 1.0, "m (unitless drawing, assumed)"
    else:
        try:
            scale = ezunits.conversion_factor(
                ezunits.InsertUnits(insunits), ezunits.InsertUnits.Meters
            )
        except (ValueError, TypeError, KeyError) as e:
            raise MapError(path, "$INSUNITS", f"unsupported drawing unit code {insunits}") from e
        unit_label = ezunits.decode(insunits) or str(insunits)

    wanted = None if layers is None else {name.lower() for name in layers}
    segs: list[NDArray[np.float64]] = []
    counts: dict[str, int] = {}
    for ent in _entities(doc.modelspace()):
        if wanted is not None and str(ent.dxf.get("layer", "0")).lower() not in wanted:
            continue
        t = ent.dxftype()
        if t == "POLYLINE" and (ent.is_polygon_mesh or ent.is_poly_face_mesh):
            continue
        try:
            p = ezpath.make_path(ent)
        except (TypeError, ValueError):
            continue
        parts = list(p.sub_paths()) if p.has_sub_paths else [p]
        for sp in parts:
            v = np.array([(q.x, q.y) for q in sp.flattening(chord / scale)], dtype=np.float64)
            if len(v) < 2:
                continue
            s = np.column_stack([v[:-1], v[1:]])
            s = s[np.hypot(s[:, 2] - s[:, 0], s[:, 3] - s[:, 1]) > 0]
            if len(s):
                segs.append(s)
                counts[t] = counts.get(t, 0) + 1
    if not segs:
        raise MapError(
            path,
            "ENTITIES",
            "no wall entities (LINE, LWPOLYLINE, POLYLINE, ARC, ...) in model space"
            + ("" if wanted is None else f" on layers {sorted(wanted)}"),
        )
    lines = np.concatenate(segs) * scale
    if not np.isfinite(lines).all():
        raise MapError(path, "ENTITIES", "non-finite coordinates")
    return lines, {"units": unit_label, "insunits": insunits, "entities": counts}

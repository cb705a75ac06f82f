"""Maps: load the files users have (ROS map_server, GeoJSON, DXF, point lists), fit wall
lines to grids, sample them uniformly with normals, cull by visibility, save prepared maps.

The public entry point is :class:`Map` (also ``icploc.Map``).
"""

from __future__ import annotations

from .errors import MapError
from .formats import FORMATS, MapFormat, format_for, register
from .linefit import LineFit, fit_lines
from .map import Map
from .sampling import sample_lines

__all__ = [
    "FORMATS",
    "LineFit",
    "Map",
    "MapError",
    "MapFormat",
    "fit_lines",
    "format_for",
    "register",
    "sample_lines",
]

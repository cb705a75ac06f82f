"""Wall line segments from an occupancy grid (the Rust ``icploc_core::gridlines``).

Works in *cell units* with cell ``grid[iy, ix]`` centred at ``(x, y) = (ix, iy)``; the
caller (:class:`icploc.Map`) maps that to metres with the resolution and origin.

What the core does (its module documentation has the details):

* The wall *face* is where an occupied cell meets a free one: every such cell side is a
  face edge; sides towards unknown cells or the border are not faces.
* Face edges are chained, split at corners (split-and-merge on the chain's runs), and each
  piece is refitted by total least squares without its end runs (corner cells pull a fit).
* Collinear pieces with the same free side are fitted jointly across door-sized gaps
  (``max_gap``); the door stays open (each piece keeps its own extent).
* Optionally, a direction within ``snap_sigmas`` standard deviations of the map's dominant
  direction (mod 90 degrees) is snapped to it.
* **Thin walls** (one cell thick, free on both sides) keep *both faces*, one line per face,
  each with its normal towards its own free side. ``surface_offset`` (cells, 0..0.5) moves
  faces into the occupied side: 0 for maps drawn or rasterised from floor plans (the face is
  the occupied/free boundary), 0.5 for maps built from laser hits (a surface lies anywhere
  inside the cell its hits fell into, on average at the centre); then the two faces of a
  one-cell wall coincide on its centre line.
* **Thick or cluttered walls** give the face the free side sees; occupied surface cells that
  no line explains come back as points with normals facing free space, and
  ``explained_fraction`` says how many surface cells the lines explain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: cell classes handed to the core
FREE, OCCUPIED, UNKNOWN = 0, 1, 2


@dataclass
class LineFit:
    """Result of :func:`fit_lines`, in cell units (see module doc)."""

    lines: FloatArray  # (K, 4) x1, y1, x2, y2; the left normal points to free space
    rms: FloatArray  # (K,) RMS perpendicular residual of the supporting face midpoints
    support: NDArray[np.int64]  # (K,) number of supporting face edges
    sigma_angle: FloatArray  # (K,) standard deviation of each direction [rad]
    snapped: NDArray[np.bool_]  # (K,) direction snapped to the dominant one
    points: FloatArray  # (M, 2) unexplained surface points
    normals: FloatArray  # (M, 2) their unit normals, facing free space
    surface_cells: int
    explained_cells: int
    dominant_direction: float | None

    @property
    def explained_fraction(self) -> float:
        return self.explained_cells / self.surface_cells if self.surface_cells else 1.0


def classes(occupied: NDArray[np.bool_], free: NDArray[np.bool_] | None) -> NDArray[np.uint8]:
    """The uint8 class grid of the core: 0 free, 1 occupied, 2 unknown."""
    occ = np.asarray(occupied, dtype=bool)
    if free is None:
        return np.ascontiguousarray(occ, dtype=np.uint8)
    c = np.full(occ.shape, UNKNOWN, dtype=np.uint8)
    c[np.asarray(free, dtype=bool)] = FREE
    c[occ] = OCCUPIED
    return c


def defaults() -> dict[str, Any]:
    """The core's line-extraction defaults (lengths in cells)."""
    from icploc._core import grid_line_defaults

    return dict(grid_line_defaults())


def fit_lines(
    occupied: NDArray[np.bool_],
    free: NDArray[np.bool_] | None = None,
    **settings: Any,
) -> LineFit:
    """Fit wall segments to an occupancy grid (all lengths in cells).

    ``occupied``/``free`` are boolean ``grid[iy, ix]`` arrays (``free=None``: every
    non-occupied cell is free; otherwise cells that are neither are unknown). ``settings``
    override the core's defaults (see :func:`defaults`): ``min_length``, ``max_gap``,
    ``split_tolerance``, ``join_angle_deg``, ``join_offset``, ``max_rms``, ``snap``,
    ``snap_sigmas``, ``surface_offset``.
    """
    from icploc._core import extract_grid_lines

    occ = np.asarray(occupied)
    if occ.ndim != 2:
        raise ValueError(f"occupancy grid must be 2-D, got shape {occ.shape}")
    r = extract_grid_lines(classes(occ, free), **settings)
    shift = np.array([0.5, 0.5])
    lines = r.lines - np.tile(shift, 2)
    return LineFit(
        lines=lines,
        rms=r.rms,
        support=r.support,
        sigma_angle=r.sigma_angle,
        snapped=r.snapped,
        points=r.points - shift,
        normals=r.normals,
        surface_cells=int(r.surface_cells),
        explained_cells=int(r.explained_cells),
        dominant_direction=r.dominant_direction,
    )

"""``icploc map merge``: put a map patch (what the laser saw outside the map) into the map.

Both are map_server grids (YAML + image) at the same resolution, unrotated. The merged
grid covers both; a cell the map knows (free or occupied) keeps the map's value, a cell
the map does not know (unknown, or beyond its edge) takes the patch's. A patch from
``icploc replay --map-patch`` is laid out on the map's own cells; another patch is placed
on the nearest cells (the shift is reported).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import MapError

__all__ = ["MergeResult", "merge_files", "merge_grids"]


@dataclass
class MergeResult:
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float, float]
    #: cells the patch added (unknown in the map before): occupied, free
    added_occupied: int
    added_free: int
    #: how far the patch was moved onto the map's cells [m]
    shift: float


def merge_grids(
    map_occ: NDArray[np.bool_],
    map_free: NDArray[np.bool_],
    map_origin: tuple[float, float, float],
    patch_occ: NDArray[np.bool_],
    patch_free: NDArray[np.bool_],
    patch_origin: tuple[float, float, float],
    resolution: float,
) -> MergeResult:
    """Merge two grids of cell size ``resolution`` (OccupancyGrid layout, row 0 at the
    origin): the map's known cells win, the patch fills the rest."""
    res = float(resolution)
    off = (np.asarray(patch_origin[:2]) - np.asarray(map_origin[:2])) / res
    k = np.round(off).astype(np.int64)
    shift = float(np.hypot(*(off - k)) * res)
    mh, mw = map_occ.shape
    ph, pw = patch_occ.shape
    x0, y0 = min(0, int(k[0])), min(0, int(k[1]))
    x1, y1 = max(mw, int(k[0]) + pw), max(mh, int(k[1]) + ph)
    w, h = x1 - x0, y1 - y0
    if w * h > 400_000_000:
        raise MapError(None, "grid", f"the merged grid of {w} x {h} cells is too large")
    occ = np.zeros((h, w), dtype=bool)
    free = np.zeros((h, w), dtype=bool)
    px, py = int(k[0]) - x0, int(k[1]) - y0
    occ[py : py + ph, px : px + pw] = patch_occ
    free[py : py + ph, px : px + pw] = patch_free & ~patch_occ
    known_before = np.zeros((h, w), dtype=bool)
    mx, my = -x0, -y0
    mk = map_occ | map_free
    known_before[my : my + mh, mx : mx + mw] = mk
    sub_o = occ[my : my + mh, mx : mx + mw]
    sub_f = free[my : my + mh, mx : mx + mw]
    sub_o[mk] = map_occ[mk]
    sub_f[mk] = map_free[mk] & ~map_occ[mk]
    origin = (map_origin[0] + x0 * res, map_origin[1] + y0 * res, 0.0)
    return MergeResult(
        occupied=occ,
        free=free,
        resolution=res,
        origin=origin,
        added_occupied=int((occ & ~known_before).sum()),
        added_free=int((free & ~known_before).sum()),
        shift=shift,
    )


def merge_files(
    map_path: str | os.PathLike[str],
    patch_path: str | os.PathLike[str],
    out: str | os.PathLike[str],
) -> MergeResult:
    """Merge the map_server patch ``patch_path`` into the map_server map ``map_path`` and
    write the result to ``out`` (a ``.yaml``; its image beside it). No output may be one of
    the inputs (:class:`icploc.outputs.OutputClashError`), checked before anything is read."""
    from icploc.outputs import check_outputs, map_inputs

    from .ros import DEFAULT_SURFACE_OFFSET, load_ros, save_ros

    mp, pp, op = Path(map_path), Path(patch_path), Path(out)
    if op.suffix.lower() not in (".yaml", ".yml"):
        raise MapError(op, None, "the merged map is a map_server .yaml file")
    for p in (mp, pp):
        if p.suffix.lower() not in (".yaml", ".yml"):
            raise MapError(p, None, "map merge reads map_server maps (.yaml + image)")
    check_outputs(
        {"--out": op, "--out image": op.with_suffix(".pgm")},
        {"map": mp, **{f"map's {i}": q for i, q in enumerate(map_inputs(mp)[1:], 1)},
         "patch": pp, **{f"patch's {i}": q for i, q in enumerate(map_inputs(pp)[1:], 1)}},
    )  # fmt: skip
    mg = load_ros(mp)
    pg = load_ros(pp)
    for path, g in ((mp, mg), (pp, pg)):
        if abs(g.origin[2]) > 1e-9:
            raise MapError(path, "origin", f"a rotated grid (yaw {g.origin[2]}) cannot be merged")
    if not math.isclose(mg.resolution, pg.resolution, rel_tol=1e-6):
        raise MapError(
            pp,
            "resolution",
            f"{pg.resolution} m differs from the map's {mg.resolution} m; write the patch at "
            "the map's resolution",
        )
    r = merge_grids(mg.occupied, mg.free, mg.origin, pg.occupied, pg.free, pg.origin, mg.resolution)
    off = mg.meta.get("surface_offset", DEFAULT_SURFACE_OFFSET)
    save_ros(op, r.occupied, r.resolution, r.origin, free=r.free, surface_offset=float(off))
    return r

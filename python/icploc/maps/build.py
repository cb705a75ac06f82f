"""Maps built from logs: a map_server grid from a log's scans at known poses.

Every beam is a ray from the laser to its end point. Cells a ray passes through collect
*passes*, the end cell of a beam that returned collects a *hit* (beams without a return
clear space up to ``max_range``); the ray casting runs in Rust
(``icploc_core::gridcast``). A cell is **occupied** with at least ``min_hits`` hits that
are at least ``occupied_ratio`` of the rays that reached it (people walking past are
cleared by the rays through them), **free** when rays passed through it otherwise, and
**unknown** when no ray reached it.

The poses are the laser's poses in the map frame: the log's own corrected poses (CARMEN
``FLASER`` / ``ROBOTLASER1`` laser pose), or a TUM trajectory (e.g. from ``icploc replay
--out`` or a SLAM run) matched to the scans by time stamp.

A surface lies somewhere inside the cell its hits fell into, so the YAML says
``icploc_surface_offset: 0.5`` (walls on the centres of their boundary cells; see
:mod:`icploc.maps.linefit`). map_server ignores that key.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .errors import MapError

if TYPE_CHECKING:
    from icploc.logs import LogData

    from .map import Map

#: defaults of :func:`build_grid` (one source for the API and the CLI)
BUILD_DEFAULTS: dict[str, Any] = {
    "resolution": 0.05,
    "min_hits": 2,
    "occupied_ratio": 0.25,
    "max_range": 30.0,
    "margin": 1.0,
    "stamp_tolerance": 0.1,
}


@dataclass
class BuiltGrid:
    """The result of :func:`build_grid`: OccupancyGrid layout (row 0 at the origin)."""

    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float, float]
    scans_used: int
    hits: NDArray[np.uint32]
    passes: NDArray[np.uint32]

    def save(self, yaml_path: str | os.PathLike[str]) -> Path:
        """Write the grid as a trinary map_server map (YAML + PGM); returns the YAML path."""
        from .ros import save_ros

        p = Path(yaml_path)
        save_ros(
            p, self.occupied, self.resolution, self.origin, free=self.free, surface_offset=0.5
        )
        return p

    def to_map(self, **fit: Any) -> Map:
        """The grid as a :class:`icploc.Map` (lines fitted, surface offset 0.5)."""
        from .map import Map

        fit.setdefault("surface_offset", 0.5)
        return Map.from_grid(self.occupied, self.resolution, self.origin, free=self.free, **fit)


def _poses_from_tum(path: Path, stamps: NDArray[np.float64], tol: float) -> NDArray[np.float64]:
    """TUM poses matched to scan stamps (nearest stamp within ``tol``; NaN rows unmatched).
    Logs without usable stamps (all equal) match by order when the counts agree."""
    from icploc.trajectory import read_tum

    traj = read_tum(path).sorted()
    poses = np.asarray(traj.poses, dtype=np.float64)
    t = np.asarray(traj.stamps, dtype=np.float64)
    out = np.full((len(stamps), 3), np.nan)
    if len(t) == 0:
        raise MapError(path, None, "no poses in the TUM file")
    if len(stamps) and np.ptp(stamps) == 0:
        if len(t) != len(stamps):
            raise MapError(
                path,
                None,
                f"the log has no usable time stamps and the TUM file has {len(t)} poses "
                f"for {len(stamps)} scans: cannot match them",
            )
        return poses
    k = np.clip(np.searchsorted(t, stamps), 1, max(1, len(t) - 1))
    k0 = np.clip(k - 1, 0, len(t) - 1)
    k1 = np.clip(k, 0, len(t) - 1)
    pick = np.where(np.abs(t[k0] - stamps) <= np.abs(t[k1] - stamps), k0, k1)
    ok = np.abs(t[pick] - stamps) <= tol
    out[ok] = poses[pick[ok]]
    return out


def build_grid(
    log: str | os.PathLike[str] | LogData,
    *,
    poses: str | os.PathLike[str] | NDArray[np.float64] | None = None,
    resolution: float = BUILD_DEFAULTS["resolution"],
    min_hits: int = BUILD_DEFAULTS["min_hits"],
    occupied_ratio: float = BUILD_DEFAULTS["occupied_ratio"],
    max_range: float = BUILD_DEFAULTS["max_range"],
    margin: float = BUILD_DEFAULTS["margin"],
    scans: slice | NDArray[np.int64] | None = None,
) -> BuiltGrid:
    """Build an occupancy grid from a log's scans at given laser poses.

    ``log``: a log path (any format :func:`icploc.logs.open_log` reads) or a loaded
    :class:`~icploc.logs.LogData`. ``poses``: None (the log's own corrected poses), a TUM
    file, or an (N, 3) array aligned with the scans. ``scans`` selects scans (e.g. every
    other one, to hold the rest out for evaluation).
    """

    src = None
    if isinstance(log, str | os.PathLike):
        from icploc.logs import open_log

        src = Path(log)
        data = open_log(src)
    else:
        data = log
    res = float(resolution)
    if not (math.isfinite(res) and res > 0):
        raise MapError(src, "resolution", f"must be a positive finite number, got {resolution!r}")
    if isinstance(min_hits, bool) or int(min_hits) != min_hits or min_hits < 1:
        raise MapError(src, "min_hits", f"must be an integer >= 1, got {min_hits!r}")
    if not (math.isfinite(max_range) and max_range > 0):
        raise MapError(src, "max_range", f"must be a positive finite number, got {max_range!r}")
    all_scans = list(data.scans)
    if poses is None:
        p = np.asarray(data.truth_poses, dtype=np.float64).reshape(-1, 3)
        if len(p) != len(all_scans) or len(p) == 0:
            raise MapError(
                src,
                "poses",
                f"the log has {len(p)} corrected poses for {len(all_scans)} scans; "
                "give the poses as a TUM file (--poses)",
            )
    elif isinstance(poses, str | os.PathLike):
        stamps = np.array([s.stamp for s in all_scans], dtype=np.float64)
        p = _poses_from_tum(Path(poses), stamps, BUILD_DEFAULTS["stamp_tolerance"])
    else:
        p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
        if len(p) != len(all_scans):
            raise MapError(src, "poses", f"{len(p)} poses for {len(all_scans)} scans")
    idx = np.arange(len(all_scans))[scans] if scans is not None else np.arange(len(all_scans))
    origins, ends, hit = [], [], []
    used = 0
    for i in idx.tolist():
        pose = p[i]
        if not np.isfinite(pose).all():
            continue
        s = all_scans[i]
        r = np.asarray(s.ranges, dtype=np.float64)
        a = np.asarray(s.angles, dtype=np.float64)
        lim = min(float(s.max_range), max_range)
        ok = s.valid_mask(max_range=lim)
        # beams without a return (at or beyond the range limit) clear space up to it
        miss = np.isfinite(r) & (r >= lim) & ~ok
        rr = np.where(ok, r, lim)
        sel = ok | miss
        if not sel.any():
            continue
        c, sn = math.cos(pose[2]), math.sin(pose[2])
        lx, ly = rr[sel] * np.cos(a[sel]), rr[sel] * np.sin(a[sel])
        ends.append(np.column_stack([pose[0] + c * lx - sn * ly, pose[1] + sn * lx + c * ly]))
        origins.append(np.broadcast_to(pose[:2], (int(sel.sum()), 2)))
        hit.append(ok[sel])
        used += 1
    if used == 0:
        raise MapError(src, "scans", "no scan with a pose and a valid beam to build a map from")
    e = np.ascontiguousarray(np.concatenate(ends))
    o = np.ascontiguousarray(np.concatenate(origins))
    h = np.ascontiguousarray(np.concatenate(hit))
    pts = np.concatenate([e[h], o[:1]]) if h.any() else o
    lo = np.minimum(pts.min(axis=0), o.min(axis=0)) - margin
    hi = np.maximum(pts.max(axis=0), o.max(axis=0)) + margin
    try:
        return grid_from_rays(
            o, e, h, lo, hi, res, min_hits=min_hits, occupied_ratio=occupied_ratio, scans_used=used
        )
    except ValueError as exc:
        raise MapError(src, "resolution", str(exc)) from None


def grid_from_rays(
    origins: NDArray[np.float64],
    ends: NDArray[np.float64],
    hit: NDArray[np.bool_],
    lo: NDArray[np.float64],
    hi: NDArray[np.float64],
    resolution: float,
    *,
    align: tuple[float, float] = (0.0, 0.0),
    min_hits: int = BUILD_DEFAULTS["min_hits"],
    occupied_ratio: float = BUILD_DEFAULTS["occupied_ratio"],
    scans_used: int = 0,
) -> BuiltGrid:
    """The occupancy rules, in one place (:func:`build_grid`, :mod:`icploc.mappatch`): beams
    from ``origins`` to ``ends`` (``hit``: the beam ended on something) ray-cast into a grid
    covering ``lo``..``hi`` whose cell corners lie on ``align`` + multiples of
    ``resolution``. A cell is occupied with at least ``min_hits`` hits that are at least
    ``occupied_ratio`` of the beams that reached it, free when a beam passed it otherwise.
    ValueError when the grid would exceed 400M cells."""
    from icploc._core import cast_rays

    res = float(resolution)
    a = np.asarray(align, dtype=np.float64)
    origin_xy = a + np.floor((lo - a) / res) * res
    w = int(math.ceil((hi[0] - origin_xy[0]) / res))
    hgt = int(math.ceil((hi[1] - origin_xy[1]) / res))
    if w * hgt > 400_000_000:
        raise ValueError(f"a {w} x {hgt} grid at {res} m is too large (limit 400M cells)")
    o = np.ascontiguousarray(origins, dtype=np.float64)
    e = np.ascontiguousarray(ends, dtype=np.float64)
    h = np.ascontiguousarray(hit, dtype=bool)
    hits, passes = cast_rays(o, e, h, (float(origin_xy[0]), float(origin_xy[1])), res, w, hgt)
    total = hits.astype(np.float64) + passes
    occupied = (hits >= min_hits) & (hits >= occupied_ratio * total)
    free = (passes > 0) & ~occupied
    return BuiltGrid(
        occupied=occupied,
        free=free,
        resolution=res,
        origin=(float(origin_xy[0]), float(origin_xy[1]), 0.0),
        scans_used=scans_used,
        hits=hits,
        passes=passes,
    )


def build_map(
    log: str | os.PathLike[str] | LogData,
    out: str | os.PathLike[str] | None = None,
    **options: Any,
) -> Map:
    """:func:`build_grid`, written as a map_server map to ``out`` (a ``.yaml``) when given,
    returned as a :class:`icploc.Map`."""
    g = build_grid(log, **options)
    if out is not None:
        outp = Path(out)
        if outp.suffix.lower() not in (".yaml", ".yml"):
            raise MapError(outp, None, "the output of a built map is a .yaml file")
        g.save(outp)
        from .map import Map

        return Map.load(outp, cache=False)
    return g.to_map()

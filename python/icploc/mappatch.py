"""Where the map is missing: a map_server grid of what the laser saw outside the map.

:class:`icploc.outside.OutsideMonitor` (with ``record=True``) keeps, for every stretch
outside the map, the scans' points and the poses they were coasted at, up to the scan
that locked again. Dead reckoning drifts; the lock says by how much at the stretch's end.
:func:`corrected_poses` spreads that correction along the stretch: the heading error in
proportion to the motion of each step (re-integrating the odometry steps), then the
remaining position error in proportion to the motion done so far — exact at the exit (a
verified pose) and at the lock. :func:`patch_grid` ray-casts the scans at those poses
(free space along each beam, hits at its end; :func:`icploc.maps.build.build_grid`'s rules)
into a grid aligned with the map's cells, :func:`write_patch` writes it as YAML + PGM.
``icploc map merge`` (:mod:`icploc.maps.merge`) puts it into the map.

Before the correction the coasted chain is tightened by matching each scan against the
stretch's own previous scans (:func:`refined_poses`; never against the map, whose walls
are not there): the odometry steps become scan-matched steps where the walls allow.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from icploc.se2 import Pose, between, compose, wrap_angle

if TYPE_CHECKING:
    from icploc.maps.build import BuiltGrid
    from icploc.outside import Stretch

__all__ = [
    "PATCH_RESOLUTION",
    "corrected_poses",
    "grid_from_scans",
    "patch_grid",
    "refined_poses",
    "write_patch",
]

#: cell size of a patch for a map without a grid [m] (a grid map's own resolution otherwise)
PATCH_RESOLUTION = 0.05


def corrected_poses(
    start: Pose,
    coasted: Sequence[Pose],
    dead_reckoned_end: Pose,
    lock: Pose,
    trust: Sequence[float] | None = None,
) -> NDArray[np.float64]:
    """The coasted poses of a stretch corrected so its last pose is ``lock``.

    ``start`` is the verified pose before the stretch, ``coasted`` the stretch's poses
    (the last may already be the lock: ``dead_reckoned_end`` is what dead reckoning said
    there). Each odometry step gets a share of the heading error (its length plus a tenth
    of its turn, over the stretch's), the position error left then is spread by the motion
    done so far. ``trust`` (per step, 0..1; default 0): a step's share is scaled by
    ``1 - 0.9 trust`` (a scan-matched step drifts far less than an odometry one).
    Returns (N, 3)."""
    pts = [tuple(map(float, p)) for p in coasted]
    if not pts:
        return np.zeros((0, 3))
    pts[-1] = tuple(map(float, dead_reckoned_end))
    steps = [between(a, b) for a, b in zip([start, *pts[:-1]], pts, strict=True)]
    w = np.array([math.hypot(u[0], u[1]) + 0.1 * abs(u[2]) for u in steps]) + 1e-9
    if trust is not None:
        w *= 1.0 - 0.9 * np.clip(np.asarray(trust, dtype=np.float64), 0.0, 1.0)
    w /= w.sum()
    e_th = wrap_angle(lock[2] - pts[-1][2])
    out = np.zeros((len(pts), 3))
    p: Pose = (float(start[0]), float(start[1]), float(start[2]))
    for i, u in enumerate(steps):
        p = compose(p, (u[0], u[1], u[2] + e_th * float(w[i])))
        out[i] = p
    r = np.array([lock[0] - out[-1, 0], lock[1] - out[-1, 1]])
    out[:, :2] += np.cumsum(w)[:, None] * r
    out[:, 2] = np.angle(np.exp(1j * out[:, 2]))
    return out


def refined_poses(
    start: Pose,
    scans: Sequence[NDArray[np.float64]],
    coasted: Sequence[Pose],
    *,
    keep: int = 5,
    min_inliers: float = 0.6,
    gate: float = 16.0,
) -> tuple[list[Pose], list[float]]:
    """The coasted poses re-chained by matching each scan against the stretch's own
    previous ``keep`` scans (never the map). Each odometry step (its noise growing with
    its length) is fused with the scan match (its covariance from the fit: a corridor
    says nothing along itself) when the match converged, explains ``min_inliers`` of the
    scan and agrees with the odometry within the chi-square ``gate``; otherwise the
    odometry step stands. The drift left is small where walls constrain the scans; the
    lock's correction then spreads it. Returns the poses and per step how much the scan
    match tightened it (0: odometry alone .. 1)."""
    from icploc._core import IcpConfig, IcpError, MapIndex, icp
    from icploc.fusion import fuse, mahalanobis2, scan_covariance

    cfg = IcpConfig(
        window_search=False,
        max_correspondence_distance=0.5,
        min_correspondence_distance=0.1,
    )
    out: list[Pose] = []
    trust: list[float] = []
    prev: Pose = (float(start[0]), float(start[1]), float(start[2]))
    prev_c: Pose = prev
    world: list[NDArray[np.float64]] = []
    normals: list[NDArray[np.float64]] = []
    for pts, c in zip(scans, coasted, strict=True):
        c = (float(c[0]), float(c[1]), float(c[2]))
        u = between(prev_c, c)
        guess = compose(prev, u)
        pose, t = guess, 0.0
        if world and pts.shape[0] >= 20:
            try:
                res = icp(
                    pts, MapIndex(np.concatenate(world), np.concatenate(normals), None), guess, cfg
                )
            except IcpError:
                res = None
            if res is not None and res.converged and res.inlier_ratio >= min_inliers:
                z = (float(res.pose[0]), float(res.pose[1]), float(res.pose[2]))
                step = math.hypot(u[0], u[1]) + 0.3 * abs(u[2])
                sxy, sth = 0.01 + 0.02 * step, 0.003 + 0.03 * step
                P = np.diag([sxy * sxy, sxy * sxy, sth * sth])
                R = scan_covariance(res.information, int(res.inliers), float(res.mse), 0.02, 5.0)
                if mahalanobis2(guess, P, z, R) <= gate:
                    pose, P2 = fuse(guess, P, z, R)
                    t = float(np.clip(1.0 - math.sqrt(np.trace(P2) / np.trace(P)), 0.0, 1.0))
        out.append(pose)
        trust.append(t)
        if pts.shape[0] >= 3:
            co, si = math.cos(pose[2]), math.sin(pose[2])
            w = np.column_stack(
                [
                    pose[0] + co * pts[:, 0] - si * pts[:, 1],
                    pose[1] + si * pts[:, 0] + co * pts[:, 1],
                ]
            )
            n, ok = _scan_normals(w)
            world.append(w[ok])
            normals.append(n[ok])
            del world[:-keep], normals[:-keep]
        prev, prev_c = pose, c
    return out, trust


def _scan_normals(w: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Unit normals of a scan's points (beam order) from their neighbours, and which points
    have a usable one (neighbours close and on a line through the point)."""
    d = w[2:] - w[:-2]
    ln = np.hypot(d[:, 0], d[:, 1])
    n = np.zeros_like(w)
    ok = np.zeros(len(w), dtype=bool)
    good = (ln > 1e-6) & (ln < 0.5)
    n[1:-1][good] = np.column_stack([-d[good, 1], d[good, 0]]) / ln[good, None]
    ok[1:-1] = good
    return n, ok


def _stretch_poses(st: Stretch, refine: bool = True) -> NDArray[np.float64]:
    coasted: list[Pose] = [p for _, _, p in st.scans]
    if not coasted:
        return np.zeros((0, 3))
    closed = st.lock_pose is not None and st.correction is not None
    if closed and st.lock_pose is not None and st.correction is not None:
        c, lock = st.correction, st.lock_pose
        # what dead reckoning said at the lock
        coasted[-1] = (lock[0] - c[0], lock[1] - c[1], wrap_angle(lock[2] - c[2]))
    trust: list[float] | None = None
    if refine:
        coasted, trust = refined_poses(st.exit_pose, [pts for _, pts, _ in st.scans], coasted)
    if not closed or st.lock_pose is None:
        return np.asarray(coasted, dtype=np.float64).reshape(-1, 3)
    return corrected_poses(st.exit_pose, coasted, coasted[-1], st.lock_pose, trust)


def grid_from_scans(
    scans: Sequence[NDArray[np.float64]],
    poses: NDArray[np.float64] | Sequence[Any],
    *,
    resolution: float = PATCH_RESOLUTION,
    align: tuple[float, float] = (0.0, 0.0),
    mounting: Pose = (0.0, 0.0, 0.0),
    margin: float = 0.5,
) -> BuiltGrid | None:
    """Ray-cast robot-frame scan points (each an (N, 2) array of beam ends) at robot
    ``poses`` into one grid whose cell corners lie on ``align`` + multiples of
    ``resolution``; the beams start at ``mounting``. The occupancy rules are
    :func:`icploc.maps.build.build_grid`'s. None without a point."""
    from icploc._core import cast_rays
    from icploc.maps.build import BUILD_DEFAULTS, BuiltGrid

    res = float(resolution)
    if not (math.isfinite(res) and res > 0):
        raise ValueError(f"map patch: resolution must be a positive number, got {resolution!r}")
    origins: list[NDArray[np.float64]] = []
    ends: list[NDArray[np.float64]] = []
    used = 0
    for pts, pose in zip(scans, poses, strict=True):
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0 or not np.isfinite(np.asarray(pose, dtype=np.float64)).all():
            continue
        p = (float(pose[0]), float(pose[1]), float(pose[2]))
        c, s = math.cos(p[2]), math.sin(p[2])
        ends.append(
            np.column_stack(
                [p[0] + c * pts[:, 0] - s * pts[:, 1], p[1] + s * pts[:, 0] + c * pts[:, 1]]
            )
        )
        origins.append(np.broadcast_to(np.array(compose(p, mounting)[:2]), pts.shape))
        used += 1
    if not used:
        return None
    e = np.ascontiguousarray(np.concatenate(ends))
    o = np.ascontiguousarray(np.concatenate(origins))
    lo = np.minimum(e.min(axis=0), o.min(axis=0)) - margin
    hi = np.maximum(e.max(axis=0), o.max(axis=0)) + margin
    a = np.asarray(align, dtype=np.float64)
    origin = a + np.floor((lo - a) / res) * res
    w = int(math.ceil((hi[0] - origin[0]) / res))
    h = int(math.ceil((hi[1] - origin[1]) / res))
    if w * h > 400_000_000:
        raise ValueError(f"map patch: a {w} x {h} grid at {res} m is too large")
    hit = np.ones(len(e), dtype=bool)
    hits, passes = cast_rays(o, e, hit, (float(origin[0]), float(origin[1])), res, w, h)
    total = hits.astype(np.float64) + passes
    occupied = (hits >= BUILD_DEFAULTS["min_hits"]) & (
        hits >= BUILD_DEFAULTS["occupied_ratio"] * total
    )
    free = (passes > 0) & ~occupied
    return BuiltGrid(
        occupied=occupied,
        free=free,
        resolution=res,
        origin=(float(origin[0]), float(origin[1]), 0.0),
        scans_used=used,
        hits=hits,
        passes=passes,
    )


def patch_grid(
    stretches: Sequence[Stretch],
    *,
    resolution: float = PATCH_RESOLUTION,
    align: tuple[float, float] = (0.0, 0.0),
    mounting: Pose = (0.0, 0.0, 0.0),
    refine: bool = True,
) -> BuiltGrid | None:
    """The recorded scans of ``stretches`` ray-cast at their corrected poses
    (:func:`grid_from_scans`; ``refine``: re-chained by :func:`refined_poses` first).
    None when no stretch recorded a scan."""
    scans: list[NDArray[np.float64]] = []
    poses: list[NDArray[np.float64]] = []
    for st in stretches:
        scans.extend(pts for _, pts, _ in st.scans)
        poses.extend(_stretch_poses(st, refine))
    return grid_from_scans(scans, poses, resolution=resolution, align=align, mounting=mounting)


def patch_layout(map_: Any) -> tuple[float, tuple[float, float]]:
    """(resolution, cell alignment) of a patch for ``map_``: a grid map's own, else
    :data:`PATCH_RESOLUTION` on multiples of it."""
    res = getattr(map_, "resolution", None)
    origin = getattr(map_, "origin", None)
    if getattr(map_, "grid", None) is not None and res and origin is not None:
        return float(res), (float(origin[0]), float(origin[1]))
    return PATCH_RESOLUTION, (0.0, 0.0)


def patch_outputs(path: str | os.PathLike[str]) -> dict[str, Path]:
    """The files ``--map-patch PATH`` writes (for the output checks made before a run);
    :class:`icploc.outputs.OutputError` unless PATH is a ``.yaml``."""
    from icploc.outputs import OutputError

    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise OutputError(f"--map-patch {p}: a map patch is a map_server .yaml file")
    return {"--map-patch": p, "--map-patch image": p.with_suffix(".pgm")}


def write_patch(
    path: str | os.PathLike[str],
    stretches: Sequence[Stretch],
    map_: Any = None,
    *,
    mounting: Pose = (0.0, 0.0, 0.0),
) -> BuiltGrid | None:
    """Write the patch of ``stretches`` as a map_server YAML + PGM at ``path`` (a ``.yaml``)
    in ``map_``'s cell layout; returns the grid (None and nothing written without a
    recorded scan outside the map)."""
    p = Path(path)
    if p.suffix.lower() not in (".yaml", ".yml"):
        raise ValueError(f"--map-patch {p}: a map patch is a map_server .yaml file")
    res, align = patch_layout(map_)
    g = patch_grid(stretches, resolution=res, align=align, mounting=mounting)
    if g is None:
        return None
    g.save(p)
    return g

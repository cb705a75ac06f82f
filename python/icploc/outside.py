"""Outside the map: recognise it from the scan, coast on odometry, come back in.

Maps are rarely complete. When most of a scan's beams end in space the map knows nothing
about (unknown cells of a map_server grid, or beyond the map's bounds; for a map of lines
or points: far from every wall) while the localizer still believes its pose, the robot has
left the mapped area. Matching there would pull the pose onto whatever walls happen to be
near, so :class:`OutsideMonitor` takes over the scan instead:

* **when**: only once the localizer has been ``tracking`` since the monitor was attached
  (a pose verified on the map left it; a wrong initial pose whose scan lands off the map
  is lost and searched for, as without the monitor).
* **outside**: no scan matching and no global search; the pose is the odometry
  prediction (calibrated by :mod:`icploc.calibration`, its covariance grown by the motion
  model each scan). Status ``degraded`` (``lost`` once the covariance is wider than
  ``localizer.lost_sigma_xy``), reason ``outside_map``, ``Estimate.mapped`` False. The
  localizer's own status stays ``degraded`` (``lost``, its prediction would grow by
  ``localizer.lost_noise_gain``: the dead reckoning is unchecked here, not contradicted).
* **re-entry**: once the scan lands mostly on mapped space again (``exit_share``, for
  ``confirm_scans`` scans in a row) the localizer is declared lost *at the dead-reckoned
  pose with its covariance*, and :class:`ReentryRecovery` searches around it over that
  whole uncertainty and verifies; after a few scans the localizer's own recovery
  (:mod:`icploc.recovery`, :mod:`icploc.relocalize`: global) runs beside it. The scans from re-entry to the lock are counted per stretch; they report
  the dead-reckoned pose as ``degraded``, reason ``reentering`` (``lost`` once the
  covariance is wider than ``localizer.lost_sigma_xy``) while the localizer's own status
  is ``lost`` (that runs the search).
* **leaving**: a scan matched as usual before a stretch begins that is ``tracking`` but
  mostly off the map at the pose found is ``degraded``, reason ``leaving_map``, in the
  estimate and in the localizer's own status.
* **where the map is missing**: every stretch (first outside scan .. the re-entry lock)
  is kept in :attr:`OutsideMonitor.stretches`; with ``record=True`` also the scans' points
  and their poses by odometry alone from the exit (the last ``tracking`` pose), and the
  scans just after the lock, for :mod:`icploc.mappatch`.

A localizer gets a monitor with :func:`attach`; the :class:`~icploc.localizer.Localizer`
calls :meth:`OutsideMonitor.before` ahead of its own matching and
:meth:`OutsideMonitor.after` on every estimate (its ``outside`` hook).
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from icploc.se2 import Pose
from icploc.status import Reason

if TYPE_CHECKING:
    from collections.abc import Callable

    from icploc.localizer import Estimate, Localizer
    from icploc.messages import Scan

    #: :attr:`OutsideMonitor.observer`: (monitor, localizer, estimate, scan points)
    Observer = Callable[["OutsideMonitor", Localizer, Estimate, NDArray[np.float64]], None]

__all__ = [
    "MappedArea",
    "OutsideConfig",
    "OutsideMonitor",
    "Stretch",
    "attach",
    "attach_default",
    "knows_unknown",
    "stretch_lines",
]

#: the Estimate reason of a scan outside the map
REASON = Reason.OUTSIDE_MAP
#: ... and of a scan back on the map, dead-reckoned while the re-entry search runs
REENTERING = Reason.REENTERING
#: ... and of a scan matched inside the map but mostly off it at the pose found (the
#: scans before a stretch begins): degraded, never ``tracking``
LEAVING = Reason.LEAVING_MAP


def _map_default(key: str) -> int:
    """A default of the typed config's ``map`` section (their one source)."""
    from icploc.config import MapSection

    return int(getattr(MapSection(), key))


@dataclass(frozen=True)
class OutsideConfig:
    """Settings of the outside-the-map state (one source of their defaults)."""

    #: share of a scan's beams on unmapped space (at the predicted pose) that means outside
    enter_share: float = 0.5
    #: ... after a scan with at least this share (a streak that begins from a scan nearly
    #: all on the map is a pose gone wrong at once, not the map's edge: a kidnapped robot.
    #: At a streak's start, measured: benches/global_bench.py's kidnaps 0.00-0.08; the real
    #: partial maps' exits, benches/eval_partial.py, 0.17 and up)
    rise_share: float = 0.12
    #: ... unless the jump stays: after this many scans in a row at ``enter_share`` or more
    #: since the jump, the localizer's pose all along within ``sudden_drift`` of the
    #: odometry from the pose before it and no recovery lock, the streak begins (a sharp
    #: map edge, a fast robot through a doorway into an unmapped hall: the scan jumps off
    #: the map and stays there; a kidnapped robot's localizer relocalizes elsewhere, 19
    #: of benches/global_bench.py's 20 lab kidnaps within 20 scans). 0: never
    sudden_scans: int = 20
    sudden_drift: float = 1.0
    #: a stretch the sudden rule began whose re-entry lock lies farther than
    #: ``jump_sigmas`` times its widest coasted position sigma (and at least ``jump_min``
    #: metres) from its dead reckoning was no drive off the map: the scan jumped off it
    #: because the robot was carried elsewhere (a kidnap its localizer did not relocalize
    #: within ``sudden_scans``). Said so in the summary (:attr:`Stretch.jumped`) and left
    #: out of a map patch (its poses are the dead reckoning of a place the robot was not).
    #: Real dead reckoning errs far beyond its sigma (benches/eval_partial.py's 33 gradual
    #: stretches: up to 19 sigma, intel's 1.5 m at 0.08 m), so the floor: of those 33 and
    #: the simulated sudden exit (tests/partial_world.py: 1.65 m at sigma 0.81) none would
    #: count as a kidnap, whose correction is the metres the robot was carried. The floor
    #: also grows by ``jump_per_m`` per metre coasted (review: a long coast off a sharp map
    #: edge errs more than 2 m and would be taken for a kidnap and left out of the patch;
    #: the real-data bases' dead reckoning errs up to 3 % in scale and 1 deg/m in heading)
    jump_sigmas: float = 3.0
    jump_min: float = 2.0
    jump_per_m: float = 0.1
    #: ... for this many scans in a row (the scans before the last are localized as
    #: usual): a map made from another pass has gaps a scan wide. On the real-data
    #: benchmark's full maps (benches/eval_real.py, 60 folds of the tuned set) 1 began a
    #: stretch of 2-3 scans on 9 folds (p95 up to +1.8 cm, a max +30 cm after the re-entry
    #: search), 2 on 4 (all freiburg-101's third fold, a place only it saw), 3 on 3
    enter_scans: int = 2
    #: a scan between ``exit_share`` and ``enter_share`` (along the map's edge: neither
    #: mostly off the map nor back on it) neither counts towards nor breaks a streak that
    #: has begun (aces' partial map, benches/eval_partial.py: the robot skirted the edge
    #: for 11 scans at 0.35-0.58, never 0.5 twice in a row, and the localizer was lost
    #: there for 24 scans, searching the whole map, on scans the map explains nowhere, not
    #: even at their reference poses; with the hold the stretch begins: lost 13 -> 5 %),
    #: for at most this many such scans in a row (review: a long run along the edge would
    #: otherwise begin a stretch from the dead reckoning of its first scan, discarding the
    #: matched poses in between); 0: no hold
    enter_hold: int = 20
    #: a lost localizer's dead-reckoned pose still counts (outside the map may begin lost:
    #: the scan half unmapped contradicts the pose) while its sigma is at most this [m]
    lost_sigma: float = 1.0
    #: share at or below which the scan explains the map again (re-entry)
    exit_share: float = 0.35
    #: scans in a row below ``exit_share`` before re-entry starts
    confirm_scans: int = 2
    #: a beam ending farther than this from every mapped cell/point is unmapped [m] (maps
    #: without free space: lines, points)
    reach: float = 1.0
    #: mapped cells of a grid are grown by this much before the test [m] (pose error, a
    #: wall seen from the other side)
    margin: float = 0.2
    #: cell size of the mapped-area mask of a map without a grid [m] (coarser when the
    #: mask would have more than ``max_mask_cells`` cells: a map kilometres wide)
    resolution: float = 0.1
    max_mask_cells: int = 16_000_000
    #: the re-entry watch also tries poses within this many sigmas of the dead-reckoned
    #: one (at most ``probe_radius`` metres): a drifted pose must not hide the map
    probe_sigmas: float = 3.0
    probe_radius: float = 5.0
    #: ... and at least this far [m] (long dead reckoning drifts more than its covariance
    #: says: real odometry errors are systematic)
    probe_min_radius: float = 1.0
    #: a stretch's exit anchor is the last ``tracking`` pose when the odometry from it to
    #: the first scan outside is at most this long [m] (else the last believed pose)
    exit_odometry: float = 3.0
    #: with ``record``: scans recorded after a stretch's lock (:attr:`Stretch.lead_out`);
    #: its default and YAML key: ``map.patch_lead_out_scans``
    lead_out_scans: int = field(default_factory=lambda: _map_default("patch_lead_out_scans"))
    #: with ``record``: at most this many scans between a stretch's exit anchor (the last
    #: ``tracking`` pose) and its first outside scan kept for the patch's pose graph
    #: (:attr:`Stretch.lead_in`: scan-matched steps instead of the odometry alone over
    #: the exit gap); its default and YAML key: ``map.patch_lead_in_scans``
    lead_in_scans: int = field(default_factory=lambda: _map_default("patch_lead_in_scans"))
    #: scans a re-entry candidate must stay put (by odometry) before it locks
    reentry_confirm: int = 2
    #: scans of the local re-entry search alone; after them the localizer's own recovery
    #: (global) runs beside it on every scan (the local search goes on: a scan may land
    #: on known space a while before it explains the walls there)
    reentry_local_scans: int = 10
    #: the local search's probe grid: positions this far apart [m] over the whole
    #: uncertainty (a disc of the watch's radius) ...
    reentry_step: float = 0.4
    #: ... times headings this far apart [rad] within ``probe_sigmas`` sigma
    reentry_heading_step: float = math.radians(4.0)
    #: at most about this many probe poses per scan (the position step grows beyond it;
    #: the default grid at its widest, 5 m and +-45 deg, is about 11,300: a slower
    #: machine may trade the search's reach for time here: 3,000 made belgioioso's lock
    #: 2 scans later and its patch 10 points worse)
    reentry_max_probes: int = 12000
    #: probe poses (by beams on walls) refined by ICP, and of those verified
    reentry_starts: int = 12
    reentry_verify: int = 3

    def validate(self) -> OutsideConfig:
        if not (0.0 < self.exit_share < self.enter_share <= 1.0):
            raise ValueError(
                "outside: need 0 < exit_share < enter_share <= 1, got "
                f"exit_share={self.exit_share}, enter_share={self.enter_share}"
            )
        if not 0.0 <= self.rise_share <= self.enter_share:
            raise ValueError(
                f"outside: need 0 <= rise_share <= enter_share, got {self.rise_share}"
            )
        if self.sudden_scans < 0 or not (math.isfinite(self.sudden_drift) and self.sudden_drift > 0):
            raise ValueError(
                "outside: need sudden_scans >= 0 and sudden_drift > 0, got "
                f"{self.sudden_scans}, {self.sudden_drift}"
            )
        if self.enter_scans < 1:
            raise ValueError(f"outside: enter_scans must be >= 1, got {self.enter_scans}")
        if (
            isinstance(self.enter_hold, bool)
            or not isinstance(self.enter_hold, int)
            or self.enter_hold < 0
        ):
            raise ValueError(
                f"outside: enter_hold must be an integer >= 0 (scans), got {self.enter_hold!r}"
            )
        if self.confirm_scans < 1:
            raise ValueError(f"outside: confirm_scans must be >= 1, got {self.confirm_scans}")
        if self.reentry_confirm < 1 or self.reentry_local_scans < 0:
            raise ValueError("outside: reentry_confirm must be >= 1, reentry_local_scans >= 0")
        if self.lead_out_scans < 0 or self.lead_in_scans < 0:
            raise ValueError(
                "outside: lead_out_scans and lead_in_scans must be >= 0, got "
                f"{self.lead_out_scans}, {self.lead_in_scans}"
            )
        if self.max_mask_cells < 1:
            raise ValueError(f"outside: max_mask_cells must be >= 1, got {self.max_mask_cells}")
        if self.reentry_starts < 1 or self.reentry_verify < 1 or self.reentry_max_probes < 1:
            raise ValueError(
                "outside: reentry_starts, reentry_verify and reentry_max_probes must be >= 1"
            )
        for k in ("reach", "margin", "resolution", "probe_sigmas", "probe_radius",
                  "probe_min_radius", "reentry_step", "reentry_heading_step",
                  "exit_odometry", "jump_sigmas", "jump_min", "jump_per_m"):  # fmt: skip
            v = getattr(self, k)
            positive = k in ("resolution", "reentry_step", "reentry_heading_step")
            if not (math.isfinite(v) and v >= 0.0) or (positive and v <= 0.0):
                raise ValueError(f"outside: {k} must be a finite number >= 0, got {v!r}")
        return self


def _dilate(mask: NDArray[np.bool_], r: int) -> NDArray[np.bool_]:
    """``mask`` grown by a (2r+1)-square (a cell is set when any cell within r of it in x
    and in y is; nothing beyond the edges). On the rows packed 8 cells a byte: 2r shifted
    ORs along the rows (bits moved across bytes), then 2r along the columns, each from the
    unshifted array (a shift past an edge drops what it moves out, the edge's zero
    padding). A map_server grid of 26 M cells (freiburg-campus, 5 cm) in ~20 ms; the
    earlier doubling ORs of whole bool arrays took ~50-80 ms (and 0.2 s and more on a
    loaded machine) of every process that attaches the monitor."""
    m = np.asarray(mask, dtype=bool)
    if r <= 0:
        return np.array(m, dtype=bool)
    if m.ndim != 2:
        raise ValueError(f"outside: the mask must be 2-D, got shape {m.shape}")
    w = m.shape[1]
    return _unpack(_grow_packed(np.packbits(m, axis=1, bitorder="little"), r), w)


def _unpack(p: NDArray[np.uint8], w: int) -> NDArray[np.bool_]:
    return np.unpackbits(p, axis=1, count=w, bitorder="little").view(bool)


def _grow_packed(x: NDArray[np.uint8], r: int) -> NDArray[np.uint8]:
    """:func:`_dilate` on rows packed little-endian (cell j: bit j % 8 of byte j // 8; the
    bits past the last cell zero)."""
    h = np.empty_like(x)
    for a in range(0, x.shape[0], 256):  # row blocks: each block's shifts stay in cache
        h[a : a + 256] = _grow_rows(x[a : a + 256], r)
    out = h.copy()
    n = h.shape[0]
    for k in range(1, min(r, n - 1) + 1):
        out[k:] |= h[:-k]
        out[:-k] |= h[k:]
    return out


def _grow_rows(x: NDArray[np.uint8], r: int) -> NDArray[np.uint8]:
    """The packed rows ``x`` each grown by r cells both ways."""
    nb = x.shape[1]
    h = x.copy()
    for k in range(1, r + 1):
        q, b = divmod(k, 8)
        if q >= nb:
            break
        # toward higher cells: cell j gets cell j - k
        y = np.zeros_like(x)
        y[:, q:] = x[:, : nb - q]
        if b:
            z = y << np.uint8(b)
            z[:, 1:] |= y[:, :-1] >> np.uint8(8 - b)
            y = z
        h |= y
        # toward lower cells: cell j gets cell j + k
        y = np.zeros_like(x)
        y[:, : nb - q] = x[:, q:]
        if b:
            z = y >> np.uint8(b)
            z[:, :-1] |= y[:, 1:] << np.uint8(8 - b)
            y = z
        h |= y
    return h


@dataclass
class MappedArea:
    """Where the map knows anything: a boolean mask ``known[iy, ix]`` of cells
    ``resolution`` wide from ``origin`` (axis-aligned); everything beyond it is unmapped."""

    known: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float]
    yaw: float = 0.0

    @classmethod
    def of(cls, map_: Any, index: Any, config: OutsideConfig | None = None) -> MappedArea:
        """The mapped area of a localizer's map: a grid's observed (free or occupied) cells
        grown by ``margin``; otherwise cells within ``reach`` of a map point."""
        cfg = config or OutsideConfig()
        grid = getattr(map_, "grid", None)
        free = getattr(map_, "free", None)
        res = getattr(map_, "resolution", None)
        if grid is not None and free is not None and res:
            g, f = np.asarray(grid, dtype=bool), np.asarray(free, dtype=bool)
            if g.shape != f.shape or g.ndim != 2:
                raise ValueError(f"outside: grid {g.shape} and free {f.shape} differ")
            r = int(math.ceil(cfg.margin / float(res) - 1e-9))
            # packed first: the OR of two packed grids is an eighth of the work
            p = np.packbits(g, axis=1, bitorder="little")
            p |= np.packbits(f, axis=1, bitorder="little")
            known = _unpack(_grow_packed(p, r) if r > 0 else p, g.shape[1])
            o = map_.origin
            return cls(known, float(res), (float(o[0]), float(o[1])), float(o[2]))
        pts = np.asarray(index.points, dtype=np.float64).reshape(-1, 2)
        if pts.shape[0] == 0:
            raise ValueError("outside: the map holds no points")
        span = pts.max(axis=0) - pts.min(axis=0) + 2.0 * cfg.reach
        res = max(cfg.resolution, math.sqrt(float(span[0] * span[1]) / cfg.max_mask_cells))
        lo = np.floor((pts.min(axis=0) - cfg.reach) / res) * res - res
        hi = pts.max(axis=0) + cfg.reach + res
        w, h = (int(math.ceil(v)) + 1 for v in (hi - lo) / res)
        known = np.zeros((h, w), dtype=bool)
        c = np.floor((pts - lo) / res).astype(np.int64)
        known[c[:, 1], c[:, 0]] = True
        return cls(
            _dilate(known, int(math.ceil(cfg.reach / res))), res, (float(lo[0]), float(lo[1]))
        )

    def unmapped(self, xy: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Per map-frame point: beyond the mask or in an unknown cell."""
        q = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.asarray(self.origin)
        if self.yaw:
            c, s = math.cos(self.yaw), math.sin(self.yaw)
            q = np.column_stack([c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]])
        cell = np.floor(q / self.resolution).astype(np.int64)
        h, w = self.known.shape
        inside = (cell[:, 0] >= 0) & (cell[:, 0] < w) & (cell[:, 1] >= 0) & (cell[:, 1] < h)
        out = np.ones(len(q), dtype=bool)
        ci = cell[inside]
        out[inside] = ~self.known[ci[:, 1], ci[:, 0]]
        return out

    def best_share(self, points: NDArray[np.float64], poses: NDArray[np.float64]) -> float:
        """The lowest unmapped share of ``points`` over ``poses`` (K, 3) (nan without
        points); every fourth point is used."""
        p = points[::4] if points.shape[0] >= 40 else points
        if p.shape[0] == 0:
            return float("nan")
        c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
        x = poses[:, 0:1] + c * p[:, 0] - s * p[:, 1]
        y = poses[:, 1:2] + s * p[:, 0] + c * p[:, 1]
        un = self.unmapped(np.column_stack([x.ravel(), y.ravel()])).reshape(len(poses), -1)
        return float(un.mean(axis=1).min())

    def unmapped_share(self, points: NDArray[np.float64], pose: Pose) -> float:
        """Share of robot-frame ``points`` that end on unmapped space seen from ``pose``
        (nan without points)."""
        if points.shape[0] == 0:
            return float("nan")
        c, s = math.cos(pose[2]), math.sin(pose[2])
        xy = np.column_stack(
            [
                pose[0] + c * points[:, 0] - s * points[:, 1],
                pose[1] + s * points[:, 0] + c * points[:, 1],
            ]
        )
        return float(self.unmapped(xy).mean())


def _probe_poses(pose: Pose, cov: NDArray[np.float64], cfg: OutsideConfig) -> NDArray[np.float64]:
    """Poses within ``probe_sigmas`` of ``pose`` (at most ``probe_radius``): a 9 x 9 grid
    of positions times three headings; (K, 3) with ``pose`` first."""
    sxy = math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0))
    sth = math.sqrt(max(float(cov[2, 2]), 0.0))
    r = min(max(cfg.probe_sigmas * sxy, cfg.probe_min_radius), cfg.probe_radius)
    dth = min(cfg.probe_sigmas * sth, math.pi)
    g = np.linspace(-r, r, 9) if r > 0.05 else np.zeros(1)
    h = np.array([0.0, -dth, dth]) if dth > 0.01 else np.zeros(1)
    dx, dy, dt = np.meshgrid(g, g, h, indexing="ij")
    out = np.column_stack([pose[0] + dx.ravel(), pose[1] + dy.ravel(), pose[2] + dt.ravel()])
    return np.vstack([np.asarray(pose, dtype=np.float64)[None, :], out])


def _search_poses(pose: Pose, cov: NDArray[np.float64], cfg: OutsideConfig) -> NDArray[np.float64]:
    """The re-entry search's probe poses: positions ``reentry_step`` apart on the disc of
    :func:`_probe_poses`'s radius (farther apart when more than about
    ``reentry_max_probes`` poses would be probed), times headings ``reentry_heading_step``
    apart within ``probe_sigmas`` sigma (at most 45 deg); (K, 3) with ``pose`` first."""
    sxy = math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0))
    sth = math.sqrt(max(float(cov[2, 2]), 0.0))
    r = min(max(cfg.probe_sigmas * sxy, cfg.probe_min_radius), cfg.probe_radius)
    dth = min(cfg.probe_sigmas * sth, math.radians(45.0))
    m = int(math.floor(dth / cfg.reentry_heading_step))
    h = np.arange(-m, m + 1) * cfg.reentry_heading_step
    # the position step grows when the disc times the headings would exceed the budget
    step = max(cfg.reentry_step, math.sqrt(math.pi * r * r * len(h) / cfg.reentry_max_probes))
    n = int(math.floor(r / step))
    g = np.arange(-n, n + 1) * step
    gx, gy = np.meshgrid(g, g, indexing="ij")
    disc = gx * gx + gy * gy <= r * r + 1e-9
    dx = np.repeat(gx[disc], len(h))
    dy = np.repeat(gy[disc], len(h))
    dt = np.tile(h, int(disc.sum()))
    out = np.column_stack([pose[0] + dx, pose[1] + dy, pose[2] + dt])
    return np.vstack([np.asarray(pose, dtype=np.float64)[None, :], out])


class ReentryRecovery:
    """The recovery (:class:`icploc.recovery.Recovery`) a localizer uses while it comes
    back into the map: a verified local search around the dead-reckoned pose over its
    whole uncertainty (:func:`_search_poses`: the probe poses ranked by the share of beams
    that end on map walls, the best ``reentry_starts`` distinct ones refined by ICP, the
    best ``reentry_verify`` fits verified by the localizer; a pose that stays put by
    odometry for ``reentry_confirm`` scans locks). After ``reentry_local_scans`` scans the
    localizer's own recovery (global) runs beside it on every scan, and whichever locks
    first wins: a scan may land on known space well before it explains the walls there
    (a corridor the map saw from its far end), and the dead reckoning still says where
    to look."""

    def __init__(
        self,
        fallback: Any,
        index: Any,
        hit_distance: float,
        config: OutsideConfig,
    ) -> None:
        self.fallback = fallback
        self.index = index
        self.hit_distance = hit_distance
        self.config = config
        self.confirm = config.reentry_confirm
        self.local_scans = config.reentry_local_scans
        self._leader: Pose | None = None
        self._streak = 0
        self.scans = 0

    def reset(self) -> None:
        self._leader, self._streak, self.scans = None, 0, 0
        self.fallback.reset()

    def __getattr__(self, name: str) -> Any:  # check_pose and the like: the fallback's
        if name == "fallback":
            raise AttributeError(name)
        return getattr(self.fallback, name)

    def _ranked(self, view: Any, points: NDArray[np.float64]) -> list[Pose]:
        """The dead-reckoned pose and the best distinct probe poses by beams on walls."""
        cfg = self.config
        poses = _search_poses(view.pose, view.covariance, cfg)
        p = points[:: max(1, points.shape[0] // 30)]
        hit = np.zeros(len(poses))
        for a in range(0, len(poses), 4096):  # bounded memory
            q = poses[a : a + 4096]
            c, s = np.cos(q[:, 2])[:, None], np.sin(q[:, 2])[:, None]
            x = q[:, 0:1] + c * p[:, 0] - s * p[:, 1]
            y = q[:, 1:2] + s * p[:, 0] + c * p[:, 1]
            d, _ = self.index.nearest(np.ascontiguousarray(np.column_stack([x.ravel(), y.ravel()])))
            hit[a : a + 4096] = (np.asarray(d).reshape(len(q), -1) < self.hit_distance).mean(axis=1)
        order = np.argsort(-hit, kind="stable")
        out: list[Pose] = [(float(poses[0, 0]), float(poses[0, 1]), float(poses[0, 2]))]
        sep = max(2.0 * cfg.reentry_step, 0.5)
        for i in order:
            cand = (float(poses[i, 0]), float(poses[i, 1]), float(poses[i, 2]))
            if all(
                math.hypot(cand[0] - o[0], cand[1] - o[1]) > sep
                or abs(math.remainder(cand[2] - o[2], 2 * math.pi)) > math.radians(10.0)
                for o in out
            ):
                out.append(cand)
            if len(out) >= cfg.reentry_starts:
                break
        return out

    def _local(self, view: Any, points: NDArray[np.float64]) -> tuple[Pose, Any] | None:
        """The best verified fit from the local search's starts (None: none verified)."""
        from icploc._core import IcpError, icp_batch

        starts = self._ranked(view, points)
        try:
            results = icp_batch(
                [points], view.index, np.asarray(starts, dtype=np.float64), view.icp_config
            )
        except IcpError:
            return None
        fits = sorted(
            (r for r in results if r.converged and all(math.isfinite(v) for v in r.pose)),
            key=lambda r: (r.inlier_ratio, -r.mse),
            reverse=True,
        )
        tried: list[Pose] = []
        for r in fits:
            z = (float(r.pose[0]), float(r.pose[1]), float(r.pose[2]))
            if any(math.hypot(z[0] - t[0], z[1] - t[1]) <= 0.15 for t in tried):
                continue
            tried.append(z)
            ok, res, pose = view.verify(points, z)
            if ok and res is not None:
                return pose, res
            if len(tried) >= self.config.reentry_verify:
                break
        return None

    def recover(self, view: Any, points: NDArray[np.float64]) -> Any:
        from icploc.recovery import Candidate, RecoveryStep
        from icploc.se2 import compose, wrap_angle

        self.scans += 1
        if self._leader is not None and view.motion is not None:
            self._leader = compose(self._leader, view.motion)
        fallback = None
        if self.scans > self.local_scans:
            # the global recovery beside the local search (every scan: it follows the
            # odometry between its calls)
            fallback = self.fallback.recover(view, points)
            if fallback.state == "locked":
                self._leader, self._streak = None, 0
                return fallback
        best = self._local(view, points)
        if best is None:
            self._leader, self._streak = None, 0
            return fallback if fallback is not None else RecoveryStep("searching")
        pose, res = best
        lead = self._leader
        if (
            lead is not None
            and math.hypot(pose[0] - lead[0], pose[1] - lead[1]) <= 0.15
            and abs(wrap_angle(pose[2] - lead[2])) <= math.radians(5.0)
        ):
            self._streak += 1
        else:
            self._streak = 1
        self._leader = pose
        hyp = (Candidate(pose, float(res.inlier_ratio), float(res.inlier_ratio), True),)
        if self._streak >= self.confirm:
            self._leader, self._streak = None, 0
            return RecoveryStep("locked", hyp, lock=pose, result=res)
        return RecoveryStep("confirming", hyp)


@dataclass
class Stretch:
    """One stretch outside the map: from its first outside scan to the re-entry lock."""

    start: int  #: index (scans processed by the localizer) of the first outside scan
    start_stamp: float
    exit_pose: Pose  #: the last pose before leaving (the coasting's origin)
    #: the localizer's odometry motion model at the exit (:class:`icploc.motion.MotionModel`,
    #: its learned noise gain): the noise of the odometry from the exit to the first
    #: outside scan (:func:`icploc.mappatch.graph_solution`); None: the configured defaults
    exit_motion: Any = field(default=None, repr=False)
    end: int | None = None  #: index of the scan that locked again (None: not back yet)
    end_stamp: float | None = None
    #: scans from the start of re-entry (the scan explains the map again) to the lock
    reentry_scans: int | None = None
    outside_scans: int = 0  #: scans coasted outside the map
    distance: float = 0.0  #: metres coasted (odometry)
    max_sigma_xy: float = 0.0  #: the widest coasted position sigma
    #: the re-lock's correction of the dead-reckoned pose (dx, dy, dtheta; map frame)
    correction: Pose | None = None
    #: begun by the sudden rule (``OutsideConfig.sudden_scans``: the scan jumped off the
    #: map in one scan and stayed there): a sharp map edge, or a kidnapped robot
    sudden: bool = False
    #: a sudden stretch whose lock lies beyond its dead reckoning's uncertainty
    #: (``OutsideConfig.jump_sigmas``, ``jump_min``): the robot was carried elsewhere, not
    #: driven off the map; not in a map patch
    jumped: bool = False
    lock_pose: Pose | None = None
    #: the localizer was reset (:meth:`~icploc.localizer.Localizer.reset`, or declared
    #: lost) before this scan while the stretch was open: it ended there, not back in the
    #: map by a lock (None: not reset)
    reset_at: int | None = None
    #: with ``record``: per scan (index, points in the robot frame, coasted pose), from the
    #: first of the ``enter_scans`` scans that began the stretch (those before
    #: :attr:`start` were localized as usual; here their poses by odometry from the exit)
    scans: list[tuple[int, NDArray[np.float64], Pose]] = field(default_factory=list, repr=False)
    #: with ``record``: the scans after the lock (inside the map: not in the patch), their
    #: poses by odometry from the lock (they tie the lock to the mapped walls for the
    #: patch's pose graph)
    lead_out: list[tuple[int, NDArray[np.float64], Pose]] = field(
        default_factory=list, repr=False
    )
    #: with ``record``: the scans between the exit anchor (the last ``tracking`` pose) and
    #: the first outside scan (inside the map: not in the patch), their poses by odometry
    #: from the exit (they chain the exit to the stretch by scan matches for the patch's
    #: pose graph, and tie it to the mapped walls); empty when the exit is the last scan
    #: before the stretch
    lead_in: list[tuple[int, NDArray[np.float64], Pose]] = field(
        default_factory=list, repr=False
    )
    #: set by the map patch (:func:`icploc.mappatch.patch_solution`): how its poses were
    #: placed (``placement``: ``"submap"``, the stretch's own scans matched to each other,
    #: or ``"graph"``, the pose graph's, where the submap matches did not verify) and the
    #: figures that chose it (:meth:`icploc.mappatch.SubmapRefinement.record`); None: not
    #: drawn, or not refined
    patch_placement: dict[str, Any] | None = field(default=None, repr=False)

    @property
    def closed(self) -> bool:
        return self.end is not None


class OutsideMonitor:
    """The outside-the-map state of one localizer (see the module docstring)."""

    def __init__(
        self,
        area: MappedArea,
        config: OutsideConfig | None = None,
        *,
        record: bool = False,
        mounting: Pose = (0.0, 0.0, 0.0),
        observer: Observer | None = None,
    ) -> None:
        self.area = area
        #: called first in :meth:`after` with (monitor, localizer, estimate, scan points),
        #: the monitor's state still the scan's own; it must not change the localizer or
        #: the monitor (benches/eval_partial.py: is a re-entering scan explained at its
        #: reference pose?). None: nothing
        self.observer = observer
        #: the map's walls and mapped area for the patch (:class:`icploc.mappatch.MappedWalls`;
        #: set by :func:`attach`)
        self.walls: Any = None
        self.config = (config or OutsideConfig()).validate()
        self.record = record
        self.mounting = mounting
        #: "inside", "outside" (coasting) or "reentering" (lost at the dead-reckoned pose,
        #: the recovery searching)
        self.state = "inside"
        self.stretches: list[Stretch] = []
        #: a scan has been ``tracking`` since the monitor was attached: only a pose that
        #: was verified on the map can leave it (a wrong initial pose whose scan lands off
        #: the map is lost, and the localizer's recovery searches, as without the monitor)
        self._verified = False
        #: scans in a row that would begin a stretch (``enter_scans``), the last believed
        #: pose before the first of them, and the dead reckoning from it
        self._entering = 0
        #: scans in a row along the map's edge that held the streak (``enter_hold``)
        self._held = 0
        self._streak_exit: Pose | None = None
        self._streak_dr: Pose = (0.0, 0.0, 0.0)
        #: with ``record``: the streak's scans before its last (localized as usual), their
        #: points and poses by odometry from the streak's exit and from the last
        #: ``tracking`` pose (None: more than ``exit_odometry`` since it)
        self._streak_rec: list[tuple[int, NDArray[np.float64], Pose, Pose | None]] = []
        #: the streak began by the sudden rule (its stretch: :attr:`Stretch.sudden`)
        self._streak_sudden = False
        self.last_share = float("nan")
        #: the share of the scan before (``rise_share``), and whether the share jumped
        #: there from a scan on the map (no stretch begins until it falls again)
        self._prev_share = float("nan")
        self._sudden = False
        #: since the jump: scans at ``enter_share`` or more (-1: the localizer's pose left
        #: the odometry from before the jump, or a recovery locked: no exit) and the
        #: odometry from the pose before it
        self._sudden_n = 0
        self._sudden_dr: Pose = (0.0, 0.0, 0.0)
        self._below = 0
        self._above = 0
        self._fallback: Any = None  #: the localizer's own recovery while re-entering
        self._reentry_start: int | None = None
        self._last_pose: Pose | None = None
        self._last_odom: Pose | None = None
        #: the stretch's own dead reckoning (the calibrated odometry from the exit): while
        #: re-entering, the localizer's lost coasting may pull its pose onto the map scan
        #: by scan; the patch and the lock's correction need the odometry alone
        self._dr: Pose | None = None
        #: inside the map: the last ``tracking`` pose and the odometry since it (the exit
        #: anchor of a stretch: the degraded scans just before leaving are often the
        #: worst, half their beams already off the map)
        self._tracked: Pose | None = None
        self._since: Pose | None = None
        self._since_m = 0.0
        #: with ``record``, inside the map: the scans since the last ``tracking`` one, their
        #: poses by odometry from it (a stretch's lead-in)
        self._gap: list[tuple[int, NDArray[np.float64], Pose]] | None = []
        #: after a lock: scans still to record into the stretch's lead-out, their odometry
        self._lead_left = 0
        self._lead_dr: Pose | None = None
        #: the localizer's scan index of the last :meth:`before` (a reset while that scan
        #: is processed is the localizer's own, see :meth:`on_reset`)
        self._k_in: int | None = None

    # -- the localizer's hook --------------------------------------------------------------
    def before(
        self,
        loc: Localizer,
        scan: Scan,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64],
        odom: Pose | None,
        t0: float,
    ) -> Estimate | None:
        """Called before the localizer matches ``scan``: an Estimate when the scan is
        outside the map (coasted), None to let the localizer go on."""
        from icploc.localizer import Status
        from icploc.se2 import between, compose

        self._k_in = loc.scans_processed
        share = self.area.unmapped_share(pts, pred)
        self._prev_share = self.last_share
        self.last_share = share
        cfg = self.config
        k = loc.scans_processed
        known = share == share and pts.shape[0] >= loc.config.scan.min_points
        # the odometry step the localizer predicts with, from its last pose
        step = between(loc.pose, pred)
        if self.state != "inside" and self._dr is not None:
            self._dr = compose(self._dr, step)
        elif self.state == "inside" and self._since is not None:
            self._since = compose(self._since, step)
            self._since_m += math.hypot(step[0], step[1])
        if self.state == "inside" and self._lead_dr is not None:
            self._lead_dr = compose(self._lead_dr, step)
        if self.state == "inside":
            if (
                self._held < cfg.enter_hold
                and self._entering > 0
                and known
                and self._verified
                and cfg.exit_share < share < cfg.enter_share
                and (loc.status is not Status.LOST or _believed(pred_cov, cfg.lost_sigma))
            ):
                # along the map's edge (the scan neither mostly off the map nor back on it):
                # the streak holds, its dead reckoning runs on
                self._held += 1
                self._streak_dr = compose(self._streak_dr, step)
                if self.record:
                    self._streak_rec.append((k, np.array(pts), self._streak_dr, self._since))
                return None
            self._held = 0
            if not known or share < cfg.enter_share or not self._verified:
                self._entering = 0
                self._sudden = False
                return None
            if loc.status is Status.LOST and not _believed(pred_cov, cfg.lost_sigma):
                self._entering = 0
                return None
            sudden_start = False
            if self._entering == 0 and (self._sudden or not self._prev_share >= cfg.rise_share):
                # from a scan nearly all on the map to one mostly off it in one step: not
                # the edge of the map, which a robot drives towards, but a pose that went
                # wrong at once (a robot carried elsewhere); the localizer's own checks and
                # recovery deal with it, until the scan is back on the map; unless it stays
                # off the map while the localizer, lost or not, stays on the odometry
                # (``sudden_scans``): a sharp edge of the map, a fast robot
                if not self._sudden:
                    self._sudden, self._sudden_n, self._sudden_dr = True, 0, pred
                elif self._sudden_n >= 0:
                    self._sudden_dr = compose(self._sudden_dr, step)
                    d = math.hypot(pred[0] - self._sudden_dr[0], pred[1] - self._sudden_dr[1])
                    if d > cfg.sudden_drift:
                        self._sudden_n = -1  # relocalized elsewhere: a kidnap, not an exit
                if self._sudden_n >= 0:
                    self._sudden_n += 1
                if cfg.sudden_scans == 0 or self._sudden_n < cfg.sudden_scans:
                    return None
                self._sudden = False  # the jump stayed: the map's edge; the streak begins
                sudden_start = True
            # the stretch begins at the streak's first scan: its later ones coast from the
            # dead reckoning since (the scans before the last were matched as usual, maybe
            # against the wrong walls; with enter_scans 1 this is the prediction itself)
            if self._entering == 0:
                self._streak_exit, self._streak_dr = self._last_pose, pred
                self._streak_rec = []
                self._streak_sudden = sudden_start
            else:
                self._streak_dr = compose(self._streak_dr, step)
            self._entering += 1
            if self._entering < cfg.enter_scans:
                if self.record:
                    self._streak_rec.append((k, np.array(pts), self._streak_dr, self._since))
                return None
            self._entering = 0
            pred = self._streak_dr
            self._lead_left, self._lead_dr = 0, None
            exit_pose = self._streak_exit if self._streak_exit else pred
            self._dr = pred
            if (
                self._tracked is not None
                and self._since is not None
                and self._since_m <= cfg.exit_odometry
            ):
                # from the last tracking pose by odometry (not the degraded poses since)
                exit_pose, self._dr = self._tracked, self._since
                lead_in = self._gap or []
                tracked = True
            else:
                lead_in, tracked = [], False
            # the streak's earlier scans belong to the stretch's record (localized as
            # usual, but mostly off the map all the same: with enter_scans 1 they were
            # coasted and drawn; left out, the patch's chain crossed the exit without
            # them: belgioioso's walls within 10 cm 54 -> 41 %), their poses by the
            # odometry the stretch's own dead reckoning takes
            streak = {i for i, _, _, _ in self._streak_rec}
            lead_in = [g for g in lead_in if g[0] not in streak]
            head = [
                (i, q, since if tracked and since is not None else dr)
                for i, q, dr, since in self._streak_rec
            ]
            self._streak_rec = []
            self._gap = []
            self._last_odom = None  # the stretch's metres from its first scan on
            self.stretches.append(
                Stretch(k, float(scan.stamp), exit_pose, exit_motion=loc.motion_model,
                        lead_in=lead_in, scans=head, sudden=self._streak_sudden)
            )  # fmt: skip
            self.state = "outside"
            self._below = 0
            return self._coast(loc, scan, pts, pred, pred_cov, odom, t0, share)
        # outside or re-entering: is there a pose within the dead reckoning's uncertainty
        # where the scan lands on the map?
        best = share
        if known and share > cfg.exit_share:
            best = min(share, self.area.best_share(pts, _probe_poses(pred, pred_cov, cfg)))
        if self.state == "reentering":
            # the recovery searches on until no pose near the dead reckoning lands on the map
            self._above = self._above + 1 if known and best >= cfg.enter_share else 0
            if self._above < cfg.confirm_scans:
                return None
            self.state = "outside"  # out again before the lock: coast on
            self._below = 0
            self._reentry_start = None
            self._restore(loc)
            loc.reset(pred, pred_cov, Status.DEGRADED)
            return self._coast(loc, scan, pts, pred, pred_cov, odom, t0, share)
        self._below = self._below + 1 if known and best <= cfg.exit_share else 0
        if self._below >= cfg.confirm_scans:
            # the scan explains the map again: lost at the dead-reckoned pose, so the
            # recovery searches around it first (then globally)
            self.state = "reentering"
            self._above = 0
            self._reentry_start = k
            loc.pose, loc.covariance = pred, pred_cov
            self._fallback = loc.recovery
            loc.recovery = ReentryRecovery(
                self._fallback, loc.index, loc.quality.hit_distance(), cfg
            )
            loc.declare_lost()
            return None
        return self._coast(loc, scan, pts, pred, pred_cov, odom, t0, share)

    def after(self, loc: Localizer, est: Estimate, pts: NDArray[np.float64]) -> Estimate:
        """Called on every estimate: marks it, closes a stretch at the re-entry lock."""
        if self.observer is not None:
            self.observer(self, loc, est, pts)
        from icploc.localizer import Status
        from icploc.status import LOCK_REASONS

        mapped = self.state != "outside"
        if self.state == "reentering" and est.reason in LOCK_REASONS:
            st = self.stretches[-1]
            k = loc.scans_processed
            st.end, st.end_stamp = k, float(est.stamp)
            st.reentry_scans = k - (self._reentry_start or k) + 1
            st.lock_pose = est.pose
            pred = self._dr if self._dr is not None else est.prediction
            st.correction = (
                est.pose[0] - pred[0],
                est.pose[1] - pred[1],
                math.remainder(est.pose[2] - pred[2], 2 * math.pi),
            )
            cfg = self.config
            off = math.hypot(st.correction[0], st.correction[1])
            st.jumped = st.sudden and off > max(
                cfg.jump_min, cfg.jump_sigmas * st.max_sigma_xy, cfg.jump_per_m * st.distance
            )
            if self.record:
                st.scans.append((k, np.array(pts), est.pose))
            self.state = "inside"
            self._reentry_start = None
            self._restore(loc)
            if self.record and self.config.lead_out_scans > 0:
                self._lead_left, self._lead_dr = self.config.lead_out_scans, est.pose
        elif self.state == "inside" and self._lead_left > 0 and self._lead_dr is not None:
            self.stretches[-1].lead_out.append((loc.scans_processed, np.array(pts), self._lead_dr))
            self._lead_left -= 1
            if self._lead_left == 0:
                self._lead_dr = None
        elif self.state == "reentering" and self.record and self.stretches:
            dr = self._dr if self._dr is not None else est.pose
            self.stretches[-1].scans.append((loc.scans_processed, np.array(pts), dr))
        if self._sudden and self._sudden_n >= 0 and est.reason in LOCK_REASONS:
            self._sudden_n = -1  # a recovery locked after the jump: a kidnap, not an exit
        if (
            self.state == "inside"
            and est.status is Status.TRACKING
            and self._verified
            and est.reason not in LOCK_REASONS  # a lock: the recovery's strict check
            and self.last_share >= self.config.enter_share
            and self.area.unmapped_share(pts, est.pose) >= self.config.enter_share
        ):
            # mostly off the map at the pose found too: the scans before a stretch begins
            # (enter_scans, the sudden exit's wait) are matched as usual, but a pose that
            # most beams cannot check is not promised; the localizer's own status says so
            # too (it was ``tracking``: its next fit would count as one that follows a
            # promised pose, a corridor's weakly constrained fit promised at once)
            est = dataclasses.replace(est, status=Status.DEGRADED, reason=LEAVING)
            loc.status = Status.DEGRADED
        if est.status is not Status.LOST or est.reason == REASON:
            self._last_pose = est.pose
        if self.state == "inside" and est.status is Status.TRACKING and not self._entering:
            self._verified = True
            self._tracked = self._since = est.pose
            self._since_m = 0.0
            self._gap = []
        elif self.state != "inside":
            self._tracked = self._since = None
            self._gap = []
        elif self.record and self._since is not None:
            # a scan between the last tracking one and a stretch that may follow
            if self._gap is not None and len(self._gap) < self.config.lead_in_scans:
                self._gap.append((loc.scans_processed, np.array(pts), self._since))
            else:
                self._gap = None  # more than lead_in_scans since the tracking pose: none
        if est.mapped != mapped:
            est = dataclasses.replace(est, mapped=mapped)
        if self.state == "reentering" and est.status is Status.LOST:
            # the dead-reckoned pose as outside the map, a search running around it: as
            # sure as the coasted pose was (lost once its covariance is too wide)
            sig = math.sqrt(max(float(est.covariance[0, 0] + est.covariance[1, 1]), 0.0))
            if sig <= loc.config.localizer.lost_sigma_xy:
                est = dataclasses.replace(est, status=Status.DEGRADED, reason=REENTERING)
        return est

    def on_reset(self, loc: Localizer) -> None:
        """Called by :meth:`~icploc.localizer.Localizer.reset` and
        :meth:`~icploc.localizer.Localizer.declare_lost`. Between scans (a pose the user
        knows, a kidnapping known from outside, a saved state restored) the monitor starts
        over as if just attached: an open stretch ends there (:attr:`Stretch.reset_at`;
        not back in the map, so not in a patch), the localizer gets its own recovery back,
        and a stretch begins again only after a ``tracking`` scan. Before, a reset while
        outside was coasted over from the next scan on (the pose given ignored, a declared
        kidnapping never searched for). A reset while a scan is processed is the
        localizer's own (a lock, this monitor's re-entry) and changes nothing here."""
        if self._k_in is not None and loc.scans_processed == self._k_in:
            return  # within an update: the localizer's or this monitor's own
        if self.state != "inside" and self.stretches:
            self.stretches[-1].reset_at = loc.scans_processed
        self._restore(loc)
        self.state = "inside"
        self._verified = False
        self._entering = self._held = 0
        self._streak_rec = []
        self._sudden, self._sudden_n = False, 0
        self._below = self._above = 0
        self._reentry_start = None
        self._dr = self._tracked = self._since = None
        self._since_m = 0.0
        self._gap = []
        self._lead_left, self._lead_dr = 0, None
        self._last_pose = None
        self._last_odom = None
        self.last_share = self._prev_share = float("nan")

    def _restore(self, loc: Localizer) -> None:
        """Give the localizer its own recovery back (after a re-entry)."""
        if self._fallback is not None:
            loc.recovery = self._fallback
            self._fallback = None

    def _coast(
        self,
        loc: Localizer,
        scan: Scan,
        pts: NDArray[np.float64],
        pred: Pose,
        pred_cov: NDArray[np.float64],
        odom: Pose | None,
        t0: float,
        share: float,
    ) -> Estimate:
        from icploc.localizer import Estimate, Status

        st = self.stretches[-1]
        st.outside_scans += 1
        if odom is not None and self._last_odom is not None:
            st.distance += math.hypot(odom[0] - self._last_odom[0], odom[1] - self._last_odom[1])
        self._last_odom = odom
        sig = math.sqrt(max(float(pred_cov[0, 0] + pred_cov[1, 1]), 0.0))
        st.max_sigma_xy = max(st.max_sigma_xy, sig)
        if self.record:
            st.scans.append((loc.scans_processed, np.array(pts), self._dr or pred))
        status = Status.LOST if sig > loc.config.localizer.lost_sigma_xy else Status.DEGRADED
        loc.pose, loc.covariance = pred, pred_cov
        loc.status = Status.DEGRADED  # the monitor keeps the scans; no recovery runs
        return Estimate(
            stamp=scan.stamp,
            pose=pred,
            covariance=pred_cov,
            status=status,
            inlier_ratio=float("nan"),
            iterations=0,
            time=time.perf_counter() - t0,
            accepted=False,
            reason=REASON,
            prediction=pred,
            odometry=odom,
            num_points=pts.shape[0],
            hit_ratio=1.0 - share,
            calibration=loc.calibration.factors,
            mapped=False,
        )

    # -- what happened ---------------------------------------------------------------------
    def summary_lines(self, scans: int) -> list[str]:
        """Lines for the replay summary: which stretches were outside the map."""
        return stretch_lines(self.stretches, scans)

    def finish(
        self,
        res: Any,
        map_: Any,
        patch: str | os.PathLike[str] | None,
        include_open: bool = False,
        confident_only: bool = False,
    ) -> None:
        """At the end of a replay: the stretches into its summary, the map patch written
        (``icploc replay --map-patch``; ``include_open``: ``--map-patch-open``, also the
        stretches that never came back into the map; ``confident_only``:
        ``--confident-only``, the less sure wall cells left unknown:
        :func:`icploc.mappatch.write_patch`)."""
        res.notes.extend(self.summary_lines(res.scans))
        if patch is None:
            return
        from icploc.mappatch import in_patch, write_patch

        g = write_patch(
            patch, self.stretches, map_, mounting=self.mounting, walls=self.walls,
            include_open=include_open, confident_only=confident_only,
        )  # fmt: skip
        for i, s in enumerate(self.stretches, 1):
            pl = s.patch_placement
            if s.scans and in_patch(s, include_open) and pl is not None:
                if pl["placement"] == "submap":
                    res.notes.append(
                        f"map patch: stretch {i} placed by its own scans matched to each other "
                        f"({pl['submap_matches_verified']} of {pl['submap_scans']} matches "
                        f"verified, loop error at the lock {pl['submap_loop_error_m']:.2f} m "
                        f"against the odometry's {pl['odometry_loop_error_m']:.2f} m)"
                    )
                else:
                    res.notes.append(
                        f"map patch: stretch {i} placed by the odometry pose graph ({pl['why']})"
                    )
            if not s.scans or in_patch(s):
                continue
            if s.jumped:
                res.notes.append(
                    f"map patch: stretch {i} left out: a kidnap rather than a drive off the map "
                    "(it began with a jump off the map and locked beyond its dead reckoning's "
                    "uncertainty)"
                )
            elif include_open:
                res.notes.append(
                    f"map patch: stretch {i} drawn although not back in the map (--map-patch-open): "
                    "its poses are dead reckoning nothing checked"
                )
            else:
                res.notes.append(
                    f"map patch: stretch {i} left out: not back in the map, its poses are dead "
                    "reckoning nothing checked (--map-patch-open draws it)"
                )
        if g is None:
            if not self.stretches:
                why = "never outside the map"
            elif all(s.jumped for s in self.stretches):
                why = "every stretch was left out as a kidnap"
            else:
                why = "no stretch came back into the map"
            res.notes.append(f"map patch: nothing to write to {patch} ({why})")
            return
        h, w = g.occupied.shape
        res.notes.append(
            f"map patch: {w} x {h} cells at {g.resolution} m from {g.scans_used} scans, "
            f"{int(g.occupied.sum())} occupied; merge with: icploc map merge MAP {patch} --out OUT"
        )
        res.files["map_patch"] = Path(patch)
        import yaml

        from icploc.mappatch import sigma_path

        conf = yaml.safe_load(Path(patch).read_text()).get("icploc_patch_confidence") or {}
        if conf:
            res.notes.append(
                f"map patch: {conf['confident_wall_cells']} of {conf['wall_cells']} wall cells "
                f"confident (sigma of their walls <= {conf['sigma_bound_m'] * 100:g} cm); "
                f"the sigma per cell in {sigma_path(patch)}"
                + ("; the others left unknown (--confident-only)" if confident_only else "")
            )
        res.files["map_patch_sigma"] = sigma_path(patch)


def _believed(cov: NDArray[np.float64], sigma: float) -> bool:
    """A position covariance no wider than ``sigma`` (the pose still means something)."""
    return math.sqrt(max(float(cov[0, 0] + cov[1, 1]), 0.0)) <= sigma


def stretch_lines(stretches: list[Stretch], scans: int) -> list[str]:
    """The replay summary's lines about the stretches outside the map."""
    if not stretches:
        return ["outside the map: never"]
    n = sum(s.outside_scans for s in stretches)
    share = n / scans if scans else 0.0
    jumps = sum(1 for s in stretches if s.jumped)
    out = [
        f"outside the map: {len(stretches)} stretch(es), {n} scans ({share:.1%}) coasted on "
        "odometry (reason outside_map, mapped 0 in the estimates CSV)"
        + (f"; {jumps} of them a kidnap rather than a drive off the map" if jumps else "")
    ]
    for i, s in enumerate(stretches, 1):
        back = (
            f"back at scan {s.end} (t={s.end_stamp:.2f}) after {s.reentry_scans} re-entry "
            f"scan(s), correction {math.hypot(s.correction[0], s.correction[1]):.2f} m "
            f"{math.degrees(s.correction[2]):+.1f} deg"
            if s.end is not None and s.correction is not None
            else f"ended by a reset before scan {s.reset_at} (not back in the map)"
            if s.reset_at is not None
            else "not back in the map at the end"
        )
        why = ""
        if s.jumped:
            why = (
                "; it began with a jump off the map and locked beyond its dead reckoning's "
                "uncertainty: a robot carried elsewhere (a kidnap) rather than driven off the "
                "map, not in a map patch"
            )
        elif s.sudden:
            why = "; it began with a jump off the map (a sharp map edge, or a kidnap)"
        out.append(
            f"  {i}: scans {s.start}.. (t={s.start_stamp:.2f}), {s.outside_scans} outside, "
            f"{s.distance:.1f} m coasted, sigma up to {s.max_sigma_xy:.2f} m; {back}{why}"
        )
    return out


def knows_unknown(map_: Any) -> bool:
    """The map says where it knows nothing: a grid with free space and at least one cell
    neither free nor occupied (a map_server grid's unknown cells). A grid with every cell
    known (an image thresholded to walls and free space) says nothing of where the map
    was not made: a doorway onto an unmapped hall looks like free space, so only the
    grid's bounds would be "unmapped" there. A map of lines or points does not say where
    it ends either."""
    grid, free = getattr(map_, "grid", None), getattr(map_, "free", None)
    if grid is None or free is None:
        return False
    return not bool(np.logical_or(grid, free).all())


def attach_default(loc: Localizer) -> OutsideMonitor | None:
    """What a :class:`~icploc.localizer.Localizer` does with ``outside.enabled`` (the
    default): attach the monitor when its map marks unknown space (:func:`knows_unknown`:
    a grid with unknown cells), else nothing. On a map of lines the mapped area is only
    "within ``reach`` of a wall": in the simulated glass lab (``icploc.sim.lab``) beams through the glass end beyond it
    and the monitor coasted the robot standing in the middle of the map; such maps get the
    monitor only on request (:func:`attach`, ``replay(partial_map=True)``,
    ``--partial-map``)."""
    return attach(loc) if knows_unknown(loc.map) else None


def attach(
    loc: Localizer,
    config: OutsideConfig | None = None,
    *,
    record: bool = False,
    observer: Observer | None = None,
) -> OutsideMonitor:
    """Give ``loc`` an outside-the-map monitor (its ``outside`` hook) and return it.
    Without ``config``: the defaults, the patch's lead-in and lead-out from ``loc``'s
    configuration (``map.patch_lead_in_scans``, ``map.patch_lead_out_scans``). ``observer``:
    see :class:`OutsideMonitor`."""
    if config is None:
        mc = loc.config.map
        config = OutsideConfig(
            lead_in_scans=mc.patch_lead_in_scans, lead_out_scans=mc.patch_lead_out_scans
        )
    area = MappedArea.of(loc.map, loc.index, config)
    from icploc.mappatch import MappedWalls

    mon = OutsideMonitor(
        area, config, record=record, mounting=loc.config.scan.mounting, observer=observer
    )
    mon.walls = MappedWalls(loc.index, area)
    loc.outside = mon
    return mon

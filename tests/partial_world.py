"""A simulated building whose map lacks a wing (tests of icploc.outside / icploc.mappatch).

The simulator is imported here only (``sim`` is merging icploc.worlds into icploc.sim:
re-point the two imports below and nothing else changes).

The building: a main hall 14 m x 10 m with rooms, desks and pillars; a 2 m door in its
east wall opens on a 6 m corridor to a wing (a 10 m x 12 m room with pillars). The robot
tours the main hall, drives into the wing, tours it, comes back and tours the hall again.
The map is built the way a real one is: from the scans of the first tour at the true
poses (ray casting: free, occupied and unknown cells), so the wing is unknown space.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from icploc.sim import World, simulate  # the simulator (re-point here)
from numpy.typing import NDArray

__all__ = [
    "WING_BOX",
    "PartialRun",
    "building",
    "cached_run",
    "drive",
    "errors",
    "go_on",
    "half_known_grid",
    "localized",
    "partial_run",
    "sudden_exit_run",
    "wall_distance",
]

#: the wing (corridor beyond the door and its room): x0, y0, x1, y1
WING_BOX = (14.0, -2.0, 30.0, 12.0)


def _rect(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def building() -> World:
    w: list[list[float]] = []
    # main hall, door in the east wall at y 4..6
    w += [[0, 0, 14, 0], [0, 10, 14, 10], [0, 0, 0, 10], [14, 0, 14, 4], [14, 6, 14, 10]]
    w += [[0, 6.5, 4, 6.5], [4, 6.5, 4, 8.5]]  # a room in the north-west corner
    w += [[9, 10, 9, 7.5], [9, 7.5, 11, 7.5]]  # another in the north
    w += _rect(5.0, 1.0, 6.5, 1.6) + _rect(10.5, 2.0, 11.1, 2.6) + _rect(6.0, 4.0, 6.4, 4.4)
    # the wing: corridor x 14..20 (y 4..6), room x 20..30, y -2..12
    w += [[14, 4, 20, 4], [14, 6, 20, 6]]
    w += [[20, 4, 20, -2], [20, -2, 30, -2], [30, -2, 30, 12], [30, 12, 20, 12], [20, 12, 20, 6]]
    w += _rect(23.0, 2.0, 23.6, 2.6) + _rect(26.5, 7.0, 27.3, 7.6) + [[24, 12, 24, 9.5]]
    return World("building with a wing", np.array(w, dtype=np.float64), start=(2.0, 2.5, 0.0))


HALL = [(2.0, 2.5), (8.5, 2.8), (12.5, 3.0), (12.5, 8.5), (7.0, 8.8), (2.5, 5.0), (2.0, 2.5)]
INTO_WING = [(8.0, 5.0), (13.0, 5.0), (17.0, 5.0), (21.5, 5.0)]
WING = [(22.5, 9.5), (28.5, 10.5), (28.5, 0.0), (24.5, 0.0), (21.5, 5.0)]
BACK = [(17.0, 5.0), (13.0, 5.0), (9.0, 5.5)]


def path() -> NDArray[np.float64]:
    return np.array(HALL + HALL[1:] + INTO_WING + WING + BACK + HALL[1:], dtype=np.float64)


@dataclass
class PartialRun:
    world: World
    truth: NDArray[np.float64]  #: (N, 3) true poses per scan
    items: list  #: time-ordered Scan / Odometry
    scans: list
    map_scans: int  #: the map was built from the first ``map_scans`` scans


def partial_run(seed: int = 0, resolution: float = 0.05) -> tuple[PartialRun, object]:
    """The run and the map of its first hall tour (an icploc Map, unknown wing)."""
    from icploc.mappatch import grid_from_scans
    from icploc.maps import Map

    world = building()
    frames = list(simulate(world, path(), start=(2.0, 2.5, 0.0), seed=seed))
    truth = np.array([f.truth for f in frames])
    items: list = []
    for f in frames:
        items += [f.odometry, f.scan]
    # the map: the scans of the first hall tour (until the robot is back at the start)
    d = np.hypot(truth[:, 0] - 2.0, truth[:, 1] - 2.5)
    first = int(np.argmax((np.arange(len(d)) > 100) & (d < 0.3)))
    pts = []
    for f in frames[:first]:
        r = np.asarray(f.scan.ranges)
        ok = np.isfinite(r)
        a = np.asarray(f.scan.angles)[ok]
        pts.append(np.column_stack([r[ok] * np.cos(a), r[ok] * np.sin(a)]))
    g = grid_from_scans(pts, truth[:first], resolution=resolution)
    assert g is not None
    m = Map.from_grid(g.occupied, g.resolution, g.origin, free=g.free, surface_offset=0.5)
    run = PartialRun(world, truth, items, [f.scan for f in frames], first)
    return run, m


@functools.lru_cache(maxsize=2)
def localized(seed: int = 0, monitor: bool = True) -> tuple[PartialRun, object, list, object]:
    """The run localized against its partial map from the true start (cached per test
    session): (run, map, estimates, the localizer's outside monitor or None)."""
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer, run

    r, m = partial_run(seed)
    # the default config attaches the monitor; without it: outside.enabled false
    cfg = LocalizerConfig.from_dict({"outside": {"enabled": monitor}})
    loc = Localizer(m, cfg, initial_pose=tuple(r.truth[0]))
    mon = loc.outside
    if mon is not None:
        mon.record = True
    ests = run(loc, r.items)
    return r, m, ests, mon


def sudden_exit_run(seed: int = 0) -> tuple[PartialRun, object, list[int]]:
    """The run with a sudden exit (``OutsideConfig.rise_share``'s blind spot): the map
    ends sharply at the wing's door (every cell east of x = 14.1 m unknown: no corridor
    seen through the door) and the robot's first drive into the wing has no scans from
    x = 11 m to 13.9 m (a fast robot, a scanner that drops out at the doorway: the scan's
    unmapped share jumps from 0.10 to 0.71 from one scan to the next). (run, the cut map,
    the run's frame indices kept: scan ``i`` of the localizer is frame ``kept[i]``)."""
    from icploc.maps import Map

    r, m = partial_run(seed)
    occ, free = np.array(m.grid, dtype=bool), np.array(m.free, dtype=bool)  # type: ignore[attr-defined]
    xs = m.origin[0] + (np.arange(occ.shape[1]) + 0.5) * m.resolution  # type: ignore[attr-defined]
    occ[:, xs > 14.1] = False
    free[:, xs > 14.1] = False
    cut = Map.from_grid(occ, m.resolution, m.origin, free=free, surface_offset=0.5)  # type: ignore[attr-defined]
    t = r.truth
    into = int(np.argmax(t[:, 0] > 14.5))  # the first time in the wing
    gap0 = int(np.nonzero(t[:into, 0] < 11.0)[0][-1]) + 1
    gap1 = int(np.argmax(t[:, 0] > 13.9))
    kept = [i for i in range(len(r.scans)) if not gap0 <= i < gap1]
    items = [x for i in kept for x in r.items[2 * i : 2 * i + 2]]
    run = PartialRun(r.world, t[kept], items, [r.scans[i] for i in kept], r.map_scans)
    return run, cut, kept


@functools.lru_cache(maxsize=1)
def cached_run() -> tuple[PartialRun, object]:
    """Seed 0's run and map (:func:`partial_run`), built once per test session."""
    return partial_run(0)


def errors(run: PartialRun, ests: list) -> NDArray[np.float64]:
    """Per scan: the position error of ``ests`` against ``run``'s true poses [m]."""
    p = np.array([e.pose for e in ests])
    return np.hypot(p[:, 0] - run.truth[:, 0], p[:, 1] - run.truth[:, 1])


def half_known_grid(unknown: bool = True) -> object:
    """A 4 m x 4 m map_server-like grid at 10 cm: the left half observed (free, a wall at
    x = 0.05), the right half unknown (``unknown`` False: free as well, every cell known)."""
    from icploc.maps import Map

    occ = np.zeros((40, 40), dtype=bool)
    free = np.zeros((40, 40), dtype=bool)
    occ[:, 0] = True
    free[:, 1 : (20 if unknown else 40)] = True
    return Map.from_grid(occ, 0.1, (0.0, 0.0, 0.0), free=free, fit=False)


def drive(until: str, record: bool = False, n: int = 3) -> tuple[PartialRun, object, int]:
    """Seed 0's run localized from the true start with the default config, scan by scan
    (each with its odometry), until the localizer's outside monitor is in state ``until``
    (``inside``, ``outside``, ``reentering``) for the ``n``-th scan in a row: (run, the
    localizer, the next scan's index). ``record``: the monitor records its stretches."""
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer

    run, m = cached_run()
    loc = Localizer(m, LocalizerConfig(), initial_pose=tuple(run.truth[0]))
    mon = loc.outside
    assert mon is not None
    mon.record = record
    streak = 0
    for k in range(len(run.scans)):
        loc.update(run.items[2 * k + 1], run.items[2 * k])
        streak = streak + 1 if mon.state == until else 0
        if streak == n:
            return run, loc, k + 1
    raise AssertionError(f"the monitor never was {until!r} for {n} scans")


def go_on(run: PartialRun, loc: object, k: int, n: int) -> list:
    """The estimates of scans ``k`` .. ``k + n - 1`` of ``run`` by ``loc``."""
    return [loc.update(run.items[2 * i + 1], run.items[2 * i]) for i in range(k, k + n)]  # type: ignore[attr-defined]


def wall_distance(world: World, xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distance of each point to the nearest wall of ``world``."""
    a, b = world.walls[:, :2], world.walls[:, 2:]
    ab = b - a
    t = np.clip(((xy[:, None, :] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
    q = a + t[..., None] * ab
    return np.hypot(xy[:, None, 0] - q[..., 0], xy[:, None, 1] - q[..., 1]).min(axis=1)

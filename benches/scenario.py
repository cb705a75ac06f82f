"""Deterministic 2D benchmark scenarios: four families of floor plans, sampled maps, noisy scans.

Everything here is plain numpy and depends only on the seed, so every method in
``benches/peers.py`` sees exactly the same maps, scans and start poses.

Families (:data:`FAMILIES`, :func:`make_scenario` ``family=``): the office below; a clinic
wing (:func:`clinic_world`: narrow rooms, a door every 3-4 m, beds and cabinets, glass room
fronts, an 8 m scanner, people); a warehouse of pallet racks (:func:`warehouse_world`);
and, held out from tuning, an apartment (:func:`apartment_world`: open plan, a 45 degree
wall, a glass door, round legs and pillar, a turned desk, a 12 m scanner). The clinic,
the warehouse and the apartment were laid out on their own, not derived from the office.
The office:

* The map is a set of line segments (outer walls, rooms off a corridor with door gaps,
  mapped furniture, one slanted wall). :func:`sample_map` samples it uniformly at a
  spacing chosen to give a target point count (1k ... 1M) and returns the exact 2D
  normals of the segments.
* Scans are 361 beams over 180 degrees (0.5 degree step), ray-cast exactly against the
  segments, with Gaussian range noise (1 cm by default). A fixed fraction of beams
  (20 %: 72 of 361) hits unmapped obstacles: boxes (a flat face spanning a block of
  beams) and people (a circle whose angular width spans a block of beams). Obstacle
  blocks are constructed so the obstacle covers exactly those beams, so the fraction is
  exact, not just expected.
* Start poses are the true pose plus an error of fixed magnitude per axis with random
  signs, e.g. (+-0.3 m, +-0.3 m, +-10 deg).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

NUM_BEAMS = 361
FOV = math.pi  # 180 degrees
ANGLE_STEP = FOV / (NUM_BEAMS - 1)  # 0.5 degree
MAX_RANGE = 30.0

#: Start-error levels: (|dx| m, |dy| m, |dtheta| rad), signs drawn at random per pose.
ERROR_LEVELS: dict[str, tuple[float, float, float]] = {
    "small": (0.3, 0.3, math.radians(10.0)),
    "large": (1.0, 0.5, math.radians(25.0)),
}

#: Target map sizes (points).
MAP_SIZES = (1_000, 10_000, 100_000, 1_000_000)


def beam_angles(num_beams: int = NUM_BEAMS, fov: float = FOV) -> NDArray[np.float64]:
    """Beam angles in the sensor frame, from -fov/2 to +fov/2 (0 straight ahead)."""
    return np.linspace(-fov / 2.0, fov / 2.0, num_beams)


def _rect(x0: float, y0: float, x1: float, y1: float) -> list[tuple[float, float, float, float]]:
    return [(x0, y0, x1, y0), (x1, y0, x1, y1), (x1, y1, x0, y1), (x0, y1, x0, y0)]


def _wall_with_doors(
    x0: float, x1: float, y: float, doors: list[tuple[float, float]]
) -> list[tuple[float, float, float, float]]:
    """A horizontal wall from x0 to x1 at height y with gaps [a, b) for doors."""
    segs = []
    x = x0
    for a, b in sorted(doors):
        if a > x:
            segs.append((x, y, a, y))
        x = b
    if x < x1:
        segs.append((x, y, x1, y))
    return segs


def office_segments() -> NDArray[np.float64]:
    """The office floor plan as a (K, 4) array of segments [x1, y1, x2, y2] (metres).

    24 m x 14 m: a 2 m corridor along x (y in [6, 8]); four rooms to the south and four
    (of different widths) to the north, each with a 0.9 m door onto the corridor; mapped
    cabinets and desks, two pillars in the corridor and a slanted wall in one room, so
    that no two places look alike.
    """
    s: list[tuple[float, float, float, float]] = []
    s += _rect(0.0, 0.0, 24.0, 14.0)  # outer walls
    # Corridor walls with doors (south rooms: x edges 0, 6, 12, 18, 24; north: 0, 5, 10, 16, 24).
    s += _wall_with_doors(0.0, 24.0, 6.0, [(2.5, 3.4), (8.0, 8.9), (14.6, 15.5), (20.1, 21.0)])
    s += _wall_with_doors(0.0, 24.0, 8.0, [(1.5, 2.4), (7.2, 8.1), (12.0, 12.9), (19.5, 20.4)])
    for x in (6.0, 12.0, 18.0):
        s.append((x, 0.0, x, 6.0))
    for x in (5.0, 10.0, 16.0):
        s.append((x, 8.0, x, 14.0))
    # Mapped furniture: cabinets / desks / a column, as closed rectangles.
    s += _rect(0.4, 0.4, 1.6, 1.0)
    s += _rect(3.8, 2.0, 5.2, 2.8)
    s += _rect(7.0, 0.0, 9.0, 0.6)
    s += _rect(10.4, 3.5, 11.4, 5.6)
    s += _rect(13.0, 1.5, 14.6, 2.3)
    s += _rect(19.0, 3.0, 19.8, 3.8)
    s += _rect(22.6, 0.0, 24.0, 1.2)
    s += _rect(0.0, 12.8, 2.0, 14.0)
    s += _rect(6.5, 10.5, 8.5, 11.3)
    s += _rect(11.0, 9.0, 11.6, 9.6)
    s += _rect(14.0, 12.0, 16.0, 14.0)
    s += _rect(20.0, 10.0, 21.2, 11.6)
    # Pillars in the corridor (against the walls so the corridor stays passable).
    s += _rect(5.6, 7.6, 6.0, 8.0)
    s += _rect(16.5, 6.0, 16.9, 6.4)
    # A slanted wall cutting a corner of the last north room.
    s.append((22.0, 14.0, 24.0, 12.0))
    return np.asarray(s, dtype=np.float64)


def segment_normals(segments: NDArray[np.float64]) -> NDArray[np.float64]:
    d = segments[:, 2:4] - segments[:, 0:2]
    length = np.hypot(d[:, 0], d[:, 1])
    return np.column_stack((-d[:, 1], d[:, 0])) / length[:, None]


def total_length(segments: NDArray[np.float64]) -> float:
    d = segments[:, 2:4] - segments[:, 0:2]
    return float(np.hypot(d[:, 0], d[:, 1]).sum())


def sample_map(
    segments: NDArray[np.float64], spacing: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Points every ``spacing`` metres along each segment (cell centres, no duplicated
    corners) and their unit normals (the segment's normal)."""
    p0 = segments[:, 0:2]
    d = segments[:, 2:4] - p0
    length = np.hypot(d[:, 0], d[:, 1])
    counts = np.maximum(1, np.ceil(length / spacing).astype(np.int64))
    seg_id = np.repeat(np.arange(len(segments)), counts)
    start = np.cumsum(counts) - counts
    k = np.arange(int(counts.sum())) - np.repeat(start, counts)
    t = (k + 0.5) / counts[seg_id]
    pts = p0[seg_id] + t[:, None] * d[seg_id]
    normals = segment_normals(segments)[seg_id]
    return pts, normals


def map_for_size(
    segments: NDArray[np.float64], num_points: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], float]:
    """Sample the map to about ``num_points`` points; returns (points, normals, spacing)."""
    spacing = total_length(segments) / float(num_points)
    pts, nrm = sample_map(segments, spacing)
    return pts, nrm, spacing


# --------------------------------------------------------------------------- ray casting


def raycast_segments(
    segments: NDArray[np.float64],
    origin: tuple[float, float],
    directions: NDArray[np.float64],
    max_range: float = MAX_RANGE,
) -> NDArray[np.float64]:
    """Exact range along each unit direction (M, 2) to the nearest segment; inf if none."""
    ox, oy = origin
    ux = directions[:, 0][:, None]
    uy = directions[:, 1][:, None]
    ax = segments[:, 0][None, :] - ox
    ay = segments[:, 1][None, :] - oy
    ex = (segments[:, 2] - segments[:, 0])[None, :]
    ey = (segments[:, 3] - segments[:, 1])[None, :]
    # Solve o + t u = a + s e  ->  t u - s e = a
    den = ux * (-ey) - uy * (-ex)
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ax * (-ey) - ay * (-ex)) / den
        s = (ux * ay - uy * ax) / den
    ok = (np.abs(den) > 1e-15) & (t > 1e-12) & (s >= 0.0) & (s <= 1.0)
    t = np.where(ok, t, np.inf)
    r = t.min(axis=1)
    r[r > max_range] = np.inf
    return r


@dataclass
class Obstacles:
    """Unmapped obstacles in the world frame: box faces (segments) and people (circles)."""

    segments: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    circles: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))  # cx, cy, r


@dataclass
class SimScan:
    """One simulated scan: sensor-frame beams and what each beam hit."""

    pose: tuple[float, float, float]
    angles: NDArray[np.float64]
    ranges: NDArray[np.float64]  #: noisy ranges (inf: no return)
    ranges_true: NDArray[np.float64]  #: noise-free ranges
    obstacle: NDArray[np.bool_]  #: beams that hit an unmapped obstacle
    obstacles: Obstacles

    def points(self, noisy: bool = True) -> NDArray[np.float64]:
        """Valid beams as (M, 2) sensor-frame points."""
        r = self.ranges if noisy else self.ranges_true
        ok = np.isfinite(r)
        return np.column_stack((r[ok] * np.cos(self.angles[ok]), r[ok] * np.sin(self.angles[ok])))


def _split_blocks(total: int, rng: np.random.Generator) -> list[int]:
    """Split ``total`` beams into 3-6 obstacle blocks of at least 5 beams."""
    n = int(rng.integers(3, 7))
    while True:
        cuts = np.sort(rng.choice(np.arange(1, total), size=n - 1, replace=False))
        sizes = np.diff(np.concatenate(([0], cuts, [total])))
        if sizes.min() >= 5:
            return [int(v) for v in sizes]


def simulate_scan(
    segments: NDArray[np.float64],
    pose: tuple[float, float, float],
    rng: np.random.Generator,
    noise: float = 0.01,
    obstacle_fraction: float = 0.2,
    angles: NDArray[np.float64] | None = None,
    max_range: float = MAX_RANGE,
    glass: NDArray[np.float64] | None = None,
    people_only: bool = False,
) -> SimScan:
    """Ray-cast a scan at ``pose`` with unmapped obstacles covering exactly
    ``round(obstacle_fraction * beams)`` beams, then add Gaussian range noise.

    ``glass``: mapped glass segments (not in ``segments``); a beam that meets glass first
    passes through it with probability one half. ``people_only``: every obstacle block is a
    person (no boxes)."""
    a = beam_angles() if angles is None else np.asarray(angles, dtype=np.float64)
    nb = len(a)
    x, y, th = pose
    world = a + th
    dirs = np.column_stack((np.cos(world), np.sin(world)))
    r_map = raycast_segments(segments, (x, y), dirs, max_range)
    if glass is not None and len(glass):
        r_glass = raycast_segments(glass, (x, y), dirs, max_range)
        stops = (r_glass < r_map) & (rng.random(nb) < 0.5)
        r_map = np.where(stops, r_glass, r_map)
    ranges = r_map.copy()
    hit = np.zeros(nb, dtype=bool)
    obs_segs: list[tuple[float, float, float, float]] = []
    obs_circ: list[tuple[float, float, float]] = []
    n_obs = int(round(obstacle_fraction * nb))
    step = float(a[1] - a[0]) if nb > 1 else ANGLE_STEP
    if n_obs > 0:
        for _attempt in range(200):
            sizes = _split_blocks(n_obs, rng)
            # place blocks left to right with random gaps (>= 1 beam apart)
            free = nb - n_obs - len(sizes) + 1
            if free < 0:
                continue
            gaps = np.sort(rng.integers(0, free + 1, size=len(sizes)))
            order = rng.permutation(len(sizes))
            starts, cursor = [], 0
            for j, k in enumerate(order):
                g = int(gaps[j]) - (int(gaps[j - 1]) if j else 0)
                cursor += g
                starts.append((cursor, sizes[k]))
                cursor += sizes[k] + 1
            need = 0.8 if _attempt < 100 else 0.45  # relax in doorways
            ok = all(np.isfinite(r_map[s : s + n]).all() and r_map[s : s + n].min() > need for s, n in starts)
            if ok:
                break
        else:  # no room for the blocks (a short-range scan facing a wall): no obstacles
            starts = []
        for s, n in starts:
            idx = np.arange(s, s + n)
            rmin = float(r_map[idx].min())
            lo_ang = world[s] - step / 2.0
            hi_ang = world[s + n - 1] + step / 2.0
            half = (hi_ang - lo_ang) / 2.0
            mid = (hi_ang + lo_ang) / 2.0
            dmax = min(rmin - 0.2, 8.0)
            dmin = min(0.4, dmax - 0.05)
            person_d = 0.22 / math.sin(half)  # a person of radius 0.22 m spanning the block
            if (people_only or rng.random() < 0.5) and 0.5 < person_d < dmax - 0.1:
                rad = 0.22
                cx, cy = x + person_d * math.cos(mid), y + person_d * math.sin(mid)
                # circle seen under exactly +-half: centre distance D, radius D sin(half)
                obs_circ.append((cx, cy, rad))
                ux, uy = dirs[idx, 0], dirs[idx, 1]
                wx, wy = cx - x, cy - y
                tc = ux * wx + uy * wy
                perp2 = wx * wx + wy * wy - tc * tc
                ranges[idx] = tc - np.sqrt(np.maximum(rad * rad - perp2, 0.0))
            else:
                d1 = float(rng.uniform(dmin, dmax))
                d2 = float(np.clip(d1 + rng.uniform(-0.5, 0.5), dmin, dmax))
                p1 = (x + d1 * math.cos(lo_ang), y + d1 * math.sin(lo_ang))
                p2 = (x + d2 * math.cos(hi_ang), y + d2 * math.sin(hi_ang))
                seg = np.array([[p1[0], p1[1], p2[0], p2[1]]])
                obs_segs.append(tuple(seg[0]))
                ranges[idx] = raycast_segments(seg, (x, y), dirs[idx], max_range)
            hit[idx] = True
    true_r = ranges.copy()
    noisy = ranges + (rng.normal(0.0, noise, nb) if noise > 0 else 0.0)
    noisy = np.where(np.isfinite(true_r), np.maximum(noisy, 0.01), np.inf)
    return SimScan(
        pose=(float(x), float(y), float(th)),
        angles=a,
        ranges=noisy,
        ranges_true=true_r,
        obstacle=hit,
        obstacles=Obstacles(
            segments=np.asarray(obs_segs, dtype=np.float64).reshape(-1, 4),
            circles=np.asarray(obs_circ, dtype=np.float64).reshape(-1, 3),
        ),
    )


def distance_to_segments(points: NDArray[np.float64], segments: NDArray[np.float64]) -> NDArray[np.float64]:
    """Euclidean distance from each (M, 2) point to the nearest of the (K, 4) segments."""
    p = points[:, None, :]
    a = segments[None, :, 0:2]
    e = segments[None, :, 2:4] - a
    ee = np.maximum((e * e).sum(-1), 1e-300)
    t = np.clip(((p - a) * e).sum(-1) / ee, 0.0, 1.0)
    q = a + t[..., None] * e
    return np.sqrt(((p - q) ** 2).sum(-1)).min(axis=1)


def sample_free_poses(
    segments: NDArray[np.float64], n: int, rng: np.random.Generator, clearance: float = 0.5
) -> NDArray[np.float64]:
    """``n`` poses inside the floor plan at least ``clearance`` from every wall, random heading."""
    lo = segments[:, [0, 2]].min(), segments[:, [1, 3]].min()
    hi = segments[:, [0, 2]].max(), segments[:, [1, 3]].max()
    out: list[tuple[float, float, float]] = []
    while len(out) < n:
        xy = rng.uniform((lo[0] + clearance, lo[1] + clearance), (hi[0] - clearance, hi[1] - clearance), size=(4 * n, 2))
        d = distance_to_segments(xy, segments)
        for (px, py), dd in zip(xy, d, strict=True):
            if dd >= clearance and not _inside_furniture(px, py):
                out.append((float(px), float(py), float(rng.uniform(-math.pi, math.pi))))
                if len(out) == n:
                    break
    return np.asarray(out, dtype=np.float64)


def _inside_furniture(x: float, y: float) -> bool:
    """Rough test: is (x, y) inside one of the closed rectangles (not free space)?"""
    rects = [
        (0.4, 0.4, 1.6, 1.0), (3.8, 2.0, 5.2, 2.8), (7.0, 0.0, 9.0, 0.6), (10.4, 3.5, 11.4, 5.6),
        (13.0, 1.5, 14.6, 2.3), (19.0, 3.0, 19.8, 3.8), (22.6, 0.0, 24.0, 1.2), (0.0, 12.8, 2.0, 14.0),
        (6.5, 10.5, 8.5, 11.3), (11.0, 9.0, 11.6, 9.6), (14.0, 12.0, 16.0, 14.0), (20.0, 10.0, 21.2, 11.6),
        (5.6, 7.6, 6.0, 8.0), (16.5, 6.0, 16.9, 6.4),
    ]  # fmt: skip
    if x + y > 36.0:  # beyond the slanted wall (22,14)-(24,12)
        return True
    return any(x0 <= x <= x1 and y0 <= y <= y1 for x0, y0, x1, y1 in rects)


def initial_poses(
    poses: NDArray[np.float64], error: tuple[float, float, float], rng: np.random.Generator
) -> NDArray[np.float64]:
    """True poses plus an error of exactly the given magnitudes with random signs (world frame)."""
    signs = rng.choice(np.array([-1.0, 1.0]), size=poses.shape)
    init = poses + signs * np.asarray(error)[None, :]
    init[:, 2] = np.remainder(init[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    return init


@dataclass
class Scenario:
    """Poses, scans and start poses for one benchmark run (the maps are sampled separately)."""

    segments: NDArray[np.float64]
    poses: NDArray[np.float64]
    scans: list[SimScan]
    starts: dict[str, NDArray[np.float64]]
    seed: int

    def scan_points(self, i: int) -> NDArray[np.float64]:
        return self.scans[i].points(noisy=True)


def make_scenario(
    num_poses: int = 50,
    seed: int = 7,
    noise: float = 0.01,
    obstacle_fraction: float | None = None,
    family: str = "office",
) -> Scenario:
    """The deterministic scenario of one family (:data:`FAMILIES`): ``num_poses`` true poses,
    one noisy scan each, and a start pose per error level (seeded independently of the pose
    count for the first poses). ``obstacle_fraction`` defaults to the family's."""
    w = world(family)
    segs = w.segments
    frac = w.obstacle_fraction if obstacle_fraction is None else obstacle_fraction
    rng_pose = np.random.default_rng([seed, 1])
    if family == "office":
        poses = sample_free_poses(segs, num_poses, rng_pose)
    else:
        poses = sample_world_poses(w, num_poses, rng_pose)
    scans = [
        simulate_scan(
            w.seen_opaque, tuple(p), np.random.default_rng([seed, 2, i]), noise, frac,
            max_range=w.max_range, glass=w.glass, people_only=w.people_only,
        )
        for i, p in enumerate(poses)
    ]
    starts = {
        name: initial_poses(poses, err, np.random.default_rng([seed, 3, k]))
        for k, (name, err) in enumerate(ERROR_LEVELS.items())
    }
    return Scenario(segments=segs, poses=poses, scans=scans, starts=starts, seed=seed)


# --------------------------------------------------------------------------- families
#
# Two more worlds, laid out independently of the office (not by perturbing it): the same
# layouts as `rust/icploc-core/src/testkit.rs` (`clinic_world`, `warehouse_world`), which
# `cargo bench` uses.

Segs = list[tuple[float, float, float, float]]


def _split_glass(seg: tuple[float, float, float, float], a: float, b: float, opaque: Segs, glass: Segs) -> None:
    """The part of a horizontal wall segment with x in [a, b] becomes glass."""
    x0, x1, y = min(seg[0], seg[2]), max(seg[0], seg[2]), seg[1]
    g0, g1 = max(x0, a), min(x1, b)
    if g0 >= g1:
        opaque.append(seg)
        return
    if x0 < g0:
        opaque.append((x0, y, g0, y))
    glass.append((g0, y, g1, y))
    if g1 < x1:
        opaque.append((g1, y, x1, y))


@dataclass
class World:
    """A benchmark world: mapped opaque walls and mapped glass, the scanner's range, the
    unmapped clutter per scan, and the free regions poses are drawn from."""

    name: str
    opaque: NDArray[np.float64]
    glass: NDArray[np.float64]
    max_range: float
    obstacle_fraction: float
    people_only: bool
    regions: list[tuple[float, float, float, float]]
    #: mapped, but no longer there (in the map, not in the scans)
    gone: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    #: there, but not mapped (in the scans, not in the map)
    unmapped: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))

    @property
    def segments(self) -> NDArray[np.float64]:
        """Every mapped segment (opaque, glass, and what has gone since)."""
        return np.vstack([s for s in (self.opaque, self.glass, self.gone) if len(s)])

    @property
    def seen_opaque(self) -> NDArray[np.float64]:
        """The opaque segments a scan sees: the mapped ones still there and the unmapped."""
        return np.vstack([self.opaque, self.unmapped]) if len(self.unmapped) else self.opaque


def clinic_world() -> World:
    """A clinic wing, 36 m x 12 m: a 2 m corridor (y 5..7) between twelve narrow 3 m rooms
    to the south and nine 4 m rooms to the north, a 1 m door into every room (a door every
    3-4 m), a bed and a cabinet or desk (mapped blocks) per room, columns along the
    corridor, two glass room fronts (nurse station, observation room), an 8 m scanner and
    people (15 % of the beams, as 3-6 people)."""
    opaque: Segs = list(_rect(0.0, 0.0, 36.0, 12.0))
    glass: Segs = []
    south_doors = []
    for k in range(12):
        x = 3.0 * k
        d = x + 0.4 + 0.3 * (k % 4)
        south_doors.append((d, d + 1.0))
        if k > 0:
            opaque.append((x, 0.0, x, 5.0))
        bx = x + 0.3 + 0.4 * (k % 3)
        opaque += _rect(bx, 0.0, bx + 0.9, 2.0)
        if k % 2 == 0:
            opaque += _rect(x + 2.3, 4.1, x + 2.8, 4.6)
    north_doors = []
    for k in range(9):
        x = 4.0 * k
        d = x + 0.5 + 0.5 * (k % 3)
        north_doors.append((d, d + 1.1))
        if k > 0:
            opaque.append((x, 7.0, x, 12.0))
        bx = x + 0.8 + 0.5 * (k % 2)
        opaque += _rect(bx, 11.1, bx + 2.0, 12.0)
        if k % 3 != 0:
            opaque += _rect(x + 2.6, 8.0, x + 3.8, 8.6)
    for seg in _wall_with_doors(0.0, 36.0, 5.0, south_doors):
        _split_glass(seg, 21.0, 24.0, opaque, glass)
    for seg in _wall_with_doors(0.0, 36.0, 7.0, north_doors):
        _split_glass(seg, 16.0, 20.0, opaque, glass)
    for cx in (9.0, 15.5, 27.0, 33.5):
        opaque += _rect(cx, 5.0, cx + 0.3, 5.3)
    regions = [(0.6, 5.6, 35.4, 6.4)]
    regions += [(3.0 * k + 0.5, 2.4, 3.0 * k + 2.5, 3.8) for k in range(12)]
    regions += [(4.0 * k + 0.5, 9.0, 4.0 * k + 3.5, 10.6) for k in range(9)]
    return World("clinic", np.asarray(opaque), np.asarray(glass).reshape(-1, 4), 8.0, 0.15, True, regions)


def warehouse_world() -> World:
    """A warehouse, 40 m x 30 m: six rows of pallet racks (1.2 m deep) with 3 m aisles and a
    cross aisle; each rack a line of 0.1 m uprights every 2.5 m with a pallet in two bays of
    three (mapped); columns along the west wall, dock doors in the south wall; a 20 m
    scanner; 10 % of the beams on unmapped clutter (pallets left in aisles, people)."""
    opaque: Segs = _wall_with_doors(0.0, 40.0, 0.0, [(8.0, 11.0), (16.0, 19.0), (24.0, 27.0)])
    opaque += [(40.0, 0.0, 40.0, 30.0), (40.0, 30.0, 0.0, 30.0), (0.0, 30.0, 0.0, 0.0)]
    for a in (8.0, 16.0, 24.0):
        opaque += [(a, 0.0, a, -1.0), (a, -1.0, a + 3.0, -1.0), (a + 3.0, -1.0, a + 3.0, 0.0)]
    regions: list[tuple[float, float, float, float]] = []
    for r in range(6):
        y = 3.0 + 4.2 * r
        for rack, (xa, xb) in enumerate(((4.0, 19.0), (21.0, 36.0))):
            bays = round((xb - xa) / 2.5)
            for b in range(bays + 1):
                x = xa + 2.5 * b
                opaque += _rect(x - 0.05, y, x + 0.05, y + 0.1)
                opaque += _rect(x - 0.05, y + 1.1, x + 0.05, y + 1.2)
                if b < bays and (r * 7 + rack * 3 + b) % 3 != 0:
                    opaque += _rect(x + 0.15, y + 0.05, x + 2.35, y + 1.15)
        regions.append((5.0, y + 1.9, 35.0, y + 3.5))
    regions += [(5.0, 1.0, 35.0, 2.3), (19.4, 3.0, 20.6, 27.0)]
    for cy in (8.0, 16.0, 24.0):
        opaque += _rect(1.5, cy, 1.9, cy + 0.4)
    return World("warehouse", np.asarray(opaque), np.zeros((0, 4)), 20.0, 0.1, False, regions)


def office_world() -> World:
    """The office of :func:`office_segments` as a world (30 m range, 20 % clutter)."""
    segs = office_segments()
    return World("office", segs, np.zeros((0, 4)), MAX_RANGE, 0.2, False, [])


def _polygon(pts: list[tuple[float, float]]) -> Segs:
    """The closed polygon through ``pts``."""
    return [(*pts[i], *pts[(i + 1) % len(pts)]) for i in range(len(pts))]


def _turned_rect(cx: float, cy: float, w: float, h: float, angle: float) -> Segs:
    """A ``w`` x ``h`` rectangle centred on (cx, cy), turned by ``angle`` (rad)."""
    c, s = math.cos(angle), math.sin(angle)
    a, b = w / 2, h / 2
    return _polygon([(cx + c * u - s * v, cy + s * u + c * v) for u, v in ((-a, -b), (a, -b), (a, b), (-a, b))])


def _round(cx: float, cy: float, r: float, n: int) -> Segs:
    """A round pillar or table leg: a regular ``n``-gon of radius ``r``."""
    return _polygon([(cx + r * math.cos(2 * math.pi * k / n), cy + r * math.sin(2 * math.pi * k / n)) for k in range(n)])


def apartment_world() -> World:
    """The held-out family (laid out after the other three were tuned, and not tuned on): an
    apartment, 16 m x 11 m. Three rooms (two bedrooms, a bathroom) off an open-plan living
    room and kitchen; the south-east corner cut by a 45 degree wall; a glass balcony door in
    the east wall; a round pillar; a dining table seen only as its four round legs; a
    kitchen island, counters, a sofa, an armchair and a desk turned by 30 degrees; a 12 m
    scanner; 10 % of the beams on unmapped clutter (people, chairs, bags). The layout of
    ``apartment_world`` in ``rust/icploc-core/src/testkit.rs``."""
    opaque: Segs = [(0.0, 0.0, 13.0, 0.0), (13.0, 0.0, 16.0, 3.0), (16.0, 3.0, 16.0, 5.0)]
    glass: Segs = [(16.0, 5.0, 16.0, 8.0)]
    opaque += [(16.0, 8.0, 16.0, 11.0), (16.0, 11.0, 0.0, 11.0), (0.0, 11.0, 0.0, 0.0)]
    opaque += [(6.0, s[0], 6.0, s[2]) for s in _wall_with_doors(0.0, 11.0, 0.0, [(1.5, 2.4), (4.8, 5.6), (8.0, 8.9)])]
    opaque += [(0.0, 4.0, 6.0, 4.0), (0.0, 6.5, 6.0, 6.5)]
    opaque += _rect(0.0, 0.0, 1.9, 2.1) + _rect(4.9, 0.0, 6.0, 0.6) + _rect(0.0, 4.0, 1.7, 4.75) + _round(4.2, 6.25, 0.2, 10)
    opaque += _rect(0.0, 9.0, 2.0, 11.0) + _round(2.35, 10.6, 0.2, 10)
    opaque += _round(11.0, 4.0, 0.2, 12)
    for lx, ly in ((8.5, 2.0), (10.1, 2.0), (8.5, 2.9), (10.1, 2.9)):
        opaque += _round(lx, ly, 0.03, 6)
    opaque += _rect(9.0, 7.5, 12.0, 8.1) + _rect(8.0, 10.4, 14.0, 11.0) + _rect(12.5, 5.6, 14.5, 6.3)
    opaque += _rect(14.8, 9.0, 15.5, 9.7) + _turned_rect(7.5, 9.2, 1.0, 0.5, math.radians(30.0))
    regions = [(6.5, 0.5, 15.5, 10.0), (2.3, 0.5, 5.5, 3.5), (0.5, 2.5, 2.3, 3.5), (2.0, 4.5, 5.5, 6.0),
               (2.4, 7.0, 5.5, 10.5), (0.5, 7.0, 2.4, 8.6)]  # fmt: skip
    return World("apartment", np.asarray(opaque), np.asarray(glass), 12.0, 0.1, False, regions)


class _SplitMix:
    """The SplitMix64 generator of ``rust/icploc-core/src/testkit.rs`` (``Rng``), so that the
    garage's parked cars are the same in both."""

    def __init__(self, seed: int) -> None:
        self.s = (seed ^ 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF

    def next_u64(self) -> int:
        self.s = (self.s + 0x9E3779B97F4A7C15) & 0xFFFFFFFFFFFFFFFF
        z = self.s
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & 0xFFFFFFFFFFFFFFFF
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
        return z ^ (z >> 31)

    def uniform(self) -> float:
        return (self.next_u64() >> 11) / float(1 << 53)

    def range(self, lo: float, hi: float) -> float:
        return lo + (hi - lo) * self.uniform()


def garage_world() -> World:
    """A second held-out family, laid out after the core's rules were set and not tuned on:
    one level of a parking garage, 56 m x 36 m. Rows of 2.5 m bays against the south and
    north walls and a double row in the middle, 7 m aisles, 0.5 m square pillars every
    7.5 m along the rows' fronts (a repeating pattern), a stair and lift core with a glass
    door, the north-east corner cut at 45 degrees, a ramp out through the east wall whose
    rising floor crosses the scan plane. The map was made with 70 % of the bays taken;
    since then a fifth of those cars have left (mapped, not seen) and a third of the empty
    bays have filled (seen, not mapped). A 25 m scanner; 10 % of the beams on unmapped
    clutter (people, trolleys). The layout of ``garage_world`` in ``testkit.rs``."""
    opaque: Segs = [(0.0, 0.0, 56.0, 0.0), (56.0, 0.0, 56.0, 14.0), (56.0, 22.0, 56.0, 30.0),
                    (56.0, 30.0, 50.0, 36.0), (50.0, 36.0, 0.0, 36.0), (0.0, 36.0, 0.0, 0.0)]  # fmt: skip
    opaque += [(56.0, 14.0, 62.0, 14.0), (56.0, 22.0, 62.0, 22.0), (61.0, 14.0, 61.0, 22.0)]
    opaque += [(26.0, 15.5, 27.5, 15.5), (29.5, 15.5, 31.0, 15.5), (31.0, 15.5, 31.0, 20.5),
               (31.0, 20.5, 26.0, 20.5), (26.0, 20.5, 26.0, 15.5)]  # fmt: skip
    glass: Segs = [(27.5, 15.5, 29.5, 15.5)]
    for k in range(1, 8):
        x = 7.5 * k
        for y in (5.25, 12.75, 23.25, 30.75):
            opaque += _rect(x - 0.25, y - 0.25, x + 0.25, y + 0.25)
    gone: Segs = []
    unmapped: Segs = []
    rng = _SplitMix(5713)
    for r, (back, sign) in enumerate(((0.3, 1.0), (17.7, -1.0), (18.3, 1.0), (35.7, -1.0))):
        for k in range(22):
            x0 = 0.5 + 2.5 * k
            middle = r in (1, 2)
            if middle and ((21.0 < x0 < 31.0) or x0 >= 50.0):
                continue
            if r == 3 and x0 + 2.5 > 50.0:
                continue
            jx = rng.range(-0.15, 0.15)
            jy = rng.range(0.0, 0.3)
            cx0, cx1 = x0 + 0.35 + jx, x0 + 2.15 + jx
            ya, yb = back + sign * jy, back + sign * (jy + 4.6)
            car = _rect(cx0, min(ya, yb), cx1, max(ya, yb))
            mapped = rng.uniform() < 0.7
            u = rng.uniform()
            if mapped and u < 0.2:
                gone += car
            elif mapped:
                opaque += car
            elif u < 1.0 / 3.0:
                unmapped += car
    regions = [(1.0, 5.9, 55.0, 12.1), (1.0, 23.9, 55.0, 30.1), (50.3, 13.0, 55.6, 23.0),
               (23.2, 13.0, 25.6, 23.0), (31.4, 13.0, 32.8, 23.0)]  # fmt: skip
    return World("garage", np.asarray(opaque), np.asarray(glass), 25.0, 0.1, False, regions,
                 np.asarray(gone).reshape(-1, 4), np.asarray(unmapped).reshape(-1, 4))  # fmt: skip


FAMILIES = ("office", "clinic", "warehouse", "apartment", "garage")
#: Families the core's defaults were tuned on; the rest are held out (the apartment, and
#: the garage, laid out after the rules were set).
TUNED_FAMILIES = ("office", "clinic", "warehouse")


def world(name: str) -> World:
    """One of :data:`FAMILIES`."""
    makers = {"office": office_world, "clinic": clinic_world, "warehouse": warehouse_world, "apartment": apartment_world,
              "garage": garage_world}  # fmt: skip
    if name not in makers:
        raise ValueError(f"unknown scenario family {name!r}; choose from {', '.join(FAMILIES)}")
    return makers[name]()


def sample_world_poses(w: World, n: int, rng: np.random.Generator, clearance: float = 0.35) -> NDArray[np.float64]:
    """``n`` poses in the world's free regions (uniform by area), at least ``clearance``
    from every mapped segment, random heading."""
    regions = np.asarray(w.regions, dtype=np.float64)
    area = (regions[:, 2] - regions[:, 0]) * (regions[:, 3] - regions[:, 1])
    out: list[tuple[float, float, float]] = []
    segs = np.vstack([w.segments, w.unmapped]) if len(w.unmapped) else w.segments
    while len(out) < n:
        k = rng.choice(len(regions), size=4 * n, p=area / area.sum())
        lo, hi = regions[k, :2], regions[k, 2:]
        xy = lo + rng.random((4 * n, 2)) * (hi - lo)
        d = distance_to_segments(xy, segs)
        for (px, py), dd in zip(xy, d, strict=True):
            if dd >= clearance:
                out.append((float(px), float(py), float(rng.uniform(-math.pi, math.pi))))
                if len(out) == n:
                    break
    return np.asarray(out, dtype=np.float64)


# --------------------------------------------------------------------------- replay log


def _path_waypoints() -> list[tuple[float, float]]:
    """A tour along the corridor, through doors into rooms and back (all in free space)."""
    return [
        (1.0, 7.0), (2.95, 7.0), (2.95, 4.0), (2.0, 3.5), (2.95, 4.5), (2.95, 7.0),
        (7.65, 7.0), (7.65, 9.5), (9.25, 9.9), (9.25, 12.5), (9.25, 9.9), (7.65, 9.5), (7.65, 7.0),
        (15.05, 7.0), (15.05, 4.0), (16.5, 2.0), (15.05, 4.0), (15.05, 7.0),
        (19.95, 7.0), (19.95, 9.0), (22.5, 9.0), (19.95, 9.0), (19.95, 7.0), (23.0, 7.0),
        (12.45, 7.0), (12.45, 11.0), (13.5, 12.5), (12.45, 11.0), (12.45, 7.0), (1.0, 7.0),
    ]  # fmt: skip


@dataclass
class ReplayLog:
    """A generated log: true poses, drifting odometry and scans, one of each per step."""

    segments: NDArray[np.float64]
    stamps: NDArray[np.float64]
    truth: NDArray[np.float64]  #: (T, 3)
    odometry: NDArray[np.float64]  #: (T, 3) drifting odometry poses (odometry frame)
    scans: list[SimScan]


def make_replay_log(num_scans: int = 1000, seed: int = 11, rate: float = 10.0) -> ReplayLog:
    """Drive the waypoint tour at constant speed (looping), scanning at ``rate`` Hz, with
    odometry that drifts (2 % scale error on distance, 1 % on rotation, random walk)."""
    segs = office_segments()
    wp = np.asarray(_path_waypoints())
    seg_len = np.hypot(*(np.diff(wp, axis=0).T))
    cum = np.concatenate(([0.0], np.cumsum(seg_len)))
    rng = np.random.default_rng([seed, 5])
    speed = 0.6
    stamps = np.arange(num_scans) / rate
    dist = np.mod(stamps * speed, cum[-1])
    k = np.clip(np.searchsorted(cum, dist, side="right") - 1, 0, len(seg_len) - 1)
    t = (dist - cum[k]) / seg_len[k]
    xy = wp[k] + t[:, None] * (wp[k + 1] - wp[k])
    heading = np.arctan2(*(wp[k + 1] - wp[k])[:, ::-1].T)
    # smooth the heading a little so turns take a few scans (robots turn, not teleport)
    unwrapped = np.unwrap(heading)
    kernel = np.ones(9) / 9.0
    smooth = np.convolve(np.pad(unwrapped, 4, mode="edge"), kernel, mode="valid")
    truth = np.column_stack((xy, np.remainder(smooth + math.pi, 2 * math.pi) - math.pi))
    # odometry: integrate true increments with scale errors and noise
    odo = np.zeros_like(truth)
    odo[0] = truth[0]
    for i in range(1, num_scans):
        a, b = truth[i - 1], truth[i]
        c, s = math.cos(a[2]), math.sin(a[2])
        dx, dy = b[0] - a[0], b[1] - a[1]
        lx, ly = c * dx + s * dy, -s * dx + c * dy
        dth = math.remainder(b[2] - a[2], 2 * math.pi)
        lx = lx * 1.02 + rng.normal(0, 0.002)
        ly = ly + rng.normal(0, 0.001)
        dth = dth * 1.01 + rng.normal(0, 0.002)
        o = odo[i - 1]
        co, so = math.cos(o[2]), math.sin(o[2])
        odo[i] = (o[0] + co * lx - so * ly, o[1] + so * lx + co * ly, math.remainder(o[2] + dth, 2 * math.pi))
    scans = [
        simulate_scan(segs, tuple(p), np.random.default_rng([seed, 6, i])) for i, p in enumerate(truth)
    ]
    return ReplayLog(segments=segs, stamps=stamps, truth=truth, odometry=odo, scans=scans)

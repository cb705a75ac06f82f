"""Built-in worlds with exact truth: the paper's lab, a crowd, long repetitive aisles.

A :class:`World` is a floor plan of opaque wall segments, glass segments (the laser
passes through glass with some probability and sees what lies behind, the paper's
Fig. 11 experiment) and people walking on closed paths (moving circles that occlude
the laser). :func:`simulate` drives a robot along a path and produces, at the laser
rate, the true pose, drifting wheel odometry and a noisy scan — a fast kinematic
stand-in for the device simulators, used by the benchmarks and tests. The demo drives
the same worlds through the real drivers and the pty device simulators.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from icploc.se2 import Pose, compose, wrap_angle
from icploc.sim.world import ray_circles
from icploc.types import BEAM_NO_RETURN, Odometry, Scan

__all__ = [
    "Person",
    "SimFrame",
    "World",
    "aisles",
    "circle_path",
    "crowd",
    "lab",
    "lab_random_walk",
    "simulate",
    "tour_path",
]


def _rect(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


@dataclass
class Person:
    """A person (a circle) walking a closed polyline at constant speed."""

    path: NDArray[np.float64]  # (K, 2) closed loop (last joins first)
    speed: float = 0.8
    radius: float = 0.2
    phase: float = 0.0  # metres along the path at t = 0

    def __post_init__(self) -> None:
        self.path = np.asarray(self.path, dtype=np.float64).reshape(-1, 2)
        seg = np.diff(np.vstack([self.path, self.path[:1]]), axis=0)
        self._len = np.hypot(seg[:, 0], seg[:, 1])
        self._cum = np.concatenate([[0.0], np.cumsum(self._len)])
        self._seg = seg

    def position(self, t: float) -> tuple[float, float]:
        total = float(self._cum[-1])
        if total <= 0.0:
            return float(self.path[0, 0]), float(self.path[0, 1])
        s = (self.phase + self.speed * t) % total
        i = int(np.searchsorted(self._cum, s, side="right") - 1)
        i = min(i, len(self._len) - 1)
        f = (s - self._cum[i]) / max(self._len[i], 1e-12)
        p = self.path[i] + f * self._seg[i]
        return float(p[0]), float(p[1])


@dataclass
class World:
    """A floor plan with walls, glass and people. Coordinates in metres."""

    name: str
    walls: NDArray[np.float64]  # (K, 4) opaque segments [x1, y1, x2, y2]
    glass: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    people: list[Person] = field(default_factory=list)
    #: probability that a beam passes through glass (and sees what is behind it)
    glass_transmission: float = 0.7
    start: Pose = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        self.walls = np.asarray(self.walls, dtype=np.float64).reshape(-1, 4)
        self.glass = np.asarray(self.glass, dtype=np.float64).reshape(-1, 4)

    @property
    def lines(self) -> NDArray[np.float64]:
        """The floor plan a map maker would draw: walls and glass."""
        return np.vstack([self.walls, self.glass])

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        p = self.lines.reshape(-1, 2)
        return (
            float(p[:, 0].min()),
            float(p[:, 1].min()),
            float(p[:, 0].max()),
            float(p[:, 1].max()),
        )

    def people_at(self, t: float) -> NDArray[np.float64]:
        """(P, 3) people as circles [x, y, radius] at time ``t``."""
        if not self.people:
            return np.zeros((0, 3))
        return np.array([[*p.position(t), p.radius] for p in self.people])

    def ranges(
        self,
        sensor_pose: Sequence[float],
        angles: NDArray[np.float64],
        max_range: float,
        t: float = 0.0,
        rng: np.random.Generator | None = None,
        noise: float = 0.0,
    ) -> NDArray[np.float64]:
        """True (plus Gaussian ``noise``) ranges from ``sensor_pose``; ``inf`` where nothing
        is hit within ``max_range``. Glass is seen or passed per beam at random."""
        r = _raycast(self.walls, sensor_pose, angles, max_range)
        if self.glass.shape[0]:
            rg = _raycast(self.glass, sensor_pose, angles, max_range)
            hit_glass = rg < r
            u = rng.random(angles.shape[0]) if rng is not None else np.zeros(angles.shape[0])
            passes = np.less(u, self.glass_transmission)
            r = np.where(hit_glass & ~passes, rg, r)
        circles = self.people_at(t)
        if circles.shape[0]:
            r = np.minimum(r, ray_circles(sensor_pose, angles, circles))
        if noise > 0.0 and rng is not None:
            fin = np.isfinite(r)
            r = r.copy()
            r[fin] += rng.normal(0.0, noise, int(fin.sum()))
            r[fin] = np.maximum(r[fin], 0.0)
        r[r >= max_range] = np.inf
        return r


def _raycast(
    segs: NDArray[np.float64], pose: Sequence[float], angles: NDArray[np.float64], max_range: float
) -> NDArray[np.float64]:
    if segs.shape[0] == 0:
        return np.full(angles.shape[0], np.inf)
    try:
        from icploc._core import raycast

        return np.asarray(
            raycast(segs, (pose[0], pose[1], pose[2]), angles, max_range), dtype=np.float64
        )
    except ImportError:  # pragma: no cover - the core is always built in practice
        pass
    a = angles + pose[2]
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]
    ex, ey = (segs[:, 2] - segs[:, 0])[None], (segs[:, 3] - segs[:, 1])[None]
    wx, wy = (segs[:, 0] - pose[0])[None], (segs[:, 1] - pose[1])[None]
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
    ok = (np.abs(den) > 1e-12) & (t > 0) & (u >= 0) & (u <= 1)
    r = np.where(ok, t, np.inf).min(axis=1)
    r[r > max_range] = np.inf
    return r


# -- the worlds -----------------------------------------------------------------------------


def lab(people: int = 3, seed: int = 7) -> World:
    """The paper's lab: 7.5 m × 7.5 m (56.25 m²), a 5 m glass wall section on one side,
    some furniture, and ``people`` walking loops through the room. Origin at the room's
    centre, so the robot starts at (0, 0, 0) as in Tables 3–5."""
    h = 3.75
    walls: list[list[float]] = []
    # outer walls; the north wall is glass from x = -2.5 to 2.5 (a 5 m glass section)
    walls += [[-h, -h, h, -h], [h, -h, h, h], [-h, h, -h, -h]]
    walls += [[h, h, 2.5, h], [-2.5, h, -h, h]]
    glass = [[2.5, h, -2.5, h]]
    # a corridor wall 1.5 m behind the glass, visible through it
    walls += [[-h - 0.5, h + 1.5, h + 0.5, h + 1.5]]
    # furniture: desks and a cabinet, a pillar
    walls += _rect(-3.45, -3.45, -2.25, -2.75)
    walls += _rect(2.0, -3.45, 3.45, -2.85)
    walls += _rect(2.95, 0.2, 3.45, 1.7)
    walls += _rect(-3.25, -1.0, -2.75, -0.5)
    walls += [[-3.75, 1.2, -2.6, 1.2]]
    rng = np.random.default_rng(seed)
    persons = []
    loops = [
        [(-2.5, -1.0), (-1.0, 2.5), (1.5, 2.6), (2.3, -0.5), (0.8, -2.4), (-1.8, -2.2)],
        [(2.5, 2.5), (-2.5, 2.5), (-2.5, -0.5), (2.5, -1.0)],
        [(-1.5, 0.0), (0.0, 1.8), (1.8, 0.0), (0.0, -1.0)],
        [(-3.0, 2.6), (3.0, 2.6)],
        [(-2.8, -2.3), (2.8, -2.3)],
        [(0.5, 3.0), (0.5, -2.6)],
    ]
    for i in range(people):
        path = np.array(loops[i % len(loops)], dtype=np.float64)
        persons.append(
            Person(
                path, speed=0.6 + 0.4 * rng.random(), radius=0.22, phase=float(rng.random() * 10)
            )
        )
    return World("lab", np.array(walls), np.array(glass), persons, start=(0.0, 0.0, 0.0))


def crowd(people: int = 12, seed: int = 11) -> World:
    """The lab with a crowd: many people, several of them circling close to the robot."""
    w = lab(people=0)
    rng = np.random.default_rng(seed)
    persons = []
    for i in range(people):
        r = 0.8 + 1.8 * rng.random()
        c = (rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0))
        k = np.linspace(0, 2 * np.pi, 13)[:-1]
        sign = 1 if i % 2 else -1
        path = np.column_stack([c[0] + r * np.cos(sign * k), c[1] + r * np.sin(sign * k)])
        path = np.clip(path, -3.3, 3.3)
        persons.append(
            Person(
                path,
                speed=0.5 + 0.7 * rng.random(),
                radius=0.2 + 0.05 * rng.random(),
                phase=float(rng.random() * 20),
            )
        )
    w.people = persons
    w.name = "crowd"
    return w


def aisles(length: float = 40.0, n_aisles: int = 3, spacing: float = 2.5) -> World:
    """Long parallel shelf aisles (a warehouse): along an aisle every scan looks the same,
    so ICP cannot fix the position along it. End walls exist but lie far beyond range."""
    walls: list[list[float]] = []
    width = n_aisles * spacing
    for i in range(n_aisles + 1):
        y = i * spacing
        # shelves with regular gaps every 4 m (repetitive structure)
        x = 0.0
        while x < length:
            walls.append([x, y, min(x + 3.6, length), y])
            x += 4.0
    walls += [[-2.0, -0.5, -2.0, width + 0.5], [length + 2.0, -0.5, length + 2.0, width + 0.5]]
    walls += [[-2.0, -0.5, length + 2.0, -0.5], [-2.0, width + 0.5, length + 2.0, width + 0.5]]
    return World("aisles", np.array(walls), start=(1.0, spacing / 2, 0.0))


# -- paths ------------------------------------------------------------------------------------


def tour_path(waypoints: Sequence[Sequence[float]], laps: int = 1) -> NDArray[np.float64]:
    """A closed polyline repeated ``laps`` times."""
    w = np.asarray(waypoints, dtype=np.float64)
    return np.vstack([w] * laps + [w[:1]])


def lab_random_walk(length: float = 22.0, seed: int = 3) -> NDArray[np.float64]:
    """A random walk in the lab's free space of at least ``length`` metres, starting and
    ending at the origin (the paper marked the start on the floor and drove back to it)."""
    rng = np.random.default_rng(seed)
    pts = [(0.0, 0.0)]
    total = 0.0
    free = [(-2.0, 2.0), (-2.0, 2.3)]
    while total < length - 3.0:
        for _ in range(100):
            q = (rng.uniform(*free[0]), rng.uniform(*free[1]))
            if math.dist(q, pts[-1]) > 1.2:
                break
        total += math.dist(q, pts[-1])
        pts.append(q)
    pts.append((0.0, 0.0))
    return np.array(pts)


def circle_path(
    radius: float = 1.5, laps: int = 3, center: tuple[float, float] = (0.0, 0.0), n: int = 36
) -> NDArray[np.float64]:
    """``laps`` circles (polyline of ``n`` points per lap) through ``center``, starting
    there heading along +x and turning left."""
    k = np.linspace(0.0, 2.0 * np.pi, n + 1)
    lap = np.column_stack([center[0] + radius * np.sin(k), center[1] + radius * (1.0 - np.cos(k))])
    return np.vstack([lap] * laps)


# -- kinematic simulation -----------------------------------------------------------------------


@dataclass(frozen=True)
class SimFrame:
    """One laser frame of a simulated run."""

    truth: Pose
    odometry: Odometry
    scan: Scan


def _follow(
    path: NDArray[np.float64], start: Pose, speed: float, omega_max: float, dt: float
) -> Iterator[tuple[float, float]]:
    """A pure-pursuit controller along ``path``: yields (v, w) commands per step."""
    x, y, th = start
    i = 1
    while i < len(path):
        tx, ty = path[i]
        d = math.hypot(tx - x, ty - y)
        if d < 0.15:
            i += 1
            continue
        err = wrap_angle(math.atan2(ty - y, tx - x) - th)
        w = max(-omega_max, min(omega_max, 2.5 * err))
        v = speed * max(0.0, math.cos(err)) ** 4 * min(1.0, d / 0.3 + 0.3)
        yield v, w
        x += v * dt * math.cos(th + 0.5 * w * dt)
        y += v * dt * math.sin(th + 0.5 * w * dt)
        th = wrap_angle(th + w * dt)


def simulate(
    world: World,
    path: NDArray[np.float64],
    *,
    start: Pose | None = None,
    rate: float = 12.5,
    speed: float = 0.5,
    omega_max: float = 1.0,
    beams: int = 361,
    fov: float = math.pi,
    max_range: float = 8.0,
    noise: float = 0.02,
    odom_scale_error: tuple[float, float] = (0.004, -0.003),
    odom_noise: float = 0.003,
    laser_offset: Pose = (0.0, 0.0, 0.0),
    seed: int = 0,
    max_frames: int | None = None,
) -> Iterator[SimFrame]:
    """Drive along ``path`` with a pure-pursuit controller; at ``rate`` Hz yield the true
    base pose, wheel odometry (per-wheel scale errors ``odom_scale_error`` and random noise
    ``odom_noise`` per metre: it drifts) and a scan of ``beams`` beams over ``fov``."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate
    pose = start if start is not None else (float(path[0, 0]), float(path[0, 1]), world.start[2])
    odo: Pose = (0.0, 0.0, 0.0)
    angles = np.linspace(-fov / 2, fov / 2, beams)
    axle = 0.5
    t = 0.0
    n = 0
    for v, w in _follow(path, pose, speed, omega_max, dt):
        # true motion
        pose = (
            pose[0] + v * dt * math.cos(pose[2] + 0.5 * w * dt),
            pose[1] + v * dt * math.sin(pose[2] + 0.5 * w * dt),
            wrap_angle(pose[2] + w * dt),
        )
        # odometry from the wheels with scale errors and noise
        vl, vr = (v - 0.5 * axle * w) * dt, (v + 0.5 * axle * w) * dt
        vl *= 1.0 + odom_scale_error[0]
        vr *= 1.0 + odom_scale_error[1]
        vl += rng.normal(0.0, odom_noise * math.sqrt(abs(vl)) + 1e-5)
        vr += rng.normal(0.0, odom_noise * math.sqrt(abs(vr)) + 1e-5)
        ds, dth = 0.5 * (vl + vr), (vr - vl) / axle
        odo = compose(odo, (ds * math.cos(0.5 * dth), ds * math.sin(0.5 * dth), dth))
        t += dt
        sensor = compose(pose, laser_offset)
        r = world.ranges(sensor, angles, max_range, t, rng, noise)
        flags = np.where(np.isfinite(r), 0, BEAM_NO_RETURN).astype(np.uint8)
        yield SimFrame(
            truth=pose,
            odometry=Odometry(stamp=t, pose=odo),
            scan=Scan(stamp=t, ranges=r, angles=angles, flags=flags, seq=n, max_range=max_range),
        )
        n += 1
        if max_frames is not None and n >= max_frames:
            return

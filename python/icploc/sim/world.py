"""A simulated 2D world for the device simulators: static walls, glass, moving people.

* walls: (K, 4) segments ``[x1, y1, x2, y2]`` in metres, ray-cast by the Rust core
  (:func:`icploc.raycast`);
* glass: (G, 4) segments the laser sees through, except near normal incidence
  (``|cos(incidence)| >= glass_normal_cos``) or, per beam, with probability
  ``glass_reflect_prob``;
* people: circles walking along polylines (looping), deterministic from a seed.

:meth:`World.scan` returns ranges (``inf`` = no return within ``max_range``) for beams
at ``angles`` (sensor frame) from a sensor ``pose`` at simulated time ``t``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray


def _raycast(segments: NDArray[np.float64], pose: Sequence[float], angles: NDArray[np.float64],
             max_range: float) -> NDArray[np.float64]:  # fmt: skip
    if segments.shape[0] == 0:
        return np.full(angles.shape[0], np.inf)
    from icploc import raycast

    return np.asarray(raycast(segments, (float(pose[0]), float(pose[1]), float(pose[2])), angles, max_range),
                      dtype=np.float64)  # fmt: skip


def ray_segments(pose: Sequence[float], angles: NDArray[np.float64], segments: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Nearest hit distance along each beam and |cos| of the incidence angle there
    (numpy; used for glass, which needs the incidence)."""
    n = angles.shape[0]
    if segments.shape[0] == 0:
        return np.full(n, np.inf), np.zeros(n)
    a = angles + pose[2]
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]
    ex = (segments[:, 2] - segments[:, 0])[None]
    ey = (segments[:, 3] - segments[:, 1])[None]
    wx = (segments[:, 0] - pose[0])[None]
    wy = (segments[:, 1] - pose[1])[None]
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wx * ey - wy * ex) / den
        u = (wx * dy - wy * dx) / den
    ok = (np.abs(den) > 1e-12) & (t > 1e-9) & (u >= 0) & (u <= 1)
    t = np.where(ok, t, np.inf)
    k = np.argmin(t, axis=1)
    r = t[np.arange(n), k]
    seg_len = np.hypot(ex[0, k], ey[0, k])
    # |cos(incidence)| = |d x e| / |e|  (angle between beam and segment normal)
    cosi = np.abs(den[np.arange(n), k]) / np.maximum(seg_len, 1e-12)
    return r, np.where(np.isfinite(r), cosi, 0.0)


def ray_circles(
    pose: Sequence[float], angles: NDArray[np.float64], circles: NDArray[np.float64]
) -> NDArray[np.float64]:
    """Distance along each beam to the nearest of the (P, 3) circles ``[x, y, r]``."""
    if circles.shape[0] == 0:
        return np.full(angles.shape[0], np.inf)
    a = angles + pose[2]
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]
    ox = pose[0] - circles[None, :, 0]
    oy = pose[1] - circles[None, :, 1]
    b = ox * dx + oy * dy
    c = ox * ox + oy * oy - circles[None, :, 2] ** 2
    disc = b * b - c
    with np.errstate(invalid="ignore"):
        t = -b - np.sqrt(disc)
    ok = (disc >= 0) & (t > 0)
    return np.where(ok, t, np.inf).min(axis=1)


@dataclass
class Person:
    """A circle walking along a closed polyline at constant speed."""

    path: NDArray[np.float64]
    speed: float = 0.8
    radius: float = 0.25
    phase: float = 0.0  #: metres along the path at t = 0

    def __post_init__(self) -> None:
        self.path = np.asarray(self.path, dtype=np.float64).reshape(-1, 2)
        closed = np.vstack([self.path, self.path[:1]])
        seg = np.diff(closed, axis=0)
        self._seg = seg
        self._len = np.hypot(seg[:, 0], seg[:, 1])
        self._cum = np.concatenate([[0.0], np.cumsum(self._len)])

    def position(self, t: float) -> tuple[float, float]:
        total = float(self._cum[-1])
        if total <= 0:
            return float(self.path[0, 0]), float(self.path[0, 1])
        s = (self.phase + self.speed * t) % total
        i = min(int(np.searchsorted(self._cum, s, side="right")) - 1, len(self._len) - 1)
        f = (s - self._cum[i]) / max(float(self._len[i]), 1e-12)
        p = self.path[i] + f * self._seg[i]
        return float(p[0]), float(p[1])


@dataclass
class World:
    """Static walls (K, 4), optional glass (G, 4) and moving people."""

    walls: NDArray[np.float64]
    glass: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    people: list[Person] = field(default_factory=list)
    glass_normal_cos: float = math.cos(math.radians(10.0))  #: reflect within 10° of normal
    glass_reflect_prob: float = 0.0

    def __post_init__(self) -> None:
        self.walls = np.asarray(self.walls, dtype=np.float64).reshape(-1, 4)
        self.glass = np.asarray(self.glass, dtype=np.float64).reshape(-1, 4)

    @classmethod
    def box(cls, width: float = 10.0, height: float = 8.0, **kw: object) -> World:
        """A closed rectangular room with its lower-left corner at the origin."""
        w, h = width, height
        walls = [[0, 0, w, 0], [w, 0, w, h], [w, h, 0, h], [0, h, 0, 0]]
        return cls(np.array(walls, dtype=np.float64), **kw)  # type: ignore[arg-type]

    def add_random_people(self, n: int, seed: int, bounds: tuple[float, float, float, float] | None = None,
                          speed: tuple[float, float] = (0.4, 1.2), radius: float = 0.25) -> None:  # fmt: skip
        """Add ``n`` people walking random 4-point loops inside ``bounds`` (default: the
        walls' bounding box shrunk by 1 m); deterministic from ``seed``."""
        rng = np.random.default_rng(seed)
        x0, y0, x1, y1 = bounds or self.bounds(margin=-1.0)
        for _ in range(n):
            pts = np.column_stack([rng.uniform(x0, x1, 4), rng.uniform(y0, y1, 4)])
            self.people.append(
                Person(pts, float(rng.uniform(*speed)), radius, float(rng.uniform(0, 10)))
            )

    def bounds(self, margin: float = 0.0) -> tuple[float, float, float, float]:
        p = np.vstack([self.walls, self.glass]).reshape(-1, 2)
        if p.shape[0] == 0:
            return (-margin, -margin, margin, margin)
        return (float(p[:, 0].min()) - margin, float(p[:, 1].min()) - margin,
                float(p[:, 0].max()) + margin, float(p[:, 1].max()) + margin)  # fmt: skip

    @property
    def lines(self) -> NDArray[np.float64]:
        """What a map maker would draw: walls and glass."""
        return np.vstack([self.walls, self.glass])

    def people_at(self, t: float) -> NDArray[np.float64]:
        if not self.people:
            return np.zeros((0, 3))
        return np.array([[*p.position(t), p.radius] for p in self.people], dtype=np.float64)

    def scan(
        self,
        pose: Sequence[float],
        angles: ArrayLike,
        max_range: float,
        noise_std: float = 0.0,
        rng: np.random.Generator | None = None,
        t: float = 0.0,
    ) -> NDArray[np.float64]:
        """Ranges (m) from a sensor at ``pose`` (world frame) along ``angles`` (sensor
        frame); ``inf`` where nothing is hit within ``max_range``."""
        ang = np.asarray(angles, dtype=np.float64)
        r = _raycast(self.walls, pose, ang, max_range)
        if self.glass.shape[0]:
            rg, cosi = ray_segments(pose, ang, self.glass)
            reflect = cosi >= self.glass_normal_cos
            if self.glass_reflect_prob > 0 and rng is not None:
                reflect |= rng.random(ang.shape[0]) < self.glass_reflect_prob
            r = np.where((rg < r) & reflect, rg, r)
        circles = self.people_at(t)
        if circles.shape[0]:
            r = np.minimum(r, ray_circles(pose, ang, circles))
        if noise_std > 0.0:
            if rng is None:
                rng = np.random.default_rng()
            fin = np.isfinite(r)
            r = r.copy()
            r[fin] = np.maximum(r[fin] + rng.normal(0.0, noise_std, int(fin.sum())), 0.0)
        r = np.asarray(r, dtype=np.float64)
        r[r >= max_range] = np.inf
        return r

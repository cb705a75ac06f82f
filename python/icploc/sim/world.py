"""The simulated 2D world: static walls, glass, moving people, with exact truth.

* walls: (K, 4) opaque segments ``[x1, y1, x2, y2]`` in metres, ray-cast by the Rust
  core (:func:`icploc.raycast`);
* glass: (G, 4) segments the laser may see through; what it does there is the world's
  glass model, one of

  - :class:`RandomGlass` (the default): per beam, the laser passes through with
    probability ``transmission`` and sees what lies behind, else the glass returns it
    (the paper's glass-wall experiment, Fig. 11);
  - :class:`IncidenceGlass`: the laser passes through except near normal incidence
    (``|cos(incidence)| >= normal_cos``) or, per beam, with probability ``reflect_prob``;
* people: circles walking closed polylines, deterministic from their phase.

:meth:`World.ranges` returns ranges (``inf`` = no return within ``max_range``) for
beams at ``angles`` (sensor frame) from a sensor ``pose`` at simulated time ``t``. The
built-in worlds are in :mod:`icploc.sim.scenes`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.se2 import Pose

__all__ = [
    "GlassModel",
    "IncidenceGlass",
    "Person",
    "RandomGlass",
    "World",
    "ray_circles",
    "ray_segments",
]


def _raycast(segments: NDArray[np.float64], pose: Sequence[float], angles: NDArray[np.float64],
             max_range: float) -> NDArray[np.float64]:  # fmt: skip
    if segments.shape[0] == 0:
        return np.full(angles.shape[0], np.inf)
    from icploc._core import raycast

    return np.asarray(raycast(segments, (float(pose[0]), float(pose[1]), float(pose[2])), angles, max_range),
                      dtype=np.float64)  # fmt: skip


def ray_segments(pose: Sequence[float], angles: NDArray[np.float64], segments: NDArray[np.float64]
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:  # fmt: skip
    """Nearest hit distance along each beam and |cos| of the incidence angle there
    (numpy; used for glass under :class:`IncidenceGlass`, which needs the incidence)."""
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


# -- glass ----------------------------------------------------------------------------------


class GlassModel(Protocol):
    """What glass does to a beam that reaches it: return it (the laser sees the glass)
    or let it pass (the laser sees what lies behind). ``incidence``: the model needs the
    |cos| of each beam's incidence angle on the glass."""

    incidence: bool

    def returned(
        self, cos_incidence: NDArray[np.float64] | None, n: int, rng: np.random.Generator | None
    ) -> NDArray[np.bool_]:
        """Per beam (``n`` of them): True where the glass returns it."""
        ...


@dataclass(frozen=True)
class RandomGlass:
    """Per beam, the laser passes through glass with probability ``transmission`` and
    sees what lies behind; otherwise the glass returns it. Without a random generator
    every beam passes (``transmission`` > 0) or none does."""

    transmission: float = 0.7
    incidence = False

    def returned(
        self, cos_incidence: NDArray[np.float64] | None, n: int, rng: np.random.Generator | None
    ) -> NDArray[np.bool_]:
        u = rng.random(n) if rng is not None else np.zeros(n)
        return ~np.less(u, self.transmission)


@dataclass(frozen=True)
class IncidenceGlass:
    """The laser passes through glass except within ``acos(normal_cos)`` of normal
    incidence (default 10°) or, per beam, with probability ``reflect_prob``."""

    normal_cos: float = math.cos(math.radians(10.0))
    reflect_prob: float = 0.0
    incidence = True

    def returned(
        self, cos_incidence: NDArray[np.float64] | None, n: int, rng: np.random.Generator | None
    ) -> NDArray[np.bool_]:
        assert cos_incidence is not None
        reflect = cos_incidence >= self.normal_cos
        if self.reflect_prob > 0 and rng is not None:
            reflect |= rng.random(n) < self.reflect_prob
        return reflect


# -- people and the world -------------------------------------------------------------------


@dataclass
class Person:
    """A person (a circle) walking a closed polyline at constant speed."""

    path: NDArray[np.float64]  #: (K, 2) closed loop (the last point joins the first)
    speed: float = 0.8
    radius: float = 0.25
    phase: float = 0.0  #: metres along the path at t = 0

    def __post_init__(self) -> None:
        self.path = np.asarray(self.path, dtype=np.float64).reshape(-1, 2)
        seg = np.diff(np.vstack([self.path, self.path[:1]]), axis=0)
        self._seg = seg
        self._len = np.hypot(seg[:, 0], seg[:, 1])
        self._cum = np.concatenate([[0.0], np.cumsum(self._len)])

    def position(self, t: float) -> tuple[float, float]:
        total = float(self._cum[-1])
        if total <= 0.0:
            return float(self.path[0, 0]), float(self.path[0, 1])
        s = (self.phase + self.speed * t) % total
        i = min(int(np.searchsorted(self._cum, s, side="right")) - 1, len(self._len) - 1)
        f = (s - self._cum[i]) / max(float(self._len[i]), 1e-12)
        p = self.path[i] + f * self._seg[i]
        return float(p[0]), float(p[1])


@dataclass
class World:
    """A floor plan with walls, glass and people; coordinates in metres. ``start`` is
    where a robot in this world starts by default."""

    name: str
    walls: NDArray[np.float64]  #: (K, 4) opaque segments [x1, y1, x2, y2]
    glass: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 4)))
    people: list[Person] = field(default_factory=list)
    glass_model: GlassModel = field(default_factory=RandomGlass)
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
        """(xmin, ymin, xmax, ymax) of walls and glass; all zero for an empty world."""
        p = self.lines.reshape(-1, 2)
        if p.shape[0] == 0:
            return (0.0, 0.0, 0.0, 0.0)
        return (float(p[:, 0].min()), float(p[:, 1].min()),
                float(p[:, 0].max()), float(p[:, 1].max()))  # fmt: skip

    def add_random_people(self, n: int, seed: int, bounds: tuple[float, float, float, float] | None = None,
                          speed: tuple[float, float] = (0.4, 1.2), radius: float = 0.25) -> None:  # fmt: skip
        """Add ``n`` people walking random 4-point loops inside ``bounds`` (default: the
        floor plan's bounding box shrunk by 1 m); deterministic from ``seed``."""
        rng = np.random.default_rng(seed)
        if bounds is None:
            b = self.bounds
            bounds = (b[0] + 1.0, b[1] + 1.0, b[2] - 1.0, b[3] - 1.0)
        x0, y0, x1, y1 = bounds
        for _ in range(n):
            pts = np.column_stack([rng.uniform(x0, x1, 4), rng.uniform(y0, y1, 4)])
            self.people.append(
                Person(pts, float(rng.uniform(*speed)), radius, float(rng.uniform(0, 10)))
            )

    def people_at(self, t: float) -> NDArray[np.float64]:
        """(P, 3) people as circles [x, y, radius] at time ``t``."""
        if not self.people:
            return np.zeros((0, 3))
        return np.array([[*p.position(t), p.radius] for p in self.people], dtype=np.float64)

    def ranges(
        self,
        sensor_pose: Sequence[float],
        angles: ArrayLike,
        max_range: float,
        t: float = 0.0,
        rng: np.random.Generator | None = None,
        noise: float = 0.0,
    ) -> NDArray[np.float64]:
        """True (plus Gaussian ``noise``, which needs ``rng``) ranges (m) from a sensor at
        ``sensor_pose`` (world frame) along ``angles`` (sensor frame); ``inf`` where
        nothing is hit within ``max_range``. Glass as the :attr:`glass_model` says."""
        ang = np.asarray(angles, dtype=np.float64)
        if noise > 0.0 and rng is None:
            raise ValueError("World.ranges: range noise needs a random generator (rng=)")
        r = _raycast(self.walls, sensor_pose, ang, max_range)
        if self.glass.shape[0]:
            cosi: NDArray[np.float64] | None = None
            if self.glass_model.incidence:  # numpy: the Rust ray caster gives no incidence
                rg, cosi = ray_segments(sensor_pose, ang, self.glass)
            else:
                rg = _raycast(self.glass, sensor_pose, ang, max_range)
            returned = self.glass_model.returned(cosi, ang.shape[0], rng)
            r = np.where((rg < r) & returned, rg, r)
        circles = self.people_at(t)
        if circles.shape[0]:
            r = np.minimum(r, ray_circles(sensor_pose, ang, circles))
        if noise > 0.0 and rng is not None:
            fin = np.isfinite(r)
            r = r.copy()
            r[fin] = np.maximum(r[fin] + rng.normal(0.0, noise, int(fin.sum())), 0.0)
        r = np.asarray(r, dtype=np.float64)
        r[r >= max_range] = np.inf
        return r

"""Built-in worlds with exact truth, and paths to drive through them.

Worlds: :func:`lab` (the paper's lab: 7.5 m x 7.5 m with a 5 m glass wall and walking
people), :func:`crowd` (the lab full of people), :func:`aisles` (long repetitive shelf
aisles), :func:`box` (a closed rectangular room), :func:`from_plan` (any floor plan, e.g.
the clinic and warehouse families of ``benches/scenario.py``).

Paths (polylines for :func:`icploc.sim.kinematic.simulate` and the device simulators'
pure pursuit): :func:`lab_random_walk` (a :func:`random_walk` in the lab), :func:`circle_path`,
:func:`tour_path`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.se2 import Pose
from icploc.sim.world import GlassModel, Person, RandomGlass, World


def rect(x0: float, y0: float, x1: float, y1: float) -> list[list[float]]:
    """The four sides of an axis-aligned rectangle as segments [x1, y1, x2, y2]."""
    return [[x0, y0, x1, y0], [x1, y0, x1, y1], [x1, y1, x0, y1], [x0, y1, x0, y0]]


def box(
    width: float = 10.0,
    height: float = 8.0,
    *,
    glass: ArrayLike | None = None,
    people: list[Person] | None = None,
    glass_model: GlassModel | None = None,
    name: str = "box",
) -> World:
    """A closed rectangular room with its lower-left corner at the origin."""
    return World(
        name,
        np.array(rect(0.0, 0.0, width, height), dtype=np.float64),
        np.zeros((0, 4)) if glass is None else np.asarray(glass, dtype=np.float64),
        people if people is not None else [],
        glass_model if glass_model is not None else RandomGlass(),
    )


def from_plan(
    name: str,
    walls: ArrayLike,
    glass: ArrayLike | None = None,
    *,
    start: Pose = (0.0, 0.0, 0.0),
    glass_model: GlassModel | None = None,
) -> World:
    """A world from a floor plan: (K, 4) opaque ``walls`` and (G, 4) ``glass`` segments,
    e.g. ``from_plan(w.name, w.opaque, w.glass)`` for a ``benches/scenario.py`` world."""
    return World(
        name,
        np.asarray(walls, dtype=np.float64),
        np.zeros((0, 4)) if glass is None else np.asarray(glass, dtype=np.float64),
        [],
        glass_model if glass_model is not None else RandomGlass(),
        start,
    )


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
    walls += rect(-3.45, -3.45, -2.25, -2.75)
    walls += rect(2.0, -3.45, 3.45, -2.85)
    walls += rect(2.95, 0.2, 3.45, 1.7)
    walls += rect(-3.25, -1.0, -2.75, -0.5)
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
    return World("lab", np.array(walls), np.array(glass), persons, RandomGlass(0.7), (0.0, 0.0, 0.0))


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
    return random_walk(length, seed, box=((-2.0, 2.0), (-2.0, 2.3)))


def random_walk(
    length: float,
    seed: int,
    box: tuple[tuple[float, float], tuple[float, float]],
    start: Sequence[tuple[float, float]] = ((0.0, 0.0),),
) -> NDArray[np.float64]:
    """Waypoints of a random walk of at least ``length`` metres: from the polyline
    ``start``, each next waypoint drawn uniformly in ``box`` ((x min, x max), (y min,
    y max)), more than 1.2 m from the one before (100 tries), until 3 m short of
    ``length``; then back to the origin."""
    rng = np.random.default_rng(seed)
    pts = list(start)
    total = sum(math.dist(a, b) for a, b in zip(pts, pts[1:], strict=False))
    while total < length - 3.0:
        for _ in range(100):
            q = (float(rng.uniform(*box[0])), float(rng.uniform(*box[1])))
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

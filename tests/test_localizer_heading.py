"""A prediction whose heading is off after a turn (odometry with a rotation scale error)."""

from __future__ import annotations

import math

import numpy as np
from icploc import sim as worlds
from icploc.localizer import Localizer
from icploc.messages import Scan
from icploc.se2 import wrap_angle
from sampled_walls import walls_index as sample_lines

ANGLES = np.linspace(-math.pi / 2, math.pi / 2, 361)


def scan_at(world: worlds.World, pose: tuple[float, float, float], stamp: float) -> Scan:
    r = world.ranges(pose, ANGLES, 8.0, stamp, np.random.default_rng(0), 0.0)
    return Scan(stamp=stamp, ranges=r, angles=ANGLES, max_range=8.0)


def pillar_field(spacing: float = 1.0, half: float = 0.1) -> worlds.World:
    """Square pillars on a regular grid and nothing else: turned by a few tenths of a
    radian, the scan lines its beams up with neighbouring pillars as well."""
    walls = []
    for i in range(-5, 6):
        for j in range(-5, 6):
            if i == 0 and j == 0:
                continue
            cx, cy = i * spacing + 0.5, j * spacing + 0.5
            a, b = (cx - half, cy - half), (cx + half, cy - half)
            c, d = (cx + half, cy + half), (cx - half, cy + half)
            walls += [[*a, *b], [*b, *c], [*c, *d], [*d, *a]]
    return worlds.World("pillars", np.array(walls, dtype=float))


def test_a_turn_the_odometry_under_reports_does_not_turn_the_pose_off() -> None:
    """Edmonton, bad odometry base (rotation scale -5 %): after a turn the prediction's
    heading was a tenth of a radian off, point-to-line from there settled in a minimum
    that half explains the scan, the heading error stayed in the pose and the next steps'
    dead reckoning carried it metres off. Here the robot spins 1.6 rad a scan in a field of
    pillars while the odometry reports 15 % less: the fit from the prediction does not
    verify, the one retried from the prediction turned by its heading uncertainty does,
    and the heading stays right."""
    world = pillar_field()
    loc = Localizer(sample_lines(world.lines), initial_pose=(0.0, 0.0, 0.0))
    for k in range(5):
        loc.update(scan_at(world, (0.0, 0.0, 0.0), 0.1 * k), (0.0, 0.0, 0.0))
    heading_errors = []
    for k in range(1, 4):
        truth = (0.0, 0.0, 1.6 * k)
        e = loc.update(scan_at(world, truth, 1.0 + 0.1 * k), (0.0, 0.0, 0.85 * 1.6 * k))
        heading_errors.append(abs(wrap_angle(e.pose[2] - truth[2])))
    assert max(heading_errors) < math.radians(0.5)

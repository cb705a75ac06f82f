"""A fast kinematic stand-in for the device simulators: :func:`simulate` drives a robot
along a path through a :class:`~icploc.sim.world.World` and yields, at the laser rate,
the true pose, drifting wheel odometry and a noisy scan. Used by the benchmarks and tests;
the demo drives the same worlds through the real drivers and the pty device simulators
(:mod:`icploc.sim.harness`).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from icploc.messages import BEAM_NO_RETURN, Odometry, Scan
from icploc.se2 import Pose, compose, wrap_angle
from icploc.sim.pursuit import PurePursuit
from icploc.sim.world import World

__all__ = ["SimFrame", "simulate"]


@dataclass(frozen=True)
class SimFrame:
    """One laser frame of a simulated run."""

    truth: Pose
    odometry: Odometry
    scan: Scan


def _follow(
    path: NDArray[np.float64], start: Pose, speed: float, omega_max: float, dt: float
) -> Iterator[tuple[float, float]]:
    """Pure pursuit along ``path`` on the pose it integrates itself: (v, w) per step."""
    pursuit = PurePursuit(path, speed=speed, omega_max=omega_max, tolerance=0.15, approach=0.3,
                          brake=None)  # fmt: skip
    x, y, th = start
    while (cmd := pursuit.command((x, y, th))) is not None:
        v, w = cmd
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

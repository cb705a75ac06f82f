"""A differential-drive robot with PowerBot dimensions, acceleration limits and noisy
wheel encoders: a true pose (what the world sees) and an odometry pose (what the
controller reports).

Dimensions from PROTOCOLS.md §B.8 (ARIA ``powerbot.p``): radius 550 mm, width 680 mm,
length 911 mm, maximum 2000 mm/s and 360 °/s; the effective wheel base 2 / DiffConvFactor
= 2 / 0.00373 ≈ 536 mm is derived, not sourced. Acceleration limits are our own choice.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from icploc.se2 import wrap_angle


@dataclass(frozen=True)
class RobotGeometry:
    wheel_base: float = 2.0 / 0.00373 / 1000.0  #: m (derived from DiffConvFactor)
    radius: float = 0.550
    width: float = 0.680
    length: float = 0.911
    max_velocity: float = 2.0  #: m/s
    max_rot_velocity: float = math.radians(360.0)
    trans_accel: float = 1.0  #: m/s^2
    trans_decel: float = 1.5
    rot_accel: float = math.radians(200.0)  #: rad/s^2
    laser_x: float = 0.251  #: laser mount, m ahead of the centre
    laser_flipped: bool = True


POWERBOT_GEOMETRY = RobotGeometry()


@dataclass
class EncoderNoise:
    """Per-step relative noise on each wheel's travel plus systematic calibration error."""

    relative_std: float = 0.01
    left_scale: float = 1.0
    right_scale: float = 1.0
    wheel_base_scale: float = 1.0


def _ramp(cur: float, target: float, up: float, down: float, dt: float) -> float:
    if target == cur:
        return cur
    rate = up if abs(target) > abs(cur) and target * cur >= 0 else down
    step = rate * dt
    if abs(target - cur) <= step:
        return target
    return cur + math.copysign(step, target - cur)


@dataclass
class DiffDriveRobot:
    """Integrates commanded velocities into a true pose and a noisy odometry pose.

    :attr:`time` is the robot's simulated time (s). The device simulators, each in its
    own thread, call :meth:`advance_to` with their current time before they sample the
    pose (laser) or report odometry (base), so truth, scans and odometry all follow one
    continuous motion. Hold :attr:`lock` to read a consistent state after advancing.
    """

    pose: tuple[float, float, float] = (0.0, 0.0, 0.0)  #: true pose in the world (m, rad)
    geometry: RobotGeometry = POWERBOT_GEOMETRY
    noise: EncoderNoise = field(default_factory=EncoderNoise)
    seed: int = 0
    #: optional predicate: True if the robot at this pose would hit something
    collides: Callable[[tuple[float, float, float]], bool] | None = None

    def __post_init__(self) -> None:
        self.rng = np.random.default_rng(self.seed)
        self.odom = (0.0, 0.0, 0.0)  #: odometry pose (m, rad), starts at 0
        self.v_cmd = 0.0
        self.w_cmd = 0.0
        self.v = 0.0
        self.w = 0.0
        self.left_speed = 0.0  #: measured wheel speeds, m/s
        self.right_speed = 0.0
        self.enabled = True
        self.estopped = False
        self.left_stall = False
        self.right_stall = False
        self.time = 0.0  #: simulated time (s) the pose and odometry belong to
        self.distance = 0.0
        self.lock = threading.RLock()
        #: host clock reading at robot time 0 (real-time mode, set by :meth:`clock_time`)
        self.clock_origin: float | None = None

    def set_velocity(self, v: float, w: float) -> None:
        g = self.geometry
        with self.lock:
            self.v_cmd = max(-g.max_velocity, min(g.max_velocity, v))
            self.w_cmd = max(-g.max_rot_velocity, min(g.max_rot_velocity, w))
            self.estopped = False

    def set_wheels(self, left: float, right: float) -> None:
        b = self.geometry.wheel_base
        self.set_velocity((left + right) / 2.0, (right - left) / b)

    def stop(self) -> None:
        with self.lock:
            self.v_cmd = 0.0
            self.w_cmd = 0.0

    def e_stop(self) -> None:
        with self.lock:
            self.v_cmd = self.w_cmd = self.v = self.w = 0.0
            self.estopped = True

    def reset_odometry(self, odom: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
        with self.lock:
            self.odom = odom

    def clock_time(self, now: float) -> float:
        """Robot time at host clock reading ``now`` (real-time mode): the first call ties
        the current :attr:`time` to ``now``, so every device maps the shared clock alike."""
        with self.lock:
            if self.clock_origin is None:
                self.clock_origin = now - self.time
            return now - self.clock_origin

    def advance_to(self, t: float, max_step: float = 0.02) -> None:
        """Integrate the motion with the current commands up to simulated time ``t``
        (nothing if the robot is already there). Steps end on the grid of multiples of
        ``max_step`` (and at ``t``), so callers on that grid (test mode: SIPs every 0.1 s,
        scans every 0.04 s) get the same integration however their calls interleave."""
        with self.lock:
            while t - self.time > 1e-9:
                nxt = (math.floor(self.time / max_step + 1e-6) + 1) * max_step
                target = min(t, nxt)
                self.step(target - self.time)
                self.time = target

    def step(self, dt: float) -> None:
        """Advance ``dt`` seconds."""
        if dt <= 0:
            return
        g = self.geometry
        v_t, w_t = (self.v_cmd, self.w_cmd) if self.enabled and not self.estopped else (0.0, 0.0)
        self.v = _ramp(self.v, v_t, g.trans_accel, g.trans_decel, dt)
        self.w = _ramp(self.w, w_t, g.rot_accel, g.rot_accel, dt)
        b = g.wheel_base
        dl = (self.v - self.w * b / 2.0) * dt
        dr = (self.v + self.w * b / 2.0) * dt
        new = _arc(self.pose, dl, dr, b)
        if self.collides is not None and (dl or dr) and self.collides(new):
            self.v = self.w = 0.0
            self.left_stall = self.right_stall = True
            dl = dr = 0.0
        else:
            self.left_stall = self.right_stall = False
            self.pose = new
        n = self.noise
        s = n.relative_std
        ml = dl * n.left_scale * (1.0 + (self.rng.normal(0.0, s) if s > 0 else 0.0))
        mr = dr * n.right_scale * (1.0 + (self.rng.normal(0.0, s) if s > 0 else 0.0))
        self.odom = _arc(self.odom, ml, mr, b * n.wheel_base_scale)
        self.left_speed = ml / dt
        self.right_speed = mr / dt
        self.time += dt
        self.distance += abs(dl + dr) / 2.0


def _arc(
    pose: tuple[float, float, float], dl: float, dr: float, b: float
) -> tuple[float, float, float]:
    """Exact differential-drive motion for wheel travels dl, dr (constant over the step)."""
    x, y, th = pose
    ds = (dl + dr) / 2.0
    dth = (dr - dl) / b
    if abs(dth) < 1e-9:
        return (x + ds * math.cos(th), y + ds * math.sin(th), wrap_angle(th))
    rad = ds / dth
    return (x + rad * (math.sin(th + dth) - math.sin(th)), y - rad * (math.cos(th + dth) - math.cos(th)),
            wrap_angle(th + dth))  # fmt: skip

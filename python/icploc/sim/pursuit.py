"""Pure pursuit along a polyline: the one path follower of the simulators.

:class:`PurePursuit` turns a pose into a velocity command towards the next waypoint of a
path (turn towards it, slow down while the heading is off and near the waypoint, move to
the next one within ``tolerance``). The kinematic simulator
(:func:`icploc.sim.kinematic.simulate`) feeds it its own integrated pose;
:class:`PursuitPlan` feeds it the device simulator's true pose (a person with a joystick).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.se2 import wrap_angle

__all__ = ["PurePursuit", "PursuitPlan"]


@dataclass
class PurePursuit:
    """A pure-pursuit controller along ``path`` ((N, 2) waypoints; it starts heading for
    the second). :meth:`command` returns ``(v m/s, w rad/s)``, or None once the last
    waypoint is reached.

    * ``w`` = ``gain`` x heading error, clipped to ``omega_max``;
    * ``v`` = ``speed`` x cos(heading error)^4 x min(1, d / ``approach`` + 0.3) at
      distance ``d`` from the waypoint;
    * ``brake`` (m/s², or None): on the last leg ``v`` is kept low enough to stop there.
    """

    path: NDArray[np.float64]
    speed: float = 0.6
    omega_max: float = 1.2
    tolerance: float = 0.12
    approach: float = 0.4
    brake: float | None = 1.0
    gain: float = 2.5
    #: index of the waypoint being approached
    i: int = field(default=1, init=False)

    def __post_init__(self) -> None:
        self.path = np.asarray(self.path, dtype=np.float64).reshape(-1, 2)

    @property
    def done(self) -> bool:
        return self.i >= len(self.path)

    def command(self, pose: Sequence[float]) -> tuple[float, float] | None:
        """The command at ``pose`` (x, y, theta); None when the path is done."""
        x, y, th = pose[0], pose[1], pose[2]
        while self.i < len(self.path):
            tx, ty = self.path[self.i]
            d = math.hypot(tx - x, ty - y)
            if d >= self.tolerance:
                break
            self.i += 1
        else:
            return None
        err = wrap_angle(math.atan2(ty - y, tx - x) - th)
        w = max(-self.omega_max, min(self.omega_max, self.gain * err))
        v = self.speed * max(0.0, math.cos(err)) ** 4 * min(1.0, d / self.approach + 0.3)
        if self.brake is not None and self.i == len(self.path) - 1:
            v = min(v, 0.7 * math.sqrt(2.0 * self.brake * d) + 0.05)
        return (v, w)


class PursuitPlan:
    """A velocity plan for the simulated base (``t -> (v, w)``, see
    :data:`icploc.sim.powerbot_device.VelocityPlan`): :class:`PurePursuit` along
    ``path`` on the simulator's true pose (``pose()``), then stop. :attr:`done` is set
    when the last waypoint is reached."""

    def __init__(
        self,
        path: ArrayLike,
        pose: Callable[[], Sequence[float]],
        speed: float = 0.6,
        omega_max: float = 1.2,
        tolerance: float = 0.12,
    ) -> None:
        self.pursuit = PurePursuit(np.asarray(path, dtype=np.float64), speed=speed,
                                   omega_max=omega_max, tolerance=tolerance)  # fmt: skip
        self.pose = pose
        self.done = threading.Event()

    def __call__(self, t: float) -> tuple[float, float]:
        cmd = None if self.pursuit.done else self.pursuit.command(self.pose())
        if cmd is None:
            self.done.set()
            return (0.0, 0.0)
        return cmd

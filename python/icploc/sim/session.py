"""A whole simulated robot on two pseudo-terminals: a PLS and a PowerBot device
simulator driven by one world and one robot, in background threads.

>>> from icploc.sim.session import SimSession
>>> from icploc.sim.scenes import box
>>> from icploc.drivers.sick import PLS
>>> from icploc.drivers.powerbot import PowerBot
>>> with SimSession(box(10, 8), start_pose=(2, 2, 0),                 # doctest: +SKIP
...                 plan=waypoint_plan([(5, 0.4, 0.0), (3, 0.0, 0.5)])) as sim:
...     with PLS(sim.laser_port) as laser, PowerBot(sim.base_port) as bot:
...         for scan in laser.scans(): ...

The laser sees the :class:`icploc.sim.world.World` (any of :mod:`icploc.sim.scenes`).
``icploc sim serve`` runs a session until Ctrl-C and prints its two ports.

A velocity ``plan`` (``t -> (v, w)``) moves the robot by itself, overriding host
velocity commands (like a joystick); without a plan the robot obeys the PowerBot
driver's VEL / RVEL / VEL2. Ground truth: :attr:`SimSession.truth` holds
``(stamp, true robot pose, true laser pose)`` for every scan the laser simulator
generated, stamped on :func:`icploc.clock.now` at the moment the scan was taken (which,
in real-time mode, is when its first byte went out).
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from icploc import clock
from icploc.drivers import arcos_protocol as ap
from icploc.se2 import compose
from icploc.sim.device import DeviceRunner, Faults
from icploc.sim.pls_device import PLSDevice
from icploc.sim.powerbot_device import PowerBotDevice, VelocityPlan
from icploc.sim.robot import DiffDriveRobot, EncoderNoise, RobotGeometry
from icploc.sim.world import World


class SimSession:
    """Start with :meth:`start` (or ``with``); drivers open :attr:`laser_port` and
    :attr:`base_port`; :meth:`stop` ends both simulators and closes the ptys."""

    def __init__(
        self,
        world: World,
        *,
        start_pose: Sequence[float] = (0.0, 0.0, 0.0),
        plan: VelocityPlan | None = None,
        realtime: bool = True,
        laser_noise_std: float = 0.01,
        encoder_noise: EncoderNoise | None = None,
        geometry: RobotGeometry | None = None,
        laser_variant: str = "pls",
        laser_flipped: bool = False,
        laser_max_range: float = 50.0,
        laser_faults: Faults | None = None,
        base_faults: Faults | None = None,
        base_params: ap.RobotParams = ap.POWERBOT,
        seed: int = 0,
        unpluggable: bool = False,
    ) -> None:
        self.world = world
        self.geometry = geometry or RobotGeometry()
        self.robot = DiffDriveRobot(
            pose=(float(start_pose[0]), float(start_pose[1]), float(start_pose[2])),
            geometry=self.geometry,
            noise=encoder_noise or EncoderNoise(),
            seed=seed,
        )
        self.laser_offset = (self.geometry.laser_x, 0.0, 0.0)
        self.laser_max_range = laser_max_range
        self.laser_noise_std = laser_noise_std
        self._rng = np.random.default_rng(seed + 1)
        self._lock = threading.Lock()
        self.truth: list[tuple[float, tuple[float, float, float], tuple[float, float, float]]] = []
        self.laser = PLSDevice(
            source=self._scan,
            variant=laser_variant,
            realtime=realtime,
            flipped=laser_flipped,
            faults=laser_faults or Faults(seed=seed + 2),
            max_range=laser_max_range,
            robot=self.robot,
        )
        self.base = PowerBotDevice(
            robot=self.robot,
            params=base_params,
            realtime=realtime,
            plan=plan,
            faults=base_faults or Faults(seed=seed + 3),
        )
        self._angles = self.laser.beam_angles()
        # unpluggable: the ports are symlinks the runners can remove and restore
        # (DeviceRunner.unplug / replug: a USB adapter pulled and plugged back)
        self.laser_runner = DeviceRunner(self.laser, realtime=realtime, name="pls",
                                         unpluggable=unpluggable)  # fmt: skip
        self.base_runner = DeviceRunner(self.base, realtime=realtime, name="powerbot",
                                        unpluggable=unpluggable)  # fmt: skip
        self._started = False

    @property
    def laser_port(self) -> str:
        return self.laser_runner.port

    @property
    def base_port(self) -> str:
        return self.base_runner.port

    @property
    def ports(self) -> tuple[str, str]:
        """(laser port, base port)."""
        return self.laser_port, self.base_port

    def _scan(self, t: float) -> NDArray[np.float64]:
        pose = self.robot.pose
        lp = compose(pose, self.laser_offset)
        r = self.world.ranges(lp, self._angles, self.laser_max_range, t=t, rng=self._rng,
                              noise=self.laser_noise_std)  # fmt: skip
        with self._lock:
            self.truth.append((clock.now(), pose, lp))
        return np.asarray(r, dtype=np.float64)

    def start(self) -> tuple[str, str]:
        """Start both simulators; returns (laser port, base port)."""
        if not self._started:
            self.laser_runner.start()
            self.base_runner.start()
            self._started = True
        return self.ports

    def stop(self) -> None:
        if self._started:
            self.laser_runner.stop()
            self.base_runner.stop()
            self._started = False

    def __enter__(self) -> SimSession:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def errors(self) -> list[BaseException]:
        """Exceptions that ended a simulator thread (should be empty)."""
        return [e for e in (self.laser_runner.error, self.base_runner.error) if e is not None]

    def true_pose_at(self, stamp: float) -> tuple[float, float, float] | None:
        """True robot pose of the scan taken closest to ``stamp`` (None if no scans yet)."""
        with self._lock:
            if not self.truth:
                return None
            stamps = np.array([t for t, _, _ in self.truth])
            i = int(np.argmin(np.abs(stamps - stamp)))
            return self.truth[i][1]

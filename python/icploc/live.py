"""Live localization: the laser and base drivers stream in their own threads, everything
is stamped on :func:`icploc.clock.now`, each scan is localized as it arrives.

:func:`run_live` is the loop; :func:`run_hardware` opens real devices (``icploc run
--map MAP --laser PORT --base PORT``); :func:`run_simulated` runs the identical path
against the device simulators on pseudo-terminals (``icploc run --simulate``).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from icploc import clock
from icploc.localizer import Estimate, Localizer
from icploc.se2 import Pose, wrap_angle

__all__ = ["LiveResult", "PursuitPlan", "run_hardware", "run_live", "run_simulated", "tum_row"]


def tum_row(stamp: float, pose: Sequence[float]) -> str:
    """One TUM trajectory line: ``stamp x y z qx qy qz qw`` (planar: z = qx = qy = 0)."""
    h = 0.5 * pose[2]
    return f"{stamp:.6f} {pose[0]:.6f} {pose[1]:.6f} 0 0 0 {math.sin(h):.9f} {math.cos(h):.9f}\n"


@dataclass
class LiveResult:
    estimates: list[Estimate] = field(default_factory=list)
    odometry: list[tuple[float, Pose]] = field(default_factory=list)
    wall_time: float = 0.0


def run_live(
    localizer: Localizer,
    laser: Any,
    base: Any | None,
    *,
    duration: float | None = None,
    max_scans: int | None = None,
    stop: threading.Event | Callable[[], bool] | None = None,
    on_estimate: Callable[[Estimate], None] | None = None,
    tum: TextIO | None = None,
    odometry_wait: float = 0.15,
) -> LiveResult:
    """Localize scans from ``laser`` (a started :class:`icploc.drivers.sick.SickLaser`,
    anything with ``get(timeout)`` returning a Scan or None) with odometry from ``base``
    (a connected :class:`icploc.drivers.powerbot.PowerBot`: ``get(timeout)`` returning a
    SIP with ``to_odometry()``, or None). Before each scan the loop waits up to
    ``odometry_wait`` s for an odometry sample at or after the scan stamp, so the pose is
    interpolated, not extrapolated. Stops after ``duration`` s, ``max_scans`` scans, or
    when ``stop`` is set / returns True."""
    res = LiveResult()
    t_start = clock.now()

    def stopped() -> bool:
        if stop is None:
            return False
        return stop.is_set() if isinstance(stop, threading.Event) else bool(stop())

    def take_odometry(timeout: float) -> bool:
        if base is None:
            return False
        sip = base.get(timeout=timeout)
        if sip is None:
            return False
        odo = sip.to_odometry() if hasattr(sip, "to_odometry") else sip
        localizer.add_odometry(odo)
        res.odometry.append((odo.stamp, odo.pose))
        return True

    while not stopped():
        if duration is not None and clock.now() - t_start >= duration:
            break
        if max_scans is not None and len(res.estimates) >= max_scans:
            break
        while take_odometry(0.0):
            pass
        scan = laser.get(timeout=0.1)
        if scan is None:
            continue
        if base is not None:
            deadline = clock.now() + odometry_wait
            while True:
                last = localizer.odometry.last_stamp
                if last is not None and last >= scan.stamp:
                    break
                left = deadline - clock.now()
                if left <= 0 or not take_odometry(left):
                    break
        est = localizer.update(scan)
        res.estimates.append(est)
        if tum is not None:
            tum.write(tum_row(est.stamp, est.pose))
        if on_estimate is not None:
            on_estimate(est)
    res.wall_time = clock.now() - t_start
    return res


class PursuitPlan:
    """A velocity plan for the simulated base (``t -> (v, w)``): pure pursuit along a
    polyline using the simulator's true pose (a person with a joystick), then stop.
    ``done`` is set when the last waypoint is reached."""

    def __init__(
        self,
        path: NDArray[np.float64],
        pose: Callable[[], Sequence[float]],
        speed: float = 0.6,
        omega_max: float = 1.2,
        tolerance: float = 0.12,
    ) -> None:
        self.path = np.asarray(path, dtype=np.float64)
        self.pose = pose
        self.speed = speed
        self.omega_max = omega_max
        self.tolerance = tolerance
        self.i = 1
        self.done = threading.Event()

    def __call__(self, t: float) -> tuple[float, float]:
        if self.i >= len(self.path):
            self.done.set()
            return (0.0, 0.0)
        x, y, th = self.pose()
        tx, ty = self.path[self.i]
        d = math.hypot(tx - x, ty - y)
        if d < self.tolerance:
            self.i += 1
            return self(t)
        err = wrap_angle(math.atan2(ty - y, tx - x) - th)
        w = max(-self.omega_max, min(self.omega_max, 2.5 * err))
        v = self.speed * max(0.0, math.cos(err)) ** 4 * min(1.0, d / 0.4 + 0.3)
        if self.i == len(self.path) - 1:  # brake in time to stop on the last waypoint
            v = min(v, 0.7 * math.sqrt(2.0 * 1.0 * d) + 0.05)
        return (v, w)


def run_hardware(
    map_path: str | Path,
    laser_port: str,
    base_port: str | None,
    *,
    config: Any = None,
    initial_pose: Sequence[float] | None = None,
    out: str | Path | None = None,
    record: str | Path | None = None,
    laser_baud: int = 38400,
    duration: float | None = None,
    on_estimate: Callable[[Estimate], None] | None = None,
    on_localizer: Callable[[Localizer], None] | None = None,
) -> LiveResult:
    """Open the PLS (and the PowerBot), localize until ``duration`` or Ctrl-C; write the
    trajectory (TUM) to ``out`` and the raw bytes of both devices to ``record``. Without an
    initial pose (argument or config) the robot localizes globally."""
    from icploc.config import LocalizerConfig
    from icploc.drivers.powerbot import PowerBot
    from icploc.drivers.recording import Recorder
    from icploc.drivers.sick import PLS
    from icploc.maps import Map

    # a live loop must not stall on a lost check (a global search): run them in the back
    cfg = (config or LocalizerConfig()).replace(localizer={"lost_check": "background"})
    m = Map.load(map_path)
    start = initial_pose or cfg.localizer.initial_pose
    loc = Localizer(m, cfg, initial_pose=start)
    if start is None:
        # no pose given: start lost and localize globally (multi-hypothesis, verified lock)
        from icploc.localizer import Status
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:  # hooks: icploc.state (--state), icploc.mcap_export (--mcap)
        on_localizer(loc)
    rec = Recorder(record) if record is not None else None
    tum = open(out, "w") if out is not None else None  # noqa: SIM115
    try:
        with PLS(laser_port, baudrate=laser_baud, recorder=rec) as laser:
            laser.start()
            if base_port is None:
                return run_live(
                    loc, laser, None, duration=duration, on_estimate=on_estimate, tum=tum
                )
            with PowerBot(base_port, recorder=rec) as bot:
                return run_live(
                    loc, laser, bot, duration=duration, on_estimate=on_estimate, tum=tum
                )
    except KeyboardInterrupt:
        return LiveResult()
    finally:
        if tum is not None:
            tum.close()
        if rec is not None:
            rec.close()


def run_simulated(
    world: Any = None,
    path: NDArray[np.float64] | None = None,
    *,
    config: Any = None,
    map_: Any = None,
    speed: float = 0.6,
    laser_baud: int = 500000,
    laser_noise: float = 0.01,
    encoder_noise: Any = None,
    seed: int = 0,
    out: str | Path | None = None,
    record: str | Path | None = None,
    timeout: float = 120.0,
    on_estimate: Callable[[Estimate], None] | None = None,
    global_start: bool = False,
    on_localizer: Callable[[Localizer], None] | None = None,
) -> tuple[LiveResult, list[tuple[float, Pose]]]:
    """The live path against the PLS and PowerBot simulators on pseudo-terminals, in real
    time: the base drives ``path`` (default: the lab random walk) by pure pursuit. Returns
    the live result and the simulator's truth ``(stamp, robot pose)`` per generated scan.
    ``global_start``: the localizer is not told where the robot starts and localizes
    globally (multi-hypothesis search, lock verified over the next scans)."""
    from icploc import worlds
    from icploc.config import LocalizerConfig
    from icploc.drivers.powerbot import PowerBot
    from icploc.drivers.recording import Recorder
    from icploc.drivers.sick import PLS
    from icploc.maps import Map
    from icploc.sim.robot import EncoderNoise
    from icploc.sim.session import SimSession

    world = world if world is not None else worlds.lab()
    path = path if path is not None else worlds.lab_random_walk()
    start = (float(path[0, 0]), float(path[0, 1]), float(world.start[2]))
    sess_holder: list[Any] = []
    plan = PursuitPlan(path, lambda: sess_holder[0].robot.pose, speed=speed)
    enc = encoder_noise or EncoderNoise(relative_std=0.01, left_scale=1.004, right_scale=0.997)
    sess = SimSession(
        world,
        start_pose=start,
        plan=plan,
        realtime=True,
        laser_noise_std=laser_noise,
        encoder_noise=enc,
        laser_max_range=8.0,
        seed=seed,
    )
    sess_holder.append(sess)
    cfg = config or LocalizerConfig()
    cfg = cfg.replace(
        scan={
            "laser_x": sess.laser_offset[0],
            "laser_y": sess.laser_offset[1],
            "laser_theta": sess.laser_offset[2],
        },
        localizer={"lost_check": "background"},  # as on the robot (run_hardware)
    )
    m = (
        (Map.load(map_) if isinstance(map_, (str, Path)) else map_)
        if map_ is not None
        else Map.from_lines(world.lines)
    )
    loc = Localizer(m, cfg, initial_pose=None if global_start else start)
    if global_start:
        from icploc.localizer import Status
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:  # hooks: icploc.state (--state), icploc.mcap_export (--mcap)
        on_localizer(loc)
    rec = Recorder(record) if record is not None else None
    tum = open(out, "w") if out is not None else None  # noqa: SIM115
    t_end = [math.inf]

    def finished() -> bool:
        now = clock.now()
        if plan.done.is_set() and t_end[0] == math.inf:
            t_end[0] = now + 0.5  # let the robot come to a stop
        return now >= t_end[0]

    try:
        with sess:
            with PLS(sess.laser_port, baudrate=laser_baud, recorder=rec) as laser:
                laser.start()
                with PowerBot(sess.base_port, recorder=rec) as bot:
                    # the odometry frame starts where the robot is: align it with the map
                    result = run_live(
                        loc,
                        laser,
                        bot,
                        duration=timeout,
                        stop=finished,
                        on_estimate=on_estimate,
                        tum=tum,
                    )
            truth = [(t, p) for t, p, _ in sess.truth]
    finally:
        if tum is not None:
            tum.close()
        if rec is not None:
            rec.close()
    return result, truth


def truth_at(
    truth: list[tuple[float, Pose]], stamps: Sequence[float] | NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N, 3) true poses at ``stamps`` (the generated scan nearest in time)."""
    t = np.array([s for s, _ in truth])
    p = np.array([q for _, q in truth])
    idx = np.clip(np.searchsorted(t, np.asarray(stamps)), 1, len(t) - 1)
    prev = idx - 1
    choose = np.abs(t[prev] - np.asarray(stamps)) <= np.abs(t[idx] - np.asarray(stamps))
    idx = np.where(choose, prev, idx)
    return np.asarray(p[idx], dtype=np.float64)

"""The live path (:mod:`icploc.live`) against the PLS and PowerBot device simulators on
pseudo-terminals, in real time: ``icploc run --simulate`` and the demo.

:func:`run_simulated` builds a :class:`~icploc.sim.session.SimSession` for a world (the
lab by default), drives its base along a path by pure pursuit, opens the simulated ports
with the real drivers and runs :func:`icploc.live.run_live` on them, exactly as
:func:`icploc.live.run_hardware` does on a robot. :func:`truth_at` looks up the
simulator's truth for the estimates.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc import clock
from icploc.live import (
    LiveResult,
    RunError,
    RunOutputs,
    RunUsageError,
    check_outputs,
    open_devices,
    run_live,
    start_localizer,
)
from icploc.localizer import Estimate, Localizer
from icploc.outputs import map_inputs
from icploc.se2 import Pose

__all__ = ["run_simulated", "truth_at"]


def run_simulated(
    world: Any = None,
    path: NDArray[np.float64] | None = None,
    *,
    config: Any = None,
    map_: Any = None,
    initial_pose: Sequence[float] | None = None,
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
    reconnect_timeout: float = 60.0,
    on_session: Callable[[Any], None] | None = None,
    config_path: str | Path | None = None,
) -> tuple[LiveResult, list[tuple[float, Pose]]]:
    """The live path against the PLS and PowerBot simulators on pseudo-terminals, in real
    time: the base drives ``path`` (default: the lab random walk) by pure pursuit. Returns
    the live result and the simulator's truth ``(stamp, robot pose)`` per generated scan,
    in time order; a scan the loop localized carries the stamp its driver gave it, so an
    estimate's stamp finds its own scan's truth (:func:`truth_at`) however late a loaded
    host read the scan (the time of generation would find a later scan's truth).

    The localizer is told where the robot starts (the path's start), or ``initial_pose``
    (as on a robot: the pose it is told, right or wrong); ``global_start``: it is told
    nothing and localizes globally (multi-hypothesis search, lock verified over the next
    scans). Both at once is a :class:`~icploc.live.RunUsageError`.

    The simulated ports can be unplugged and plugged back
    (``session.laser_runner.unplug()`` / ``replug()``, likewise ``base_runner``), or the
    devices silenced (``session.laser.vanish()`` / ``revive()``): ``on_session(session)``
    is called once the drivers are connected, e.g. to schedule such faults."""
    from icploc.config import LocalizerConfig
    from icploc.maps import Map
    from icploc.sim import scenes
    from icploc.sim.pursuit import PursuitPlan
    from icploc.sim.robot import EncoderNoise
    from icploc.sim.session import SimSession

    if global_start and initial_pose is not None:
        raise RunUsageError("an initial pose and a global start contradict each other: give one")
    world = world if world is not None else scenes.lab()
    path = path if path is not None else scenes.lab_random_walk()
    start = (float(path[0, 0]), float(path[0, 1]), float(world.start[2]))
    sess_holder: list[Any] = []
    plan = PursuitPlan(path, lambda: sess_holder[0].robot.pose, speed=speed)
    enc = encoder_noise or EncoderNoise(relative_std=0.01, left_scale=1.004, right_scale=0.997)
    inputs: dict[str, str | Path | None] = {"config": config_path}
    if isinstance(map_, (str, Path)):
        for i, p in enumerate(map_inputs(map_)):
            inputs["map" if i == 0 else "map image"] = p
    check_outputs({"--out": out, "--record": record}, inputs)
    sess = SimSession(
        world,
        start_pose=start,
        plan=plan,
        realtime=True,
        laser_noise_std=laser_noise,
        encoder_noise=enc,
        laser_max_range=8.0,
        seed=seed,
        unpluggable=True,
    )
    sess_holder.append(sess)
    cfg = (config or LocalizerConfig()).replace(
        scan={
            "laser_x": sess.laser_offset[0],
            "laser_y": sess.laser_offset[1],
            "laser_theta": sess.laser_offset[2],
        },
    )
    try:
        m = (
            (Map.load(map_) if isinstance(map_, (str, Path)) else map_)
            if map_ is not None
            else Map.from_lines(world.lines)
        )
    except (OSError, ValueError) as e:
        raise RunError(str(e)) from None
    told = None if global_start else (initial_pose if initial_pose is not None else start)
    loc = start_localizer(m, cfg, told, on_localizer)
    t_end = [math.inf]

    def finished() -> bool:
        now = clock.now()
        if plan.done.is_set() and t_end[0] == math.inf:
            t_end[0] = now + 0.5  # let the robot come to a stop
        return now >= t_end[0]

    outputs = RunOutputs(out, record, cfg.scan.mounting)
    result: LiveResult | None = None
    try:
        with sess:
            # the simulators power up at 9600 Bd: probe that first (a reconnect after a
            # power cycle then finds the scanner at once)
            bauds = tuple(dict.fromkeys((9600, laser_baud, 38400, 19200, 500000)))
            with open_devices(sess.laser_port, sess.base_port, laser_baud=laser_baud,
                              recorder=outputs.rec, reconnect_timeout=reconnect_timeout,
                              connect_baudrates=bauds) as (laser, bot):  # fmt: skip
                outputs.commit()
                if on_session is not None:
                    on_session(sess)
                # the odometry frame starts where the robot is: align it with the map
                tap = _ScanTap(laser)
                result = run_live(loc, tap, bot, duration=timeout, stop=finished,
                                  on_estimate=on_estimate, tum=outputs.tum)  # fmt: skip
                truth = _truth_as_stamped(sess, laser, tap.seen)
    finally:
        outputs.close(result)
    assert result is not None
    return result, truth


class _ScanTap:
    """The laser driver as :func:`run_live` sees it, noting each scan it hands out:
    (the driver's stamp, a hash of its ranges)."""

    def __init__(self, laser: Any) -> None:
        self._laser = laser
        self.seen: list[tuple[float, int]] = []

    def get(self, timeout: float | None = None) -> Any:
        scan = self._laser.get(timeout=timeout)
        if scan is not None:
            self.seen.append((float(scan.stamp), hash(scan.ranges.tobytes())))
        return scan

    def __getattr__(self, name: str) -> Any:
        return getattr(self._laser, name)


def _truth_as_stamped(
    sess: Any, laser: Any, seen: list[tuple[float, int]]
) -> list[tuple[float, Pose]]:
    """The session's truth per generated scan, each scan the host received stamped as its
    driver stamped it: the simulator's telegrams (its log, one per truth entry) are
    decoded as the driver decodes them and found again by their ranges."""
    from icploc.drivers import sick_protocol as sp

    entries = list(sess.truth)
    frames = list(sess.laser.b0_log)
    stamps = [t for t, _, _ in entries]
    if len(frames) == len(entries):
        index: dict[int, int] = {}
        for i, rec in enumerate(frames):
            tels = [e for e in sp.TelegramParser().feed(rec.frame) if isinstance(e, sp.Telegram)]
            if not tels:
                continue
            try:
                scan = sp.decode_scan(tels[0], variant=laser.variant, flipped=laser.flipped,
                                      max_range=laser.max_range)  # fmt: skip
            except sp.SickProtocolError:
                continue
            index[hash(scan.ranges.tobytes())] = i
        for stamp, key in seen:
            j = index.get(key)
            if j is not None:
                stamps[j] = stamp
    truth = [(stamps[i], entries[i][1]) for i in range(len(entries))]
    truth.sort(key=lambda e: e[0])
    return truth


def truth_at(
    truth: list[tuple[float, Pose]], stamps: Sequence[float] | NDArray[np.float64]
) -> NDArray[np.float64]:
    """(N, 3) true poses at ``stamps`` (the generated scan nearest in time:
    :meth:`icploc.trajectory.Trajectory.at`)."""
    from icploc.trajectory import Trajectory

    t = Trajectory.from_poses([s for s, _ in truth], [q for _, q in truth])
    return t.at(stamps, method="nearest", max_dt=math.inf)[0]

"""Live localization: the laser and base drivers stream in their own threads, everything
is stamped on :func:`icploc.clock.now`, each scan is localized as it arrives.

:func:`run_live` is the loop; :func:`run_hardware` opens real devices (``icploc run
--map MAP --laser PORT --base PORT``); :func:`run_simulated` runs the identical path
against the device simulators on pseudo-terminals (``icploc run --simulate``).

Before anything is opened or written, :func:`run_hardware` checks the ports (they exist,
are serial devices, may be opened) and the outputs (writable, none of them an input:
the map, its image, the config, a port); a failure is a :class:`RunError` with a message
for the user. The trajectory (TUM) and the raw-byte recording are written and flushed as
they go; an existing ``--out`` / ``--record`` is replaced only once the devices answered.

A vanished device does not end the run: the drivers reconnect by themselves (bounded
back-off, the full handshake again). While the laser is missing the estimate coasts on
odometry (status ``degraded``, reason ``laser_missing``); while the base is missing the
scans are matched without odometry (``degraded``, ``base_missing``); with both missing
the last pose is held (``laser_and_base_missing``). A device that does not come back
within ``reconnect_timeout`` ends the run with an error; Ctrl-C ends it with a summary.
"""

from __future__ import annotations

import math
import os
import threading
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, TextIO

import numpy as np
from numpy.typing import NDArray

from icploc import clock
from icploc.localizer import Estimate, Localizer, Status
from icploc.outputs import map_inputs
from icploc.se2 import Pose, between, compose, inverse, wrap_angle

__all__ = [
    "LiveResult",
    "PursuitPlan",
    "RunError",
    "RunUsageError",
    "check_outputs",
    "run_hardware",
    "run_live",
    "run_simulated",
    "tum_row",
]

#: reasons of the estimates the live loop makes while a device is missing
LASER_MISSING = "laser_missing"
BASE_MISSING = "base_missing"
BOTH_MISSING = "laser_and_base_missing"
MISSING_REASONS = (LASER_MISSING, BASE_MISSING, BOTH_MISSING)


class RunError(RuntimeError):
    """``icploc run`` cannot start or go on; the message says why and what to check.
    ``exit_code``: 1 (an error: a port, a device, a file), 2 (a usage error)."""

    exit_code = 1


class RunUsageError(RunError):
    """The arguments contradict each other (an output that is an input, ...)."""

    exit_code = 2


def tum_row(stamp: float, pose: Sequence[float]) -> str:
    """One TUM trajectory line: ``stamp x y z qx qy qz qw`` (planar: z = qx = qy = 0)."""
    h = 0.5 * pose[2]
    return f"{stamp:.6f} {pose[0]:.6f} {pose[1]:.6f} 0 0 0 {math.sin(h):.9f} {math.cos(h):.9f}\n"


@dataclass
class LiveResult:
    #: one estimate per scan localized
    estimates: list[Estimate] = field(default_factory=list)
    #: the estimates made without a scan while the laser was missing (coasting on
    #: odometry, or holding): ``reason`` ``laser_missing`` / ``laser_and_base_missing``
    coasted: list[Estimate] = field(default_factory=list)
    odometry: list[tuple[float, Pose]] = field(default_factory=list)
    wall_time: float = 0.0
    scans: int = 0  #: scans localized
    laser_outages: int = 0  #: times the laser went missing
    base_outages: int = 0  #: times the base went missing
    reconnects: dict[str, int] = field(default_factory=dict)  #: per device, by the drivers
    interrupted: bool = False  #: ended by Ctrl-C
    error: str | None = None  #: what ended the run early (a device that did not come back)
    write_errors: list[str] = field(default_factory=list)  #: outputs that failed mid-run
    files: dict[str, Path] = field(default_factory=dict)  #: outputs written

    def timeline(self) -> list[Estimate]:
        """Every estimate, from scans and coasted, in time order (what ``on_estimate``
        saw and the trajectory file holds)."""
        return sorted(self.estimates + self.coasted, key=lambda e: e.stamp)

    def status_counts(self) -> dict[str, int]:
        """Scan estimates by status, plus the coasted ones by reason."""
        out: dict[str, int] = {}
        for e in self.estimates:
            out[e.status.value] = out.get(e.status.value, 0) + 1
        for e in self.coasted:
            out[e.reason] = out.get(e.reason, 0) + 1
        return out

    def summary(self) -> str:
        how = " (interrupted)" if self.interrupted else ""
        parts = [f"{self.scans} scans in {self.wall_time:.1f} s{how}"]
        counts = self.status_counts()
        if counts:
            parts.append(", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
        if self.laser_outages or self.base_outages:
            parts.append(f"laser missing {self.laser_outages}x, base missing {self.base_outages}x")
        if any(self.reconnects.values()):
            parts.append("reconnects: " + ", ".join(f"{k} {v}" for k, v in self.reconnects.items()))
        return "; ".join(parts)


class _TumWriter:
    """TUM rows written and flushed one by one; a write error stops the file, not the run."""

    def __init__(self, f: TextIO | None, name: str = "--out") -> None:
        self.f = f
        self.name = name
        self.error: str | None = None

    def write(self, est: Estimate) -> None:
        if self.f is None:
            return
        try:
            self.f.write(tum_row(est.stamp, est.pose))
            self.f.flush()
        except OSError as e:
            self.error = f"{self.name}: writing stopped: {e.strerror or e}"
            self.f = None


def _device_failures() -> tuple[type[BaseException], ...]:
    from icploc.drivers.powerbot import PowerBotError
    from icploc.drivers.sick import SickError

    return (SickError, PowerBotError, OSError)


_DEVICE_FAILURES = _device_failures()


def _link_up(dev: Any) -> bool:
    return bool(getattr(dev, "link_up", True))


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
    laser_timeout: float = 1.0,
    base_timeout: float = 0.5,
    coast_period: float = 0.1,
) -> LiveResult:
    """Localize scans from ``laser`` (a started :class:`icploc.drivers.sick.SickLaser`,
    anything with ``get(timeout)`` returning a Scan or None) with odometry from ``base``
    (a connected :class:`icploc.drivers.powerbot.PowerBot`: ``get(timeout)`` returning a
    SIP with ``to_odometry()``, or None). Before each scan the loop waits up to
    ``odometry_wait`` s for an odometry sample at or after the scan stamp, so the pose is
    interpolated, not extrapolated. Stops after ``duration`` s, ``max_scans`` scans, or
    when ``stop`` is set / returns True; Ctrl-C stops it too (``interrupted``), and so
    does a driver error (``error``: a device that did not come back).

    No scan for ``laser_timeout`` s (or a driver reporting ``link_up`` False: it is
    reconnecting): every
    ``coast_period`` s an estimate dead-reckoned from the last scan's pose by odometry
    (``laser_missing``). No odometry for ``base_timeout`` s: scans are matched without
    waiting for odometry and reported ``degraded`` (``base_missing``)."""
    res = LiveResult()
    t_start = clock.now()
    out = _TumWriter(tum)

    def stopped() -> bool:
        if stop is None:
            return False
        return stop.is_set() if isinstance(stop, threading.Event) else bool(stop())

    last_odo_t = [t_start]
    # after an outage of the base the odometry is re-anchored: its first new sample
    # continues from the pose held meanwhile (the motion in the gap is unknown to it,
    # and the scans matched without odometry already accounted for it)
    odo_offset: list[Pose | None] = [None]
    rebase = [False]

    def take_odometry(timeout: float) -> bool:
        if base is None:
            return False
        sip = base.get(timeout=timeout)
        if sip is None:
            return False
        odo = sip.to_odometry() if hasattr(sip, "to_odometry") else sip
        if rebase[0]:
            rebase[0] = False
            held = res.odometry[-1][1] if res.odometry else odo.pose
            odo_offset[0] = compose(held, inverse(odo.pose))
        if odo_offset[0] is not None:
            odo = replace(odo, pose=compose(odo_offset[0], odo.pose))
        localizer.add_odometry(odo)
        res.odometry.append((odo.stamp, odo.pose))
        last_odo_t[0] = clock.now()
        return True

    def emit(est: Estimate, coasted: bool = False) -> None:
        (res.coasted if coasted else res.estimates).append(est)
        out.write(est)
        if on_estimate is not None:
            on_estimate(est)

    def coast(now: float, base_missing: bool) -> Estimate | None:
        last = localizer.last_estimate
        if last is None:
            return None  # nothing to coast from yet
        ref = localizer.last_odometry
        pose: Pose = localizer.pose
        odo: Pose | None = None
        stamp = now
        if base is not None and not base_missing and ref is not None and res.odometry:
            stamp, odo = res.odometry[-1]  # the pose where the latest odometry puts it
            pose = compose(localizer.pose, between(ref, odo))
            reason = LASER_MISSING
        else:
            reason = BOTH_MISSING
        prev = max(res.estimates[-1].stamp if res.estimates else -math.inf,
                   res.coasted[-1].stamp if res.coasted else -math.inf)  # fmt: skip
        if stamp <= max(prev, last.stamp):
            return None  # no odometry since the last estimate: nothing new to say
        status = Status.LOST if localizer.status is Status.LOST else Status.DEGRADED
        return Estimate(stamp=stamp, pose=pose, covariance=localizer.covariance,
                        status=status, inlier_ratio=0.0, iterations=0, time=0.0, accepted=False,
                        reason=reason, prediction=pose, odometry=odo)  # fmt: skip

    last_scan_t = t_start
    laser_missing = base_missing = False
    last_coast = -math.inf
    try:
        while not stopped():
            if duration is not None and clock.now() - t_start >= duration:
                break
            if max_scans is not None and res.scans >= max_scans:
                break
            while take_odometry(0.0):
                pass
            now = clock.now()
            if base is not None:
                missing = not _link_up(base) or now - last_odo_t[0] > base_timeout
                if missing and not base_missing:
                    res.base_outages += 1
                    rebase[0] = True
                base_missing = missing
            scan = laser.get(timeout=0.1)
            now = clock.now()
            if scan is None:
                missing = not _link_up(laser) or now - last_scan_t > laser_timeout
                if missing and not laser_missing:
                    res.laser_outages += 1
                laser_missing = missing
                if laser_missing and now - last_coast >= coast_period:
                    est = coast(now, base_missing)
                    if est is not None:
                        last_coast = now
                        emit(est, coasted=True)
                continue
            last_scan_t = now
            laser_missing = False
            if base is not None and not base_missing:
                deadline = clock.now() + odometry_wait
                while True:
                    last = localizer.odometry.last_stamp
                    if last is not None and last >= scan.stamp:
                        break
                    left = deadline - clock.now()
                    if left <= 0 or not take_odometry(left):
                        break
            if base_missing:
                # no odometry: the robot is assumed still (held), ICP takes the motion
                held = res.odometry[-1][1] if res.odometry else None
                est = localizer.update(scan, held)
            else:
                est = localizer.update(scan)
            res.scans += 1
            if base_missing and est.status is not Status.LOST:
                est = replace(est, status=Status.DEGRADED, reason=BASE_MISSING)
            emit(est)
    except KeyboardInterrupt:
        res.interrupted = True
    except _DEVICE_FAILURES as e:  # a driver gave up: a device that did not come back
        res.error = str(e)
    res.wall_time = clock.now() - t_start
    if out.error is not None:
        res.write_errors.append(out.error)
    for name, dev in (("laser", laser), ("base", base)):
        counters = getattr(dev, "counters", None)
        if isinstance(counters, dict) and "reconnects" in counters:
            res.reconnects[name] = int(counters["reconnects"])
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


def check_outputs(
    outputs: Mapping[str, str | Path | None], inputs: Mapping[str, str | Path | None]
) -> None:
    """:func:`icploc.outputs.check_outputs` for a run: an output (option name -> path)
    that is one of the ``inputs`` (label -> path) or another output is a
    :class:`RunUsageError`; one that cannot be written (a directory, a missing or
    read-only directory, a read-only file) a :class:`RunError`. Nothing is written."""
    from icploc import outputs as out_checks

    try:
        out_checks.check_outputs(outputs, inputs)
    except out_checks.OutputClashError as e:
        raise RunUsageError(str(e)) from None
    except out_checks.OutputError as e:
        raise RunError(str(e)) from None


class _Outputs:
    """The run's output files, created only once the devices answered: the recording
    goes to a temporary file beside ``--record`` (so the handshake is in it) and replaces
    ``--record`` at :meth:`commit`; ``--out`` is opened there too."""

    def __init__(self, out: str | Path | None, record: str | Path | None) -> None:
        from icploc.drivers.recording import Recorder

        self.out = Path(out) if out is not None else None
        self.record = Path(record) if record is not None else None
        self.tum: TextIO | None = None
        self.rec: Recorder | None = None
        self._tmp: Path | None = None
        if self.record is not None:
            self._tmp = self.record.with_name(f".{self.record.name}.{os.getpid()}.partial")
            try:
                self.rec = Recorder(self._tmp)
            except OSError as e:
                raise RunError(f"--record {self.record}: {e.strerror or e}") from None

    def commit(self) -> None:
        if self.rec is not None and self.record is not None:
            try:
                self.rec.rename(self.record)
            except OSError as e:
                raise RunError(f"--record {self.record}: {e.strerror or e}") from None
            self._tmp = None
        if self.out is not None:
            try:
                self.tum = open(self.out, "w", encoding="utf-8")  # noqa: SIM115
            except OSError as e:
                raise RunError(f"--out {self.out}: {e.strerror or e}") from None

    def close(self, res: LiveResult | None) -> None:
        if self.tum is not None:
            try:
                self.tum.close()
            except OSError as e:
                if res is not None:
                    res.write_errors.append(f"--out {self.out}: {e.strerror or e}")
            if res is not None and self.out is not None:
                res.files["trajectory"] = self.out
        if self.rec is not None:
            self.rec.close()
            if self._tmp is not None:  # the devices never answered: keep nothing
                self._tmp.unlink(missing_ok=True)
            elif res is not None and self.record is not None:
                res.files["recording"] = self.record
            if res is not None and self.rec.error is not None:
                res.write_errors.append(
                    f"--record {self.record}: recording stopped: {self.rec.error.strerror or self.rec.error}"
                )


@contextmanager
def _devices(
    laser_port: str,
    base_port: str | None,
    *,
    laser_baud: int,
    recorder: Any,
    reconnect_timeout: float,
    connect_baudrates: tuple[int, ...] | None = None,
) -> Iterator[tuple[Any, Any]]:
    """Open the PLS (and the PowerBot) with automatic reconnection; errors while
    connecting become :class:`RunError` naming the device and the port."""
    import serial

    from icploc.drivers.powerbot import PowerBot, PowerBotError
    from icploc.drivers.sick import PLS, SickError

    failures = (SickError, PowerBotError, OSError, serial.SerialException)
    laser = PLS(laser_port, baudrate=laser_baud, recorder=recorder, auto_reconnect=True,
                stall_timeout=1.0, reconnect_timeout=reconnect_timeout,
                connect_baudrates=connect_baudrates)  # fmt: skip
    bot = None
    try:
        try:
            laser.open()
        except failures as e:
            raise RunError(
                f"laser (--laser {laser_port}): {e} — is the PLS powered and on this port?"
            ) from None
        laser.start()
        if base_port is not None:
            bot = PowerBot(base_port, recorder=recorder, auto_reconnect=True, stall_timeout=1.0,
                           reconnect_timeout=reconnect_timeout)  # fmt: skip
            try:
                bot.connect()
            except failures as e:
                raise RunError(
                    f"base (--base {base_port}): {e} — is the robot on and on this port?"
                ) from None
        yield laser, bot
    finally:
        if bot is not None:
            bot.close()
        laser.close()


def run_hardware(
    map_path: str | Path,
    laser_port: str,
    base_port: str | None,
    *,
    config: Any = None,
    config_path: str | Path | None = None,
    initial_pose: Sequence[float] | None = None,
    out: str | Path | None = None,
    record: str | Path | None = None,
    laser_baud: int = 38400,
    duration: float | None = None,
    reconnect_timeout: float = 60.0,
    on_estimate: Callable[[Estimate], None] | None = None,
    on_localizer: Callable[[Localizer], None] | None = None,
    extra_lasers: Sequence[str] = (),
) -> LiveResult:
    """Open the PLS (and the PowerBot), localize until ``duration`` or Ctrl-C; write the
    trajectory (TUM) to ``out`` and the raw bytes of both devices to ``record``. Without an
    initial pose (argument or config) the robot localizes globally.

    Checks first (:class:`RunError` / :class:`RunUsageError`, nothing opened or written
    yet): the ports, the outputs against the inputs (map, map image, ``config_path``,
    ports). A device that does not come back within ``reconnect_timeout`` s ends the run
    (``error`` in the result; the files stay complete). ``extra_lasers``: the ports of more
    PLS (``scan.lasers`` in the config gives every laser's mounting; :mod:`icploc.multilaser`
    merges their scans)."""
    from icploc.config import LocalizerConfig
    from icploc.drivers.ports import PortError, check_port
    from icploc.maps import Map

    cfg0 = config or LocalizerConfig()
    several = bool(extra_lasers) or bool(cfg0.scan.lasers)  # hook: icploc.multilaser
    if several:
        from icploc import multilaser

        try:
            ports = multilaser.live_ports(cfg0, [laser_port, *extra_lasers])
        except ValueError as e:
            raise RunUsageError(str(e)) from None
        if record is not None and len(ports) > 1:
            raise RunUsageError("--record holds one laser; not with several lasers (scan.lasers)")
        laser_port, extra_lasers = ports[0], ports[1:]
    if base_port is not None and base_port in (laser_port, *extra_lasers):
        raise RunUsageError(f"--laser and --base are the same port ({base_port})")
    for role, port in (("laser (--laser)", laser_port), *((f"laser {i + 2} (--laser)", p) for i, p in enumerate(extra_lasers)), ("base (--base)", base_port)):  # fmt: skip
        if port is not None:
            try:
                check_port(port, role)
            except PortError as e:
                raise RunError(str(e)) from None
    inputs: dict[str, str | Path | None] = {"map": map_path, "config": config_path}
    for i, p in enumerate(map_inputs(map_path)[1:]):
        inputs[f"map image{'' if i == 0 else f' {i + 1}'}"] = p
    inputs["laser port"] = laser_port
    for i, port in enumerate(extra_lasers):
        inputs[f"laser port {i + 2}"] = port
    inputs["base port"] = base_port
    check_outputs({"--out": out, "--record": record}, inputs)

    # a live loop must not stall on a lost check (a global search): run them in the back
    cfg = (config or LocalizerConfig()).replace(localizer={"lost_check": "background"})
    try:
        m = Map.load(map_path)
    except (OSError, ValueError) as e:
        raise RunError(str(e)) from None
    start = initial_pose or cfg.localizer.initial_pose
    loc = Localizer(m, multilaser.localizer_config(cfg) if several else cfg, initial_pose=start)
    if start is None:
        # no pose given: start lost and localize globally (multi-hypothesis, verified lock)
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:  # hooks: icploc.state (--state), icploc.mcap_export (--mcap)
        on_localizer(loc)
    outputs = _Outputs(out, record)
    res: LiveResult | None = None
    try:
        with _devices(laser_port, base_port, laser_baud=laser_baud, recorder=outputs.rec,
                      reconnect_timeout=reconnect_timeout) as (laser, bot):  # fmt: skip
            outputs.commit()
            if several:  # hook: the lasers' scans merged into one (icploc.multilaser)
                res = multilaser.run_merged(loc, cfg, laser, bot, extra_lasers, laser_baud=laser_baud,
                                            reconnect_timeout=reconnect_timeout, duration=duration,
                                            on_estimate=on_estimate, tum=outputs.tum)  # fmt: skip
            else:
                res = run_live(loc, laser, bot, duration=duration, on_estimate=on_estimate,
                               tum=outputs.tum)  # fmt: skip
    finally:
        outputs.close(res)
    assert res is not None
    return res


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
    reconnect_timeout: float = 60.0,
    on_session: Callable[[Any], None] | None = None,
    config_path: str | Path | None = None,
) -> tuple[LiveResult, list[tuple[float, Pose]]]:
    """The live path against the PLS and PowerBot simulators on pseudo-terminals, in real
    time: the base drives ``path`` (default: the lab random walk) by pure pursuit. Returns
    the live result and the simulator's truth ``(stamp, robot pose)`` per generated scan.
    ``global_start``: the localizer is not told where the robot starts and localizes
    globally (multi-hypothesis search, lock verified over the next scans).

    The simulated ports can be unplugged and plugged back
    (``session.laser_runner.unplug()`` / ``replug()``, likewise ``base_runner``), or the
    devices silenced (``session.laser.vanish()`` / ``revive()``): ``on_session(session)``
    is called once the drivers are connected, e.g. to schedule such faults."""
    from icploc import worlds
    from icploc.config import LocalizerConfig
    from icploc.maps import Map
    from icploc.sim.robot import EncoderNoise
    from icploc.sim.session import SimSession

    world = world if world is not None else worlds.lab()
    path = path if path is not None else worlds.lab_random_walk()
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
    cfg = config or LocalizerConfig()
    cfg = cfg.replace(
        scan={
            "laser_x": sess.laser_offset[0],
            "laser_y": sess.laser_offset[1],
            "laser_theta": sess.laser_offset[2],
        },
        localizer={"lost_check": "background"},  # as on the robot (run_hardware)
    )
    try:
        m = (
            (Map.load(map_) if isinstance(map_, (str, Path)) else map_)
            if map_ is not None
            else Map.from_lines(world.lines)
        )
    except (OSError, ValueError) as e:
        raise RunError(str(e)) from None
    loc = Localizer(m, cfg, initial_pose=None if global_start else start)
    if global_start:
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:  # hooks: icploc.state (--state), icploc.mcap_export (--mcap)
        on_localizer(loc)
    t_end = [math.inf]

    def finished() -> bool:
        now = clock.now()
        if plan.done.is_set() and t_end[0] == math.inf:
            t_end[0] = now + 0.5  # let the robot come to a stop
        return now >= t_end[0]

    outputs = _Outputs(out, record)
    result: LiveResult | None = None
    try:
        with sess:
            # the simulators power up at 9600 Bd: probe that first (a reconnect after a
            # power cycle then finds the scanner at once)
            bauds = tuple(dict.fromkeys((9600, laser_baud, 38400, 19200, 500000)))
            with _devices(sess.laser_port, sess.base_port, laser_baud=laser_baud,
                          recorder=outputs.rec, reconnect_timeout=reconnect_timeout,
                          connect_baudrates=bauds) as (laser, bot):  # fmt: skip
                outputs.commit()
                if on_session is not None:
                    on_session(sess)
                # the odometry frame starts where the robot is: align it with the map
                result = run_live(loc, laser, bot, duration=timeout, stop=finished,
                                  on_estimate=on_estimate, tum=outputs.tum)  # fmt: skip
            truth = [(t, p) for t, p, _ in sess.truth]
    finally:
        outputs.close(result)
    assert result is not None
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

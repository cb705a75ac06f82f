"""Live localization: the laser and base drivers stream in their own threads, everything
is stamped on :func:`icploc.clock.now`, each scan is localized as it arrives.

:func:`run_live` is the loop; :func:`run_hardware` opens real devices (``icploc run
--map MAP --laser PORT --base PORT``); :func:`icploc.sim.harness.run_simulated` runs the
identical path against the device simulators on pseudo-terminals (``icploc run
--simulate``).

Before anything is opened or written, :func:`run_hardware` checks the ports (they exist,
are serial devices, may be opened) and the outputs (writable, none of them an input:
the map, its image, the config, a port); a failure is a :class:`RunError` with a message
for the user. The trajectory (TUM) and the raw-byte recording (which carries the laser mounting
the run used) are written and flushed as they go; an existing ``--out`` / ``--record`` is replaced only once the devices answered.

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
from typing import TYPE_CHECKING, Any, TextIO

from icploc import clock
from icploc.errors import IcplocError
from icploc.localizer import Estimate, Localizer, Status
from icploc.outputs import map_inputs
from icploc.se2 import Pose, between, compose, inverse
from icploc.trajectory import TumWriter, tum_line

if TYPE_CHECKING:
    from icploc.config import LocalizerConfig

__all__ = [
    "LiveResult",
    "RunError",
    "RunOutputs",
    "RunUsageError",
    "check_outputs",
    "open_devices",
    "run_hardware",
    "run_live",
    "start_localizer",
    "tum_row",
]

#: reasons of the estimates the live loop makes while a device is missing
LASER_MISSING = "laser_missing"
BASE_MISSING = "base_missing"
BOTH_MISSING = "laser_and_base_missing"
MISSING_REASONS = (LASER_MISSING, BASE_MISSING, BOTH_MISSING)


class RunError(IcplocError, RuntimeError):
    """``icploc run`` cannot start or go on; the message says why and what to check.
    ``exit_code``: 1 (an error: a port, a device, a file), 2 (a usage error)."""

    exit_code = 1


class RunUsageError(RunError):
    """The arguments contradict each other (an output that is an input, ...)."""

    exit_code = 2


#: one TUM row; kept as an alias of :func:`icploc.trajectory.tum_line` (the one TUM writer)
tum_row = tum_line


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
    """TUM rows written and flushed one by one (:class:`icploc.trajectory.TumWriter`); a
    write error stops the file, not the run."""

    def __init__(self, f: TextIO | None, name: str = "--out") -> None:
        self._w = TumWriter(f, flush_every=0.0, on_error="stop", name=name) if f is not None else None

    @property
    def error(self) -> str | None:
        return self._w.error if self._w is not None else None

    def write(self, est: Estimate) -> None:
        if self._w is not None:
            self._w.write(est.stamp, est.pose)


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


def start_localizer(
    m: Any,
    config: Any,
    initial_pose: Sequence[float] | None,
    on_localizer: Callable[[Localizer], None] | None = None,
) -> Localizer:
    """The localizer of a live run on map ``m``: lost checks (global searches) in the
    background, so the loop never stalls on one; at ``initial_pose``, or without one
    lost and localizing globally (multi-hypothesis search, lock verified over the next
    scans). ``on_localizer`` (hooks: icploc.state ``--state``, icploc.mcap_export
    ``--mcap``) sees it before the first scan."""
    cfg = config.replace(localizer={"lost_check": "background"})
    loc = Localizer(m, cfg, initial_pose=initial_pose)
    if initial_pose is None:
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:
        on_localizer(loc)
    return loc


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


class RunOutputs:
    """The run's output files, created only once the devices answered: the recording
    goes to a temporary file beside ``--record`` (so the handshake is in it) and replaces
    ``--record`` at :meth:`commit`; ``--out`` is opened there too. ``mounting``: the
    laser mounting (x m, y m, yaw rad in the robot frame) the run uses, kept in the
    recording's header so that a replay finds the scans where the run did."""

    def __init__(
        self, out: str | Path | None, record: str | Path | None, mounting: Sequence[float]
    ) -> None:
        from icploc.drivers.recording import Recorder, mounting_header

        self.out = Path(out) if out is not None else None
        self.record = Path(record) if record is not None else None
        self.tum: TextIO | None = None
        self.rec: Recorder | None = None
        self._tmp: Path | None = None
        if self.record is not None:
            self._tmp = self.record.with_name(f".{self.record.name}.{os.getpid()}.partial")
            try:
                self.rec = Recorder(self._tmp, header=mounting_header(mounting))
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
def open_devices(
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


def run_merged(
    localizer: Localizer,
    config: LocalizerConfig,
    first: Any,
    base: Any,
    extra_ports: Sequence[str],
    *,
    laser_baud: int,
    reconnect_timeout: float,
    connect_baudrates: tuple[int, ...] | None = None,
    **run_kw: Any,
) -> LiveResult:
    """:func:`run_live` with the first laser's driver ``first`` and one PLS per
    ``extra_ports`` merged (:class:`icploc.multilaser.MergedLasers`). A laser that cannot
    be opened is a :class:`RunError` naming its port."""
    from icploc.multilaser import LaserMount, LaserPortError, MergedLasers, mounts, open_lasers

    lasers = mounts(config) or (LaserMount("laser", "laser"),)
    bauds = [m.baud or laser_baud for m in lasers[1 : 1 + len(extra_ports)]]
    try:
        with open_lasers(extra_ports, bauds, reconnect_timeout=reconnect_timeout,
                         connect_baudrates=connect_baudrates) as extras:  # fmt: skip
            merged = MergedLasers([first, *extras], lasers, config, localizer.odometry)
            return run_live(localizer, merged, base, **run_kw)
    except LaserPortError as e:
        raise RunError(str(e)) from None


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

    cfg = config or LocalizerConfig()
    try:
        m = Map.load(map_path)
    except (OSError, ValueError) as e:
        raise RunError(str(e)) from None
    lcfg = multilaser.localizer_config(cfg) if several else cfg
    loc = start_localizer(m, lcfg, initial_pose or cfg.localizer.initial_pose, on_localizer)
    outputs = RunOutputs(out, record, cfg.scan.mounting)
    res: LiveResult | None = None
    try:
        with open_devices(laser_port, base_port, laser_baud=laser_baud, recorder=outputs.rec,
                          reconnect_timeout=reconnect_timeout) as (laser, bot):  # fmt: skip
            outputs.commit()
            if several:  # hook: the lasers' scans merged into one (icploc.multilaser)
                res = run_merged(loc, cfg, laser, bot, extra_lasers, laser_baud=laser_baud,
                                 reconnect_timeout=reconnect_timeout, duration=duration,
                                 on_estimate=on_estimate, tum=outputs.tum)  # fmt: skip
            else:
                res = run_live(loc, laser, bot, duration=duration, on_estimate=on_estimate,
                               tum=outputs.tum)  # fmt: skip
    finally:
        outputs.close(res)
    assert res is not None
    return res

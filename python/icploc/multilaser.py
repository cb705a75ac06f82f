"""More than one laser: several scanners, each with its own mounting, merged into one correction.

A PowerBot often carries a front and a rear SICK PLS. Each sees half the world; in a
corridor the front one sees the end ahead and the rear one the end behind, and only
together do they pin the robot down along it. Configure them as a list (the ``scan``
section of the YAML)::

    scan:
      lasers:
        - {name: front_laser, x: 0.20, y: 0.0, yaw: 0.0}
        - {name: rear_laser, x: -0.20, y: 0.0, yaw: 3.14159265, time_offset: -0.004}

Each entry (:class:`LaserMount`): ``name``; ``frame`` (the :attr:`icploc.messages.Scan.frame`
of its scans in a log, default the name: CARMEN ``FLASER`` is ``front_laser``, ``RLASER``
``rear_laser``); ``x``, ``y`` (m), ``yaw`` (rad) in the robot base frame; ``upside_down``
(mounted rolled by 180 degrees: its beams sweep clockwise); ``time_offset`` (s, added to
its stamps to put them on the odometry clock: a scanner's latency); ``port`` and
``baud`` (``icploc run``: its serial port, else the ``--laser`` options in order). With
``lasers`` set, ``scan.laser_x`` / ``laser_y`` / ``laser_theta`` must stay 0.

:class:`LaserMerger` turns the scans of all sources into one scan per round: each source's
beams are prepared as a single laser's would be (range limits, no-returns) and moved into
the base frame by its mounting; a scan taken earlier than the newest of the round is carried
to the newest one's stamp by the odometry between the two (the robot moves between two
scanners' sweeps), and the union is one :class:`~icploc.messages.Scan` in the base frame
(``frame="base_link"``, beams sorted by bearing) that the Localizer matches like any scan,
with :func:`localizer_config` (no mounting applied twice). A round closes when every
source has delivered a scan, when one source delivers its next scan first (its rate is
higher), or when a source has been silent for ``max_wait`` s of scan time: a dead scanner
leaves the others' rounds, it does not stop the run. :func:`merge_stream` does this for a
replay's time-ordered stream; :class:`MergedLasers` for live drivers (``icploc run``
with several ``--laser`` ports); :func:`simulated_laser` adds a second simulated PLS to a
:class:`icploc.sim.session.SimSession` robot.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.config import LocalizerConfig
from icploc.laser_mounts import LaserMount, check_lasers, parse_mount
from icploc.messages import Odometry, Scan
from icploc.se2 import between

__all__ = [
    "BASE_FRAME",
    "LaserMerger",
    "LaserMount",
    "LaserPortError",
    "MergedLasers",
    "check_lasers",
    "live_ports",
    "localizer_config",
    "merge_stream",
    "mounts",
    "open_lasers",
    "simulated_laser",
]

#: the frame of a merged scan
BASE_FRAME = "base_link"

def mounts(config: LocalizerConfig) -> tuple[LaserMount, ...]:
    """The configured lasers (empty: one laser, ``scan.laser_*``)."""
    lasers = getattr(config.scan, "lasers", ())
    return tuple(parse_mount(e, i, "scan.lasers") for i, e in enumerate(lasers or ()))


def localizer_config(config: LocalizerConfig) -> LocalizerConfig:
    """The config the Localizer matching merged scans uses: the scans are already in the
    base frame with each laser's range limits applied, so no mounting and no range limit
    again (decimation applies to the merged scan)."""
    if not getattr(config.scan, "lasers", ()):
        return config
    return config.replace(
        scan={
            "lasers": [],
            "laser_x": 0.0,
            "laser_y": 0.0,
            "laser_theta": 0.0,
            "min_range": 0.0,
            "max_range": 0.0,
        }
    )


@dataclass
class _Pending:
    scan: Scan
    stamp: float  #: on the odometry clock (time_offset applied)


@dataclass
class MergeCounters:
    rounds: int = 0  #: merged scans made
    partial: int = 0  #: of them without every source
    uncompensated: int = 0  #: scans merged without odometry at both stamps (assumed still)
    per_source: dict[str, int] = field(default_factory=dict)  #: scans used, by laser


class LaserMerger:
    """Merges scans from the ``lasers`` into base-frame scans (see the module docstring).
    ``config``: the full LocalizerConfig (its scan section's range limits apply to each
    source); ``odometry``: an :class:`icploc.localizer.OdometryBuffer` (default: its own,
    fed by :meth:`add_odometry`) for the motion between the sources' stamps."""

    def __init__(
        self,
        lasers: Sequence[LaserMount],
        config: LocalizerConfig | None = None,
        *,
        odometry: Any = None,
        max_wait: float = 0.5,
    ) -> None:
        from icploc.localizer import OdometryBuffer

        if not lasers:
            raise ValueError("LaserMerger: no lasers")
        if not (max_wait > 0 and math.isfinite(max_wait)):
            raise ValueError(
                f"LaserMerger: max_wait must be a positive number of seconds, got {max_wait!r}"
            )
        self.lasers = tuple(lasers)
        self.config = config or LocalizerConfig()
        self.odometry = odometry if odometry is not None else OdometryBuffer()
        self.max_wait = float(max_wait)
        self.counters = MergeCounters(per_source={m.name: 0 for m in self.lasers})
        self._by_frame = {m.frame: i for i, m in enumerate(self.lasers)}
        base = self.config.replace(
            scan={"lasers": [], "laser_x": 0.0, "laser_y": 0.0, "laser_theta": 0.0, "decimation": 1}
        )
        self._cfg = [
            base.replace(scan={"laser_x": m.x, "laser_y": m.y, "laser_theta": m.yaw})
            for m in self.lasers
        ]
        self._trig: list[Any] = []
        from icploc.scanprep import _TrigCache

        self._trig = [_TrigCache() for _ in self.lasers]
        self._pending: dict[int, _Pending] = {}
        self._last_seen: list[float] = [-math.inf] * len(self.lasers)

    def source_of(self, scan: Scan) -> int:
        """The index of the laser whose frame ``scan`` carries (ValueError if none)."""
        i = self._by_frame.get(scan.frame)
        if i is None:
            raise ValueError(
                f"a scan from frame {scan.frame!r}, but scan.lasers names the frames "
                f"{', '.join(repr(f) for f in self._by_frame)} (set each laser's 'frame')"
            )
        return i

    def add_odometry(self, odom: Odometry) -> None:
        self.odometry.add(odom)

    def add(self, scan: Scan, source: int | None = None) -> list[Scan]:
        """One scan of ``source`` (default: by its frame). Returns the rounds it closed."""
        i = self.source_of(scan) if source is None else int(source)
        m = self.lasers[i]
        p = _Pending(scan, float(scan.stamp) + m.time_offset)
        out: list[Scan] = []
        if i in self._pending:
            out.append(self._close())  # this source's next scan: its round is over
        self._pending[i] = p
        self._last_seen[i] = p.stamp
        if len(self._pending) == len(self.lasers):
            out.append(self._close())
        elif self._pending:
            oldest = min(q.stamp for q in self._pending.values())
            if p.stamp - oldest > self.max_wait:
                out.append(self._close())  # the others are silent: do not wait for them
        return out

    def flush(self) -> list[Scan]:
        """Close the open round (end of the stream)."""
        return [self._close()] if self._pending else []

    # -- merging ------------------------------------------------------------------------
    def _close(self) -> Scan:
        from icploc.scanprep import prepare_scan

        group = self._pending
        self._pending = {}
        ref = max(q.stamp for q in group.values())
        odo_ref = self.odometry.pose_at(ref)
        parts: list[NDArray[np.float64]] = []
        for i, q in sorted(group.items()):
            m = self.lasers[i]
            s = q.scan
            if m.upside_down:  # rolled by 180 degrees: its beams sweep the other way
                s = Scan(
                    s.stamp, s.ranges, -s.angles, s.flags, s.seq, s.max_range, s.min_range, s.frame
                )
            pts = prepare_scan(s, self._cfg[i], self._trig[i])
            if q.stamp != ref and pts.shape[0]:
                odo = self.odometry.pose_at(q.stamp)
                if odo is not None and odo_ref is not None:
                    # base at ref <- base at q.stamp
                    d = between(odo_ref, odo)
                    c, sn = math.cos(d[2]), math.sin(d[2])
                    pts = np.column_stack(
                        (
                            d[0] + c * pts[:, 0] - sn * pts[:, 1],
                            d[1] + sn * pts[:, 0] + c * pts[:, 1],
                        )
                    )
                else:
                    self.counters.uncompensated += 1
            parts.append(pts)
            self.counters.per_source[m.name] += 1
        pts = np.vstack(parts) if parts else np.zeros((0, 2))
        rng = np.hypot(pts[:, 0], pts[:, 1])
        ang = np.arctan2(pts[:, 1], pts[:, 0])
        order = np.argsort(ang, kind="stable")
        self.counters.rounds += 1
        if len(group) < len(self.lasers):
            self.counters.partial += 1
        return Scan(
            stamp=ref,
            ranges=rng[order],
            angles=ang[order],
            seq=self.counters.rounds - 1,
            frame=BASE_FRAME,
        )


def merge_stream(
    items: Iterable[Scan | Odometry], config: LocalizerConfig, *, max_wait: float = 0.5
) -> Iterator[Scan | Odometry]:
    """A replay's time-ordered Scan / Odometry stream with the lasers' scans merged
    (:class:`LaserMerger`); odometry passes through. A merged scan is released once the
    odometry reaches its stamp (the motion compensation interpolates, never
    extrapolates), or at the end of the stream."""
    lasers = mounts(config)
    merger = LaserMerger(lasers, config, max_wait=max_wait)
    ready: list[Scan] = []
    for it in items:
        if isinstance(it, Odometry):
            merger.add_odometry(it)
            yield it
            last = merger.odometry.last_stamp
            while ready and last is not None and ready[0].stamp <= last:
                yield ready.pop(0)
        elif isinstance(it, Scan):
            ready.extend(merger.add(it))
            last = merger.odometry.last_stamp
            while ready and last is not None and ready[0].stamp <= last:
                yield ready.pop(0)
    ready.extend(merger.flush())
    yield from ready


class MergedLasers:
    """Several live laser drivers as one (``get(timeout)`` -> a merged Scan or None), for
    :func:`icploc.live.run_live`: driver ``i`` is laser ``i`` of ``lasers``; the motion
    between their stamps comes from ``odometry`` (the localizer's buffer).

    An open round waits for a missing laser until it is ``max_wait`` s overdue: its usual
    interval between scans (the median of its last few) plus ``max_wait`` since its last
    scan came in; a laser that never delivered is not waited for. (A wait counted from
    the round's stamp would close every round alone when scans are slow to arrive: at
    38400 Bd a PLS telegram takes 0.21 s on the line, two PLS are up to one scan interval
    apart, and a loaded host reads late.)"""

    def __init__(
        self,
        drivers: Sequence[Any],
        lasers: Sequence[LaserMount],
        config: LocalizerConfig,
        odometry: Any,
        *,
        max_wait: float = 0.3,
    ) -> None:
        if len(drivers) != len(lasers):
            raise ValueError(
                f"{len(drivers)} laser driver(s) for {len(lasers)} configured laser(s)"
            )
        self.drivers = list(drivers)
        self.merger = LaserMerger(lasers, config, odometry=odometry, max_wait=max_wait)
        self._ready: list[Scan] = []
        #: per laser: clock.now() when its scans came in (the last few)
        self._arrivals: list[list[float]] = [[] for _ in self.drivers]

    @property
    def link_up(self) -> bool:
        """Up while any of the lasers is (the others' rounds go on)."""
        return any(bool(getattr(d, "link_up", True)) for d in self.drivers)

    @property
    def counters(self) -> dict[str, int]:
        out: dict[str, int] = {"reconnects": 0}
        for d in self.drivers:
            c = getattr(d, "counters", None)
            if isinstance(c, dict):
                out["reconnects"] += int(c.get("reconnects", 0))
        return out

    def get(self, timeout: float | None = None) -> Scan | None:
        import time

        from icploc import clock

        deadline = time.monotonic() + (timeout or 0.0)
        while True:
            if self._ready:
                return self._ready.pop(0)
            got = False
            for i, d in enumerate(self.drivers):
                s = d.get(timeout=0.0)
                if s is not None:
                    got = True
                    seen = self._arrivals[i]
                    seen.append(clock.now())
                    del seen[:-9]
                    self._ready.extend(self.merger.add(s, i))
            if self._ready:
                return self._ready.pop(0)
            if not got:
                left = deadline - time.monotonic()
                if left <= 0:
                    # a round open for max_wait of wall time: a silent scanner
                    if self.merger._pending and self._stale():
                        return self.merger.flush()[0]
                    return None
                time.sleep(min(0.005, left))

    def _stale(self) -> bool:
        """Every laser missing from the open round is ``max_wait`` s overdue."""
        from icploc import clock

        now = clock.now()
        for i, seen in enumerate(self._arrivals):
            if i in self.merger._pending or not seen:
                continue
            gaps = sorted(b - a for a, b in zip(seen, seen[1:], strict=False))
            usual = gaps[len(gaps) // 2] if gaps else 0.0
            if now - seen[-1] <= usual + self.merger.max_wait:
                return False
        return True

    def close(self) -> None:
        for d in self.drivers:
            close = getattr(d, "close", None)
            if close is not None:
                close()


# -- icploc run: several PLS on their serial ports ----------------------------------------------


def live_ports(config: LocalizerConfig, ports: Sequence[str]) -> list[str]:
    """The serial port of each configured laser for ``icploc run``: the ``--laser``
    options in order, then each remaining laser's ``port`` from the config. ValueError
    (naming the option or the entry) when they do not add up."""
    lasers = mounts(config)
    ports = [p for p in ports if p]
    if not lasers:
        if len(ports) > 1:
            raise ValueError(
                f"{len(ports)} --laser ports: list the lasers (each one's mounting) in "
                "scan.lasers of the config"
            )
        return list(ports)
    if len(ports) > len(lasers):
        raise ValueError(f"{len(ports)} --laser ports for {len(lasers)} laser(s) in scan.lasers")
    out = list(ports)
    for i, m in enumerate(lasers[len(ports) :], start=len(ports)):
        if m.port is None:
            raise ValueError(
                f"scan.lasers[{i}] ({m.name}) has no port: give one --laser per laser, "
                "or its port in the config"
            )
        out.append(m.port)
    if len(set(out)) != len(out):
        raise ValueError(f"the lasers' ports repeat: {', '.join(out)}")
    return out


@contextmanager
def open_lasers(
    ports: Sequence[str],
    bauds: Sequence[int],
    *,
    reconnect_timeout: float,
    connect_baudrates: tuple[int, ...] | None = None,
    stall_timeout: float = 1.0,
) -> Iterator[list[Any]]:
    """Open and start one PLS per port (automatic reconnection, as the first laser's
    driver: no scan for ``stall_timeout`` s is a stall); errors name the laser's port.
    Closed on exit."""
    import serial

    from icploc.drivers.powerbot import PowerBotError
    from icploc.drivers.sick import PLS, SickError

    failures = (SickError, PowerBotError, OSError, serial.SerialException)
    opened: list[Any] = []
    try:
        for port, baud in zip(ports, bauds, strict=True):
            dev = PLS(port, baudrate=baud, auto_reconnect=True, stall_timeout=stall_timeout,
                      reconnect_timeout=reconnect_timeout, connect_baudrates=connect_baudrates)  # fmt: skip
            try:
                dev.open()
            except failures as e:
                raise LaserPortError(
                    f"laser (--laser {port}): {e} — is the PLS powered and on this port?"
                ) from None
            opened.append(dev)
            dev.start()
        yield opened
    finally:
        for dev in opened:
            dev.close()


class LaserPortError(RuntimeError):
    """A laser of several could not be opened (the message names its port)."""


def simulated_laser(session: Any, mount: LaserMount, *, seed: int = 0, name: str = "pls-2") -> Any:
    """One more simulated PLS on the robot of an :class:`icploc.sim.session.SimSession`,
    mounted at ``mount`` and sampling the session's world (its noise and range): a
    :class:`icploc.sim.device.DeviceRunner` to start (``with``) and open by its ``port``.
    The session's own laser stays the first one."""
    from icploc.se2 import compose
    from icploc.sim.device import DeviceRunner
    from icploc.sim.pls_device import PLSDevice

    rng = np.random.default_rng(seed + 101)
    realtime = bool(session.laser.realtime)
    dev = PLSDevice(realtime=realtime, robot=session.robot, max_range=session.laser_max_range)
    angles = dev.beam_angles()
    # an upside-down scanner's beam at angle a of its own points at -a in the robot's frame
    look = -angles if mount.upside_down else angles
    world = session.world

    def source(t: float) -> NDArray[np.float64]:
        sensor = compose(session.robot.pose, mount.mounting)
        mr, noise = session.laser_max_range, session.laser_noise_std
        r = world.ranges(sensor, look, mr, t=t, rng=rng, noise=noise)
        return np.asarray(r, dtype=np.float64)

    dev.source = source
    return DeviceRunner(dev, realtime=realtime, name=name)

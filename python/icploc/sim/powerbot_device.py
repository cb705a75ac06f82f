"""An ActivMedia PowerBot (AROS) controller that speaks the client-server protocol byte
for byte (PROTOCOLS.md §B.10), driving a :class:`~icploc.sim.robot.DiffDriveRobot`.

* wait state: SYNC0 and SYNC1 are echoed verbatim, SYNC2 is answered with the name,
  type and subtype strings; an out-of-sequence SYNC restarts at SYNC0; packets with a
  bad checksum are silently ignored (the protocol has no NAK);
* connected: OPEN starts standard SIPs every ``sip_period`` (100 ms); motors start
  disabled until ENABLE 1; VEL / RVEL / VEL2 / STOP / E_STOP / SETO / ENABLE drive the
  robot; CLOSE switches the motors off, stops SIPs and returns to the wait state;
* watchdog: no valid client packet for ``watchdog`` seconds → zero velocity until the
  next packet, which restores the last set-points.

Poses are emitted as ``XPOS = round(x_mm / DistConvFactor) & 0x7FFF`` and
``THPOS = round(theta / AngleConvFactor)`` (int16), exactly what the driver undoes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from icploc.drivers import arcos_protocol as ap
from icploc.sim.device import Faults, OutputSchedule, PeriodicStream, StreamingEngine, stream_alias
from icploc.sim.robot import DiffDriveRobot

#: (v m/s, w rad/s) the robot should follow at simulated time t, or None for host commands
VelocityPlan = Callable[[float], "tuple[float, float] | None"]


@dataclass
class SipRecord:
    """Ground truth about one SIP the device sent."""

    index: int
    sim_time: float
    true_pose: tuple[float, float, float]
    odom_pose: tuple[float, float, float]
    intact: bool
    frame: bytes = b""  #: the packet as built, before fault injection


@dataclass
class PowerBotDevice(StreamingEngine):
    robot: DiffDriveRobot = field(default_factory=DiffDriveRobot)
    params: ap.RobotParams = ap.POWERBOT
    name: str = "PowerBot"
    robot_type: str = "Pioneer"
    realtime: bool = False
    sip_period: float = 0.100
    watchdog: float = 2.0
    faults: Faults = field(default_factory=Faults)
    layout: str = "aros"  #: "aros" SIP ends at DIGOUT; "arcos" adds the optional tail
    battery_volts: float = 24.5
    sonar_source: Callable[[float, int], float] | None = None  #: (t, disc) -> range m
    sonar_per_sip: int = 4
    plan: VelocityPlan | None = None
    echo_delay: float = 0.005
    keep_log: bool = True

    def __post_init__(self) -> None:
        self.parser = ap.PacketParser()
        self.schedule = OutputSchedule()
        self.stream = PeriodicStream(self.sip_period, self.realtime)
        self.sip_log: list[SipRecord] = []
        self.commands: list[ap.Command] = []
        self.watchdog_trips = 0
        self._wall_last_cmd = 0.0
        self._watchdog_active = False
        self._sonar_next = 0
        self.power_on()

    def power_on(self) -> None:
        self._baud = 9600
        self.sync_state = 0  # next expected SYNC number; 3 = connected
        self.robot.enabled = False
        self.robot.stop()
        self._saved_cmd = (0.0, 0.0)
        self.stream.reset()
        self.schedule.clear()
        self.parser.reset()

    sips_on = stream_alias("on", "Sending SIPs (after OPEN).")
    sip_index = stream_alias("index", "SIPs sent so far.")

    @property
    def parity(self) -> str:
        return "N"

    @property
    def bits_per_byte(self) -> int:
        return 10

    @property
    def connected(self) -> bool:
        return self.sync_state == 3

    # -- engine interface

    def receive(self, data: bytes, now: float) -> None:
        if self.faults.vanished:
            return
        for pkt in self.parser.feed(data, now):
            self._handle(pkt, now)

    # -- internals

    def _tick(self, now: float) -> None:
        self._check_watchdog(now)

    def _stream_frame(self, now: float) -> bytes:
        t = self.sim_time(now)
        with self.robot.lock:  # the laser thread moves the robot too
            self._advance(now, t)
            return self._sip_frame(t)

    def _mark(self, intact: bool) -> None:
        if self.keep_log:
            self.sip_log[-1].intact = intact

    def _advance(self, now: float, t: float) -> None:
        """Bring the robot to the time of this SIP (the laser simulator may have moved it
        part of the way already), then let the plan set the commands that follow it."""
        self.robot.advance_to(self.stream.robot_time(self.robot, now, t))
        if self.plan is not None:
            cmd = self.plan(t)
            if cmd is not None:
                self.robot.enabled = True
                self.robot.set_velocity(*cmd)

    def _check_watchdog(self, now: float) -> None:
        if not self.connected or self.watchdog <= 0:
            return
        if not self._watchdog_active and now - self._wall_last_cmd > self.watchdog:
            self._watchdog_active = True
            self.watchdog_trips += 1
            self._saved_cmd = (self.robot.v_cmd, self.robot.w_cmd)
            self.robot.stop()

    def _sip_frame(self, t: float) -> bytes:
        p = self.params
        r = self.robot
        x_mm, y_mm, th = r.odom[0] * 1000.0, r.odom[1] * 1000.0, r.odom[2]
        xpos = int(round(x_mm / p.dist_conv)) & 0x7FFF
        ypos = int(round(y_mm / p.dist_conv)) & 0x7FFF
        thpos = int(round(math.remainder(th, 2 * math.pi) / p.angle_conv))
        lvel = int(round(r.left_speed * 1000.0 / p.vel_conv))
        rvel = int(round(r.right_speed * 1000.0 / p.vel_conv))
        sb = (1 if r.left_stall else 0) | (0x100 if r.right_stall else 0)
        flags = (1 if r.enabled else 0) | (0x20 if r.estopped else 0)
        sonar: list[tuple[int, int]] = []
        if self.sonar_source is not None:
            for _ in range(self.sonar_per_sip):
                d = self._sonar_next
                self._sonar_next = (d + 1) % 32
                rng_m = self.sonar_source(t, d)
                mm = 5000 if not math.isfinite(rng_m) else int(min(rng_m * 1000.0, 5000))
                sonar.append((d, int(mm / p.range_conv)))
        volts10 = int(round(self.battery_volts * 10))
        moving = abs(r.v) > 1e-6 or abs(r.w) > 1e-6
        kw: dict[str, int | None] = {}
        if self.layout == "arcos":
            kw = dict(grip_state=0, anport=0, analog=0, digin=0, digout=0, battery_x10=volts10,
                      charge_state=0, rotvel=int(round(math.degrees(r.w) * 10)))  # fmt: skip
        else:
            kw = dict(grip_state=0, anport=0, analog=0, digin=0, digout=0)
        raw = ap.RawSip(
            type=ap.SIP_MOVING if moving else ap.SIP_STOPPED, xpos=xpos, ypos=ypos,
            thpos=max(-32768, min(32767, thpos)), lvel=lvel, rvel=rvel,
            battery=min(255, volts10), stall_bumpers=sb, control=0, flags=flags, compass=0,
            sonar=tuple(sonar), **kw,  # type: ignore[arg-type]
        )  # fmt: skip
        frame = ap.build_sip(raw)
        if self.keep_log:
            self.sip_log.append(SipRecord(self.sip_index, t, r.pose, r.odom, True, frame))
        self.sip_index += 1
        return frame

    def _handle(self, pkt: ap.Packet, now: float) -> None:
        f = self.faults
        if f.nak_storm > 0:  # ARCOS has no NAK: a storm of lost commands
            f.nak_storm -= 1
            return
        if f.ignore_rate and f.rng.random() < f.ignore_rate:
            return
        try:
            cmd = ap.decode_command(pkt.payload)
        except ap.ArcosProtocolError:
            return
        self.commands.append(cmd)
        if not self.connected:
            self._handshake(cmd, pkt, now)
            return
        self._wall_last_cmd = now
        if self._watchdog_active:
            self._watchdog_active = False
            self.robot.set_velocity(*self._saved_cmd)
        self._command(cmd, now)

    def _handshake(self, cmd: ap.Command, pkt: ap.Packet, now: float) -> None:
        n = cmd.cmd
        if n not in (0, 1, 2) or cmd.arg is not None:
            self.sync_state = 0
            return
        if n != self.sync_state:
            self.sync_state = 0
            if n != 0:
                return
        if n in (0, 1):
            self._send(now, self.echo_delay, ap.build_packet(pkt.payload))
            self.sync_state = n + 1
        else:
            self._send(
                now,
                self.echo_delay,
                ap.build_sync2_reply(self.name, self.robot_type, self.params.name),
            )
            self.sync_state = 3
            self._wall_last_cmd = now

    def _command(self, cmd: ap.Command, now: float) -> None:
        n, arg = cmd.cmd, cmd.arg
        r = self.robot
        iarg = arg if isinstance(arg, int) else 0
        if n == ap.OPEN:
            self.sips_on = True
        elif n == ap.CLOSE:
            r.enabled = False
            r.stop()
            self.sips_on = False
            self.sync_state = 0
            self.stream.restart_clock()
        elif n == ap.ENABLE:
            r.enabled = bool(iarg)
        elif n == ap.VEL:
            r.set_velocity(iarg / 1000.0, r.w_cmd)
        elif n == ap.RVEL:
            r.set_velocity(r.v_cmd, math.radians(iarg))
        elif n == ap.VEL2:
            left, right = ap.decode_vel2(iarg, self.params.vel2_divisor)
            r.set_wheels(left / 1000.0, right / 1000.0)
        elif n == ap.STOP:
            r.stop()
        elif n == ap.E_STOP:
            r.e_stop()
        elif n == ap.SETO:
            r.reset_odometry()
        elif n == ap.HOSTBAUD and isinstance(arg, int):
            bauds = {v: k for k, v in ap.HOSTBAUD_CODES.items()}
            if arg in bauds:
                self._baud = bauds[arg]
        # PULSE and everything else: keep-alive only


def constant_plan(v: float, w: float) -> VelocityPlan:
    return lambda t: (v, w)


def waypoint_plan(segments: list[tuple[float, float, float]]) -> VelocityPlan:
    """Piecewise-constant plan: ``[(duration s, v m/s, w rad/s), ...]``, then stop."""
    ends = np.cumsum([s[0] for s in segments])

    def plan(t: float) -> tuple[float, float] | None:
        i = int(np.searchsorted(ends, t, side="right"))
        if i >= len(segments):
            return (0.0, 0.0)
        return (segments[i][1], segments[i][2])

    return plan

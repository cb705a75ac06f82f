"""PowerBot driver against the PowerBot device simulator over a real pseudo-terminal."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator

import pytest
import serial
from icploc.drivers import arcos_protocol as ap
from icploc.drivers.powerbot import PowerBot, PowerBotError, PowerBotTimeout
from icploc.messages import Odometry
from icploc.se2 import wrap_angle
from icploc.sim.device import DeviceRunner, Faults
from icploc.sim.powerbot_device import PowerBotDevice, constant_plan
from icploc.sim.robot import DiffDriveRobot, EncoderNoise


def runner(**kw: object) -> DeviceRunner:
    return DeviceRunner(PowerBotDevice(**kw)).start()  # type: ignore[arg-type]


@pytest.fixture
def sim() -> Iterator[DeviceRunner]:
    run = runner()
    yield run
    run.stop()
    assert run.error is None


def dev_of(run: DeviceRunner) -> PowerBotDevice:
    assert isinstance(run.engine, PowerBotDevice)
    return run.engine


def wait_for(cond: object, timeout: float = 20.0) -> bool:
    """Poll ``cond`` until true; the generous timeout only matters on a loaded machine."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if cond():  # type: ignore[operator]
            return True
        time.sleep(0.005)
    return False


def test_handshake_open_enable_and_1000_sips(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    # a queue that a consumer slowed by a loaded machine cannot overflow (in test mode the
    # simulator sends SIPs as fast as the driver reads them)
    with PowerBot(sim.port, queue_size=100_000) as bot:
        assert (bot.name, bot.robot_type, bot.subtype) == ("PowerBot", "Pioneer", "powerbot")
        assert bot.params.dist_conv == 0.5813
        # the device handles ENABLE on its own thread: give it time under load
        assert wait_for(lambda: dev.connected and dev.sips_on and dev.robot.enabled)
        cmds = [(c.cmd, c.arg) for c in dev.commands]
        assert cmds[:6] == [
            (0, None),
            (1, None),
            (2, None),
            (ap.OPEN, None),
            (ap.PULSE, None),
            (ap.ENABLE, 1),
        ]
        sips = list(bot.sips(limit=1000))
        assert (
            bot.ser is not None
            and bot.ser.baudrate == 9600
            and bot.ser.parity == serial.PARITY_NONE
        )
    assert [s.seq for s in sips] == list(range(1, 1001))
    assert bot.stats["dropped_sips"] == 0 and bot.stats["parser_checksum_errors"] == 0
    assert all(b.stamp >= a.stamp for a, b in zip(sips, sips[1:], strict=False))
    assert all(s.battery_volts == pytest.approx(24.5) for s in sips)
    # CLOSE on exit: STOP, ENABLE 0, CLOSE (the device thread may still be reading them)
    assert wait_for(lambda: dev.commands[-1].cmd == ap.CLOSE)
    assert [(c.cmd, c.arg) for c in dev.commands[-3:]] == [
        (ap.STOP, None),
        (ap.ENABLE, 0),
        (ap.CLOSE, None),
    ]
    assert not dev.connected and not dev.sips_on and not dev.robot.enabled


def test_velocity_commands_reach_the_robot(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    with PowerBot(sim.port) as bot:
        bot.set_velocity(0.5, 0.2)
        assert wait_for(lambda: dev.robot.v_cmd == 0.5)
        assert wait_for(
            lambda: dev.robot.w_cmd == pytest.approx(math.radians(11))
        )  # RVEL: 1 deg/s steps
        # the queue (256 deep, filled as fast as the simulator writes) may still hold SIPs
        # from before the command: skip to the first moving one, then 6 s of sim time
        it = bot.sips(limit=600)
        assert any(s.v > 0.0 for s in it)
        sips = [s for _, s in zip(range(60), it, strict=False)]
        assert len(sips) == 60
        assert sips[-1].v == pytest.approx(0.5, abs=0.03) and sips[-1].moving
        bot.set_wheel_velocities(-0.2, 0.3)  # VEL2 with a negative left wheel
        assert wait_for(lambda: dev.robot.v_cmd == pytest.approx(0.05))
        assert dev.robot.w_cmd == pytest.approx(0.5 / dev.robot.geometry.wheel_base)
        bot.stop()
        assert wait_for(lambda: dev.robot.v_cmd == 0.0 and dev.robot.w_cmd == 0.0)
        bot.set_velocity(0.3, 0.0)
        bot.e_stop()
        assert wait_for(lambda: dev.robot.estopped)
        assert wait_for(lambda: bot.last_sip is not None and bot.last_sip.estop)


def test_close_on_exception_and_ctrl_c(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    with pytest.raises(KeyboardInterrupt), PowerBot(sim.port) as bot:
        bot.set_velocity(0.4, 0.0)
        raise KeyboardInterrupt
    assert dev.commands[-1].cmd == ap.CLOSE and not dev.connected
    with pytest.raises(RuntimeError), PowerBot(sim.port):
        raise RuntimeError("boom")
    assert dev.commands[-1].cmd == ap.CLOSE and not dev.connected


def test_heartbeat_keeps_the_watchdog_quiet() -> None:
    """PULSE every 0.1 s keeps a 2 s watchdog (the controller's default) quiet: a 20x
    margin, so a loaded machine that delays the heartbeat thread cannot trip it."""
    run = runner(watchdog=2.0)
    dev = dev_of(run)
    try:
        with PowerBot(run.port, heartbeat=0.1):
            # wait for pulses, not for a fixed time: 25 pulses span at least 2.5 s
            assert wait_for(lambda: sum(1 for c in dev.commands if c.cmd == ap.PULSE) >= 25,
                            timeout=60.0)  # fmt: skip
            assert dev.watchdog_trips == 0
    finally:
        run.stop()


def test_watchdog_stops_robot_without_heartbeat() -> None:
    run = runner(watchdog=0.3)
    dev = dev_of(run)
    try:
        with PowerBot(run.port, heartbeat=60.0) as bot:
            bot.set_velocity(0.4, 0.0)
            assert wait_for(lambda: dev.watchdog_trips == 1, timeout=10.0)
            assert dev.robot.v_cmd == 0.0
            bot.command(ap.PULSE)  # any packet restores the last set-points
            assert wait_for(lambda: dev.robot.v_cmd == 0.4)
    finally:
        run.stop()


def test_still_connected_robot_is_closed_and_reconnected(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    # a previous client connected, opened, and died without CLOSE
    s = serial.Serial(sim.port, 9600, timeout=0.2)
    for cmd in (0, 1, 2, ap.OPEN):
        s.write(ap.encode_command(cmd))
        time.sleep(0.02)
    s.close()
    assert wait_for(lambda: dev.sips_on)
    with PowerBot(sim.port, queue_size=100_000) as bot:  # the first SIP is still queued
        assert bot.stats["sync_retries"] >= 1
        assert next(bot.sips()).seq == 1
    assert sum(1 for c in dev.commands if c.cmd == ap.CLOSE) >= 2


def test_no_robot_times_out() -> None:
    run = runner(faults=Faults(vanished=True))
    try:
        with pytest.raises(PowerBotTimeout):
            PowerBot(run.port, sync_tries=2, sync_timeout=0.1).connect()
    finally:
        run.stop()


def test_lost_sync_packets_are_retried() -> None:
    run = runner(faults=Faults(nak_storm=2))  # the first two packets vanish
    try:
        # a lost packet is answered never, a heard one within milliseconds: 0.5 s (the
        # default) tells them apart on a loaded machine too
        with PowerBot(run.port, sync_timeout=0.5) as bot:
            assert bot.stats["sync_retries"] >= 1
            assert next(bot.sips()) is not None
    finally:
        run.stop()


def test_a_lost_sync2_reply_is_recovered_from() -> None:
    """The controller takes SYNC2 and connects, but its reply is lost on the line (or read
    after the driver gave up): it sends no SIPs (no OPEN yet) and takes the next SYNC0 for
    a PULSE. The driver closes it back into its wait state and connects on the next try."""
    run = runner()
    dev = dev_of(run)
    send = dev._send
    reply = ap.build_sync2_reply(dev.name, dev.robot_type, dev.params.name)
    lost: list[bytes] = []

    def lose_first_reply(now: float, delay: float, data: bytes, action: object = None) -> None:
        if data == reply and not lost:
            lost.append(data)
            return
        send(now, delay, data, action)  # type: ignore[arg-type]

    dev._send = lose_first_reply  # type: ignore[method-assign]
    try:
        # the device streams SIPs as fast as the line takes them: a queue that never drops
        # (256 by default; a starved test thread read seq 117 once) keeps the first one
        with PowerBot(run.port, sync_timeout=0.5, sync_tries=4, queue_size=100_000) as bot:
            assert (lost, next(bot.sips()).seq) == ([reply], 1)
            assert bot.counters["dropped_sips"] == 0
    finally:
        run.stop()


def test_late_sync_replies() -> None:
    run = runner(faults=Faults(late_reply=0.2))
    try:
        # replies 0.2 s late, waited for up to 3 s: a margin a loaded machine keeps
        with PowerBot(run.port, sync_timeout=3.0) as bot:
            assert bot.stats["sync_retries"] == 0 and bot.subtype == "powerbot"
    finally:
        run.stop()


def test_vanished_robot_raises_timeout(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    bot = PowerBot(sim.port, stall_timeout=1.0)
    bot.connect()
    try:
        assert len(list(bot.sips(limit=5))) == 5
        dev.vanish()
        with pytest.raises(PowerBotTimeout):
            for _ in bot.sips(limit=10**6):
                pass
    finally:
        bot.close()


def test_disconnect_and_reconnect(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    with PowerBot(sim.port) as bot:
        assert len(list(bot.sips(limit=5))) == 5
    assert not dev.connected
    with PowerBot(sim.port) as bot:
        assert dev.connected
        assert len(list(bot.sips(limit=5))) == 5


def test_corrupted_sips_and_garbage_never_decoded(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    dev.plan = constant_plan(0.8, 0.3)
    with PowerBot(sim.port, queue_size=100_000) as bot:  # nothing dropped under load either
        dev.faults.corrupt_rate = 0.05
        dev.faults.garbage_rate = 0.5
        sips = list(bot.sips(limit=400))
    frames = {ap.parse_sip(r.frame[3:-2]): r for r in dev.sip_log}
    got = [frames[s.raw] for s in sips]  # KeyError would mean a SIP the device never built
    assert all(r.intact for r in got)
    idx = [r.index for r in got]
    expect = [r.index for r in dev.sip_log[idx[0] : idx[-1] + 1] if r.intact]
    assert idx == expect
    assert sum(1 for r in dev.sip_log[idx[0] : idx[-1] + 1] if not r.intact) > 5


def _drive(
    start_odom: tuple[float, float, float], v: float, w: float, n: int
) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    robot = DiffDriveRobot(noise=EncoderNoise(relative_std=0.0))
    robot.reset_odometry(start_odom)
    run = runner(robot=robot, plan=constant_plan(v, w))
    dev = dev_of(run)
    try:
        # the first SIPs are the reference: a queue that cannot drop them under load
        with PowerBot(run.port, queue_size=100_000) as bot:
            sips = list(bot.sips(limit=n))
    finally:
        run.stop()
    return [(s.pose, dev.sip_log[s.seq - 1].odom_pose) for s in sips]


def _check_continuous(
    pairs: list[tuple[tuple[float, float, float], tuple[float, float, float]]],
) -> None:
    (d0, o0) = pairs[0]
    for d, o in pairs:
        assert d[0] - d0[0] == pytest.approx(o[0] - o0[0], abs=1.5e-3)
        assert d[1] - d0[1] == pytest.approx(o[1] - o0[1], abs=1.5e-3)
        assert wrap_angle(d[2] - o[2]) == pytest.approx(0.0, abs=2e-3)


def test_odometry_wraps_forward_across_15_bit_counter() -> None:
    limit = 32768 * 0.5813 / 1000.0  # 19.048 m
    pairs = _drive((limit - 3.0, 0.0, 0.0), 2.0, 0.0, 60)
    assert pairs[0][1][0] < limit < pairs[-1][1][0]  # the raw counter wrapped
    _check_continuous(pairs)
    xs = [d[0] for d, _ in pairs]
    assert all(b >= a for a, b in zip(xs, xs[1:], strict=False))


def test_odometry_wraps_backward_across_zero() -> None:
    pairs = _drive((1.0, 0.5, 0.0), -1.5, 0.0, 60)
    assert pairs[0][1][0] > 0 > pairs[-1][1][0]
    _check_continuous(pairs)
    assert pairs[-1][0][0] < 0  # continuous, negative: not 19 m


def test_odometry_heading_wraps_both_ways() -> None:
    for w in (2.0, -2.0):
        pairs = _drive((0.0, 0.0, 3.0 if w > 0 else -3.0), 0.2, w, 40)
        _check_continuous(pairs)
        ths = [d[2] for d, _ in pairs]
        assert max(ths) > 2.5 and min(ths) < -2.5  # crossed +-pi


def test_sip_to_odometry(sim: DeviceRunner) -> None:
    with PowerBot(sim.port) as bot:
        odo = next(bot.odometry())
    assert isinstance(odo, Odometry)
    assert odo.velocity is not None and "battery_volts" in odo.extra


def test_hostbaud_switch(sim: DeviceRunner) -> None:
    dev = dev_of(sim)
    with PowerBot(sim.port, switch_baudrate=38400, queue_size=100_000) as bot:
        assert dev.baudrate == 38400 and bot.ser is not None and bot.ser.baudrate == 38400
        assert sim.transport.host_settings().baudrate == 38400  # type: ignore[attr-defined]
        assert len(list(bot.sips(limit=20))) == 20


def test_hostbaud_switch_the_robot_missed_falls_back_and_retries() -> None:
    """The first HOSTBAUD is lost: nothing arrives at the new rate, the driver goes back
    to 9600 Bd, resends it and switches."""
    run = runner(faults=Faults())
    dev = dev_of(run)
    lost: list[int] = []
    handle = dev._command

    def lose_first_hostbaud(cmd: ap.Command, now: float) -> None:
        if cmd.cmd == ap.HOSTBAUD and not lost:
            lost.append(cmd.cmd)
            return
        handle(cmd, now)

    dev._command = lose_first_hostbaud  # type: ignore[method-assign]
    try:
        with PowerBot(run.port, switch_baudrate=38400) as bot:
            assert (lost, dev.baudrate, bot.ser is not None and bot.ser.baudrate) == (
                [ap.HOSTBAUD],
                38400,
                38400,
            )
    finally:
        run.stop()


def test_unplugged_robot_is_reconnected_and_the_odometry_continues() -> None:
    """The adapter is pulled and the controller power-cycled (its counters restart at
    0, 0, 0): the driver reconnects by itself, re-handshakes, and continues the odometry
    from the last pose instead of jumping back to the origin."""
    robot = DiffDriveRobot(noise=EncoderNoise(relative_std=0.0))
    robot.reset_odometry((3.0, -2.0, 1.0))
    run = DeviceRunner(PowerBotDevice(robot=robot), unpluggable=True).start()
    try:
        # the unplug fails the reads at once; a stall timeout a starved reader could reach
        # while SIPs still flow would add a reconnect of its own
        with PowerBot(
            run.port, auto_reconnect=True, stall_timeout=2.0, reconnect_backoff=0.05
        ) as bot:
            before = list(bot.sips(limit=5))[-1]
            run.unplug()
            assert wait_for(lambda: not bot.link_up, timeout=30.0)
            last_before = bot.decoder.seq  # SIPs up to here were sent before the unplug
            robot.reset_odometry((0.0, 0.0, 0.0))
            run.replug(power_cycle=True)
            it = bot.sips()
            after = next(it)
            while after.seq <= last_before:
                before = after
                after = next(it)
            assert (bot.stats["reconnects"], bot.stats["odometry_rebases"]) == (1, 1)
        assert after.pose == pytest.approx(before.pose, abs=0.01)
    finally:
        run.stop()


def test_robot_that_never_comes_back_raises_a_clear_timeout() -> None:
    run = DeviceRunner(PowerBotDevice(), unpluggable=True).start()
    try:
        with PowerBot(
            run.port, auto_reconnect=True, stall_timeout=0.5, reconnect_timeout=1.0
        ) as bot:
            assert len(list(bot.sips(limit=3))) == 3
            run.unplug()
            with pytest.raises(PowerBotTimeout, match="did not come back within 1 s"):
                for _ in bot.sips(limit=10**6):
                    pass
    finally:
        run.stop()


class _AdapterLine:
    """A serial line (the part of pyserial the driver uses) to a robot streaming SIPs at
    9600 Bd that obeys only its ``obeys``-th HOSTBAUD (None: none), through a USB adapter
    whose FIFO still holds one SIP sent at the old rate when the host changes its speed:
    that SIP reaches the host intact after the switch and its input flush. At a speed the
    robot is not at, the host reads line noise."""

    def __init__(self, obeys: int | None) -> None:
        self.obeys = obeys
        self.robot_baud = 9600
        self._host_baud = 9600
        self.hostbauds = 0
        self._cmds = ap.PacketParser()
        self._fifo = b""
        self._noise = iter(range(10**9))
        self._sip = ap.build_sip(ap.RawSip(type=0x32, xpos=0, ypos=0, thpos=0, lvel=0, rvel=0,
                                           battery=245, stall_bumpers=0, control=0, flags=1,
                                           compass=0, sonar=()))  # fmt: skip

    @property
    def baudrate(self) -> int:
        return self._host_baud

    @baudrate.setter
    def baudrate(self, baud: int) -> None:
        self._host_baud = baud
        self._fifo = self._sip  # sent at the robot's rate before the switch, still buffered

    @property
    def in_waiting(self) -> int:
        return 1

    def reset_input_buffer(self) -> None:
        pass  # the host's flush does not reach into the adapter's FIFO

    def write(self, data: bytes) -> int:
        for pkt in self._cmds.feed(data):
            cmd = ap.decode_command(pkt.payload)
            if cmd.cmd == ap.HOSTBAUD and self._host_baud == self.robot_baud:
                self.hostbauds += 1
                if self.hostbauds == self.obeys:
                    bauds = {code: baud for baud, code in ap.HOSTBAUD_CODES.items()}
                    self.robot_baud = bauds[int(cmd.arg or 0)]
        return len(data)

    def flush(self) -> None:
        pass

    def read(self, n: int = 1) -> bytes:
        time.sleep(0.002)
        if self._fifo:
            out, self._fifo = self._fifo, b""
            return out
        if self._host_baud == self.robot_baud:
            return self._sip
        return bytes((next(self._noise) * 37) & 0xFF for _ in range(16))


def _switch_over(line: _AdapterLine) -> PowerBot:
    bot = PowerBot("unused")
    bot.ser = line  # type: ignore[assignment]
    bot._switch_baud(38400, tries=2, verify=0.3)
    return bot


def test_hostbaud_the_robot_ignored_is_not_taken_for_a_switch() -> None:
    """One SIP from before the switch (the adapter's FIFO) is no proof the robot talks at
    the new rate: a robot that never switched leaves the driver at 9600 Bd with an error,
    not at 38400 Bd talking to nobody."""
    line = _AdapterLine(obeys=None)
    with pytest.raises(PowerBotError, match="did not answer at 38400 Bd"):
        _switch_over(line)
    assert (line.baudrate, line.hostbauds) == (9600, 2)


def test_hostbaud_the_robot_missed_is_sent_again_despite_a_stale_sip() -> None:
    line = _AdapterLine(obeys=2)
    _switch_over(line)
    assert (line.hostbauds, line.robot_baud, line.baudrate) == (2, 38400, 38400)


def test_a_late_simulator_hears_bytes_sent_before_the_host_switched(sim: DeviceRunner) -> None:
    """The host sends a packet at 9600 Bd and switches its UART to 38400 Bd before the
    device thread reads (a loaded machine): the packet went out at the device's speed,
    so the device gets it (judged at read time it was lost, and with it the OPEN and
    HOSTBAUD of a baud switch)."""
    dev = dev_of(sim)
    with serial.Serial(sim.port, 9600, timeout=0.2) as host:
        host.write(ap.encode_command(ap.SYNC0))
        assert wait_for(lambda: len(dev.commands) == 1)
        seen = sim.steps
        assert wait_for(lambda: sim.steps >= seen + 2)  # it sampled the host at 9600 Bd since
        with sim.paused():
            host.write(ap.encode_command(ap.SYNC1))
            host.flush()
            host.baudrate = 38400
        assert wait_for(lambda: [c.cmd for c in dev.commands] == [ap.SYNC0, ap.SYNC1])


def test_a_packet_that_came_while_the_driver_slept_past_its_deadline_is_read() -> None:
    """A starved thread wakes after its deadline: what arrived meanwhile still counts
    (not read, a SYNC echo sitting in the buffer failed the handshake try)."""
    from icploc import clock

    bot = PowerBot("unused")
    bot.ser = _AdapterLine(obeys=None)  # type: ignore[assignment]
    assert [p.type for p in bot._read_packets(clock.now() - 1.0)] == [0x32]

"""The simulated robot moves continuously: the laser and base simulators both bring it to
their own time before sampling the pose or reporting odometry, so truth, scans and
odometry follow one motion (not 100 ms jumps at each SIP)."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from icploc.sim.pls_device import PLSDevice
from icploc.sim.powerbot_device import PowerBotDevice, constant_plan
from icploc.sim.robot import DiffDriveRobot, EncoderNoise


def _state(r: DiffDriveRobot) -> tuple[object, ...]:
    return (r.time, r.pose, r.odom, r.v, r.w, r.left_speed, r.right_speed)


def _noisy_robot() -> DiffDriveRobot:
    r = DiffDriveRobot(noise=EncoderNoise(relative_std=0.02, left_scale=1.01), seed=7)
    r.set_velocity(0.8, 0.4)
    return r


def test_advance_to_is_independent_of_how_calls_interleave() -> None:
    # base alone: SIP times (0.1 s)
    a = _noisy_robot()
    for k in range(31):
        a.advance_to(0.1 * k)
    # base and laser (0.04 s) calls interleaved, some arriving late (no-ops)
    b = _noisy_robot()
    times = sorted([0.1 * k for k in range(31)] + [0.04 * k for k in range(76)])
    for i, t in enumerate(times):
        b.advance_to(t)
        if i % 5 == 0:
            b.advance_to(t - 0.07)  # behind the robot: nothing happens
    assert b.time == pytest.approx(3.0) and a.time == pytest.approx(3.0)
    assert _state(a) == _state(b)  # bit for bit: same steps, same encoder noise draws
    assert a.pose[0] > 1.0 and a.odom != a.pose  # it moved, and the odometry is noisy


def test_advance_to_from_two_threads() -> None:
    ref = _noisy_robot()
    ref.advance_to(4.0)
    r = _noisy_robot()

    def run(period: float) -> None:
        for k in range(int(round(4.0 / period)) + 1):
            r.advance_to(period * k)

    threads = [threading.Thread(target=run, args=(p,)) for p in (0.1, 0.04)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    assert _state(r) == _state(ref)


def _engines() -> tuple[DiffDriveRobot, PLSDevice, PowerBotDevice, list[tuple[float, ...]]]:
    robot = DiffDriveRobot(noise=EncoderNoise(relative_std=0.0))
    seen: list[tuple[float, ...]] = []

    def source(t: float) -> np.ndarray:
        seen.append((robot.time, *robot.pose))
        return np.full(361, 5.0)

    pls = PLSDevice(source=source, realtime=True, robot=robot)
    pls.streaming = True
    base = PowerBotDevice(robot=robot, realtime=True, plan=constant_plan(1.0, 0.5), watchdog=0.0)
    base.sync_state, base.sips_on = 3, True
    return robot, pls, base, seen


def test_laser_sees_the_robot_move_between_sips_realtime() -> None:
    robot, pls, base, seen = _engines()
    t0 = 1000.0
    sip_times, scan_times = [t0], [t0]
    while len(sip_times) < 21:  # as the devices schedule them
        sip_times.append(sip_times[-1] + 0.1)
    while len(scan_times) < 51:
        scan_times.append(scan_times[-1] + 0.04)
    events = sorted([(t, 0) for t in sip_times] + [(t, 1) for t in scan_times])
    for now, which in events:
        dev = base if which == 0 else pls
        assert dev.output(now, True), (now, which)
    assert len(seen) == len(scan_times) and len(base.sip_log) == len(sip_times)
    # every scan is taken at its own moment on the shared clock...
    np.testing.assert_allclose([s[0] for s in seen], np.array(scan_times) - t0, atol=1e-9)
    # ...and the robot has moved since the previous one (no pose frozen between SIPs)
    xs = np.array([s[1] for s in seen])
    moving = xs[np.searchsorted(scan_times, t0 + 1.0) :]
    assert np.all(np.diff(moving) > 0.01)
    # the laser's truth and the SIP odometry describe one motion: a reference robot
    # integrated straight through agrees with both at their times
    ref = DiffDriveRobot(noise=EncoderNoise(relative_std=0.0))
    ref.enabled = True
    ref.set_velocity(1.0, 0.5)
    by_time = {round(s[0], 6): s[1:] for s in seen}
    for rec in base.sip_log[1:]:
        ref.advance_to(rec.sim_time)
        assert rec.true_pose == pytest.approx(ref.pose, abs=1e-9)
        assert rec.odom_pose[:2] == pytest.approx(ref.pose[:2], abs=1e-9)  # noise-free
        key = round(rec.sim_time, 6)
        if key in by_time:  # a scan at the same instant saw the same pose
            assert by_time[key] == pytest.approx(ref.pose, abs=1e-9)
    # between two SIPs a scan sees the pose interpolated along the arc, not the last SIP's
    mid = next(s for s in seen if 1.5 < s[0] < 1.6 and abs(s[0] * 10 - round(s[0] * 10)) > 0.1)
    before = [r for r in base.sip_log if r.sim_time < mid[0]][-1]
    after = next(r for r in base.sip_log if r.sim_time > mid[0])
    assert before.true_pose[0] < mid[1] < after.true_pose[0]
    assert math.hypot(mid[1] - before.true_pose[0], mid[2] - before.true_pose[1]) > 0.01

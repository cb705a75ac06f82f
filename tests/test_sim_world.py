"""Simulated world (walls via the Rust ray caster, both glass models, people), the
differential-drive robot, and the two-device session with both drivers on ptys."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from icploc.drivers.powerbot import PowerBot
from icploc.drivers.sick import PLS
from icploc.se2 import compose
from icploc.sim.powerbot_device import waypoint_plan
from icploc.sim.robot import DiffDriveRobot, EncoderNoise
from icploc.sim.scenes import box
from icploc.sim.session import SimSession
from icploc.sim.world import IncidenceGlass, Person, RandomGlass


def test_box_ranges_match_geometry() -> None:
    w = box(10.0, 8.0)
    r = w.ranges((5.0, 4.0, 0.0), [0.0, math.pi / 2, math.pi, -math.pi / 2, math.atan2(4, 5)], 30.0)
    np.testing.assert_allclose(r, [5.0, 4.0, 5.0, 4.0, math.hypot(5, 4)], atol=1e-9)
    r = w.ranges((5.0, 4.0, math.pi / 2), [0.0], 30.0)  # sensor heading rotates the beams
    assert r[0] == pytest.approx(4.0)
    assert np.isinf(w.ranges((5.0, 4.0, 0.0), [0.0], 3.0)).all()  # beyond max range


def test_incidence_glass_reflects_only_near_normal_incidence() -> None:
    w = box(10.0, 8.0, glass=np.array([[7.0, 0.0, 7.0, 8.0]]), glass_model=IncidenceGlass())
    r = w.ranges((5.0, 4.0, 0.0), [0.0, math.radians(5), math.radians(30)], 30.0)
    assert r[0] == pytest.approx(2.0)  # straight on: sees the glass
    assert r[1] == pytest.approx(2.0 / math.cos(math.radians(5)))  # within 10 deg of normal
    assert r[2] == pytest.approx(5.0 / math.cos(math.radians(30)))  # passes, hits the wall


def test_incidence_glass_reflect_probability_one_returns_every_beam() -> None:
    w = box(10.0, 8.0, glass=np.array([[7.0, 0.0, 7.0, 8.0]]), glass_model=IncidenceGlass(reflect_prob=1.0))
    r = w.ranges((5.0, 4.0, 0.0), [math.radians(30)], 30.0, rng=np.random.default_rng(0))
    assert r[0] == pytest.approx(2.0 / math.cos(math.radians(30)))


def test_random_glass_passes_the_transmitted_share_of_beams() -> None:
    w = box(10.0, 8.0, glass=np.array([[7.0, 0.0, 7.0, 8.0]]), glass_model=RandomGlass(0.7))
    r = w.ranges((5.0, 4.0, 0.0), np.zeros(4000), 30.0, rng=np.random.default_rng(3))
    behind = np.isclose(r, 5.0)  # through the glass onto the wall at x = 10
    assert np.isclose(r[~behind], 2.0).all()  # every other beam is returned by the glass
    assert behind.mean() == pytest.approx(0.7, abs=0.03)


def test_random_glass_without_a_generator_lets_every_beam_pass() -> None:
    w = box(10.0, 8.0, glass=np.array([[7.0, 0.0, 7.0, 8.0]]))  # RandomGlass by default
    np.testing.assert_allclose(w.ranges((5.0, 4.0, 0.0), np.zeros(10), 30.0), 5.0)


def test_range_noise_without_a_generator_is_an_error() -> None:
    with pytest.raises(ValueError, match="rng"):
        box().ranges((5.0, 4.0, 0.0), [0.0], 30.0, noise=0.01)


def test_people_are_deterministic_and_occlude() -> None:
    a, b = box(), box()
    a.add_random_people(4, seed=9)
    b.add_random_people(4, seed=9)
    for t in (0.0, 3.3, 17.0):
        np.testing.assert_array_equal(a.people_at(t), b.people_at(t))
    assert not np.array_equal(a.people_at(0.0), a.people_at(1.0))  # they move
    w = box(10.0, 8.0, people=[Person(np.array([[8.0, 4.0], [8.0, 4.0]]), speed=0.0, radius=0.5)])
    assert w.ranges((5.0, 4.0, 0.0), [0.0], 30.0)[0] == pytest.approx(2.5)


def test_range_noise() -> None:
    w = box(10.0, 8.0)
    ang = np.zeros(5000)
    r = w.ranges((5.0, 4.0, 0.0), ang, 30.0, noise=0.02, rng=np.random.default_rng(1))
    assert np.mean(r) == pytest.approx(5.0, abs=0.002) and np.std(r) == pytest.approx(
        0.02, rel=0.05
    )


def test_robot_straight_and_turn_without_noise() -> None:
    r = DiffDriveRobot(pose=(1.0, 2.0, 0.0), noise=EncoderNoise(relative_std=0.0))
    r.set_velocity(0.5, 0.0)
    for _ in range(500):
        r.step(0.01)
    # accelerates at 1 m/s^2 to 0.5 m/s (0.125 m during the ramp, + discretisation), then cruises
    assert r.pose[0] == pytest.approx(1.0 + 0.125 + 0.5 * 4.5, abs=5e-3) and r.pose[
        1
    ] == pytest.approx(2.0)
    assert r.odom[0] == pytest.approx(r.pose[0] - 1.0)
    r.set_velocity(0.0, math.pi / 4)
    for _ in range(1000):
        r.step(0.01)
    assert abs(r.pose[2]) > 0.1 and r.odom[2] == pytest.approx(r.pose[2], abs=1e-9)


def test_encoder_noise_makes_odometry_drift() -> None:
    r = DiffDriveRobot(noise=EncoderNoise(relative_std=0.02, right_scale=1.01), seed=4)
    r.set_velocity(1.0, 0.2)
    for _ in range(2000):
        r.step(0.01)
    err = math.hypot(r.odom[0] - r.pose[0], r.odom[1] - r.pose[1])
    assert 0.01 < err < 5.0


def test_collision_stalls() -> None:
    r = DiffDriveRobot(noise=EncoderNoise(relative_std=0.0), collides=lambda p: p[0] > 1.0)
    r.set_velocity(1.0, 0.0)
    for _ in range(300):
        r.step(0.01)
    assert r.pose[0] <= 1.0 and r.left_stall and r.right_stall


def test_session_both_drivers_test_mode() -> None:
    world = box(10.0, 8.0)
    plan = waypoint_plan([(2.0, 0.5, 0.0), (2.0, 0.0, 0.5)])
    with SimSession(
        world, start_pose=(2.0, 4.0, 0.0), plan=plan, realtime=False, laser_noise_std=0.0
    ) as sim:
        with PLS(sim.laser_port, baud_settle=0.0) as laser, PowerBot(sim.base_port) as bot:
            scans = list(laser.scans(limit=20))
            sips = list(bot.sips(limit=30))
        assert sim.errors == []
    assert len(scans) == 20 and len(sips) == 30
    # every scan is consistent with the true laser pose logged when it was taken
    _, pose, lp = sim.truth[-1]
    assert lp == pytest.approx(compose(pose, (0.251, 0.0, 0.0)))
    first = sim.truth[0][2]
    exp = world.ranges(first, sim.laser.beam_angles(), 50.0)
    np.testing.assert_allclose(scans[0].ranges, np.round(exp * 100) / 100, atol=0.006)
    assert sips[-1].pose[0] > 0.5  # the plan moved the robot


@pytest.mark.slow
def test_session_realtime_rates() -> None:
    """Line-time pacing in real time. A loaded machine can only delay single telegrams,
    so medians over many are compared, with margins such delays do not reach."""
    world = box(10.0, 8.0)
    world.add_random_people(2, seed=1)
    with SimSession(world, start_pose=(3.0, 4.0, 0.0), realtime=True) as sim:
        with PLS(sim.laser_port, baud_settle=0.05) as laser, PowerBot(sim.base_port) as bot:
            t0 = time.monotonic()
            scans = list(laser.scans(limit=12))
            dt_scans = np.diff([s.stamp for s in scans])
            sips = list(bot.sips(limit=15))
            dt_sips = np.diff([s.stamp for s in sips])
            # 11 telegram times at least: the line cannot run faster than its byte time
            assert time.monotonic() - t0 > 11 * 732 * 11 / 38400
    # a 732-byte telegram at 38400 Bd 8E1 occupies the line for 0.21 s; SIPs every 100 ms.
    # Never faster than that (the pacing), and a loaded machine may stretch it, not halve it
    line = 732 * 11 / 38400
    assert 0.95 * line < np.median(dt_scans) < 2.0 * line
    assert 0.095 < np.median(dt_sips) < 0.2
    # scan stamps = first byte of the telegram, within a few ms of when the sim took the scan
    taken = np.array([t for t, _, _ in sim.truth])
    lag = [float(np.min(np.abs(taken - s.stamp))) for s in scans[2:]]
    assert np.median(lag) < 0.02


def _scenario():  # type: ignore[no-untyped-def]
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
    import scenario

    return scenario


@pytest.mark.parametrize(("model", "expected"), [(IncidenceGlass(), 1.0), (RandomGlass(1.0), 6.0)])
def test_the_clinic_family_of_the_benchmarks_is_a_world(model: object, expected: float) -> None:
    """benches/scenario.py's clinic wing as a simulated world: from the corridor, straight
    at the nurse station's glass front (y = 5) 1 m away; seen through, the room's far wall."""
    from icploc.sim.scenes import from_plan

    c = _scenario().clinic_world()
    w = from_plan(c.name, c.opaque, c.glass, glass_model=model)  # type: ignore[arg-type]
    assert w.ranges((21.5, 6.0, -math.pi / 2), [0.0], 30.0)[0] == pytest.approx(expected)


def _drive(pursuit, pose, dt: float = 0.02, steps: int = 5000):  # type: ignore[no-untyped-def]
    """Integrate the pursuit's commands from ``pose``; the final pose and the step count."""
    x, y, th = pose
    for k in range(steps):
        cmd = pursuit.command((x, y, th))
        if cmd is None:
            return (x, y, th), k
        v, w = cmd
        x, y, th = x + v * dt * math.cos(th), y + v * dt * math.sin(th), th + w * dt
    raise AssertionError("the pursuit never finished")


def test_pure_pursuit_visits_the_waypoints_and_ends_on_the_last() -> None:
    from icploc.sim.pursuit import PurePursuit

    pursuit = PurePursuit(np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 2.0]]), tolerance=0.1)
    end, _ = _drive(pursuit, (0.0, 0.0, 0.0))
    assert math.hypot(end[0] - 2.0, end[1] - 2.0) < 0.1


def test_pursuit_plan_stops_and_says_done_at_the_end() -> None:
    from icploc.sim.pursuit import PursuitPlan

    plan = PursuitPlan(np.array([[0.0, 0.0], [1.0, 0.0]]), lambda: (0.95, 0.0, 0.0))
    assert (plan(0.0), plan.done.is_set()) == ((0.0, 0.0), True)


def test_a_random_walk_starts_on_its_start_stays_in_its_box_and_ends_at_the_origin() -> None:
    from icploc.sim.scenes import random_walk

    box = ((-2.2, 2.2), (2.2, 3.1))
    w = random_walk(12.0, seed=4, box=box, start=((0.0, 0.0), (0.0, 1.5)))
    inner = w[2:-1]
    steps = np.hypot(*np.diff(w[1:-1], axis=0).T)
    assert (
        w[:2].tolist(),
        w[-1].tolist(),
        bool(np.all((inner >= [box[0][0], box[1][0]]) & (inner <= [box[0][1], box[1][1]]))),
        bool(np.all(steps > 1.2)),
        float(np.hypot(*np.diff(w[:-1], axis=0).T).sum()) >= 12.0 - 3.0,
    ) == ([[0.0, 0.0], [0.0, 1.5]], [0.0, 0.0], True, True, True)

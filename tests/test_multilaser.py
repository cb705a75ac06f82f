"""Several lasers merged into one correction (icploc.multilaser), their config, CARMEN RLASER."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from icploc.cli import app
from icploc.config import ConfigError, LocalizerConfig
from icploc.localizer import OdometryBuffer
from icploc.logs import read_carmen, write_carmen
from icploc.maps import Map
from icploc.messages import Odometry, Scan
from icploc.multilaser import (
    BASE_FRAME,
    LaserMerger,
    LaserMount,
    MergedLasers,
    merge_stream,
    mounts,
)
from typer.testing import CliRunner

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import multilaser_sim as sim  # noqa: E402

FRONT = LaserMount("front_laser", "front_laser", x=0.2)
REAR = LaserMount("rear_laser", "rear_laser", x=-0.2, yaw=math.pi)
TWO = {"scan": {"lasers": [FRONT.to_dict(), REAR.to_dict()]}}


def _one_beam(stamp: float, rng: float, angle: float, frame: str) -> Scan:
    return Scan(stamp, np.array([rng]), np.array([angle]), max_range=8.0, frame=frame)


def _points(s: Scan) -> np.ndarray:
    return np.column_stack((s.ranges * np.cos(s.angles), s.ranges * np.sin(s.angles)))


# -- geometry ---------------------------------------------------------------------------------


def test_a_rear_laser_beam_lands_behind_the_robot() -> None:
    m = LaserMerger([FRONT, REAR])
    m.add(_one_beam(0.0, 2.0, 0.0, "front_laser"))
    (got,) = m.add(_one_beam(0.0, 1.0, 0.0, "rear_laser"))
    assert got.frame == BASE_FRAME
    assert sorted(map(tuple, _points(got).round(6))) == [(-1.2, 0.0), (2.2, 0.0)]


def test_an_upside_down_laser_sweeps_the_other_way() -> None:
    flipped = LaserMount("under", "under", upside_down=True)
    m = LaserMerger([flipped])
    (got,) = m.add(_one_beam(0.0, 1.0, math.radians(30.0), "under"))
    assert _points(got)[0] == pytest.approx((math.cos(math.radians(30)), -math.sin(math.radians(30))))


def test_an_earlier_scan_is_carried_to_the_later_ones_stamp_by_odometry() -> None:
    odo = OdometryBuffer()
    odo.add(Odometry(0.0, (0.0, 0.0, 0.0)))
    odo.add(Odometry(0.2, (0.2, 0.0, 0.0)))  # 1 m/s forward
    m = LaserMerger([FRONT, REAR], odometry=odo)
    m.add(_one_beam(0.0, 2.0, 0.0, "front_laser"))  # a wall 2.2 m ahead at t = 0
    (got,) = m.add(_one_beam(0.1, 1.0, 0.0, "rear_laser"))  # merged at t = 0.1
    assert got.stamp == 0.1
    # 0.1 m later the wall ahead is 0.1 m nearer
    assert max(_points(got)[:, 0]) == pytest.approx(2.1)


def test_time_offset_moves_a_laser_onto_the_odometry_clock() -> None:
    late = LaserMount("rear_laser", "rear_laser", x=-0.2, yaw=math.pi, time_offset=-0.05)
    m = LaserMerger([FRONT, late])
    m.add(_one_beam(1.0, 2.0, 0.0, "front_laser"))
    (got,) = m.add(_one_beam(1.1, 1.0, 0.0, "rear_laser"))
    assert got.stamp == pytest.approx(1.05)


# -- rounds -----------------------------------------------------------------------------------


def test_a_source_that_delivers_twice_closes_its_round_alone() -> None:
    m = LaserMerger([FRONT, REAR])
    m.add(_one_beam(0.0, 2.0, 0.0, "front_laser"))
    out = m.add(_one_beam(0.2, 2.0, 0.0, "front_laser"))
    assert len(out) == 1 and len(out[0]) == 1 and m.counters.partial == 1


def test_a_silent_laser_does_not_stop_the_other() -> None:
    m = LaserMerger([FRONT, REAR], max_wait=0.5)
    closed = [s for k in range(10) for s in m.add(_one_beam(0.2 * k, 2.0, 0.0, "front_laser"))]
    assert len(closed) == 9  # every front scan but the last (still open) made a round


def test_a_scan_from_an_unconfigured_frame_is_an_error_naming_the_frames() -> None:
    m = LaserMerger([FRONT, REAR])
    with pytest.raises(ValueError, match="'front_laser', 'rear_laser'"):
        m.add(_one_beam(0.0, 1.0, 0.0, "laser"))


def test_merge_stream_waits_for_the_odometry_to_reach_a_merged_scan() -> None:
    cfg = LocalizerConfig.from_dict(TWO)
    items: list[Any] = [
        Odometry(0.0, (0.0, 0.0, 0.0)),
        _one_beam(0.05, 2.0, 0.0, "front_laser"),
        _one_beam(0.10, 1.0, 0.0, "rear_laser"),
        Odometry(0.08, (0.08, 0.0, 0.0)),
        Odometry(0.12, (0.12, 0.0, 0.0)),
    ]
    kinds = [type(it).__name__ for it in merge_stream(items, cfg)]
    assert kinds == ["Odometry", "Odometry", "Odometry", "Scan"]


def test_merged_live_drivers_make_one_scan_per_round() -> None:
    class Fake:
        def __init__(self, scans: list[Scan]) -> None:
            self.scans = scans

        def get(self, timeout: float = 0.0) -> Scan | None:
            return self.scans.pop(0) if self.scans else None

    front = Fake([_one_beam(0.0, 2.0, 0.0, "laser"), _one_beam(0.2, 2.0, 0.0, "laser")])
    rear = Fake([_one_beam(0.01, 1.0, 0.0, "laser"), _one_beam(0.21, 1.0, 0.0, "laser")])
    lasers = MergedLasers([front, rear], [FRONT, REAR], LocalizerConfig(), OdometryBuffer())
    got = [lasers.get(timeout=0.0), lasers.get(timeout=0.0)]
    assert [len(s) for s in got if s is not None] == [2, 2]


class _SlowLine:
    """A live laser driver whose scans come in 0.21 s after their stamp (a PLS telegram on
    a 38400 Bd line), one every 0.25 s; ``offset``: its first stamp. ``now`` is the fake
    clock the test moves."""

    def __init__(self, now: list[float], offset: float, frame: str, last: float = math.inf) -> None:
        self.now, self.frame = now, frame
        self.stamps = [offset + 0.25 * k for k in range(40) if offset + 0.25 * k <= last]

    def get(self, timeout: float = 0.0) -> Scan | None:
        if self.stamps and self.stamps[0] + 0.21 <= self.now[0]:
            return _one_beam(self.stamps.pop(0), 2.0, 0.0, self.frame)
        return None


def _merged_rounds(monkeypatch: pytest.MonkeyPatch, rear_last: float = math.inf) -> list[int]:
    """Beams per merged round of a front laser and a rear one 0.15 s behind it, the
    loop polling every 10 ms of the fake clock for 5 s."""
    from icploc import clock

    now = [0.0]
    monkeypatch.setattr(clock, "now", lambda: now[0])
    lasers = MergedLasers([_SlowLine(now, 0.0, "laser"), _SlowLine(now, 0.15, "laser", rear_last)],
                          [FRONT, REAR], LocalizerConfig(), OdometryBuffer())  # fmt: skip
    sizes = []
    for k in range(500):
        now[0] = 0.01 * k
        s = lasers.get(timeout=0.0)
        if s is not None:
            sizes.append(len(s))
    return sizes


def test_live_rounds_wait_for_a_laser_whose_scans_are_slow_to_arrive(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Both lasers alive: every round but the first (the rear laser has not spoken yet)
    holds both, though each scan comes in 0.21 s after its stamp and the rear one 0.15 s
    after the front one (a wait of 0.3 s counted from the stamp closed them all alone)."""
    sizes = _merged_rounds(monkeypatch)
    assert sizes[1:] == [2] * (len(sizes) - 1)


def test_live_rounds_go_on_without_a_laser_that_fell_silent(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    sizes = _merged_rounds(monkeypatch, rear_last=1.5)  # the rear laser's last scan
    assert sizes[-8:] == [1] * 8  # the front laser's rounds alone, one per scan


# -- accuracy: a corridor ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def corridor_errors() -> dict[str, float]:
    run = sim.simulate(16.0, seed=0)
    return {w: sim.localize(run, w)["max_m"] for w in ("front", "rear", "both")}


def test_in_a_corridor_both_lasers_beat_the_front_one_alone(corridor_errors: dict[str, float]) -> None:
    assert corridor_errors["both"] < 0.5 * corridor_errors["front"]


def test_in_a_corridor_both_lasers_beat_the_rear_one_alone(corridor_errors: dict[str, float]) -> None:
    assert corridor_errors["both"] < 0.5 * corridor_errors["rear"]


# -- config -----------------------------------------------------------------------------------


def test_the_config_round_trips_through_yaml(tmp_path: Path) -> None:
    cfg = LocalizerConfig.from_dict(TWO)
    p = tmp_path / "c.yaml"
    cfg.save(p)
    assert mounts(LocalizerConfig.from_yaml(p)) == (FRONT, REAR)


@pytest.mark.parametrize(
    ("lasers", "needle"),
    [
        ([{"name": "a", "yaw": "left"}], "scan.lasers[0].yaw: expected a number"),
        ([{"name": "a"}, {"name": "b", "x": math.inf}], "scan.lasers[1].x: must be a finite number"),
        ([{"name": "a"}, {"name": "a"}], "scan.lasers[1].name: 'a' is already scan.lasers[0].name"),
        ([{"name": "a", "upside": True}], "scan.lasers[0]: unknown key 'upside'"),
        ([{"name": "a", "upside_down": "yes"}], "scan.lasers[0].upside_down: expected true/false"),
        ([{"name": "a", "time_offset": 3.0}], "scan.lasers[0].time_offset"),
        ([{"name": "a", "baud": 1234}], "scan.lasers[0].baud"),
        ("front", "scan.lasers: expected a list of lasers"),
        ([7], "scan.lasers[0]: expected a mapping"),
    ],
)
def test_config_errors_name_the_field(tmp_path: Path, lasers: Any, needle: str) -> None:
    p = tmp_path / "c.yaml"
    import yaml

    p.write_text(yaml.safe_dump({"scan": {"lasers": lasers}}))
    with pytest.raises(ConfigError, match=str(p)) as e:
        LocalizerConfig.from_yaml(p)
    assert needle in str(e.value)


def test_a_single_laser_mounting_beside_a_list_is_an_error() -> None:
    with pytest.raises(ConfigError, match="scan.laser_x: with scan.lasers"):
        LocalizerConfig.from_dict({"scan": {"laser_x": 0.1, "lasers": [{"name": "a"}]}})


# -- CARMEN FLASER + RLASER -------------------------------------------------------------------


@pytest.fixture(scope="module")
def two_laser_log(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("two")
    run = sim.simulate(12.0, seed=1)
    scans = run["scans"]
    odo = OdometryBuffer()
    for o in run["odometry"]:
        odo.add(o)
    per_scan = [odo.pose_at(s.stamp) for s in scans]
    log = d / "two.log"
    write_carmen(log, scans, (), scan_odometry=per_scan)
    cfg = d / "lasers.yaml"
    LocalizerConfig.from_dict(TWO).save(cfg)
    return {"log": log, "map": Map.from_lines(run["walls"]).to_ros(d / "m.yaml", 0.05),
            "config": cfg, "rounds": len(scans) // 2}  # fmt: skip


def test_carmen_reads_both_laser_streams(two_laser_log: dict[str, Any]) -> None:
    data = read_carmen(two_laser_log["log"], rear_laser=True)
    frames = [s.frame for s in data.scans]
    n = two_laser_log["rounds"]
    assert (frames.count("front_laser"), frames.count("rear_laser")) == (n, n)


def test_carmen_without_rear_laser_skips_and_says_so(two_laser_log: dict[str, Any]) -> None:
    data = read_carmen(two_laser_log["log"])
    assert {s.frame for s in data.scans} == {"front_laser"}
    assert any("RLASER" in n and "scan.lasers" in n for n in data.info.notes)


def test_replay_of_a_two_laser_log_merges_them(two_laser_log: dict[str, Any], tmp_path: Path) -> None:
    out = tmp_path / "t.tum"
    r = CliRunner().invoke(
        app,
        [
            "replay", str(two_laser_log["log"]), "--map", str(two_laser_log["map"]),
            "--config", str(two_laser_log["config"]), "--initial-pose", "2,0,0",
            "--out", str(out), "--no-progress",
        ],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    rows = out.read_text().splitlines()
    assert len(rows) == two_laser_log["rounds"]  # one estimate per round


# -- icploc run with two PLS --------------------------------------------------------------------


def _pls_at(world: Any, robot: tuple[float, float, float], mount: LaserMount) -> Any:
    from icploc.se2 import compose
    from icploc.sim.device import DeviceRunner
    from icploc.sim.pls_device import PLSDevice

    sensor = compose(robot, mount.mounting)
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    ranges = np.minimum(world.ranges(sensor, angles, 8.0), 50.0)  # no return: the PLS maximum
    return DeviceRunner(PLSDevice(source=lambda t: ranges), realtime=True)


@pytest.mark.slow
def test_run_with_two_pls_merges_both(tmp_path: Path) -> None:
    from icploc import live
    from icploc.sim.world import World

    walls = np.array([[0, -1, 16, -1], [16, -1, 16, 1], [16, 1, 0, 1], [0, 1, 0, -1], [5, -1, 5, -0.6]], float)
    world = World("corridor", walls)
    robot = (3.0, 0.0, 0.0)
    m = Map.from_lines(walls).to_ros(tmp_path / "m.yaml", 0.05)
    with _pls_at(world, robot, FRONT) as a, _pls_at(world, robot, REAR) as b:
        res = live.run_hardware(m, a.port, None, config=LocalizerConfig.from_dict(TWO), initial_pose=(3.05, 0.02, 0.01),
                                duration=3.0, extra_lasers=[b.port], laser_baud=500000)  # fmt: skip
    last = res.estimates[-1]
    # both lasers' beams in one scan (each PLS gives 361; the front one's are all walls); a
    # round closed early by a starved host (a laser silent for 0.5 s) may hold one laser, so
    # most rounds, not every one, must hold both
    merged = [e for e in res.estimates if e.num_points > 361]
    assert 2 * len(merged) >= len(res.estimates) > 0
    assert math.hypot(last.x - 3.0, last.y) < 0.02


def test_run_with_two_ports_needs_the_lasers_listed(tmp_path: Path) -> None:
    from icploc import live

    m = Map.from_lines(sim.corridor()).to_ros(tmp_path / "m.yaml", 0.05)
    with pytest.raises(live.RunUsageError, match="scan.lasers"):
        live.run_hardware(m, "/dev/null", None, extra_lasers=["/dev/zero"])


def test_run_refuses_a_recording_of_several_lasers(tmp_path: Path) -> None:
    from icploc import live

    m = Map.from_lines(sim.corridor()).to_ros(tmp_path / "m.yaml", 0.05)
    with pytest.raises(live.RunUsageError, match="--record holds one laser"):
        live.run_hardware(m, "/dev/null", None, config=LocalizerConfig.from_dict(TWO),
                          extra_lasers=["/dev/zero"], record=tmp_path / "r.icpraw")  # fmt: skip


@pytest.fixture(scope="module")
def driving_two_pls() -> dict[str, Any]:
    """A simulated PowerBot driving 5 m down a corridor with its own PLS in front and a
    second simulated PLS facing back (icploc.multilaser.simulated_laser), localized live
    through MergedLasers; the error against the simulator's truth (interpolated)."""
    from icploc import clock, live
    from icploc.drivers.powerbot import PowerBot
    from icploc.localizer import Localizer
    from icploc.multilaser import localizer_config, open_lasers, simulated_laser
    from icploc.sim.pursuit import PursuitPlan
    from icploc.sim.session import SimSession
    from icploc.sim.world import World

    walls = sim.corridor(12.0)
    holder: list[Any] = []
    plan = PursuitPlan(np.array([[2.0, 0.0], [7.0, 0.0]]), lambda: holder[0].robot.pose, speed=0.6)
    sess = SimSession(World("corridor", walls), start_pose=(2.0, 0.0, 0.0), plan=plan, laser_max_range=8.0, seed=0)
    holder.append(sess)
    front = LaserMount("front", "front", x=sess.laser_offset[0])
    cfg = LocalizerConfig.from_dict({"scan": {"lasers": [front.to_dict(), REAR.to_dict()]}})
    loc = Localizer(Map.from_lines(walls), localizer_config(cfg), initial_pose=(2.0, 0.0, 0.0))
    end = [math.inf]

    def finished() -> bool:
        now = clock.now()
        if plan.done.is_set() and end[0] == math.inf:
            end[0] = now + 0.5
        return now >= end[0]

    with sess, simulated_laser(sess, REAR) as rear:
        # the simulators share the host with the loop: a stall timeout a starved host cannot
        # reach while they stream (1 s was, now and then: both lasers reconnected mid-run)
        with open_lasers([sess.laser_port, rear.port], [38400, 38400], reconnect_timeout=5.0,
                         connect_baudrates=(9600, 38400), stall_timeout=4.0) as drivers:  # fmt: skip
            bot = PowerBot(sess.base_port)
            bot.connect()
            try:
                merged = MergedLasers(drivers, mounts(cfg), cfg, loc.odometry)
                res = live.run_live(loc, merged, bot, duration=30.0, stop=finished)
            finally:
                bot.close()
        truth = [(t, p) for t, p, _ in sess.truth]
    ts = np.array([t for t, _ in truth])
    ps = np.array([p for _, p in truth])
    st = np.array([e.stamp for e in res.estimates])
    err = np.hypot(np.array([e.x for e in res.estimates]) - np.interp(st, ts, ps[:, 0]),
                   np.array([e.y for e in res.estimates]) - np.interp(st, ts, ps[:, 1]))  # fmt: skip
    return {"res": res, "err": err, "points": [e.num_points for e in res.estimates]}


@pytest.mark.slow
def test_driving_with_two_pls_merges_both_lasers(driving_two_pls: dict[str, Any]) -> None:
    assert np.median(driving_two_pls["points"]) > 361  # one PLS gives 361 beams


@pytest.mark.slow
def test_driving_with_two_pls_stays_on_the_truth(driving_two_pls: dict[str, Any]) -> None:
    assert np.median(driving_two_pls["err"]) < 0.01


@pytest.mark.slow
def test_driving_with_two_pls_keeps_tracking(driving_two_pls: dict[str, Any]) -> None:
    res = driving_two_pls["res"]
    assert sum(e.status.value == "tracking" for e in res.estimates) >= 0.8 * len(res.estimates)

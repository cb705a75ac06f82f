"""Start refinement without moving (icploc.startrefine): verdicts and what the localizer does."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from icploc.cli import app
from icploc.live import tum_row
from icploc.localizer import Localizer, Status
from icploc.logs import write_carmen
from icploc.maps import Map
from icploc.messages import Odometry, Scan
from icploc.se2 import wrap_angle
from icploc.sim.world import World
from icploc.startrefine import REFINING, StartRefineConfig, combine_scans
from typer.testing import CliRunner

#: a room with features (no symmetry): every pose in it is unique
ROOM = np.array(
    [
        [0, 0, 12, 0], [12, 0, 12, 8], [12, 8, 0, 8], [0, 8, 0, 0],
        [3, 0, 3, 3], [7, 8, 7, 5], [9, 2, 11, 2], [5, 3, 6, 4],
    ],
    dtype=np.float64,
)  # fmt: skip
#: a square room: seen from its centre it looks the same every 90 degrees
SQUARE = np.array([[0, 0, 6, 0], [6, 0, 6, 6], [6, 6, 0, 6], [0, 6, 0, 0]], dtype=np.float64)
ANGLES = np.radians(np.arange(-180.0, 180.0, 1.0))
HALF = np.radians(np.arange(-90.0, 90.5, 0.5))


def _scans(walls: np.ndarray, pose: tuple[float, float, float], n: int, angles: np.ndarray = HALF,
           seed: int = 0) -> list[Scan]:  # fmt: skip
    w = World("room", walls)
    rng = np.random.default_rng(seed)
    return [
        Scan(0.2 * k, w.ranges(pose, angles, 8.0, rng=rng, noise=0.01), angles, max_range=8.0)
        for k in range(n)
    ]


def _localizer(walls: np.ndarray, given: tuple[float, float, float], sxy: float, sth: float) -> Localizer:
    loc = Localizer(Map.from_lines(walls), initial_pose=given)
    loc.reset(given, np.diag([sxy**2, sxy**2, sth**2]))
    return loc


def _err(a: tuple[float, float, float], b: tuple[float, float, float]) -> tuple[float, float]:
    return math.hypot(a[0] - b[0], a[1] - b[1]), abs(wrap_angle(a[2] - b[2]))


def test_a_start_off_within_its_covariance_is_refined_onto_the_truth() -> None:
    truth = (4.0, 5.0, 0.3)
    given = (4.35, 4.8, 0.42)  # 0.4 m and 7 deg off; the stated sigma: 0.2 m, 0.1 rad
    loc = _localizer(ROOM, given, 0.2, 0.1)
    r = loc.refine_start()
    for s in _scans(ROOM, truth, 5):
        loc.update(s, (0.0, 0.0, 0.0))
    assert r.verdict is not None and r.verdict.verdict == "refined"
    d, a = _err(loc.pose, truth)
    assert d < 0.02 and a < math.radians(0.5)


def test_the_verdict_says_how_far_the_pose_moved() -> None:
    truth = (4.0, 5.0, 0.3)
    given = (4.35, 4.8, 0.42)
    loc = _localizer(ROOM, given, 0.2, 0.1)
    r = loc.refine_start()
    for s in _scans(ROOM, truth, 5):
        loc.update(s, (0.0, 0.0, 0.0))
    assert r.verdict is not None
    dx, dy, dth = r.verdict.change
    assert (dx, dy, dth) == pytest.approx((-0.35, 0.2, -0.12), abs=0.02)


def test_nothing_is_tracking_before_the_verdict() -> None:
    truth = (4.0, 5.0, 0.3)
    loc = _localizer(ROOM, truth, 0.2, 0.1)
    r = loc.refine_start()
    early = []
    for s in _scans(ROOM, truth, 5):
        e = loc.update(s, (0.0, 0.0, 0.0))
        if r.verdict is None:
            early.append((e.status, e.reason))
    assert early and all(st is Status.DEGRADED and why == REFINING for st, why in early)


def test_tracking_resumes_after_a_refined_start() -> None:
    truth = (4.0, 5.0, 0.3)
    loc = _localizer(ROOM, (4.3, 5.2, 0.2), 0.2, 0.1)
    r = loc.refine_start()
    last = None
    for s in _scans(ROOM, truth, 6):
        last = loc.update(s, (0.0, 0.0, 0.0))
    assert r.verdict is not None and r.verdict.refined
    assert last is not None and last.status is Status.TRACKING


def test_a_symmetric_room_is_ambiguous_and_the_localizer_says_lost() -> None:
    # the centre of a square room, the heading known to +-1 rad: 90 degrees apart the
    # room looks the same
    truth = (3.0, 3.0, 0.2)
    loc = _localizer(SQUARE, (3.05, 2.95, 0.3), 0.1, 1.0)
    r = loc.refine_start()
    last = None
    for s in _scans(SQUARE, truth, 5, ANGLES):
        last = loc.update(s, (0.0, 0.0, 0.0))
        if r.verdict is not None:
            break
    assert r.verdict is not None and r.verdict.verdict == "ambiguous"
    assert last is not None and (last.status, last.reason) == (Status.LOST, "start_ambiguous")


def test_a_start_somewhere_else_is_rejected_and_localized_globally() -> None:
    truth = (4.0, 5.0, 0.3)
    given = (9.5, 6.0, -1.0)  # the wrong place, claimed to 5 cm
    loc = _localizer(ROOM, given, 0.05, 0.02)
    r = loc.refine_start()
    for s in _scans(ROOM, truth, 5):
        loc.update(s, (0.0, 0.0, 0.0))
        if r.verdict is not None:
            break
    assert r.verdict is not None and r.verdict.verdict == "rejected"
    assert loc.status is Status.LOST and loc.covariance[0, 0] > 1e3


def test_a_robot_that_moves_before_the_refinement_converged_stops_it() -> None:
    truth = (4.0, 5.0, 0.3)
    loc = _localizer(ROOM, truth, 0.2, 0.1)
    r = loc.refine_start()
    scans = _scans(ROOM, truth, 2)
    loc.update(scans[0], (0.0, 0.0, 0.0))
    loc.update(scans[1], (0.10, 0.0, 0.0))  # 10 cm of odometry
    assert r.verdict is not None and r.verdict.verdict == "moved"
    assert r.verdict.pose == truth and loc.status is not Status.LOST


def test_the_moved_verdict_says_how_far_the_odometry_moved() -> None:
    truth = (4.0, 5.0, 0.3)
    loc = _localizer(ROOM, truth, 0.2, 0.1)
    r = loc.refine_start()
    scans = _scans(ROOM, truth, 2)
    loc.update(scans[0], (0.0, 0.0, 0.0))
    loc.update(scans[1], (0.10, 0.0, 0.0))
    assert r.verdict is not None and "the odometry moved 0.100 m" in r.verdict.reason


def test_refine_start_needs_a_pose() -> None:
    loc = Localizer(Map.from_lines(ROOM))  # no initial pose: lost
    with pytest.raises(ValueError, match="no pose to refine"):
        loc.refine_start()


@pytest.mark.parametrize(
    ("field", "value"),
    [("scans", 0), ("window_sigmas", -1.0), ("still_distance", math.nan), ("confirm_scans", 9)],
)
def test_bad_settings_name_the_field(field: str, value: float) -> None:
    with pytest.raises(ValueError, match=f"startrefine.{field}"):
        StartRefineConfig(**{field: value})


def test_combining_scans_drops_a_person_seen_in_a_minority_of_them() -> None:
    walls = _scans(ROOM, (4.0, 5.0, 0.3), 5)
    person = [s.ranges.copy() for s in walls]
    for r in person[:2]:
        r[170:190] = 0.8  # someone passing in front in two of five scans
    scans = [Scan(s.stamp, r, s.angles, max_range=8.0) for s, r in zip(walls, person, strict=True)]
    got = combine_scans(scans)
    assert got is not None
    assert np.all(got.ranges[170:190] > 1.5)


def test_combining_scans_with_different_beams_gives_none() -> None:
    a = _scans(ROOM, (4.0, 5.0, 0.3), 1)[0]
    b = _scans(ROOM, (4.0, 5.0, 0.3), 1, ANGLES)[0]
    assert combine_scans([a, b]) is None


@pytest.fixture(scope="module")
def still_log(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("refine")
    truth = (4.0, 5.0, 0.3)
    scans = _scans(ROOM, truth, 8)
    odoms = [Odometry(s.stamp, (0.0, 0.0, 0.0)) for s in scans]
    log = d / "still.log"
    write_carmen(log, scans, odoms, scan_odometry=[o.pose for o in odoms])
    tum = d / "truth.tum"
    tum.write_text("".join(tum_row(s.stamp, truth) for s in scans))
    return {"log": log, "map": Map.from_lines(ROOM).to_ros(d / "m.yaml", 0.05), "truth": tum}


def test_replay_refine_start_prints_the_verdict(still_log: dict[str, Path]) -> None:
    r = CliRunner().invoke(
        app,
        [
            "replay", str(still_log["log"]), "--map", str(still_log["map"]),
            "--initial-pose", "4.3,4.8,0.4", "--refine-start", "--no-progress",
        ],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "start refined after" in r.output


def test_replay_refine_start_without_a_pose_is_one_error_line(still_log: dict[str, Path]) -> None:
    r = CliRunner().invoke(
        app, ["replay", str(still_log["log"]), "--map", str(still_log["map"]), "--refine-start"]
    )
    assert r.exit_code == 1
    assert "no pose to refine" in r.output and "Traceback" not in r.output

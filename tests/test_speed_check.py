"""The tracking kidnap check (``GlobalRelocalization.check_pose``) decides from its one
floored search when no distinct pose reaches the floor: ``""`` when the tracked place
itself reached it (or the tracked pose is a good fit), ``"unsure"`` when no place did. It
no longer searches the whole map a second time, down to the plain search's own floor, to
tell the two apart (on freiburg-campus' 5 cm maps that second search was 2-4x the first)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from icploc import sim
from icploc.config import LocalizerConfig
from icploc.localizer import prepare_scan
from icploc.relocalize import GlobalRelocalization, Relocalizer, global_localizer

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import global_bench as gb  # noqa: E402

CFG = LocalizerConfig()
SENSOR = gb.Sensor()


class Spy:
    """A GlobalLocalizer that records each search's floor."""

    def __init__(self, glob: Any) -> None:
        self.glob = glob
        self.floors: list[float | None] = []

    def search(self, *a: Any, **k: Any) -> Any:
        self.floors.append(k.get("min_score"))
        return self.glob.search(*a, **k)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.glob, name)


def _room() -> sim.World:
    """One irregular room (12 m x 8 m with a notch, a pillar and a wall stub): no two
    places in it look alike."""
    w = [
        [0.0, 0.0, 12.0, 0.0], [12.0, 0.0, 12.0, 5.0], [12.0, 5.0, 9.0, 5.0],
        [9.0, 5.0, 9.0, 8.0], [9.0, 8.0, 0.0, 8.0], [0.0, 8.0, 0.0, 0.0],
        [3.0, 0.0, 3.0, 2.5], [6.0, 6.0, 7.5, 6.0],
    ]  # fmt: skip
    w += sim.rect(5.0, 2.5, 5.6, 3.1)
    return sim.World("room", np.array(w), start=(2.0, 5.0, 0.0))


@pytest.fixture(scope="module")
def room() -> tuple[sim.World, Any]:
    world = _room()
    return world, global_localizer(world.lines, 0.05)


def _checker(glob: Any) -> tuple[GlobalRelocalization, Spy]:
    spy = Spy(glob)
    return GlobalRelocalization(Relocalizer(None, localizer=spy), config=CFG), spy


def _cluttered(world: sim.World, truth: tuple[float, float, float], frac: float, seed: int) -> Any:
    """A scan at ``truth`` with ``frac`` of its points replaced by clutter 0.3-1.5 m in
    front of the robot (people, boxes): the true place fits half well, others worse."""
    rng = np.random.default_rng(seed)
    pts = prepare_scan(gb.scan_at(world, truth, 0.0, SENSOR, rng), CFG)
    k = rng.choice(len(pts), int(frac * len(pts)), replace=False)
    a, r = rng.uniform(-math.pi / 2, math.pi / 2, len(k)), rng.uniform(0.3, 1.5, len(k))
    pts[k] = np.column_stack([r * np.cos(a), r * np.sin(a)])
    return pts


def test_the_one_place_at_the_floor_is_confirmed_with_one_search(room) -> None:  # noqa: ANN001
    """Half the scan clutter: the true place is the only one the floored search finds
    (nothing distinct reaches the floor), so the tracked pose explains the scan as well
    as any: "" from that one search, as the plain search says too."""
    world, glob = room
    checker, spy = _checker(glob)
    truth = (8.0, 2.0, 2.5)
    pts = _cluttered(world, truth, 0.5, 0)
    found = glob.search(pts, min_score=0.8 * checker.relocalizer.config.min_score).candidates
    assert found and not [c for c in found if glob.distinct(truth, c.pose)]
    spy.floors.clear()
    v = checker.check_pose(glob.index, pts, truth)
    assert (v.verdict, v.pose) == ("", None) and v.here == v.best
    assert len(spy.floors) == 1 and spy.floors[0] > checker.global_search.min_score
    assert checker.check_pose(glob.index, pts, truth, floored=False).verdict == ""


def test_one_search_decides_and_differs_from_the_plain_one_only_between_calm_verdicts(
    room,  # noqa: ANN001
) -> None:
    """Across clutter levels and places: every floored tracking check makes one search,
    finds what the plain search finds ("elsewhere" and its pose alike), and where the two
    differ it is "" against the plain "unsure": the tracked place the only one at the
    floor, the plain search's best distinct pose below the confirming minimum and no
    better than the tracked pose."""
    world, glob = room
    checker, spy = _checker(glob)
    need = checker.relocalizer.config.min_score
    seen = {"": 0, "unsure": 0, "differ": 0}
    for seed in range(4, 10):
        for truth in [(2.0, 5.0, 0.3), (8.0, 2.0, 2.5), (10.5, 3.5, -1.9)]:
            for frac in (0.2, 0.55, 0.65):
                pts = _cluttered(world, truth, frac, seed)
                spy.floors.clear()
                a = checker.check_pose(glob.index, pts, truth)
                assert len(spy.floors) == 1
                b = checker.check_pose(glob.index, pts, truth, floored=False)
                assert a.here == b.here
                seen[a.verdict] = seen.get(a.verdict, 0) + 1
                if a.verdict == b.verdict:
                    continue
                seen["differ"] += 1
                assert (a.verdict, b.verdict) == ("", "unsure")
                assert b.best < need and b.best <= 0.8 * a.here
    assert seen[""] and seen["unsure"], seen


def test_a_kidnapped_robot_is_found_elsewhere_with_one_search(room) -> None:  # noqa: ANN001
    world, glob = room
    checker, spy = _checker(glob)
    rng = np.random.default_rng(4)
    truth, tracked = (8.0, 2.0, 2.5), (2.0, 5.0, 0.3)
    pts = prepare_scan(gb.scan_at(world, truth, 0.0, SENSOR, rng), CFG)
    spy.floors.clear()
    v = checker.check_pose(glob.index, pts, tracked)
    assert v.verdict == "elsewhere" and v.pose is not None
    assert math.hypot(v.pose[0] - truth[0], v.pose[1] - truth[1]) < 0.2
    assert len(spy.floors) == 1
    assert v.best > v.here


def test_a_scan_that_fits_nowhere_is_unsure_with_one_search(room) -> None:  # noqa: ANN001
    """A scan of scattered points (nothing the room has) fits no place of it, the
    tracked one included: no place reaches the floor, and the check says so without a
    second whole-map search."""
    _world, glob = room
    checker, spy = _checker(glob)
    pts = np.random.default_rng(1).uniform(-6.0, 6.0, size=(300, 2))
    assert not glob.search(pts, min_score=0.8 * checker.relocalizer.config.min_score).candidates
    spy.floors.clear()
    v = checker.check_pose(glob.index, pts, (6.0, 4.0, 0.0))
    assert v.verdict == "unsure" and v.pose is None
    assert len(spy.floors) == 1 and spy.floors[0] is not None
    assert v.best == 0.0 and v.here < checker.relocalizer.config.min_score
    # a floor at or below the search's own (a map whose usual fit is poor): the plain
    # search, decided as before
    low = GlobalRelocalization(Relocalizer(None, localizer=spy), config=CFG)
    low.relocalizer._min_score = 0.5 * low.global_search.min_score
    spy.floors.clear()
    low.check_pose(glob.index, pts, (6.0, 4.0, 0.0))
    assert spy.floors == [None]

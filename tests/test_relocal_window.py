"""While lost with a dead-reckoned pose that means something (lost on biased odometry, not
kidnapped), the global search looks where the robot can be — a window of the
dead-reckoned pose's covariance — and a leader there locks after
``relocalize.prior_confirm_scans`` scans; every ``relocalize.full_search_every``-th search
and every search from a pose that says nothing (a kidnapping, no initial pose) still
covers the whole map."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from icploc import GlobalLocalizer
from icploc import sim as worlds
from icploc.config import ConfigError, LocalizerConfig
from icploc.localizer import prepare_scan
from icploc.recovery import RecoveryView
from icploc.relocalize import GlobalRelocalization, Relocalizer, global_localizer
from icploc.se2 import Pose, between

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import global_bench as gb  # noqa: E402

SENSOR = gb.Sensor()
CFG = LocalizerConfig()


@pytest.fixture(scope="module")
def bld() -> worlds.World:
    return gb.building()


@pytest.fixture(scope="module")
def bld_glob(bld: worlds.World) -> GlobalLocalizer:
    return global_localizer(bld.walls, 0.05)


class Recording:
    """A GlobalLocalizer that records the region and heading of every search."""

    def __init__(self, glob: GlobalLocalizer) -> None:
        self.glob = glob
        self.calls: list[tuple[Any, Any]] = []

    def search(self, pts: Any, region: Any = None, heading: Any = None) -> Any:
        self.calls.append((region, heading))
        return self.glob.search(pts, region, heading)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.glob, name)


def _view(glob: GlobalLocalizer, pose: Pose, cov: np.ndarray, k: int, cfg: LocalizerConfig = CFG) -> RecoveryView:
    return RecoveryView(
        pose=pose,
        covariance=cov,
        motion=(0.0, 0.0, 0.0),
        stamp=0.1 * k,  # 10 Hz
        scans_processed=k,
        lost_scans=k + 1,
        index=glob.index,
        icp_config=cfg.icp.to_icp_config(window_search=False),
        config=cfg,
        verify=lambda pts, p: (False, None, p),  # never locks: only the searches matter
    )


#: the dead-reckoned pose (in the corridor) and where the robot really is (an office)
DR = (10.0, 1.0, 0.3)
TRUTH = (30.0, 15.0, 1.0)
#: the search schedule under the defaults and under other settings (no time throttle, so
#: the scan counts alone decide): the tests check the schedule follows the settings
SCHEDULES = [
    CFG,
    CFG.replace(
        localizer={"global_search_every": 6, "global_search_interval": 0.0, "local_recovery_scans": 2},
        relocalize={"full_search_every": 3},
    ),
]


def _searches(
    bld: worlds.World, glob: GlobalLocalizer, cov: np.ndarray, n: int, cfg: LocalizerConfig = CFG
) -> list:
    rec = Recording(glob)
    gr = GlobalRelocalization(Relocalizer(None, localizer=rec), config=cfg)
    pts = prepare_scan(gb.scan_at(bld, TRUTH, 0.0, SENSOR, np.random.default_rng(0)), cfg)
    calls = []
    for k in range(n):
        before = len(rec.calls)
        gr.recover(_view(glob, DR, cov, k, cfg), pts)
        calls += [(k, *c) for c in rec.calls[before:]]
    return calls


def test_a_meaningful_dead_reckoned_pose_bounds_the_search(bld, bld_glob) -> None:
    """sigma 0.5 m, 0.1 rad: after the local phase (local_recovery_scans, 3) the search
    covers +- (3 x 0.5 + 1) m around the pose and +- (3 x 0.1 + 0.35) rad, clipped to the
    map, not the 40 x 20 m floor (the held-out orebro log: a search of the whole map took
    ~1 s, most of its run time)."""
    calls = _searches(bld, bld_glob, np.diag([0.25, 0.25, 0.01]), 4)
    assert len(calls) == 1
    k, region, heading = calls[0]
    assert k == 3
    assert region == pytest.approx((7.5, 0.0, 12.5, 3.5))
    assert heading == pytest.approx((0.3 - 0.65, 0.3 + 0.65))


def _periods(cfg: LocalizerConfig) -> tuple[int, int, int]:
    lc = cfg.localizer
    return lc.local_recovery_scans, lc.global_search_every, cfg.relocalize.full_search_every


@pytest.mark.parametrize("cfg", SCHEDULES, ids=["defaults", "other-settings"])
def test_the_whole_map_after_a_fruitless_window_and_then_once_per_full_search_every_periods(
    bld, bld_glob, cfg: LocalizerConfig
) -> None:
    """A robot carried off that the lost detector caught before any kidnap check did: its
    covariance does not say its dead reckoning means nothing. The first global search (after
    the local phase) is the window; it brings no leader, so the next scan searches the whole
    map; from then on the whole map once per full_search_every x global_search_every scans,
    the window in the periods between."""
    local, every, k = _periods(cfg)
    n = local + 2 + 2 * every * k  # the window, the whole map, then two full periods
    calls = _searches(bld, bld_glob, np.diag([0.25, 0.25, 0.01]), n, cfg)
    whole = [s for s, region, _ in calls if region is None]
    first_window = min(s for s, region, _ in calls if region is not None)
    assert first_window == local
    assert whole[0] == first_window + 1
    assert np.diff(whole).tolist() == [every * k] * 2
    between = [s for s, region, _ in calls if region is not None and whole[0] < s < whole[1]]
    assert len(between) == k - 1


@pytest.mark.parametrize("cfg", SCHEDULES, ids=["defaults", "other-settings"])
def test_the_window_is_throttled_as_the_whole_map_is(bld, bld_glob, cfg: LocalizerConfig) -> None:
    """Refining a window's seeds costs about as much as a whole-map search's: after the
    whole map, at most one search per global_search_every scans (none locks here, so none
    is made to verify a leader), each a full period after the last."""
    local, every, k = _periods(cfg)
    calls = _searches(bld, bld_glob, np.diag([0.25, 0.25, 0.01]), local + 2 + 2 * every * k, cfg)
    steps = [s for s, _, _ in calls]
    assert steps == sorted(set(steps))  # one search per scan at most
    assert np.diff(steps[1:]).tolist() == [every] * (len(steps) - 2)


@pytest.mark.parametrize("cfg", SCHEDULES, ids=["defaults", "other-settings"])
def test_a_pose_that_says_nothing_searches_the_whole_map(bld, bld_glob, cfg: LocalizerConfig) -> None:
    """A kidnapping (or no initial pose): the localizer's unknown covariance; the whole map
    from the first lost scan on (no local phase: the pose is nowhere near), throttled as
    before (one search per global_search_every scans)."""
    _, every, _ = _periods(cfg)
    calls = _searches(bld, bld_glob, np.diag([1e6, 1e6, math.pi**2]), 2 * every + 5, cfg)
    assert {r for _, r, _ in calls} == {None}
    assert [s for s, _, _ in calls] == [0, every, 2 * every]


def test_a_window_covering_most_of_the_map_searches_all_of_it(bld, bld_glob) -> None:
    calls = _searches(bld, bld_glob, np.diag([25.0, 25.0, 0.01]), 1)  # sigma 5 m
    assert [(r, h) for _, r, h in calls] == [(None, None)]


class _Index:
    """A stand-in for a MapIndex with the given ``bounds`` (``missing``: no attribute)."""

    def __init__(self, bounds: Any = "missing") -> None:
        if bounds != "missing":
            self.bounds = bounds


def _window_of(index: Any, pose: Pose = DR) -> Any:
    gr = GlobalRelocalization(None, config=CFG)
    view = _view(_FakeGlob(index), pose, np.diag([0.25, 0.25, 0.01]), 5)  # type: ignore[arg-type]
    return gr.window(view)


class _FakeGlob:
    def __init__(self, index: Any) -> None:
        self.index = index


def test_the_window_is_clipped_to_the_map_bounds() -> None:
    got = _window_of(_Index((0.0, 0.0, 40.0, 20.0)))
    assert got is not None
    assert got[0] == pytest.approx((7.5, 0.0, 12.5, 3.5))


@pytest.mark.parametrize("bounds", ["missing", None], ids=["no-attribute", "none"])
def test_an_index_without_bounds_searches_the_whole_map(bounds: Any) -> None:
    """No map extent: the window can be neither clipped nor compared with the map, so the
    whole map is searched (as for a pose that says nothing), where the same pose on a map
    with bounds gets a window."""
    assert _window_of(_Index((0.0, 0.0, 40.0, 20.0))) is not None
    assert _window_of(_Index(bounds)) is None


@pytest.mark.parametrize(
    "bounds", [(0.0, 0.0, 40.0), (0.0, 0.0, math.nan, 20.0), (40.0, 0.0, 0.0, 20.0), "abcd", 7]
)
def test_broken_index_bounds_are_an_error_not_a_whole_map_search(bounds: Any) -> None:
    with pytest.raises(ValueError, match=r"map index bounds .*expected \(xmin, ymin, xmax, ymax\)"):
        _window_of(_Index(bounds))


def _drive(world: worlds.World, start: Pose, n: int) -> list[tuple[Pose, np.ndarray]]:
    rng = np.random.default_rng(4)
    return [(p, prepare_scan(s, CFG)) for p, s in gb.drive(world, start, n, SENSOR, rng)]


def _statuses(glob: GlobalLocalizer, frames: list, prior_offset: float | None) -> list[str]:
    rel = Relocalizer(None, localizer=glob)
    out, prev = [], None
    cov = np.diag([0.25, 0.25, 0.01])
    for pose, pts in frames:
        m = between(prev, pose) if prev is not None else None
        prior = None
        if prior_offset is not None:
            prior = ((pose[0] + prior_offset, pose[1], pose[2]), cov)
        out.append(rel.update(pts, m, search=True, prior=prior).status)
        prev = pose
    return out


START = (18.0, 0.8, 0.1)  # the corridor by the cross corridor: one place explains it


def test_a_leader_where_the_dead_reckoning_says_locks_on_the_second_scan(bld, bld_glob) -> None:
    """Scans on a map from another pass fit well on two scans in a row, rarely on three
    (orebro 5 cm, bad odometry: the truth led the hypotheses, 1-2 cm off, while the
    dead-reckoned pose drifted 9 m): a leader the dead reckoning backs needs two."""
    assert _statuses(bld_glob, _drive(bld, START, 2), prior_offset=0.5) == ["confirming", "locked"]


def test_without_a_prior_a_lock_still_takes_three_scans(bld, bld_glob) -> None:
    st = _statuses(bld_glob, _drive(bld, START, 3), prior_offset=None)
    assert st == ["confirming", "confirming", "locked"]


def test_a_leader_far_from_the_dead_reckoning_takes_three_scans(bld, bld_glob) -> None:
    st = _statuses(bld_glob, _drive(bld, START, 3), prior_offset=8.0)
    assert st == ["confirming", "confirming", "locked"]


@pytest.mark.parametrize(
    "bad",
    [{"window_sigmas": 0.0}, {"window_margin": -1.0}, {"full_search_every": 0},
     {"prior_confirm_scans": 0}, {"window_heading_margin": float("nan")}],
)  # fmt: skip
def test_window_settings_are_validated(bad: dict) -> None:
    with pytest.raises(ConfigError):
        LocalizerConfig().replace(relocalize=bad).validate()


def test_a_leader_outside_the_searched_window_needs_the_usual_scans(bld, bld_glob) -> None:
    """The sooner lock is for a leader inside the window the recovery searches (± 3 σ of
    the covariance's larger axis + 1 m: 2.5 m here); a leader 3 m from the dead reckoning
    (inside the old, looser 3·√(σ² + 1 m²) = 3.35 m) needs the usual confirm_scans."""
    from icploc.relocalize import window_extent

    half, _ = window_extent(np.diag([0.25, 0.25, 0.01]), CFG.relocalize)
    assert half == pytest.approx(2.5)
    assert _statuses(bld_glob, _drive(bld, START, 2), prior_offset=3.0) == ["confirming", "confirming"]

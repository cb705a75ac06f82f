"""Smoke tests for the peer benchmark (benches/peers.py): the scenario generator is exact,
the numpy baseline and icploc align a tiny case, and the runner works with whatever peers
are installed (missing ones are skipped, never failed)."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path

import numpy as np
import pytest

BENCHES = Path(__file__).resolve().parent.parent / "benches"
sys.path.insert(0, str(BENCHES))

import scenario as sc  # noqa: E402
from numpy_icp import NumpyIcp  # noqa: E402
from numpy_tracker import NumpyTracker  # noqa: E402


def _has(mod: str) -> bool:
    try:
        return importlib.util.find_spec(mod) is not None
    except (ImportError, ValueError):
        return False


def _icploc_core() -> bool:
    try:
        import icploc  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.fixture(scope="module")
def scen() -> sc.Scenario:
    return sc.make_scenario(num_poses=6, seed=3)


def _world_points(s: sc.SimScan, ranges: np.ndarray) -> np.ndarray:
    x, y, th = s.pose
    a = s.angles + th
    return np.column_stack((x + ranges * np.cos(a), y + ranges * np.sin(a)))


def test_scan_shape_and_obstacle_fraction(scen: sc.Scenario) -> None:
    for s in scen.scans:
        assert len(s.angles) == 361
        assert np.isclose(s.angles[1] - s.angles[0], math.radians(0.5))
        assert np.isclose(s.angles[0], -math.pi / 2) and np.isclose(s.angles[-1], math.pi / 2)
        assert int(s.obstacle.sum()) == round(0.2 * 361)
        assert np.isfinite(s.ranges).all()  # the office is closed: every beam returns


def test_noise_free_scan_lies_on_map_or_obstacles(scen: sc.Scenario) -> None:
    """Noise-free returns of the true pose: map beams lie on the map segments, obstacle beams
    on the obstacles (not on the map, and nearer than the wall behind them)."""
    for s in scen.scans:
        p = _world_points(s, s.ranges_true)
        on_map = sc.distance_to_segments(p[~s.obstacle], scen.segments)
        assert on_map.max() < 1e-9
        q = p[s.obstacle]
        d = np.full(len(q), np.inf)
        if len(s.obstacles.segments):
            d = np.minimum(d, sc.distance_to_segments(q, s.obstacles.segments))
        for cx, cy, r in s.obstacles.circles:
            d = np.minimum(d, np.abs(np.hypot(q[:, 0] - cx, q[:, 1] - cy) - r))
        assert d.max() < 1e-9
        # the obstacles are unmapped: their returns are off the map
        assert sc.distance_to_segments(q, scen.segments).min() > 0.05
        wall = sc.raycast_segments(scen.segments, s.pose[:2], np.column_stack((np.cos(s.angles + s.pose[2]), np.sin(s.angles + s.pose[2]))))
        assert (s.ranges_true[s.obstacle] < wall[s.obstacle]).all()


def test_noise_is_about_one_centimetre(scen: sc.Scenario) -> None:
    d = np.concatenate([s.ranges - s.ranges_true for s in scen.scans])
    assert 0.008 < d.std() < 0.012


def test_deterministic() -> None:
    a = sc.make_scenario(num_poses=3, seed=5)
    b = sc.make_scenario(num_poses=3, seed=5)
    assert np.array_equal(a.poses, b.poses)
    for s, t in zip(a.scans, b.scans, strict=True):
        assert np.array_equal(s.ranges, t.ranges)
    for k in a.starts:
        assert np.array_equal(a.starts[k], b.starts[k])


def test_start_errors_have_exact_magnitudes(scen: sc.Scenario) -> None:
    for name, (ex, ey, eth) in sc.ERROR_LEVELS.items():
        d = scen.starts[name] - scen.poses
        assert np.allclose(np.abs(d[:, 0]), ex) and np.allclose(np.abs(d[:, 1]), ey)
        dth = np.abs(np.remainder(d[:, 2] + math.pi, 2 * math.pi) - math.pi)
        assert np.allclose(dth, eth)


def test_map_sampling_sizes_and_normals() -> None:
    segs = sc.office_segments()
    for n in (1_000, 10_000):
        pts, nrm, spacing = sc.map_for_size(segs, n)
        assert n <= len(pts) < 1.1 * n
        assert sc.distance_to_segments(pts[::7], segs).max() < 1e-9
        assert np.allclose(np.hypot(nrm[:, 0], nrm[:, 1]), 1.0)
        assert spacing == pytest.approx(sc.total_length(segs) / n)


def test_poses_are_in_free_space(scen: sc.Scenario) -> None:
    assert sc.distance_to_segments(scen.poses[:, :2], scen.segments).min() >= 0.5


def test_numpy_baseline_aligns_small_error(scen: sc.Scenario) -> None:
    pts, _, _ = sc.map_for_size(scen.segments, 10_000)
    icp = NumpyIcp(pts)
    # noise- and obstacle-free scan: the baseline must land on the truth
    s = scen.scans[0]
    ok = ~s.obstacle
    q = np.column_stack((s.ranges_true[ok] * np.cos(s.angles[ok]), s.ranges_true[ok] * np.sin(s.angles[ok])))
    start = np.asarray(s.pose) + np.array([0.1, -0.1, math.radians(3)])
    r = icp.align(q, start)
    assert math.hypot(r.pose[0] - s.pose[0], r.pose[1] - s.pose[1]) < 0.01
    assert abs(math.remainder(r.pose[2] - s.pose[2], 2 * math.pi)) < math.radians(0.3)


def test_numpy_tracker_follows_a_short_log() -> None:
    log = sc.make_replay_log(num_scans=30)
    pts, _, _ = sc.map_for_size(log.segments, 10_000)
    tr = NumpyTracker(pts, tuple(log.truth[0]))
    for i in range(30):
        est = tr.update(log.scans[i].points(), tuple(log.odometry[i]))
    assert math.hypot(est[0] - log.truth[-1][0], est[1] - log.truth[-1][1]) < 0.05


@pytest.mark.skipif(not _icploc_core(), reason="icploc native core not built")
def test_icploc_aligns_tiny_case(scen: sc.Scenario) -> None:
    import icploc

    pts, nrm, _ = sc.map_for_size(scen.segments, 10_000)
    index = icploc.MapIndex(pts, nrm)
    cfg = icploc.IcpConfig(metric="point_to_line", max_correspondence_distance=1.0, min_correspondence_distance=0.25)
    s = scen.scans[0]
    ok = ~s.obstacle
    q = np.column_stack((s.ranges_true[ok] * np.cos(s.angles[ok]), s.ranges_true[ok] * np.sin(s.angles[ok])))
    start = tuple(np.asarray(s.pose) + np.array([0.1, -0.1, math.radians(3)]))
    r = icploc.icp(q, index, start, cfg)
    assert math.hypot(r.pose[0] - s.pose[0], r.pose[1] - s.pose[1]) < 0.01


def test_runner_quick_tiny(tmp_path: Path) -> None:
    """The runner end to end on a tiny case, in-process, with whatever peers import."""
    import peers

    args = peers.parse_args(["--quick", "--sizes", "1000", "--poses", "2", "--replay-scans", "0", "--out", str(tmp_path)])
    res = peers.run_mode(args, "single")
    names = {r["method"] for r in res["rows"]}
    assert "numpy+cKDTree p2p" in names
    for mod, name in (("open3d", "Open3D p2p"), ("small_gicp", "small_gicp ICP"), ("kiss_icp", "KISS-ICP")):
        if not _has(mod):
            assert name not in names  # skipped, not failed
    if _icploc_core():
        assert "icploc p2l" in names
    for r in res["rows"]:
        assert r["poses"] == 2 and r["median_ms"] > 0
    md = peers.render_markdown(
        {"machine": "test", "command": "x", "poses": 2, "big_map_poses": 2, "sizes": [1000], "modes": [res]}
    )
    assert "numpy+cKDTree p2p" in md

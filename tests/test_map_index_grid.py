"""The closest-point grid behind MapIndex: never silently coarsened, exact fallback said once,
extreme coordinates a clear error."""

from __future__ import annotations

import math
import warnings

import icploc
import numpy as np
import pytest
from icploc import IcpConfig, Localizer, LocalizerConfig, Map, MapIndex, Scan

# A 12 m x 8 m floor with rooms, a door gap, a diagonal wall and a box.
OFFICE = np.array(
    [
        [0, 0, 12, 0], [12, 0, 12, 8], [12, 8, 0, 8], [0, 8, 0, 0],
        [4, 0, 4, 3], [4, 4, 4, 8], [8, 8, 8, 5], [8, 4, 12, 4],
        [1, 6, 2.5, 7.5], [6, 1.5, 7, 1.5], [7, 1.5, 7, 2.5], [7, 2.5, 6, 2.5], [6, 2.5, 6, 1.5],
    ],
    dtype=np.float64,
)
# one stray 10 m segment 5 km away (below-left, so it moves the map's lower bounds)
STRAY = np.array([[-5000.0, -3000.0, -4990.0, -3000.0]])
ANGLES = np.linspace(-math.pi / 2, math.pi / 2, 361)


def scan_points(pose: tuple[float, float, float], rng: np.random.Generator) -> np.ndarray:
    r = icploc.raycast(OFFICE, pose, ANGLES, 20.0)
    ok = np.isfinite(r)
    r = r[ok] + 0.005 * rng.standard_normal(int(ok.sum()))
    return np.column_stack((r * np.cos(ANGLES[ok]), r * np.sin(ANGLES[ok])))


def path(n: int) -> list[tuple[float, float, float]]:
    """n poses along a loop through the free space of the office."""
    t = np.linspace(0.0, 2 * math.pi, n, endpoint=False)
    return [(6.0 + 3.8 * math.cos(a), 4.0 + 2.6 * math.sin(a), a + math.pi / 2) for a in t]


def test_a_stray_far_segment_keeps_the_grid_resolution_without_a_warning():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        idx = Map.from_lines(np.vstack((OFFICE, STRAY))).index(0.05)
    assert (idx.cache_resolution, idx.cache_fallback) == (0.02, None)


def test_a_stray_far_segment_changes_no_alignment():
    plain = Map.from_lines(OFFICE).index(0.05)
    stray = Map.from_lines(np.vstack((OFFICE, STRAY))).index(0.05)
    rng = np.random.default_rng(5)
    cfg = IcpConfig()
    diffs = []
    for truth in path(120):
        scan = scan_points(truth, rng)
        init = (truth[0] + rng.uniform(-0.2, 0.2), truth[1] + rng.uniform(-0.2, 0.2),
                truth[2] + rng.uniform(-0.1, 0.1))
        a = icploc.icp(scan, plain, init, cfg).pose
        b = icploc.icp(scan, stray, init, cfg).pose
        diffs.append(max(abs(a[0] - b[0]), abs(a[1] - b[1]), abs(math.remainder(a[2] - b[2], math.tau))))
    assert max(diffs) < 1e-9


def run_localizer(map_: Map, poses: list[tuple[float, float, float]]) -> tuple[np.ndarray, list[str]]:
    rng = np.random.default_rng(8)
    loc = Localizer(map_, LocalizerConfig(), initial_pose=poses[0])
    out, status = [], []
    for k, truth in enumerate(poses):
        r = icploc.raycast(OFFICE, truth, ANGLES, 20.0)
        r = np.where(np.isfinite(r), r + 0.005 * rng.standard_normal(r.shape), np.inf)
        odom = (truth[0] + 0.02 * k * 0.1, truth[1], truth[2])  # odometry drifting 2 mm a scan
        est = loc.update(Scan(stamp=0.1 * k, ranges=r, angles=ANGLES, max_range=20.0), odom)
        out.append(est.pose)
        status.append(str(est.status))
    return np.asarray(out), status


def test_a_stray_far_segment_changes_no_localization():
    poses = path(120)
    plain, s_plain = run_localizer(Map.from_lines(OFFICE), poses)
    stray, s_stray = run_localizer(Map.from_lines(np.vstack((OFFICE, STRAY))), poses)
    # every scan tracked with the stray segment, at exactly the poses found without it
    assert s_stray == s_plain == ["tracking"] * 120
    assert np.abs(stray - plain).max() < 1e-9


def test_a_grid_beyond_the_memory_bound_falls_back_to_exact_answers_and_warns_once():
    # points scattered over 10 km x 10 km: the 2 cm grid would need far more than 2^23 cells
    rng = np.random.default_rng(1)
    m = Map.from_points(rng.uniform(0.0, 1e4, (3000, 2)))
    with pytest.warns(RuntimeWarning, match="cache_resolution=0.02 m not built") as rec:
        idx = m.index(0.05)
        assert m.index(0.05) is idx
    assert len(rec) == 1
    assert (idx.cache_resolution, idx.cache_bytes) == (None, 0)
    # ICP gets the exact answers: a noise-free scan of 60 of the points is matched exactly
    pts = np.asarray(idx.points)[:60]
    truth = (5000.0, 5000.0, 0.3)
    c, s = math.cos(truth[2]), math.sin(truth[2])
    d = pts - truth[:2]
    scan = np.column_stack((c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]))
    cfg = IcpConfig(metric="point_to_point", step_tolerance=0.0, mse_change=0.0, mse_threshold=0.0,
                    max_iterations=100, min_correspondence_distance=0.5)
    r = icploc.icp(scan, idx, (5000.03, 4999.98, 0.3001), cfg)
    np.testing.assert_allclose(r.pose, truth, rtol=0, atol=1e-9)


def test_the_grid_memory_is_reported():
    idx = MapIndex(np.array([[0.0, 0.0], [1.0, 0.0]]))
    # one point's tiles: 9 x 9 tiles of 32 x 32 cells, 4 bytes each, and the tile table
    assert 9 * 9 * 32 * 32 * 4 <= idx.cache_bytes < 2 * 9 * 9 * 32 * 32 * 4
    assert MapIndex(np.array([[0.0, 0.0]]), cache_resolution=None).cache_bytes == 0


def test_map_coordinates_beyond_a_billion_metres_are_a_clear_error():
    with pytest.raises(icploc.InvalidInputError, match=r"map points: row 1 \(1e0, 1e154\) is farther than 1e9 m"):
        MapIndex(np.array([[0.0, 0.0], [1.0, 1e154]]))

"""The localizer's per-scan arithmetic moved into the core (``icploc._core.fit_score``,
``icploc._core.noise_factor``) gives what the numpy code it replaced gave: the reference
implementations below are that code, unchanged, run on the same fixtures."""

from __future__ import annotations

import math

import numpy as np
import pytest
from icploc import _core
from icploc.fitcheck import FitChecker, MapQuality
from icploc.motion import NoiseGain
from sampled_walls import walls_index

#: an office-like room with a corridor and a pillar (the exact map of the fixtures)
_WALLS = [
    (0.0, 0.0, 12.0, 0.0),
    (12.0, 0.0, 12.0, 8.0),
    (12.0, 8.0, 0.0, 8.0),
    (0.0, 8.0, 0.0, 0.0),
    (4.0, 0.0, 4.0, 5.0),
    (7.0, 8.0, 7.0, 3.0),
    (9.0, 2.0, 10.0, 2.0),
    (10.0, 2.0, 10.0, 3.0),
    (10.0, 3.0, 9.0, 3.0),
    (9.0, 3.0, 9.0, 2.0),
]


def _reference_check(index: _core.MapIndex, points: np.ndarray, pose: tuple[float, float, float],
                     max_beams: int, hd: float) -> tuple[float, float, int]:
    """``FitChecker.check`` without see-through, as it was in numpy."""
    n = points.shape[0]
    if n > max_beams:
        points = points[np.linspace(0, n - 1, max_beams).round().astype(np.int64)]
        n = points.shape[0]
    c, s = math.cos(pose[2]), math.sin(pose[2])
    wx = pose[0] + c * points[:, 0] - s * points[:, 1]
    wy = pose[1] + s * points[:, 0] + c * points[:, 1]
    d, j = index.nearest(np.column_stack((wx, wy)))
    hits = d < hd
    nh = int(hits.sum())
    nrm = np.asarray(index.normals)[j]
    mp_all = np.asarray(index.points)
    if nh:
        mp = mp_all[j[hits]]
        r = (wx[hits] - mp[:, 0]) * nrm[hits, 0] + (wy[hits] - mp[:, 1]) * nrm[hits, 1]
        rms = float(np.sqrt(np.mean(r * r)))
    else:
        rms = math.inf
    return nh / n, rms, n


def _scan(rng: np.random.Generator, n: int, noise: float) -> np.ndarray:
    """A scan of the room taken at (3, 6, 0.3): ranges cast against the walls (robot
    frame), with ``noise`` m of range noise."""
    segs = np.asarray(_WALLS, dtype=float)
    ang = np.linspace(-math.pi / 2, math.pi / 2, n)
    r = _core.raycast(segs, (3.0, 6.0, 0.3), ang, 30.0)
    r = r + rng.normal(0.0, noise, n)
    return np.column_stack((r * np.cos(ang), r * np.sin(ang)))


@pytest.mark.parametrize("n", [5, 60, 119, 120, 121, 181, 361, 541, 1081])
def test_fit_score_equals_the_numpy_check_bit_for_bit(n: int) -> None:
    rng = np.random.default_rng(n)
    index = walls_index(_WALLS)
    pts = _scan(rng, n, 0.02)
    shares = []
    for k in range(40):
        pose = (3.0 + rng.normal(0, 0.3), 6.0 + rng.normal(0, 0.3), 0.3 + rng.normal(0, 0.1))
        if k == 0:
            pose = (3.0, 6.0, 0.3)
        for hd in (0.03, 0.1, 0.4):
            got = _core.fit_score(index, pts, pose, 120, hd)
            want = _reference_check(index, pts, pose, 120, hd)
            assert got == want, (pose, hd)  # exactly: the localizer compares them with thresholds
            shares.append(got[0])
    # the fixtures cover a fit where every beam hits and poses where many miss
    assert max(shares) == 1.0 and min(shares) < 0.5


def test_fit_score_with_no_hit_and_through_the_checker() -> None:
    index = walls_index(_WALLS)
    pts = _scan(np.random.default_rng(3), 181, 0.0)
    # far outside the room: no beam ends on a wall
    hit, rms, beams = _core.fit_score(index, pts, (50.0, 50.0, 0.0), 120, 0.1)
    assert (hit, beams) == (0.0, 120)
    assert rms == math.inf
    q = MapQuality.from_config(0.05)
    chk = FitChecker(index, q).check(pts, (3.0, 6.0, 0.3))
    assert (chk.hit, chk.rms, chk.beams) == _reference_check(index, pts, (3.0, 6.0, 0.3), 120, q.hit_distance())
    assert chk.hit == 1.0 and chk.see_through == 0.0


def test_fit_score_takes_poses_and_points_in_any_form() -> None:
    index = walls_index(_WALLS)
    pts = _scan(np.random.default_rng(4), 90, 0.01)
    a = _core.fit_score(index, pts, (3.0, 6.0, 0.3), 120, 0.1)
    assert _core.fit_score(index, pts, [3.0, 6.0, 0.3], 120, 0.1) == a
    assert _core.fit_score(index, pts, np.array([3.0, 6.0, 0.3]), 120, 0.1) == a
    assert _core.fit_score(index, np.asfortranarray(pts), (3.0, 6.0, 0.3), 120, 0.1) == a
    with pytest.raises(_core.InvalidInputError, match="pose"):
        _core.fit_score(index, pts, (3.0, 6.0), 120, 0.1)
    with pytest.raises(_core.InvalidInputError, match="points"):
        _core.fit_score(index, pts[:, :1], (3.0, 6.0, 0.3), 120, 0.1)


def _reference_factor(v: np.ndarray, P: np.ndarray, R: np.ndarray, max_gain: float) -> float | None:
    """``NoiseGain.observe``'s factor as it was in numpy."""
    def nis(Pg: np.ndarray) -> float:
        try:
            return float(v @ np.linalg.solve(Pg + R, v))
        except np.linalg.LinAlgError:
            return math.inf

    if not (np.all(np.isfinite(v)) and np.all(np.isfinite(P)) and np.all(np.isfinite(R))):
        return None
    lo, hi = 1e-3, max_gain * 4.0
    if nis(hi * P) > 2.366:
        return hi
    if nis(lo * P) < 2.366:
        return lo
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        if nis(mid * P) > 2.366:
            lo = mid
        else:
            hi = mid
    return math.sqrt(lo * hi)


def _random_cov(rng: np.random.Generator, scale: np.ndarray) -> np.ndarray:
    a = rng.normal(size=(3, 3)) * scale[:, None]
    return a @ a.T + np.diag(scale**2) * 1e-3


def test_noise_factor_equals_the_numpy_bisection() -> None:
    rng = np.random.default_rng(11)
    scale = np.array([0.05, 0.05, math.radians(2.0)])
    kinds = {"top": 0, "bottom": 0, "between": 0}
    for k in range(600):
        P = _random_cov(rng, scale)
        R = _random_cov(rng, scale * rng.uniform(0.05, 1.0))
        v = rng.normal(size=3) * scale * 10.0 ** rng.uniform(-2.0, 1.5)
        if k % 50 == 0:
            v = np.zeros(3)
        max_gain = float(rng.choice([3.0, 10.0]))
        want = _reference_factor(v, P, R, max_gain)
        got = _core.noise_factor(tuple(v), P, R, max_gain, 2.366)
        assert want is not None and got is not None
        # LAPACK's solve and the core's may round differently: the same root to 1e-9
        assert got == pytest.approx(want, rel=1e-9)
        if want == 4.0 * max_gain:
            kinds["top"] += 1
        elif want == 1e-3:
            kinds["bottom"] += 1
        else:
            kinds["between"] += 1
    assert min(kinds.values()) >= 20, kinds  # every branch is exercised


def test_noise_factor_without_finite_input_is_no_evidence() -> None:
    P = np.eye(3) * 1e-3
    assert _core.noise_factor((math.nan, 0.0, 0.0), P, P, 10.0, 2.366) is None
    bad = P.copy()
    bad[2, 1] = math.inf
    assert _core.noise_factor((0.1, 0.0, 0.0), P, bad, 10.0, 2.366) is None
    ng = NoiseGain()
    ng.observe((0.0, 0.0, 0.0), bad, (0.1, 0.0, 0.0), P)
    assert len(ng._g) == 0
    ng.observe((0.0, 0.0, 0.0), P, (0.1, 0.0, 0.0), P)
    assert list(ng._g) == [pytest.approx(_reference_factor(np.array([0.1, 0.0, 0.0]), P, P, 10.0))]
    with pytest.raises(_core.InvalidInputError, match="P"):
        _core.noise_factor((0.1, 0.0, 0.0), np.eye(2), P, 10.0, 2.366)


def _reference_scan_covariance(information: np.ndarray, inliers: int, mse: float, sigma_floor: float,
                               independent_beams: float, min_axis_beams: float) -> np.ndarray:
    """``fusion.scan_covariance`` as it was in Python (its weak-axis branch left out: the
    core hands those cases back to it)."""
    from icploc.fusion import _HUGE, _inv3

    n = max(int(inliers), 1)
    H = np.asarray(information, dtype=np.float64).reshape(3, 3).tolist()
    s2 = max(float(mse) if math.isfinite(mse) else 0.0, sigma_floor * sigma_floor)
    f = min(float(independent_beams), float(n)) / (n * s2)
    eps = 1.0 / _HUGE
    info = [
        [H[0][0] * f + eps, 0.5 * (H[0][1] + H[1][0]) * f, 0.5 * (H[0][2] + H[2][0]) * f],
        [0.0, H[1][1] * f + eps, 0.5 * (H[1][2] + H[2][1]) * f],
        [0.0, 0.0, H[2][2] * f + eps],
    ]
    inv = _inv3(info)
    return np.eye(3) * _HUGE if inv is None else np.array(inv)


def test_scan_covariance_equals_the_python_bit_for_bit() -> None:
    from icploc.fusion import scan_covariance

    rng = np.random.default_rng(5)
    handed_back = 0
    for _ in range(500):
        # the information of unit normals: counts of beams along two directions plus coupling
        a, b = 10.0 ** rng.uniform(-1.0, 2.5, 2)
        u = rng.uniform(0, math.pi)
        c, s = math.cos(u), math.sin(u)
        H = np.array([[a * c * c + b * s * s, (a - b) * c * s, rng.normal(0, 5)],
                      [(a - b) * c * s, a * s * s + b * c * c, rng.normal(0, 5)],
                      [0.0, 0.0, rng.uniform(10.0, 5000.0)]])
        H[2, 0], H[2, 1] = H[0, 2] + rng.normal(0, 1e-3), H[1, 2]  # slightly asymmetric, as fits are
        inliers = int(rng.integers(0, 400))
        mse = float(rng.choice([rng.uniform(1e-6, 1e-2), math.nan, math.inf]))
        floor, beams = float(rng.uniform(0.005, 0.05)), float(rng.choice([5.0, 12.0, 40.0]))
        bound = float(rng.choice([0.0, 8.0]))
        got = _core.scan_covariance(H, inliers, mse, floor, beams, bound)
        if got is None:
            handed_back += 1
            assert bound > 0.0
            continue
        np.testing.assert_array_equal(got, _reference_scan_covariance(H, inliers, mse, floor, beams, bound))
        np.testing.assert_array_equal(scan_covariance(H, inliers, mse, floor, beams, bound), got)
    assert 50 < handed_back < 250  # both paths are exercised
    # no information at all: a huge covariance
    np.testing.assert_array_equal(_core.scan_covariance(np.full((3, 3), math.nan), 0, 0.0, 0.01, 12.0, 8.0),
                                  np.eye(3) * 1e6)


def test_prepare_points_equals_the_numpy_preparation() -> None:
    from icploc.config import LocalizerConfig
    from icploc.messages import BEAM_DAZZLE, BEAM_INVALID, BEAM_NO_RETURN, Scan
    from icploc.scanprep import prepare_scan

    rng = np.random.default_rng(9)
    n = 361
    ang = np.linspace(-math.pi / 2, math.pi / 2, n)
    bad = BEAM_NO_RETURN | BEAM_DAZZLE | BEAM_INVALID
    for k in range(30):
        r = rng.uniform(0.0, 40.0, n)
        r[rng.integers(0, n, 20)] = math.inf
        r[rng.integers(0, n, 5)] = math.nan
        flags = rng.choice([0, 0, 0, BEAM_DAZZLE, 8], n).astype(np.uint8) if k % 2 else None
        scan = Scan(float(k), r, ang, flags, max_range=float(rng.choice([30.0, math.inf])), min_range=0.02)
        cfg = LocalizerConfig().replace(scan={
            "decimation": int(rng.choice([1, 2, 3])),
            "laser_x": float(rng.choice([0.0, 0.12])), "laser_y": float(rng.choice([0.0, -0.03])),
            "laser_theta": float(rng.choice([0.0, 0.05])), "min_range": float(rng.choice([0.0, 0.5])),
        })
        sc = cfg.scan
        # the numpy preparation as it was
        hi = sc.max_range if sc.max_range > 0.0 else scan.max_range
        if hi != math.inf:
            hi = hi * sc.max_range_margin
        lo = sc.min_range if sc.min_range > scan.min_range else scan.min_range
        ok = (r < hi) & (r > lo)
        if flags is not None:
            ok &= (flags & np.uint8(bad)) == 0
        idx = ok.nonzero()[0][:: sc.decimation]
        c, s = np.cos(ang + sc.laser_theta), np.sin(ang + sc.laser_theta)
        want = np.column_stack((r[idx] * c[idx], r[idx] * s[idx]))
        if sc.laser_x != 0.0 or sc.laser_y != 0.0:
            want += (sc.laser_x, sc.laser_y)
        got = prepare_scan(scan, cfg)
        assert got.shape == want.shape and got.shape[0] > 50
        np.testing.assert_array_equal(got, want)

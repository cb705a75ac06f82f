"""The motion model, the information update and the odometry calibration (issue 11)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from icploc.calibration import OdometryCalibration
from icploc.fusion import fuse, mahalanobis2, scan_covariance
from icploc.motion import MotionModel, NoiseGain, fit_alphas
from icploc.se2 import compose

MM = MotionModel(1e-3, 1e-4, 1e-3, 1e-4, 5e-4)


def test_motion_noise_grows_with_distance_and_turn() -> None:
    q0 = MM.motion_covariance((0.0, 0.0, 0.0))
    q1 = MM.motion_covariance((1.0, 0.0, 0.0))
    q2 = MM.motion_covariance((2.0, 0.0, 0.0))
    qt = MM.motion_covariance((0.0, 0.0, 1.0))
    assert q0 == pytest.approx(np.zeros((3, 3)))
    assert q2[0, 0] == pytest.approx(4 * q1[0, 0])  # std proportional to distance
    assert q1[0, 0] == pytest.approx(1e-3) and q1[1, 1] == pytest.approx(5e-4)  # along, across
    assert qt[2, 2] == pytest.approx(1e-3) and q1[2, 2] == pytest.approx(1e-4)


def test_motion_covariance_follows_the_direction_of_travel() -> None:
    q = MM.motion_covariance((0.0, 1.0, 0.0))  # sideways chord: along is y
    assert q[1, 1] == pytest.approx(1e-3) and q[0, 0] == pytest.approx(5e-4)


def test_predict_propagates_heading_uncertainty_into_position() -> None:
    P = np.diag([0.0, 0.0, 0.01])
    pred, P2 = MM.predict((0.0, 0.0, 0.0), P, (2.0, 0.0, 0.0))
    assert pred == pytest.approx((2.0, 0.0, 0.0))
    # 0.1 rad of heading doubt over 2 m: 0.2 m across
    assert P2[1, 1] == pytest.approx(0.04 + 4 * 5e-4)
    assert P2[1, 2] == pytest.approx(0.02)


def test_fit_alphas_recovers_the_model_that_made_the_errors() -> None:
    rng = np.random.default_rng(0)
    true = MotionModel(4e-4, 4e-5, 1e-3, 1e-4, 2.5e-4)
    ref, odo = [], []
    for _ in range(600):
        d = (rng.uniform(0.2, 0.6), rng.normal(0.0, 0.02), rng.normal(0.0, 0.3))
        e = rng.multivariate_normal(np.zeros(3), true.motion_covariance(d))
        ref.append(d)
        odo.append(compose(d, e))
    a1, a2, a3, a4, a5 = fit_alphas(odo, ref, floor_xy=1e-4, floor_theta=1e-4)
    assert a3 == pytest.approx(1e-3, rel=0.5)
    assert a5 == pytest.approx(2.5e-4, rel=0.5)
    assert a1 + a2 / 0.16 == pytest.approx(4e-4 + 4e-5 / 0.16, rel=0.6)  # heading, at 0.4 m


def test_scan_covariance_counts_independent_beams_and_floors_the_noise() -> None:
    H = np.diag([1000.0, 1000.0, 5000.0])  # 1,000 beams
    c = scan_covariance(H, 1000, 1e-6, 0.03, 10.0)
    # 10 independent beams of 3 cm (the floor, above the fit's 1 mm)
    assert c[0, 0] == pytest.approx(0.03**2 / 10.0, rel=1e-4)
    corridor = scan_covariance(np.diag([0.0, 1000.0, 5000.0]), 1000, 1e-4, 0.03, 10.0)
    assert corridor[0, 0] > 1e5  # nothing along the corridor


def test_fuse_is_the_kalman_update_and_keeps_the_prediction_where_the_scan_says_nothing() -> None:
    P = np.array([[0.01, 0.002, 0.001], [0.002, 0.02, -0.001], [0.001, -0.001, 0.003]])
    R = np.array([[0.004, 0.0, 0.0005], [0.0, 0.5, 0.0], [0.0005, 0.0, 0.001]])
    x, c = fuse((0.0, 0.0, 0.0), P, (0.1, 0.2, 0.05), R)
    K = P @ np.linalg.inv(P + R)
    assert x == pytest.approx(tuple(K @ np.array([0.1, 0.2, 0.05])))
    assert c == pytest.approx((np.eye(3) - K) @ P)
    R2 = np.diag([1e6, 1e-4, 1e-6])
    x2, _ = fuse((1.0, 1.0, 0.0), np.diag([0.01, 0.01, 0.001]), (1.5, 1.06, 0.0), R2)
    assert x2[0] == pytest.approx(1.0, abs=1e-6)
    assert x2[1] == pytest.approx(1.06, abs=1e-3)


def test_mahalanobis_is_chi_square_distance() -> None:
    P = np.diag([0.01, 0.01, 0.01])
    R = np.diag([0.03, 0.03, 0.03])
    assert mahalanobis2((0.0, 0.0, 0.0), P, (0.2, 0.0, 0.0), R) == pytest.approx(1.0)
    # headings wrap
    d = mahalanobis2((0.0, 0.0, math.pi - 0.1), P, (0.0, 0.0, -math.pi + 0.1), R)
    assert d == pytest.approx(0.04 / 0.04)


def test_calibration_learns_scale_and_drift_slowly_and_bounded() -> None:
    cal = OdometryCalibration()
    # the odometry reads 2 % long and drifts -0.5 deg per metre; 2 m straight pairs
    for _ in range(100):
        cal.observe((2.04, 0.0, -math.radians(1.0)), (2.0, 0.0, 0.0))
    assert cal.scale == pytest.approx(1 / 1.02, abs=0.003)
    assert cal.drift == pytest.approx(math.radians(0.5), abs=math.radians(0.05))
    assert cal.apply((2.04, 0.0, -math.radians(1.0))) == pytest.approx((2.0, 0.0, 0.0), abs=5e-3)
    one = OdometryCalibration()
    one.observe((2.0, 0.0, 0.0), (2.2, 0.0, 0.0))  # one pair says 10 %: a small step only
    assert 1.0 < one.scale < 1.02
    big = OdometryCalibration()
    for _ in range(200):
        big.observe((2.0, 0.0, 0.0), (2.16, 0.0, 0.0))  # 8 %: held at the bound
    assert big.scale == pytest.approx(1.0 + big.max_scale)
    far = OdometryCalibration()
    for _ in range(200):
        far.observe((2.0, 0.0, 0.0), (2.5, 0.0, 0.0))  # 25 %: not a scale error, ignored
    assert far.scale == 1.0


def test_calibration_learns_the_turn_scale() -> None:
    cal = OdometryCalibration()
    for _ in range(100):
        cal.observe((0.0, 0.0, 0.93), (0.0, 0.0, 1.0))  # turns read 7 % short
    assert cal.turn_scale == pytest.approx(1 / 0.93, abs=0.01)


def _noise_run(true_gain: float, model_gain: float = 1.0, wrong_share: float = 0.0, seed: int = 7) -> float:
    """A NoiseGain fed 60 scans: prediction covariance P (made with ``model_gain``), scan
    covariance R, prediction errors drawn with ``true_gain / model_gain`` x P plus R; a share
    of wrong fits 1 m off."""
    rng = np.random.default_rng(seed)
    P = np.diag([0.03**2, 0.02**2, math.radians(1.0) ** 2])
    R = np.diag([0.01**2, 0.01**2, math.radians(0.2) ** 2])
    ng = NoiseGain()
    for _ in range(60):
        v = rng.multivariate_normal(np.zeros(3), P * (true_gain / model_gain) + R)
        if rng.uniform() < wrong_share:
            v = np.array([1.0, 0.0, 0.0])
        ng.observe((0.0, 0.0, 0.0), P, tuple(v), R, current=model_gain)
    return ng.gain


def _gains(*args: float, **kw: float) -> list[float]:
    """The learned gain over 21 seeds (one seed's 60 scans vary by tens of percent)."""
    return [_noise_run(*args, **kw, seed=s) for s in range(21)]  # type: ignore[misc]


def test_noise_gain_learns_odometry_four_times_noisier_than_its_model() -> None:
    assert 3.5 < float(np.median(_gains(4.0))) < 4.5


def test_noise_gain_stays_at_the_model_when_the_odometry_is_as_modelled() -> None:
    g = _gains(1.0)
    assert float(np.median(g)) < 1.1
    assert min(g) >= 1.0  # never below the model


def test_noise_gain_is_raised_little_by_a_few_wrong_fits() -> None:
    # 10 % of the fits 1 m off (each one's chi-square ~1,000): the median factor moves little
    assert float(np.median(_gains(1.0, wrong_share=0.1))) < 1.35


def test_noise_gain_is_relative_to_the_gain_already_in_use() -> None:
    # the prediction was made with gain 4 and the errors match it: the gain stays near 4
    assert 3.5 < float(np.median(_gains(4.0, model_gain=4.0))) < 4.5


def _feed(ng: NoiseGain, factor: float, n: int) -> list[float]:
    """``n`` scans whose prediction error is exactly what ``factor`` x P explains (the
    chi-square statistic at its median): the learned gain after each."""
    from icploc.fusion import CHI2_3_MEDIAN

    P = np.diag([0.03**2, 0.03**2, 0.01**2])
    R = np.diag([1e-12, 1e-12, 1e-12])
    v = (0.03 * math.sqrt(factor * CHI2_3_MEDIAN), 0.0, 0.0)
    out = []
    for _ in range(n):
        ng.observe((0.0, 0.0, 0.0), P, v, R)
        out.append(ng.gain)
    return out


@pytest.mark.parametrize("settings", [{}, {"min_samples": 2}, {"min_samples": 9, "window": 9}])
def test_noise_gain_keeps_the_model_until_min_samples_factors_are_in(settings: dict) -> None:
    ng = NoiseGain(**settings)
    got = _feed(ng, 4.0, ng.min_samples + 3)
    assert got[: ng.min_samples - 1] == [1.0] * (ng.min_samples - 1)
    assert got[ng.min_samples - 1 :] == pytest.approx([4.0] * 4, rel=1e-3)


@pytest.mark.parametrize("settings", [{}, {"window": 7}, {"window": 8, "min_samples": 1}])
def test_noise_gain_forgets_factors_older_than_its_window(settings: dict) -> None:
    """Odometry that was 4x noisier than its model, then 2x: the median over the last
    ``window`` factors moves to 2 once more than half of the window is the new ones."""
    ng = NoiseGain(**settings)
    _feed(ng, 4.0, ng.window)
    got = _feed(ng, 2.0, ng.window)  # got[j - 1]: with j new factors in the window
    old = [got[j - 1] for j in range(1, ng.window + 1) if j < ng.window / 2]
    new = [got[j - 1] for j in range(1, ng.window + 1) if j > ng.window / 2]
    assert old == pytest.approx([4.0] * len(old), rel=1e-3)
    assert new == pytest.approx([2.0] * len(new), rel=1e-3)


def test_noise_gain_settings_of_the_config_reach_the_localizer() -> None:
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer

    pts = np.array([[x * 0.05, 0.0] for x in range(100)] + [[0.0, y * 0.05] for y in range(100)])
    cfg = LocalizerConfig().replace(localizer={"noise_gain_window": 5, "noise_gain_min_samples": 2})
    ng = Localizer(pts, cfg, (1.0, 1.0, 0.0))._noise
    got = _feed(ng, 3.0, 4) + _feed(ng, 1.0, 3)
    # learned from the second factor on; the seventh leaves two of the four old ones in the
    # window of five: the median is a new one (the default window of 31 would keep 3)
    assert got == pytest.approx([1.0, 3.0, 3.0, 3.0, 3.0, 3.0, 1.0], rel=1e-3)


def test_scan_covariance_beam_count_does_not_grow_on_a_finer_map() -> None:
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer

    pts = np.array([[x * 0.05, 0.0] for x in range(200)] + [[0.0, y * 0.05] for y in range(200)])
    counts = []
    for res in (0.05, 0.10):
        cfg = LocalizerConfig()
        cfg.map.resolution = res
        counts.append(Localizer(pts, cfg, (1.0, 1.0, 0.0))._independent_beams)
    assert counts[0] == counts[1]


def test_calibration_learns_the_turn_scale_of_a_route_that_turns_a_little_at_a_time() -> None:
    # 2 m pairs turning 0, +-0.5 or 1 rad: turns read 5 % short, 1 deg/m heading drift. The
    # turn evidence per pair is small against the distance; after 200 m the turn scale is
    # learned (a prior fading with the turn alone held it near 1.3 % here)
    rng = np.random.default_rng(3)
    cal = OdometryCalibration()  # the localizer's (the config's) memory
    for _ in range(100):
        turn = float(rng.choice([0.0, 0.5, -0.5, 1.0]))
        cal.observe((2.0, 0.0, turn * 0.95 - math.radians(1.0) * 2.0), (2.0, 0.0, turn))
    assert cal.turn_scale == pytest.approx(1 / 0.95, abs=0.005)


def _lab_run(noise_factor: float) -> float:
    """The localizer in the simulated lab, scans ~0.5 m apart, the odometry off per step by
    ``noise_factor`` x the motion model's standard deviations; returns the learned gain."""
    from icploc import sim as worlds
    from icploc.localizer import Localizer
    from icploc.se2 import between

    lab = worlds.lab(people=0)
    frames = list(worlds.simulate(lab, worlds.lab_random_walk(40.0, seed=4), seed=3))
    loc = Localizer(_lab_index(lab), initial_pose=frames[0].truth)
    rng = np.random.default_rng(11)
    odo = frames[0].truth
    last = frames[0]
    for f in frames[1:]:
        d = between(last.truth, f.truth)
        if math.hypot(d[0], d[1]) < 0.5 and abs(d[2]) < 0.5:
            continue
        e = rng.multivariate_normal(np.zeros(3), loc.motion_model.motion_covariance(d) / loc.motion_model.gain)
        odo = compose(odo, compose(d, tuple(noise_factor * e)))
        loc.update(f.scan, odo)
        last = f
    return loc.motion_model.gain


def _lab_index(lab):  # type: ignore[no-untyped-def]
    from icploc import MapIndex

    pts, nrm = [], []
    for x1, y1, x2, y2 in np.asarray(lab.lines, dtype=float):
        length = math.hypot(x2 - x1, y2 - y1)
        k = max(int(length / 0.05), 1)
        t = (np.arange(k) + 0.5) / k
        pts.append(np.column_stack([x1 + t * (x2 - x1), y1 + t * (y2 - y1)]))
        nrm.append(np.tile([-(y2 - y1) / length, (x2 - x1) / length], (k, 1)))
    return MapIndex(np.vstack(pts), np.vstack(nrm))


def test_localizer_learns_odometry_three_times_noisier_than_its_model() -> None:
    assert _lab_run(3.0) > 3.0


def test_localizer_keeps_the_model_for_odometry_as_modelled() -> None:
    assert _lab_run(1.0) < 1.6


def _odometry_of(step: tuple[float, float, float], exact: bool = False, n: int = 10) -> tuple[float, float, float]:
    """A step as a base with systematic errors reads it (3 % short, 2 % sideways per metre,
    turns 5 % short, -1 deg/m heading drift), integrated over ``n`` sub-steps; ``exact``:
    the step itself, integrated the same way."""
    scale, skew, turn, bias = (0.0, 0.0, 0.0, 0.0) if exact else (-0.03, -0.02, -0.05, math.radians(-1.0))
    sub = (step[0] / n, step[1] / n, step[2] / n)
    p = (0.0, 0.0, 0.0)
    for _ in range(n):
        d = math.hypot(sub[0], sub[1])
        p = compose(p, ((1 + scale) * sub[0], sub[1] + skew * sub[0], (1 + turn) * sub[2] + bias * d))
    return p


def _dead_reckoning_error(cal: OdometryCalibration | None) -> float:
    """Position error after 20 m of 1 m steps (a 0.2 rad turn every fifth) dead-reckoned with
    ``cal`` applied (None: the raw odometry)."""
    truth = raw = (0.0, 0.0, 0.0)
    for k in range(20):
        step = (1.0, 0.0, 0.2 if k % 5 == 0 else 0.0)
        o = _odometry_of(step, n=5)
        truth = compose(truth, _odometry_of(step, exact=True, n=5))
        raw = compose(raw, o if cal is None else cal.apply(o))
    return math.hypot(raw[0] - truth[0], raw[1] - truth[1])


def _learned(cal: OdometryCalibration | None = None) -> OdometryCalibration:
    """``cal`` (None: one with the defaults) after 300 m of the base of :func:`_odometry_of`."""
    rng = np.random.default_rng(1)
    cal = cal or OdometryCalibration()
    for _ in range(150):  # 300 m of 2 m pairs, some turning
        step = (2.0, 0.0, float(rng.choice([0.0, 0.0, 0.3, -0.3])))
        cal.observe(_odometry_of(step), _odometry_of(step, exact=True))
    return cal


def test_calibration_learns_the_sideways_skew_apart_from_the_heading_drift() -> None:
    assert _learned().skew == pytest.approx(0.02, abs=0.002)


def test_calibrated_dead_reckoning_drifts_a_fraction_of_the_raw_odometry() -> None:
    # raw: 4.2 m off after 20 m; with scale, turn scale and drift learned but no skew: 0.36 m
    assert _dead_reckoning_error(_learned()) < 0.05 * _dead_reckoning_error(None)


def test_without_the_skew_the_calibrated_dead_reckoning_drifts_sideways() -> None:
    assert _dead_reckoning_error(_learned(OdometryCalibration(max_skew=0.0))) > 0.2


def test_the_config_bound_on_the_skew_reaches_the_calibration() -> None:
    """``localizer.calibration_max_skew`` reaches the calibration: the same 300 m, the skew
    held at the configured bound, the dead reckoning worse for it."""
    from icploc.config import LocalizerSection

    cfg = LocalizerSection().replace(calibration_max_skew=0.005)
    cal = _learned(OdometryCalibration.from_config(cfg))
    assert cal.skew == pytest.approx(0.005)  # the base's 2 %, held at the bound
    assert _dead_reckoning_error(cal) > _dead_reckoning_error(_learned())


def _skewed_lab_run(config: object = None, skew: float = 0.02) -> tuple[float, float]:
    """The localizer in the simulated lab over a 100 m random walk, scans ~0.5 m apart, on
    odometry that runs ``skew`` sideways per metre forward (nothing else wrong with it);
    returns the sideways skew its last estimate reports and the largest other factor's
    distance from no correction."""
    from icploc import sim as worlds
    from icploc.localizer import Localizer
    from icploc.se2 import between

    lab = worlds.lab(people=0)
    frames = list(worlds.simulate(lab, worlds.lab_random_walk(100.0, seed=4), seed=3))
    loc = Localizer(_lab_index(lab), config, initial_pose=frames[0].truth)  # type: ignore[arg-type]
    odo, last, e = frames[0].truth, frames[0], None
    for f in frames[1:]:
        d = between(last.truth, f.truth)
        if math.hypot(d[0], d[1]) < 0.5 and abs(d[2]) < 0.5:
            continue
        odo = compose(odo, (d[0], d[1] + skew * d[0], d[2]))
        e = loc.update(f.scan, odo)
        last = f
    assert e is not None
    scale, turn, drift = e.calibration
    return e.calibration_skew, max(abs(scale - 1.0), abs(turn - 1.0), abs(drift))


def test_the_estimate_reports_the_skew_the_localizer_learns_from_the_scans() -> None:
    """Odometry 2 % sideways per metre: the localizer learns the correction (most of it
    after ~90 m, the rest held back by the prior) and its estimates report it, the other
    factors staying near no correction; with the skew bounded to 0 by the config, none."""
    from icploc.config import LocalizerConfig

    learned, others = _skewed_lab_run()
    assert -0.022 < learned < -0.012
    assert others < 0.005
    off, _ = _skewed_lab_run(LocalizerConfig().replace(localizer={"calibration_max_skew": 0.0}))
    assert off == 0.0


def test_the_chi_square_constants_are_the_distributions_quantiles() -> None:
    """The gate's quantiles and the median NoiseGain solves for (3 degrees of freedom),
    against scipy's (imported here only: the package does not import scipy for them)."""
    from icploc.fusion import CHI2_3, CHI2_3_MEDIAN
    from scipy.stats import chi2

    table = {**CHI2_3, 0.5: CHI2_3_MEDIAN}
    assert table == pytest.approx({p: float(chi2.ppf(p, 3)) for p in table}, abs=1e-3)


def test_the_motion_model_and_the_fusion_import_no_scipy() -> None:
    import subprocess
    import sys

    code = "import sys, icploc.motion, icploc.fusion, icploc.calibration; print('scipy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"

"""The motion model, the information update and the odometry calibration (issue 11)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from icploc.calibration import OdometryCalibration
from icploc.fusion import fuse, mahalanobis2, scan_covariance
from icploc.motion import MotionModel, fit_alphas
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

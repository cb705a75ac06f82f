"""Lost behaviour on biased odometry and coarse grids: what the thresholds learn from, the
odometry calibration's heading fit, and the status/reason enums."""

from __future__ import annotations

import math

import pytest
from icploc.calibration import OdometryCalibration
from icploc.fitcheck import FitCheck, MapQuality
from icploc.status import Reason, Status


def test_hit_reference_follows_consistent_fits_not_only_verified_ones() -> None:
    q = MapQuality(0.05)
    for _ in range(5):
        q.observe(FitCheck(1.0, 0.0, 0.02, 300))  # a well-mapped start
    assert q.hit_reference == pytest.approx(1.0)
    # later fits the odometry agrees with show 0.7: verified-only learning would never
    # see them (0.7 < 0.8 x 1.0), and the reference would stay at 1 for good
    for _ in range(40):
        q.observe_consistent(FitCheck(0.7, 0.0, 0.03, 300))
    assert q.hit_reference == pytest.approx(0.7)


def test_residual_is_not_loosened_by_unverified_fits() -> None:
    q = MapQuality(0.05)
    for _ in range(40):
        q.observe_consistent(FitCheck(0.7, 0.0, 0.06, 300))  # beyond the prior
    assert q.sigma == pytest.approx(q.prior)


def test_calibration_reads_the_drift_from_turning_pairs() -> None:
    cal = OdometryCalibration()
    drift = math.radians(1.0)  # rad per metre the odometry loses
    for k in range(200):
        turn = 0.5 if k % 2 else -0.3  # never straight
        cal.observe((1.0, 0.0, turn), (1.0, 0.0, turn + drift * 1.0))
    assert [cal.drift, cal.turn_scale] == pytest.approx([drift, 1.0], abs=2e-3)


def test_calibration_learns_a_turn_scale_beyond_the_old_5_degree_pair_limit() -> None:
    cal = OdometryCalibration()
    for _ in range(100):
        cal.observe((0.0, 0.0, 2.0), (0.0, 0.0, 2.1))  # 5 % short, 5.7 deg a pair
    assert cal.turn_scale == pytest.approx(1.05, abs=0.005)


def test_status_and_reason_are_their_strings() -> None:
    got = [
        Status.TRACKING == "tracking",
        str(Status.LOST),
        f"{Reason.INCONSISTENT}",
        Reason.NONE == "",
        Reason("odometry_off") is Reason.ODOMETRY_OFF,
    ]
    assert got == [True, "lost", "inconsistent", True, True]

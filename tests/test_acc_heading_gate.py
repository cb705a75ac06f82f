"""The heading tested on its own, and the turn's walk kept to turns on the spot.

A turn grows the position covariance (``localizer.turn_walk_variance``, times the learned
gain); the joint chi-square test ``v' (P + R)^-1 v`` (3 dof) then admits a heading
innovation that the heading variance alone refuses: its evidence is spread over three
degrees of freedom. With ``gating.heading_test`` the gate's statistic is the larger of the
joint one and the 3-dof value with the same tail as the heading's own ``v_t^2 / (P + R)_tt``
(1 dof). On the real-data benchmark a fit 10.8 deg off in heading after a 44 deg turn
(csail 10 cm, good base) was at 4.1 sigma of the heading but at a joint d^2 of 20.6, under
the reject quantile (21.1), and was taken as ``inflated``.

The walk was measured on turns on the spot (0.5 rad, 6 cm of travel, off by 7-11 cm of
position); a step that travels as far as the 0.5 m motions the alphas were fitted to is
covered by them (``localizer.turn_walk_max_travel``). With the walk on every step a robot
driving through six 40 deg turns grew a covariance that admitted fits 0.6-1.2 m off
(csail 10 cm, bad base: max 71 -> 115 cm). Real scans of the Intel lab (``test_acc_slip``)
for the localizer-level test; skipped when ../shared is absent.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from icploc.config import LocalizerConfig
from icploc.errors import ConfigError
from icploc.fusion import CHI2_3, chi2_3_same_tail, heading_nis, mahalanobis2
from icploc.localizer import Localizer
from icploc.messages import Scan
from icploc.motion import MotionModel
from icploc.se2 import Pose, between, compose, wrap_angle
from icploc.status import Reason
from test_acc_slip import LOG, _log, _map_near
from test_acc_unverified import update_with_fit_at

#: chi-square quantiles with 1 dof at the gate's probabilities (tables)
CHI2_1 = {0.99: 6.635, 0.999: 10.828, 0.9999: 15.137}


@pytest.mark.parametrize("p", [0.99, 0.999, 0.9999])
def test_the_same_tail_maps_the_1_dof_quantiles_onto_the_3_dof_ones(p: float) -> None:
    assert chi2_3_same_tail(CHI2_1[p]) == pytest.approx(CHI2_3[p], abs=0.01)


def test_the_same_tail_is_monotone_and_never_below_its_argument() -> None:
    xs = [0.01, 0.5, 1.0, 4.0, 9.0, 25.0, 100.0, 599.0, 601.0, 1e4]
    ys = [chi2_3_same_tail(x) for x in xs]
    assert all(b > a for a, b in zip(ys, ys[1:], strict=False)), ys
    assert all(y > x for x, y in zip(xs, ys, strict=True))
    assert chi2_3_same_tail(0.0) == 0.0
    assert chi2_3_same_tail(math.inf) == math.inf


def test_the_heading_statistic_ignores_the_position_covariance() -> None:
    pred: Pose = (1.0, 2.0, 3.1)
    z: Pose = (1.3, 1.8, -3.1)  # across +-pi: 0.0832 rad
    R = np.diag([0.01, 0.01, 0.0004])
    v = wrap_angle(z[2] - pred[2])
    for sxy in (0.05, 0.5, 5.0):
        P = np.diag([sxy**2, sxy**2, 0.0005])
        assert heading_nis(pred, P, z, R) == pytest.approx(v * v / 0.0009)
    # the joint statistic shrinks towards the heading's as the position covariance grows
    tight, wide = np.diag([0.0025, 0.0025, 0.0005]), np.diag([25.0, 25.0, 0.0005])
    assert mahalanobis2(pred, tight, z, R) > 2.0 * mahalanobis2(pred, wide, z, R)
    assert mahalanobis2(pred, wide, z, R) == pytest.approx(heading_nis(pred, wide, z, R), rel=0.01)


def _gate(heading_test: bool) -> float:
    loc = Localizer(
        np.array([[x, y] for x in np.linspace(-2, 2, 21) for y in (-2.0, 2.0)]),
        LocalizerConfig.from_dict({"gating": {"heading_test": heading_test}}),
        initial_pose=(0.0, 0.0, 0.0),
    )
    # a heading innovation of 4 sigma of the heading, no position innovation
    P = np.diag([0.04, 0.04, 0.0001])
    R = np.diag([0.0004, 0.0004, 0.0001])
    return loc._gate_statistic((0.0, 0.0, 0.0), P, (0.0, 0.0, 4.0 * math.sqrt(0.0002)), R)


def test_the_gate_takes_the_heading_alone_at_its_own_tail() -> None:
    reject = CHI2_3[LocalizerConfig().gating.chi2_reject]
    assert LocalizerConfig().gating.heading_test is True
    # 16 on 3 dof is within the reject quantile (inflated); 16 on 1 dof is beyond it
    assert _gate(False) == pytest.approx(16.0)
    assert _gate(False) < reject < _gate(True)
    assert _gate(True) == pytest.approx(chi2_3_same_tail(16.0))


def _track(offset: Pose, data: dict[str, Any], j: int = 300) -> tuple[Any, float, float]:
    """Five sparse scans up to ``j`` from the reference (odometry: the reference motion), the
    position's noise model loose (alphas 0.3: a covariance grown as a turn's walk grows
    it), the heading's tight; at ``j`` the ICP's answer is replaced by a fit at the
    prediction moved by ``offset`` (its evidence measured there). The estimate, its
    heading error (rad) and position error (m)."""
    log, keep, ref, _ = _log()
    loc = Localizer(_map_near(j), LocalizerConfig.from_dict(data), initial_pose=tuple(ref[j - 5]))
    e = None
    for k in range(j - 5, j + 1):
        scan = Scan(stamp=float(k), ranges=log.ranges[keep[k]], angles=log.angles, max_range=30.0)
        if k == j:
            z = compose(compose(loc.pose, between(tuple(ref[k - 1]), tuple(ref[k]))), offset)
            e, _ = update_with_fit_at(loc, scan, tuple(ref[k]), z)
        else:
            e = loc.update(scan, tuple(ref[k]))
    assert e is not None
    return (
        e,
        abs(wrap_angle(e.pose[2] - ref[j][2])),
        math.hypot(e.pose[0] - ref[j][0], e.pose[1] - ref[j][1]),
    )


@pytest.mark.shared_data
@pytest.mark.skipif(not LOG.exists(), reason="../shared/data is absent")
def test_a_fit_off_in_heading_is_not_admitted_by_a_wide_position_covariance() -> None:
    """A fit 1.8 deg off in heading alone: jointly (3 dof) under the accept quantile, the
    heading's own statistic beyond it. With the heading test it is doubtful, and the
    prediction, which verifies and explains the scan better, stands (``inconsistent``);
    without it the fit is fused and the heading turns with it. (The veto of an unverified
    fit explaining less than the prediction, ``unverified_worse_margin``, is off in both
    runs: the gate alone decides.)"""
    loose = {"alpha1": 1e-4, "alpha2": 1e-4, "alpha3": 0.3, "alpha5": 0.3}
    fixed = {"learn_noise": False, "calibrate_odometry": False, "unverified_worse_margin": 0.0}
    accept = CHI2_3[LocalizerConfig().gating.chi2_accept]
    e, dth, err = _track((0.0, 0.0, 0.032), {"localizer": {**loose, **fixed}})
    assert not e.accepted and e.reason == Reason.INCONSISTENT, (e.reason, e.nis)
    assert e.nis > accept
    assert dth < math.radians(0.5) and err < 0.05, (math.degrees(dth), err)
    off, dth_off, _ = _track(
        (0.0, 0.0, 0.032), {"localizer": {**loose, **fixed}, "gating": {"heading_test": False}}
    )
    assert off.accepted and off.nis < accept, (off.reason, off.nis)
    assert dth_off > dth + math.radians(0.5), (math.degrees(dth_off), math.degrees(dth))


def test_the_walk_is_a_turn_on_the_spots() -> None:
    lc = LocalizerConfig().localizer
    assert lc.turn_walk_max_travel == pytest.approx(0.5)
    on = MotionModel.from_config(lc)
    every = MotionModel.from_config(
        LocalizerConfig.from_dict({"localizer": {"turn_walk_max_travel": 0.0}}).localizer
    )
    none = MotionModel.from_config(
        LocalizerConfig.from_dict({"localizer": {"turn_walk_variance": 0.0}}).localizer
    )
    # a turn on the spot (6 cm, 0.5 rad) and a short step turning: the walk, as before
    for d in [(0.06, 0.0, 0.5), (0.4, 0.1, -0.7)]:
        assert np.allclose(on.motion_covariance(d), every.motion_covariance(d))
        assert on.motion_covariance(d)[0, 0] - none.motion_covariance(d)[0, 0] == pytest.approx(
            2.0e-3 * abs(d[2])
        )
    # a step as long as the alphas' 0.5 m motions, turning 0.7 rad: the alphas alone
    far = (0.6, 0.0, 0.7)
    assert np.allclose(on.motion_covariance(far), none.motion_covariance(far))
    assert every.motion_covariance(far)[1, 1] - on.motion_covariance(far)[1, 1] == pytest.approx(
        1.4e-3
    )
    # the heading's variance is never the walk's
    assert on.motion_covariance(far)[2, 2] == pytest.approx(every.motion_covariance(far)[2, 2])


@pytest.mark.parametrize(
    ("section", "key", "value", "says"),
    [
        ("localizer", "turn_walk_max_travel", -0.1, "localizer.turn_walk_max_travel: must be >= 0"),
        (
            "localizer",
            "turn_walk_max_travel",
            float("nan"),
            "localizer.turn_walk_max_travel: must be a finite",
        ),
        ("gating", "heading_test", "maybe", "gating.heading_test"),
    ],
)
def test_absurd_settings_are_refused_naming_the_field(
    section: str, key: str, value: Any, says: str
) -> None:
    with pytest.raises(ConfigError, match=says.replace(".", r"\.")):
        LocalizerConfig.from_dict({section: {key: value}}, source="c.yaml")

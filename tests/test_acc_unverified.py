"""A fit the chi-square test admits that the map does not back, on a real log.

The Intel lab's real scans (``test_acc_slip``); the map is the endpoints of the other scans
at their reference poses, kept only towards one side of the robot (a place the map covers
by half: at the prediction 0.57 of the beams end on walls, short of verifying), and the
odometry's noise model loose (alphas 0.3: odometry off beyond its usual model), so the
chi-square test admits fits 0.2 m off. On the localized scan the ICP's answer is replaced by
a fit at a chosen offset from the prediction, with the evidence measured there (its hit
share and residual are the map's at that pose, its covariance the real fit's): what the
localizer does with a fit that landed there. A fit that does not verify and explains more
than ``localizer.unverified_worse_margin`` less of the scan than the prediction is not fused
(reason ``inconsistent``, the pose stays on the reference); with the rule off it is fused
and the pose goes off; a fit within the margin is fused. Skipped when ../shared is absent.
"""

from __future__ import annotations

import math
from typing import Any

import icploc._core as core
import pytest
from icploc.config import LocalizerConfig
from icploc.errors import ConfigError
from icploc.localizer import Localizer
from icploc.messages import Scan
from icploc.se2 import Pose, between, compose
from icploc.status import Reason
from test_acc_slip import LOG, _log, _map_near

J = 300  # a sparse scan the map covers well all round; the crop leaves it half covered
LOOSE = {"alpha3": 0.3, "alpha5": 0.3, "alpha1": 0.01, "alpha2": 0.01}
FIXED = {"learn_noise": False, "calibrate_odometry": False}


class _Placed:
    """The real ICP result with its pose replaced and the evidence at that pose."""

    def __init__(self, res: Any, pose: Pose, hit: float, rms: float) -> None:
        self._res, self._pose, self._hit, self._rms = res, pose, hit, rms

    def __getattr__(self, k: str) -> Any:
        return getattr(self._res, k)

    @property
    def pose(self) -> Pose:
        return self._pose

    @property
    def inlier_ratio(self) -> float:
        return self._hit

    @property
    def mse(self) -> float:
        return self._rms**2


def update_with_fit_at(loc: Localizer, scan: Scan, odom: Pose, z: Pose) -> tuple[Any, Any]:
    """``loc.update(scan, odom)`` with the ICP's answer replaced by a fit at ``z`` (its
    evidence measured there by the localizer's own checker); the estimate and that check."""
    pts = loc.prepare(scan)
    at_z = loc.checker.check(pts, z)
    real = core.icp

    def _fit(*a: Any, **kw: Any) -> Any:
        return _Placed(real(*a, **kw), z, at_z.hit, at_z.rms)

    core.icp = _fit
    try:
        return loc.update(scan, odom), at_z
    finally:
        core.icp = real


def _track(offset: Pose | None, localizer: dict[str, Any]) -> tuple[Any, Any, float, Localizer]:
    """Track five sparse scans up to ``J`` from the reference (odometry: the reference
    motion); at ``J`` the fit is placed at the prediction moved by ``offset`` (robot
    frame). The estimate at ``J``, the checks at the prediction and at the fit, the
    pose's position error (m) and the localizer."""
    log, keep, ref, _ = _log()
    c = ref[J][:2]
    near = _map_near(J)
    dx, dy = near[:, 0] - c[0], near[:, 1] - c[1]
    keep_side = dy > -0.2 * (dx**2 + dy**2) ** 0.5  # the map towards the robot's +y half
    cfg = LocalizerConfig.from_dict({"localizer": {**LOOSE, **FIXED, **localizer}})
    loc = Localizer(near[keep_side], cfg, initial_pose=tuple(ref[J - 5]))
    at_pred = at_z = None
    e = None
    for k in range(J - 5, J + 1):
        scan = Scan(stamp=float(k), ranges=log.ranges[keep[k]], angles=log.angles, max_range=30.0)
        if k == J and offset is not None:
            pred = compose(loc.pose, between(tuple(ref[k - 1]), tuple(ref[k])))
            at_pred = loc.checker.check(loc.prepare(scan), pred)
            e, at_z = update_with_fit_at(loc, scan, tuple(ref[k]), compose(pred, offset))
        else:
            e = loc.update(scan, tuple(ref[k]))
    assert e is not None
    return e, (at_pred, at_z), math.hypot(e.pose[0] - ref[J][0], e.pose[1] - ref[J][1]), loc


_DATA = [
    pytest.mark.shared_data,
    pytest.mark.skipif(not LOG.exists(), reason="../shared/data is absent"),
]


def _data(f: Any) -> Any:
    for m in _DATA:
        f = m(f)
    return f


@_data
@pytest.mark.parametrize("offset", [(0.2, 0.0, 0.0), (-0.06, 0.0, 0.0), (0.0, 0.0, 0.02)])
def test_an_unverified_fit_explaining_clearly_less_is_not_fused(offset: Pose) -> None:
    _, _, err0, _ = _track((0.0, 0.0, 0.0), {})
    e, (at_pred, at_z), err, loc = _track(offset, {})
    margin = LocalizerConfig().localizer.unverified_worse_margin
    assert margin == 0.05
    # the fit does not verify and explains more than the margin less than the prediction
    assert at_pred.hit - at_z.hit > margin, (at_pred.hit, at_z.hit)
    assert not loc._verified(at_z)
    # not fused: the prediction stands, as close to the reference as the fit at it leaves it
    assert e.reason == Reason.INCONSISTENT
    assert abs(err - err0) < 0.02 and err < 0.03, (err, err0)
    # with the rule off the chi-square test admits the same fit and the pose goes its way
    off, _, err_off, _ = _track(offset, {"unverified_worse_margin": 0.0})
    assert off.reason != Reason.INCONSISTENT
    if offset[2] == 0.0:
        assert err_off > err + 0.04, (err_off, err)
    else:  # a heading off by 0.02 rad: the fused heading turns with it
        assert abs(off.pose[2] - e.pose[2]) > 0.005, (off.pose, e.pose)


@_data
def test_an_unverified_fit_within_the_margin_is_fused() -> None:
    offset = (-0.04, 0.0, 0.0)
    _, _, err0, _ = _track((0.0, 0.0, 0.0), {})
    e, (at_pred, at_z), err, loc = _track(offset, {})
    assert not loc._verified(at_z)
    drop = at_pred.hit - at_z.hit
    assert 0.0 < drop < LocalizerConfig().localizer.unverified_worse_margin, drop
    # fused: the pose moves towards the fit (the fit is 4 cm behind the prediction)
    assert e.reason != Reason.INCONSISTENT
    assert err > err0 + 0.02, (err, err0)
    # the margin decides: below this fit's drop the same fit is not fused
    tight, _, err_tight, _ = _track(offset, {"unverified_worse_margin": round(drop / 2, 4)})
    assert tight.reason == Reason.INCONSISTENT
    assert abs(err_tight - err0) < 0.02, (err_tight, err0)


@pytest.mark.parametrize(
    ("key", "value", "says"),
    [
        ("unverified_worse_margin", -0.05, "localizer.unverified_worse_margin: must be >= 0"),
        (
            "unverified_worse_margin",
            float("nan"),
            "localizer.unverified_worse_margin: must be a finite",
        ),
        ("unverified_worse_margin", 1.5, "localizer.unverified_worse_margin: must be <= 1"),
        ("step_retry_scales", [0.5, -1.0], "localizer.step_retry_scales: every scale must be >= 0"),
        ("step_retry_scales", [float("nan")], "localizer.step_retry_scales: must be a finite"),
        ("step_retry_scales", "0.5", "localizer.step_retry_scales: expected a list"),
        ("step_retry_margin", -0.01, "localizer.step_retry_margin: must be >= 0"),
        (
            "step_retry_max_offset",
            float("inf"),
            "localizer.step_retry_max_offset: must be a finite",
        ),
        ("step_retry_min_turn_deg", 200.0, "localizer.step_retry_min_turn_deg: must be <= 180"),
    ],
)
def test_absurd_rule_settings_are_refused_naming_the_field(key: str, value: Any, says: str) -> None:
    with pytest.raises(ConfigError, match=says.replace(".", r"\.")):
        LocalizerConfig.from_dict({"localizer": {key: value}}, source="c.yaml")


def test_an_empty_step_retry_list_turns_the_retry_off() -> None:
    assert (
        LocalizerConfig.from_dict(
            {"localizer": {"step_retry_scales": []}}
        ).localizer.step_retry_scales
        == ()
    )

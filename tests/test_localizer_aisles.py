"""Repetitive aisles (issue 11: `tracking` is a promise): along a shelf aisle the scan holds the
position only through the odd shelf end, and a fit slides by a gap. Such a direction is no
measurement, a fit that explains the scan less well than its verified prediction is no
evidence, and no scan may be reported `tracking` while far off."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from icploc import sim
from icploc.fusion import scan_covariance
from icploc.maps import Map
from icploc.replay import replay
from icploc.status import Status


def _aisle_information(beams_along: float) -> np.ndarray:
    # unit normals: 300 beams on the shelves (normal y), ``beams_along`` on shelf ends (x)
    return np.diag([beams_along, 300.0, 3000.0])


def test_a_direction_held_by_a_few_beams_is_left_unconstrained() -> None:
    R = scan_covariance(_aisle_information(4.0), 304, 1e-4, 0.02, 12.0, min_axis_beams=8.0)
    assert math.sqrt(R[0, 0]) > 100.0


def test_a_direction_held_by_enough_beams_is_kept() -> None:
    R = scan_covariance(_aisle_information(40.0), 340, 1e-4, 0.02, 12.0, min_axis_beams=8.0)
    assert math.sqrt(R[0, 0]) < 0.1


@pytest.mark.slow
def test_aisles_never_tracking_far_off(tmp_path: Path) -> None:
    w = sim.aisles()
    # down aisle 1 (40 m), around its end, back along aisle 2: on biased odometry
    path = np.array([(1.0, 1.25), (41.0, 1.25), (41.0, 3.75), (10.0, 3.75)])
    frames = list(
        sim.simulate(w, path, start=(1.0, 1.25, 0.0), seed=1, noise=0.02, speed=0.6)
    )
    m = Map.load(Map.from_lines(w.lines).to_ros(tmp_path / "aisles.yaml", 0.05))
    items = sorted([f.scan for f in frames] + [f.odometry for f in frames], key=lambda x: x.stamp)
    res = replay(items, m, initial_pose=frames[0].truth)
    T = np.array([f.truth for f in frames])
    err = np.hypot(res.poses[:, 0] - T[:, 0], res.poses[:, 1] - T[:, 1])
    tracking = np.array([e.status is Status.TRACKING for e in res.estimates])
    assert int(np.sum(tracking & (err > 0.5))) == 0

"""Local recovery (icploc.recovery.LocalRecovery): when a verified candidate locks."""

from __future__ import annotations

import math

import numpy as np
from icploc import MapIndex
from icploc import sim as worlds
from icploc.config import LocalizerConfig
from icploc.localizer import prepare_scan
from icploc.messages import Scan
from icploc.recovery import LocalRecovery, RecoveryView
from sampled_walls import walls_index


def _view(index: MapIndex, pose: tuple[float, float, float], verdicts: list[bool]) -> RecoveryView:
    cfg = LocalizerConfig()
    return RecoveryView(
        pose=pose,
        covariance=np.diag([0.04, 0.04, 0.01]),
        motion=(0.0, 0.0, 0.0),
        stamp=0.0,
        scans_processed=0,
        lost_scans=10,
        index=index,
        icp_config=cfg.icp.to_icp_config(window_search=False),
        config=cfg,
        verify=lambda pts, p: (verdicts.pop(0), None, p),
    )


def test_one_scan_that_does_not_verify_pauses_the_lock_count_it_does_not_end_it() -> None:
    """On a map from another pass one poor scan in a few fails verification; a streak that
    restarted on every such scan kept a robot on biased odometry lost until it was metres
    off (freiburg-campus, 10 cm grid, bad odometry: 4 scans > 5 m off while lost)."""
    lab = worlds.lab(people=0)
    index = walls_index(lab.lines)
    truth = (0.3, -0.4, 0.5)
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    r = lab.ranges(truth, angles, 8.0, 0.0, np.random.default_rng(0), 0.0)
    points = prepare_scan(Scan(stamp=0.0, ranges=r, angles=angles, max_range=8.0), LocalizerConfig())
    rec = LocalRecovery(confirm=3)
    verdicts = [True, True, False, True]
    states = [rec.recover(_view(index, truth, verdicts), points).state for _ in range(4)]
    assert states == ["confirming", "confirming", "searching", "locked"]

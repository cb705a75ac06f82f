"""The strict whole-map check of a lock is skipped only for a verified lock the dead
reckoning agrees with that already beat every rival of a whole-map search of its lost
episode (RecoveryStep.rivals_searched); every other lock is checked as before."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.config import LocalizerConfig
from icploc.kidnap import CheckVerdict
from icploc.localizer import Localizer, Status, prepare_scan
from icploc.messages import Scan
from icploc.recovery import RecoveryStep, RecoveryView
from icploc.relocalize import GlobalRelocalization, Relocalizer, global_localizer
from icploc.se2 import Pose, between
from sampled_walls import walls_index

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import global_bench as gb  # noqa: E402

CFG = LocalizerConfig()


class _Stub:
    """A recovery that locks at once on ``pose`` and counts the strict checks asked of it."""

    def __init__(self, pose: Pose, result: Any, searched: bool, verified: bool = True) -> None:
        self.pose, self.result, self.searched, self.verified = pose, result, searched, verified
        self.checks = 0

    def recover(self, view: RecoveryView, points: Any) -> RecoveryStep:
        return RecoveryStep(
            "locked",
            lock=self.pose,
            result=self.result,
            verified=self.verified,
            rivals_searched=self.searched,
        )

    def check_pose(self, index: Any, points: Any, tracked: Pose, strict: bool) -> CheckVerdict:
        self.checks += 1
        return CheckVerdict("")

    def reset(self) -> None:
        pass


def _checks(searched: bool, lock_offset: float = 0.0, verified: bool = True) -> tuple[int, Any]:
    """Lost in the lab at the true pose (the dead reckoning right, its sigma small); the
    recovery locks ``lock_offset`` m from it: the strict checks made, the estimate."""
    lab = worlds.lab(people=0)
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    rng = np.random.default_rng(0)
    truth = (0.3, -0.4, 0.5)
    lock = (truth[0] + lock_offset, truth[1], truth[2])
    loc = Localizer(walls_index(lab.lines), CFG, initial_pose=truth)
    r = lab.ranges(lock, angles, 8.0, 0.0, rng, 0.0)
    scan = Scan(stamp=0.0, ranges=r, angles=angles, max_range=8.0)
    ok, res, z = loc.verify_pose(prepare_scan(scan, CFG), lock)
    assert ok and res is not None
    stub = _Stub(z, res, searched, verified)
    loc.recovery = stub
    loc.declare_lost()
    est = loc.update(scan)
    return stub.checks, est


def test_a_lock_that_beat_a_whole_map_searchs_rivals_where_the_dead_reckoning_is_not_checked_again() -> (
    None
):
    n, est = _checks(searched=True)
    assert (n, est.status) == (0, Status.TRACKING)


def test_a_lock_without_a_whole_map_search_is_checked() -> None:
    n, est = _checks(searched=False)
    assert (n, est.status) == (1, Status.TRACKING)


def test_a_lock_away_from_the_dead_reckoning_is_checked_even_after_a_whole_map_search() -> None:
    """A kidnapping's lock lies far from the dead reckoning: always checked."""
    n, _ = _checks(searched=True, lock_offset=3.0)
    assert n == 1


def test_an_unverified_lock_is_checked_even_after_a_whole_map_search() -> None:
    n, est = _checks(searched=True, verified=False)
    assert (n, est.status) == (1, Status.DEGRADED)


@pytest.fixture(scope="module")
def bld_glob() -> Any:
    return global_localizer(gb.building().walls, 0.05)


def _step_flags(bld_glob: Any, cov: Any, n: int = 8) -> list[tuple[int, bool]]:
    """Lost in the building's corridor with the dead reckoning right and covariance
    ``cov``: the scans a lock came on and whether it beat a whole-map search's rivals."""
    bld = gb.building()
    frames = gb.drive(bld, (18.0, 0.8, 0.1), n, gb.Sensor(), np.random.default_rng(4))
    gr = GlobalRelocalization(Relocalizer(None, localizer=bld_glob), config=CFG)
    out, prev = [], None
    for k, (pose, scan) in enumerate(frames):
        view = RecoveryView(
            pose=pose,
            covariance=cov,
            motion=between(prev, pose) if prev is not None else None,
            stamp=0.1 * k,
            scans_processed=k,
            lost_scans=k + 1,
            index=bld_glob.index,
            icp_config=CFG.icp.to_icp_config(window_search=False),
            config=CFG,
            verify=lambda pts, p: (True, type("Fit", (), {"inlier_ratio": 0.9})(), p),
        )
        step = gr.recover(view, prepare_scan(scan, CFG))
        if step.lock is not None:
            out.append((k, step.rivals_searched))
        prev = pose
    return out


def test_a_trackers_lock_after_a_whole_map_search_says_so(bld_glob) -> None:
    # no prior: every search covers the whole map
    got = _step_flags(bld_glob, np.diag([1e6, 1e6, math.pi**2]))
    assert got[0] == (2, True)


def test_a_local_recoverys_lock_does_not(bld_glob) -> None:
    # a dead reckoning that means something: local recovery locks first, no whole-map search
    got = _step_flags(bld_glob, np.diag([0.01, 0.01, 0.001]))
    assert got and got[0][1] is False

"""A lock on the recovery's own evidence that the localizer's verification refuses (a place
the map covers worse than its usual fit: another pass, clutter): held one scan longer
than a lock needs, it resumes there ``degraded`` — never ``tracking`` — instead of dead
reckoning on while lost (intel 5 cm, bad odometry: the tracker held the right pose 1-5 cm
off for 10 scans while the dead-reckoned pose drifted 0.5 -> 2.6 m)."""

from __future__ import annotations

import math
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.config import LocalizerConfig
from icploc.localizer import Localizer, Status, prepare_scan
from icploc.messages import Scan
from icploc.recovery import RecoveryStep, RecoveryView
from icploc.relocalize import GlobalRelocalization, Relocalizer, global_localizer
from icploc.se2 import Pose, between
from icploc.status import Reason
from sampled_walls import walls_index

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benches"))
import global_bench as gb  # noqa: E402

SENSOR = gb.Sensor()
CFG = LocalizerConfig()
START = (18.0, 0.8, 0.1)  # the building's corridor by the cross corridor


@pytest.fixture(scope="module")
def bld_glob() -> Any:
    return global_localizer(gb.building().walls, 0.05)


def _locks(bld_glob: Any, verdict: bool, n: int = 6) -> list[tuple[int, bool]]:
    """Drive n scans; the localizer's verification answers ``verdict`` (with a fit as good
    as recovery asks for); the scans (and whether verified) a lock came on."""
    bld = gb.building()
    frames = gb.drive(bld, START, n, SENSOR, np.random.default_rng(4))
    gr = GlobalRelocalization(Relocalizer(None, localizer=bld_glob), config=CFG)
    fit = SimpleNamespace(inlier_ratio=0.9)
    out, prev = [], None
    for k, (pose, scan) in enumerate(frames):
        view = RecoveryView(
            pose=pose,
            covariance=np.diag([1e6, 1e6, math.pi**2]),  # no prior: the 3-scan lock
            motion=between(prev, pose) if prev is not None else None,
            stamp=0.1 * k,
            scans_processed=k,
            lost_scans=k + 1,
            index=bld_glob.index,
            icp_config=CFG.icp.to_icp_config(window_search=False),
            config=CFG,
            verify=lambda pts, p: (verdict, fit, p),
        )
        step = gr.recover(view, prepare_scan(scan, CFG))
        if step.lock is not None:
            out.append((k, step.verified))
        prev = pose
    return out


def test_a_lock_the_localizer_verifies_comes_on_the_third_scan(bld_glob) -> None:
    assert _locks(bld_glob, True)[0] == (2, True)


def test_a_lock_the_localizer_refuses_comes_a_scan_later_unverified(bld_glob) -> None:
    assert _locks(bld_glob, False)[0] == (3, False)


class _Stub:
    """A recovery that locks at once on ``pose`` with ``verified``."""

    def __init__(self, pose: Pose, result: Any, verified: bool) -> None:
        self.pose, self.result, self.verified = pose, result, verified

    def recover(self, view: RecoveryView, points: Any) -> RecoveryStep:
        return RecoveryStep("locked", lock=self.pose, result=self.result, verified=self.verified)

    def reset(self) -> None:
        pass


def _lab_lock(verified: bool) -> tuple[Any, Pose, Localizer, Scan]:
    lab = worlds.lab(people=0)
    truth = (0.3, -0.4, 0.5)
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    r = lab.ranges(truth, angles, 8.0, 0.0, np.random.default_rng(0), 0.0)
    scan = Scan(stamp=0.0, ranges=r, angles=angles, max_range=8.0)
    loc = Localizer(walls_index(lab.lines), CFG, initial_pose=truth)
    ok, res, z = loc.verify_pose(prepare_scan(scan, CFG), truth)
    assert ok and res is not None  # a lock the localizer would verify: only the flag differs
    loc.recovery = _Stub(z, res, verified)
    loc.declare_lost()
    est = loc.update(scan)
    return est, truth, loc, scan


def test_an_unverified_lock_resumes_degraded_not_tracking() -> None:
    est, truth, _, _ = _lab_lock(verified=False)
    assert (est.status, est.reason) == (Status.DEGRADED, Reason.LOCK_UNVERIFIED)
    assert math.dist(est.pose[:2], truth[:2]) < 0.05


def test_the_same_lock_verified_resumes_tracking() -> None:
    est, _, _, _ = _lab_lock(verified=True)
    assert (est.status, est.reason) == (Status.TRACKING, Reason.RELOCALIZED)


def test_after_an_unverified_lock_the_pose_settles_before_it_is_tracking() -> None:
    """The lock skipped the localizer's verification: the scans after it are not promised
    at once (the localizer's reset forgot every guard) but settle as after a jump:
    settle_scans verified scans first."""
    _, _, loc, scan = _lab_lock(verified=False)
    n = CFG.localizer.settle_scans
    got = [(e.status, e.reason) for e in (loc.update(scan) for _ in range(n + 1))]
    assert got == [(Status.DEGRADED, Reason.UNSETTLED)] * (n - 1) + [(Status.TRACKING, Reason.NONE)] * 2

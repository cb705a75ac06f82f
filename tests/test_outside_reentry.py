"""Coming back into the map (icploc.outside): the re-entry search over the dead
reckoning's uncertainty, and a stretch's record of its own dead reckoning."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from icploc.outside import OutsideConfig, ReentryRecovery, _search_poses
from icploc.se2 import between
from partial_world import localized


def test_the_search_grid_covers_the_uncertainty_disc_at_its_step() -> None:
    cfg = OutsideConfig(reentry_step=0.4, probe_radius=5.0, reentry_max_probes=10**6)
    cov = np.diag([4.0, 4.0, math.radians(5.0) ** 2])  # sigma 2.8 m: 3 sigma capped at 5 m
    p = _search_poses((10.0, -3.0, 0.5), cov, cfg)
    # every point of the 5 m disc is within half a diagonal step of a probe position
    rng = np.random.default_rng(1)
    r, a = 5.0 * np.sqrt(rng.uniform(size=500)), rng.uniform(0, 2 * math.pi, 500)
    q = np.column_stack([10.0 + r * np.cos(a), -3.0 + r * np.sin(a)])
    d = np.hypot(q[:, None, 0] - p[None, :, 0], q[:, None, 1] - p[None, :, 1]).min(axis=1)
    assert float(d.max()) <= 0.4 * math.sqrt(2) / 2 + 0.2  # + the rim beyond the last ring


def test_the_search_grid_keeps_to_its_budget_of_probe_poses() -> None:
    cfg = OutsideConfig(reentry_max_probes=3000)
    cov = np.diag([9.0, 9.0, math.radians(12.0) ** 2])  # 5 m and +-36 deg: 19 headings
    assert len(_search_poses((0.0, 0.0, 0.0), cov, cfg)) <= 1.1 * 3000


def test_the_search_grid_spans_three_heading_sigmas() -> None:
    cfg = OutsideConfig(reentry_heading_step=math.radians(4.0))
    cov = np.diag([0.01, 0.01, math.radians(6.0) ** 2])
    p = _search_poses((0.0, 0.0, 0.0), cov, cfg)
    assert math.degrees(float(np.abs(p[:, 2]).max())) == pytest.approx(16.0)


# -- the re-entry search on a small map: a room 8 x 6 m with a pillar -------------------


def _room() -> tuple[Any, np.ndarray]:
    from icploc._core import MapIndex

    s = np.linspace(0.0, 1.0, 200)
    walls = [((0, 0), (8, 0)), ((8, 0), (8, 6)), ((8, 6), (0, 6)), ((0, 6), (0, 0)),
             ((5, 2), (5.6, 2)), ((5.6, 2), (5.6, 2.6)), ((5.6, 2.6), (5, 2.6)), ((5, 2.6), (5, 2))]  # fmt: skip
    pts = np.concatenate(
        [np.column_stack([a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])]) for a, b in walls]
    )
    return MapIndex(pts), pts


def _scan(truth: tuple[float, float, float], pts: np.ndarray) -> np.ndarray:
    # the map points the robot sees, in its frame (a 360 deg scan, visibility ignored)
    c, s = math.cos(truth[2]), math.sin(truth[2])
    d = pts - np.array(truth[:2])
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]])[::4]


@dataclass
class _View:
    pose: tuple[float, float, float]
    covariance: np.ndarray
    index: Any
    icp_config: Any
    truth: tuple[float, float, float]
    motion: tuple[float, float, float] | None = None

    def verify(self, points: np.ndarray, start: Any) -> tuple[bool, Any, Any]:
        from icploc._core import icp

        r = icp(points, self.index, tuple(start), self.icp_config)
        ok = math.dist(r.pose[:2], self.truth[:2]) < 0.05 and r.inlier_ratio > 0.9
        return ok, r, tuple(r.pose)


class _Global:
    """A global recovery that never finds anything (and counts its calls)."""

    def __init__(self) -> None:
        self.calls = 0

    def recover(self, view: Any, points: np.ndarray) -> Any:
        from icploc.recovery import RecoveryStep

        self.calls += 1
        return RecoveryStep("searching")

    def reset(self) -> None:
        pass


def _reentry(scans_before: int) -> tuple[list[str], int]:
    """The re-entry search's states over 3 scans, after ``scans_before`` scans in which
    the scan explained nothing; the dead reckoning 1.6 m and 7 deg off."""
    from icploc._core import IcpConfig

    index, pts = _room()
    truth = (3.0, 3.5, 0.3)
    view = _View((4.2, 2.5, 0.3 - math.radians(7.0)), np.diag([1.0, 1.0, 0.03]), index,
                 IcpConfig(), truth)  # fmt: skip
    g = _Global()
    rec = ReentryRecovery(g, index, 0.1, OutsideConfig(reentry_local_scans=10))
    rec.scans = scans_before
    scan = _scan(truth, pts)
    return [rec.recover(view, scan).state for _ in range(3)], g.calls


def test_the_reentry_search_locks_from_a_dead_reckoning_metres_off() -> None:
    states, _ = _reentry(0)
    assert states == ["confirming", "locked", "confirming"]


def test_after_its_local_scans_the_reentry_search_goes_on_beside_the_global_one() -> None:
    # (the scan may land on known space well before it explains the walls there)
    assert _reentry(10) == (["confirming", "locked", "confirming"], 3)


# -- the simulated building: a stretch records its own dead reckoning ------------------


@pytest.mark.slow
def test_a_stretch_records_the_odometry_not_the_poses_the_lost_localizer_drew() -> None:
    # consecutive recorded poses of the stretch differ by the odometry step (calibrated:
    # within a few millimetres of the raw one), up to the lock; on seed 1 the lost
    # localizer's coasting pulls its pose onto the map scan by scan while re-entering
    run, _, _, mon = localized(1)
    st = mon.stretches[0]
    ks = [k for k, _, _ in st.scans][:-1]
    rec = [p for _, _, p in st.scans][:-1]
    odom = [run.items[2 * k].pose for k in ks]
    dev = [
        math.dist(between(a, b)[:2], between(c, d)[:2])
        for a, b, c, d in zip(rec, rec[1:], odom, odom[1:], strict=False)
    ]
    assert max(dev) < 0.005


@pytest.mark.slow
def test_a_stretch_records_the_scans_after_its_lock_for_the_patch() -> None:
    # (their poses by odometry from the lock tie the lock to the mapped walls)
    _, _, _, mon = localized()
    st = mon.stretches[0]
    assert st.end is not None
    assert [k for k, _, _ in st.lead_out] == list(range(st.end + 1, st.end + 21))


@pytest.mark.slow
def test_a_stretch_records_the_localizers_motion_model_at_its_exit() -> None:
    # the patch's pose graph takes the odometry's heading noise from the exit to the first
    # outside scan from it (icploc.mappatch._exit_step_heading_sigma): the configured
    # alphas with the noise gain the localizer learned by then
    from icploc.config import LocalizerSection
    from icploc.motion import MotionModel

    _, _, _, mon = localized()
    m = mon.stretches[0].exit_motion
    lc = LocalizerSection()
    assert isinstance(m, MotionModel)
    assert (m.alpha1, m.alpha2, m.alpha3) == (lc.alpha1, lc.alpha2, lc.alpha3)
    assert 1.0 <= m.gain <= lc.noise_gain_max


@pytest.mark.slow
def test_a_stretch_records_the_scans_between_its_exit_and_its_first_outside_scan() -> None:
    # the exit anchor is the last tracking pose; the scans the exit detection took after
    # it (1.3-1.6 m of the simulated corridor) are kept, at their poses by odometry from
    # it, so the patch's graph chains them by scan matches instead of one odometry step
    _, _, ests, mon = localized()
    st = mon.stretches[0]
    ks = [k for k, _, _ in st.lead_in]
    # the recorded scans begin with the streak that began the stretch (its first
    # enter_scans - 1 scans were localized as usual, before start): the lead-in runs up to
    # the first of them, no gap and no overlap
    first = st.scans[0][0]
    assert first == st.start - (OutsideConfig().enter_scans - 1)
    assert len(ks) >= 10 and ks == list(range(ks[0], first))
    exit_k = ks[0] - 1
    assert ests[exit_k].status.value == "tracking" and ests[exit_k].pose == st.exit_pose
    assert all(e.status.value != "tracking" for e in ests[ks[0] : st.start])
    # the lead-in's poses run on into the stretch's own dead reckoning
    last = st.lead_in[-1][2]
    assert math.dist(last[:2], st.scans[0][2][:2]) < 0.1


@pytest.mark.slow
def test_an_exit_gap_longer_than_lead_in_scans_records_no_lead_in() -> None:
    from icploc.localizer import Localizer, run
    from icploc.outside import attach
    from partial_world import partial_run

    with pytest.raises(ValueError, match="lead_in_scans"):
        OutsideConfig(lead_in_scans=-1).validate()
    r, m = partial_run(0)
    loc = Localizer(m, initial_pose=tuple(r.truth[0]))
    mon = attach(loc, OutsideConfig(lead_in_scans=5), record=True)
    run(loc, r.items)
    st = mon.stretches[0]
    assert st.lead_in == [] and st.scans  # the simulated gap is 30-40 scans

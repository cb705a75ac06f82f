"""A reset (or a kidnapping declared) between scans while the robot is outside the map:
the outside monitor (icploc.outside) ends its stretch there and starts over, on the
simulated building whose map lacks a wing (tests/partial_world.py)."""

from __future__ import annotations

import math

from icploc.localizer import Status
from icploc.outside import ReentryRecovery
from partial_world import drive, go_on


def test_a_reset_while_outside_ends_the_stretch_and_the_next_scan_is_not_coasted() -> None:
    run, loc, k = drive("outside")
    mon = loc.outside
    st = mon.stretches[-1]
    coasted = st.outside_scans
    loc.reset(tuple(run.truth[k - 1]))
    assert mon.state == "inside"
    assert st.reset_at == k
    assert st.end is None and not st.closed
    est = go_on(run, loc, k, 1)[0]
    assert est.reason != "outside_map"
    assert est.mapped
    assert st.outside_scans == coasted  # the ended stretch takes no more scans
    assert "ended by a reset before scan" in mon.summary_lines(k + 1)[1]


def test_a_kidnapping_declared_while_outside_is_searched_for() -> None:
    run, loc, k = drive("outside")
    loc.declare_lost()
    est = go_on(run, loc, k, 1)[0]
    assert est.status is Status.LOST
    assert est.reason != "outside_map"
    assert loc.outside.stretches[-1].reset_at == k


def test_a_reset_while_reentering_gives_the_localizer_its_own_recovery_back() -> None:
    run, loc, k = drive("reentering")
    assert isinstance(loc.recovery, ReentryRecovery)
    own = loc.recovery.fallback
    loc.reset(tuple(run.truth[k - 1]))
    assert loc.recovery is own
    assert loc.outside.state == "inside"
    ests = go_on(run, loc, k, 10)
    # (degraded at the door, half the scan off the map; matched, not dead-reckoned)
    assert [e.reason for e in ests if e.reason in ("outside_map", "reentering")] == []
    err = [math.dist(e.pose[:2], run.truth[i][:2]) for i, e in enumerate(ests, k)]
    assert max(err) < 0.3


def test_the_localizers_own_lock_while_reentering_is_no_reset() -> None:
    # the re-entry lock resets the localizer within the scan: the stretch closes by the
    # lock, not by a reset
    run, loc, k = drive("reentering")
    go_on(run, loc, k, len(run.scans) - k)
    mon = loc.outside
    st = mon.stretches[0]
    assert st.closed and st.lock_pose is not None
    assert [s.reset_at for s in mon.stretches] == [None] * len(mon.stretches)

"""A reset (or a kidnapping declared) between scans while the robot is outside the map:
the outside monitor (icploc.outside) ends its stretch there and starts over, on the
simulated building whose map lacks a wing (tests/partial_world.py)."""

from __future__ import annotations

import functools
import math

from icploc.config import LocalizerConfig
from icploc.localizer import Estimate, Localizer, Status
from icploc.outside import OutsideMonitor, ReentryRecovery
from partial_world import partial_run


@functools.lru_cache(maxsize=1)
def _run():  # type: ignore[no-untyped-def]
    return partial_run(0)


def _drive(until: str) -> tuple[Localizer, OutsideMonitor, int, list[Estimate]]:
    """A localizer from the true start, scan by scan until its monitor is in state
    ``until`` for the third scan in a row: (localizer, monitor, next scan, estimates)."""
    run, m = _run()
    loc = Localizer(m, LocalizerConfig(), initial_pose=tuple(run.truth[0]))
    mon = loc.outside
    assert isinstance(mon, OutsideMonitor)
    ests: list[Estimate] = []
    streak = 0
    for k in range(len(run.scans)):
        ests.append(loc.update(run.items[2 * k + 1], run.items[2 * k]))
        streak = streak + 1 if mon.state == until else 0
        if streak == 3:
            return loc, mon, k + 1, ests
    raise AssertionError(f"the monitor never was {until!r} for 3 scans")


def _go_on(loc: Localizer, k: int, n: int) -> list[Estimate]:
    run, _ = _run()
    return [loc.update(run.items[2 * i + 1], run.items[2 * i]) for i in range(k, k + n)]


def test_a_reset_while_outside_ends_the_stretch_and_the_next_scan_is_not_coasted() -> None:
    loc, mon, k, _ = _drive("outside")
    st = mon.stretches[-1]
    coasted = st.outside_scans
    run, _ = _run()
    loc.reset(tuple(run.truth[k - 1]))
    assert mon.state == "inside"
    assert st.reset_at == k
    assert st.end is None and not st.closed
    est = _go_on(loc, k, 1)[0]
    assert est.reason != "outside_map"
    assert est.mapped
    assert st.outside_scans == coasted  # the ended stretch takes no more scans
    assert "ended by a reset before scan" in mon.summary_lines(k + 1)[1]


def test_a_kidnapping_declared_while_outside_is_searched_for() -> None:
    loc, mon, k, _ = _drive("outside")
    loc.declare_lost()
    est = _go_on(loc, k, 1)[0]
    assert est.status is Status.LOST
    assert est.reason != "outside_map"
    assert mon.stretches[-1].reset_at == k


def test_a_reset_while_reentering_gives_the_localizer_its_own_recovery_back() -> None:
    loc, mon, k, _ = _drive("reentering")
    assert isinstance(loc.recovery, ReentryRecovery)
    own = loc.recovery.fallback
    run, _ = _run()
    loc.reset(tuple(run.truth[k - 1]))
    assert loc.recovery is own
    assert mon.state == "inside"
    ests = _go_on(loc, k, 10)
    # (degraded at the door, half the scan off the map; matched, not dead-reckoned)
    assert [e.reason for e in ests if e.reason in ("outside_map", "reentering")] == []
    err = [math.dist(e.pose[:2], run.truth[i][:2]) for i, e in enumerate(ests, k)]
    assert max(err) < 0.3


def test_the_localizers_own_lock_while_reentering_is_no_reset() -> None:
    # the re-entry lock resets the localizer within the scan: the stretch closes by the
    # lock, not by a reset
    loc, mon, k, _ = _drive("reentering")
    run, _ = _run()
    _go_on(loc, k, len(run.scans) - k)
    st = mon.stretches[0]
    assert st.closed and st.lock_pose is not None
    assert [s.reset_at for s in mon.stretches] == [None] * len(mon.stretches)

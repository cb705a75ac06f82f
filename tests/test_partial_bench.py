"""The partial-map benchmark's measuring stick (benches/eval_partial.py): which stretches
outside the map count as re-entries, and from which scan a re-entry lock is timed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

BENCHES = Path(__file__).resolve().parent.parent / "benches"
sys.path.insert(0, str(BENCHES))

import eval_partial as ep  # noqa: E402


def _stretch(start: int, end: int | None, reentry: int | None = None) -> dict:
    return {"start": start, "end": end, "outside_scans": 3, "reentry_scans": reentry,
            "distance_m": 1.0}  # fmt: skip


def test_a_stretch_open_at_the_end_without_a_revisit_after_it_never_came_back() -> None:
    rev = np.zeros(40, dtype=bool)
    rev[[5, 6, 25]] = True  # revisits before stretch 2 and inside stretch 2's span
    stretches = [_stretch(2, 10, 4), _stretch(20, None), _stretch(30, None)]
    # a closed stretch came back; an open one with a revisit after its start came back
    # (its missing lock is a failure); an open one with none after it did not
    assert ep.came_back(stretches, rev) == [True, True, False]


def test_the_table_counts_re_entries_of_the_stretches_come_back() -> None:
    row = {
        "log": "x", "method": "icploc", "scans": 40, "inside_median_m": 0.03,
        "inside_p95_m": 0.08, "revisits": 3, "revisits_within_0_5m": 1.0,
        "false_tracking": 0, "lost_share": 0.0, "outside_scans": 6, "reentries": 1,
        "reentry_scans_median": 4.0, "stretches_back": 1,
        "stretches": [_stretch(2, 10, 4), _stretch(30, None)],
        "lock_after_explained_median": 2.0, "lock_after_explained_max": 2,
        "inside_same_as_plain": [17, 20],
    }  # fmt: skip
    cells = ep.md_row(row).split(" | ")
    # inside the map: the first half scan by scan as the default replay's
    assert cells[5] == "17 of 20 identical"
    cell = cells[11]
    assert (
        cell
        == "1 of 1 (4), 2 (max 2) from the first explained; 1 open at the end, no revisit after"
    )


def test_a_lock_is_timed_from_the_first_scan_the_map_explains_in_the_last_re_entry() -> None:
    # re-entering 10..13 (none explained), out again, re-entering 16..20: 18 explained first
    explained = {10: False, 11: True, 12: False, 13: False,
                 16: False, 17: False, 18: True, 19: False, 20: True}  # fmt: skip
    st = _stretch(8, 20, 5)
    assert ep.first_explained(st, explained) == 18
    # a scan of another stretch is not this one's
    assert ep.first_explained(_stretch(8, 15, 5), {16: True, 14: False}) is None
    # still open: its re-entering scans up to the end
    assert ep.first_explained(_stretch(8, None), {30: False, 31: True}) == 31


def test_the_truth_patch_draws_the_patch_scans_at_their_reference_poses() -> None:
    from types import SimpleNamespace

    from icploc.outside import Stretch

    # a wall 2 m ahead, seen from three poses; the recorded (coasted) poses are 0.5 m off
    ys = np.linspace(-1.0, 1.0, 81)
    pts = np.column_stack([np.full_like(ys, 2.0), ys])
    ref = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.3, 0.0, 0.0]])
    closed = Stretch(0, 0.0, (0.0, 0.0, 0.0), end=3, lock_pose=(0.3, 0.0, 0.0),
                     correction=(0.0, 0.0, 0.0))  # fmt: skip
    closed.scans = [(k, pts - [0.1 * k, 0.0], (0.1 * k + 0.5, 0.0, 0.0)) for k in (1, 2, 3)]
    open_ = Stretch(3, 0.0, (0.0, 0.0, 0.0))  # not back: not in the patch
    open_.scans = [(3, pts + [3.0, 0.0], (0.3, 0.0, 0.0))]
    loc = SimpleNamespace(
        map=None, config=SimpleNamespace(scan=SimpleNamespace(mounting=(0.0, 0.0, 0.0)))
    )
    mon = SimpleNamespace(stretches=[closed, open_])
    g = ep.truth_patch(loc, mon, ref)
    assert g is not None and g.scans_used == 3
    rc = np.argwhere(g.occupied)
    x = g.origin[0] + (rc[:, 1] + 0.5) * g.resolution
    # the wall where it is (x = 2), not where the coasted poses put it (2.5), nor the open
    # stretch's (5)
    assert len(x) > 0 and np.all(np.abs(x - 2.0) <= g.resolution)

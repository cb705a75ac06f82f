"""A stretch the sudden rule began (``OutsideConfig.sudden_scans``: the scan jumped off the
map and stayed there) is a sharp map edge or a kidnapped robot its localizer did not
relocalize within 20 scans. One whose re-entry lock lies beyond its dead reckoning's
uncertainty (``jump_sigmas``, ``jump_min``) was the kidnap: the summary says so and a map
patch leaves it out (review: kidnaps coasted 20 scans off the map were counted as stretches
outside the map, their dead reckoning drawn into the patch)."""

from __future__ import annotations

import numpy as np
from icploc.localizer import Estimate, Localizer, Status
from icploc.mappatch import in_patch, patch_record
from icploc.outside import Stretch, stretch_lines
from partial_world import half_known_grid, sudden_exit_run


def _locked(sudden: bool, off: float, sigma: float = 0.1, distance: float = 0.0) -> Stretch:
    """A stretch re-entering (its dead reckoning at (1, 2, 0), coasted ``distance`` metres
    with sigma up to ``sigma``) through the monitor's lock: the localizer's recovery locks
    ``off`` metres east of the dead reckoning."""
    loc = Localizer(half_known_grid(), initial_pose=(1.0, 2.0, 0.0))
    mon = loc.outside
    st = Stretch(3, 0.3, (1.0, 2.0, 0.0), max_sigma_xy=sigma, sudden=sudden, outside_scans=3,
                 distance=distance)  # fmt: skip
    st.scans.append((3, np.zeros((30, 2)), (1.0, 2.0, 0.0)))
    mon.stretches.append(st)
    mon.state, mon._dr, mon._reentry_start = "reentering", (1.0, 2.0, 0.0), 5
    lock = Estimate(0.7, (1.0 + off, 2.0, 0.0), np.eye(3) * 1e-4, Status.TRACKING, 0.9, 5, 0.0,
                    reason="relocalized")  # fmt: skip
    mon.after(loc, lock, np.column_stack([np.full(30, -0.5), np.linspace(-1, 1, 30)]))
    assert mon.state == "inside" and st.closed
    return st


def test_a_sudden_stretch_locked_beyond_its_uncertainty_is_a_kidnap() -> None:
    st = _locked(sudden=True, off=4.0)  # 4 m: 40 sigma, beyond jump_min (2 m)
    assert (st.sudden, st.jumped, in_patch(st), in_patch(st, include_open=True)) == (
        True, True, False, False,
    )  # fmt: skip
    lines = stretch_lines([st], 10)
    assert "1 of them a kidnap rather than a drive off the map" in lines[0]
    assert "a robot carried elsewhere (a kidnap)" in lines[1]
    rec = patch_record([st])[0]
    assert (rec["in_patch"], rec["kidnap"]) == (False, True)


def test_a_sudden_stretch_locked_near_its_dead_reckoning_is_drawn() -> None:
    st = _locked(sudden=True, off=1.5)  # 15 sigma but within jump_min: dead reckoning's error
    assert (st.jumped, in_patch(st)) == (False, True)
    assert "began with a jump off the map (a sharp map edge, or a kidnap)" in stretch_lines([st], 10)[1]


def test_a_wide_coasted_sigma_raises_the_kidnap_floor() -> None:
    # 2.5 m is beyond jump_min (2 m) but within 3 sigma of a dead reckoning coasted with
    # sigma 1 m: its error, not a jump
    assert _locked(sudden=True, off=2.5, sigma=1.0).jumped is False
    assert _locked(sudden=True, off=3.5, sigma=1.0).jumped is True


def test_a_long_coast_raises_the_kidnap_floor() -> None:
    # a sharp map edge coasted 40 m (jump_per_m 0.1: a 4 m floor): a 3 m correction is
    # the dead reckoning's error; the same correction after 10 m of coasting is a jump
    assert _locked(sudden=True, off=3.0, distance=40.0).jumped is False
    assert _locked(sudden=True, off=3.0, distance=10.0).jumped is True


def test_a_gradual_exit_is_never_taken_for_a_kidnap() -> None:
    # the robot drove off the map (the share rose scan by scan): a long correction is its
    # dead reckoning's error, not a jump
    st = _locked(sudden=False, off=4.0)
    assert (st.jumped, in_patch(st)) == (False, True)
    assert "kidnap" not in " ".join(stretch_lines([st], 10))


def test_the_sudden_exit_at_the_wings_door_is_a_sudden_stretch_and_no_kidnap() -> None:
    from icploc.config import LocalizerConfig
    from icploc.localizer import run

    r, m, _ = sudden_exit_run(0)
    loc = Localizer(m, LocalizerConfig(), initial_pose=tuple(r.truth[0]))
    run(loc, r.items)
    first = loc.outside.stretches[0]
    assert (first.sudden, first.closed, first.jumped) == (True, True, False)

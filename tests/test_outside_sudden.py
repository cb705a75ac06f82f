"""The sudden exit (``OutsideConfig.rise_share``'s blind spot, tests/partial_world.py's
:func:`sudden_exit_run`): the scan jumps from nearly all on the map to mostly off it in one
scan at the wing's door. A stretch begins once the jump has stayed ``sudden_scans`` scans
while the localizer stayed on the odometry; with the rule off (``sudden_scans`` 0, main
before it) the localizer was on its own in the wing and tracked wrong poses."""

from __future__ import annotations

import numpy as np
import pytest
from partial_world import sudden_exit_run


def _localize(sudden_scans: int | None) -> tuple[np.ndarray, list, object, int]:
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer, run
    from icploc.outside import OutsideConfig, attach

    r, m, kept = sudden_exit_run(0)
    loc = Localizer(m, LocalizerConfig(), initial_pose=tuple(r.truth[0]))
    if sudden_scans is not None:
        attach(loc, OutsideConfig(sudden_scans=sudden_scans))
    ests = run(loc, r.items)
    p = np.array([e.pose for e in ests])
    err = np.hypot(p[:, 0] - r.truth[:, 0], p[:, 1] - r.truth[:, 1])
    jump = int(np.argmax(np.diff(np.asarray(kept)) > 1)) + 1  # the first scan after the gap
    return err, ests, loc.outside, jump


def _false_tracking(err: np.ndarray, ests: list) -> int:
    return sum(
        1 for e, x in zip(err, ests, strict=True) if x.status.value == "tracking" and e > 0.5
    )


def test_a_sudden_exit_begins_a_stretch_at_the_door_and_tracks_nothing_false() -> None:
    from icploc.outside import OutsideConfig

    err, ests, mon, jump = _localize(None)  # the default config's monitor
    assert mon is not None
    cfg = OutsideConfig()
    first = mon.stretches[0]  # type: ignore[attr-defined]
    # the stretch begins at the door, once the jump has stayed (not scans later in the wing)
    assert jump + cfg.sudden_scans - 1 <= first.start <= jump + cfg.sudden_scans + cfg.enter_scans
    assert err[first.start] < 0.3  # the dead reckoning from the door still holds there
    assert _false_tracking(err, ests) == 0


@pytest.mark.slow
def test_without_the_rule_the_sudden_exit_is_tracked_falsely() -> None:
    """The measurement the rule answers (main before it): no stretch at the door, and the
    localizer reports wrong poses in the wing as tracking (177 scans > 0.5 m off, seed 0)."""
    err, ests, mon, jump = _localize(0)
    assert mon is not None
    assert all(s.start > jump + 200 for s in mon.stretches)  # type: ignore[attr-defined]
    assert _false_tracking(err, ests) > 100


def test_a_pose_found_away_from_the_odometry_after_the_jump_begins_no_stretch() -> None:
    """A kidnapped robot's localizer relocalizes elsewhere: here its pose is moved 2 m (as a
    recovery would) a few scans after the jump; the jump then never begins a stretch while
    it lasts (scans that begin one at the door in the test above)."""
    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer
    from icploc.outside import OutsideConfig

    r, m, kept = sudden_exit_run(0)
    jump = int(np.argmax(np.diff(np.asarray(kept)) > 1)) + 1
    loc = Localizer(m, LocalizerConfig(), initial_pose=tuple(r.truth[0]))
    mon = loc.outside
    assert mon is not None
    for i in range(jump + 5):
        loc.update(r.items[2 * i + 1], r.items[2 * i])
    assert not mon.stretches and mon.last_share >= OutsideConfig().enter_share
    x, y, th = loc.pose
    loc.pose = (x, y + 2.0, th)  # found 2 m away from the odometry since the jump
    n = OutsideConfig().sudden_scans + 15
    for i in range(jump + 5, jump + 5 + n):
        loc.update(r.items[2 * i + 1], r.items[2 * i])
    assert not mon.stretches

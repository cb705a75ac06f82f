"""The scans that begin a stretch outside the map (``OutsideConfig.enter_scans``): those
before its first coasted scan are localized as usual, and recorded with the stretch all
the same (the map patch draws them; simulated building, tests/partial_world.py)."""

from __future__ import annotations

import math

from icploc.se2 import between
from partial_world import drive


def test_a_stretch_records_the_scans_of_the_streak_that_began_it() -> None:
    run, loc, _ = drive("outside", record=True)
    mon = loc.outside
    st = mon.stretches[0]
    n = mon.config.enter_scans - 1
    assert n >= 1  # the default takes more than one scan
    ks = [k for k, _, _ in st.scans]
    assert ks[: n + 2] == list(range(st.start - n, st.start + 2))
    assert st.start - n not in [k for k, _, _ in st.lead_in]
    # localized as usual, recorded at poses by odometry (calibrated: within millimetres)
    rec = [p for _, _, p in st.scans][: n + 2]
    odom = [run.items[2 * k].pose for k in ks[: n + 2]]
    dev = [
        math.dist(between(a, b)[:2], between(c, d)[:2])
        for a, b, c, d in zip(rec, rec[1:], odom, odom[1:], strict=False)
    ]
    assert max(dev) < 0.005

"""Unknown cells occlude in the visibility culling, as the grid's walls do."""

from __future__ import annotations

import numpy as np
from icploc.maps import Map


def corridor_behind_unknown() -> Map:
    occ = np.zeros((40, 40), dtype=bool)
    occ[5, 5:35] = True  # near wall, y 0.5 .. 0.6
    occ[30, 5:35] = True  # far wall, y 3.0 .. 3.1
    free = ~occ
    free[10:25, :] = False  # a band of unknown cells between them
    return Map.from_grid(occ, 0.1, free=free)


def test_points_behind_unknown_cells_are_hidden() -> None:
    m = corridor_behind_unknown()
    p, _ = m.sample(0.1)
    for exact in (False, True):
        idx = m.visible((2.0, 0.8, 0.0), spacing=0.1, exact=exact)
        assert len(idx) > 0
        assert (p[idx][:, 1] < 1.0).all(), exact  # nothing beyond the unknown band


def test_without_unknown_cells_the_far_wall_is_seen() -> None:
    occ = np.zeros((40, 40), dtype=bool)
    occ[5, 5:35] = True
    occ[30, 5:35] = True
    m = Map.from_grid(occ, 0.1)
    p, _ = m.sample(0.1)
    idx = m.visible((2.0, 0.8, 0.0), spacing=0.1, exact=True)
    assert (p[idx][:, 1] > 2.9).sum() > 10

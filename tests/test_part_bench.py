"""benches/eval_partial.py's ``icploc-crop`` map: the full map cropped to the partial map's
known cells (the same mapped area, the walls the whole log saw in it)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

BENCHES = Path(__file__).resolve().parent.parent / "benches"
sys.path.insert(0, str(BENCHES))

import eval_partial as ep  # noqa: E402
import real_grid as rg  # noqa: E402


def test_the_cropped_map_keeps_the_full_maps_cells_where_the_partial_map_knows_anything() -> None:
    # the full map: 6 x 4 cells, a wall along its top row, free below; the partial map:
    # 3 x 4 cells from x = 0.2 (its origin two cells right of the full map's), knowing
    # only its left two columns (one free, one occupied)
    occ = np.zeros((4, 6), dtype=bool)
    occ[3, :] = True
    full = rg.Grid(occupied=occ, free=~occ, resolution=0.1, origin=(0.0, 0.0))
    p_occ = np.zeros((4, 3), dtype=bool)
    p_free = np.zeros((4, 3), dtype=bool)
    p_free[:, 0] = True
    p_occ[:, 1] = True
    partial = rg.Grid(occupied=p_occ, free=p_free, resolution=0.1, origin=(0.2, 0.0))
    got = ep.cropped(full, partial)
    known = np.zeros((4, 6), dtype=bool)
    known[:, 2:4] = True  # the full map's columns 2 and 3 are the partial map's 0 and 1
    assert (got.origin, got.resolution) == (full.origin, full.resolution)
    assert np.array_equal(got.occupied, occ & known)  # the full map's walls, not the partial's
    assert np.array_equal(got.free, ~occ & known)
    assert not (got.occupied | got.free)[:, [0, 1, 4, 5]].any()

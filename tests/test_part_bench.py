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


def test_seeds_are_a_range_or_a_list_and_bad_ones_are_refused() -> None:
    import pytest

    assert ep.parse_seeds("0-3") == [0, 1, 2, 3]
    assert ep.parse_seeds("2,5") == [2, 5]
    assert ep.parse_seeds("7") == [7]
    for bad in ("x", "3-1", "1,1", "-1", "0-2-4", ""):
        with pytest.raises(ValueError, match="--seeds"):
            ep.parse_seeds(bad)


def test_the_seed_summary_averages_per_log_and_method_and_counts_against_the_full_map() -> None:
    def row(log: str, method: str, seed: int, med: float, p95: float) -> dict:
        return {"log": log, "method": method, "seed": seed, "scans": 10,
                "inside_median_m": med, "inside_p95_m": p95}  # fmt: skip

    rows = [
        row("aces", "icploc", 0, 0.04, 0.10), row("aces", "icploc-full", 0, 0.03, 0.08),
        row("aces", "icploc", 1, 0.02, 0.06), row("aces", "icploc-full", 1, 0.03, 0.09),
        {"log": "aces", "method": "icploc-crop", "seed": 0, "error": "failed"},
    ]  # fmt: skip
    got = {r["method"]: r for r in ep.seed_summary(rows)}
    assert set(got) == {"icploc", "icploc-full"}  # a failed run is no figure
    assert got["icploc"]["seeds"] == [0, 1]
    assert abs(got["icploc"]["inside_median_m"] - 0.03) < 1e-12
    assert abs(got["icploc"]["inside_p95_m"] - 0.08) < 1e-12
    assert got["icploc"]["median_le_full"] == [1, 2]  # seed 1 only
    assert got["icploc"]["p95_le_full"] == [1, 2]
    assert ep.seeds_md_row(got["icploc"]) == "| aces | icploc | 2 | 3.00 | 8.00 | 1 of 2 | 1 of 2 |"

"""The mapped area's grown mask (outside._dilate on rows packed 8 cells a byte) is the
square growth by definition: a cell is known when any cell within r of it (in x and in y)
is, nothing beyond the edges."""

from __future__ import annotations

import numpy as np
import pytest
from icploc.maps.map import Map
from icploc.outside import MappedArea, OutsideConfig, _dilate


def _square_grown(m: np.ndarray, r: int) -> np.ndarray:
    """The definition, cell by cell."""
    h, w = m.shape
    out = np.zeros_like(m)
    for y, x in zip(*np.nonzero(m), strict=True):
        out[max(y - r, 0) : min(y + r + 1, h), max(x - r, 0) : min(x + r + 1, w)] = True
    return out


@pytest.mark.parametrize("shape", [(37, 53), (5, 8), (1, 17), (40, 1), (9, 64), (3, 3)])
@pytest.mark.parametrize("grow", [0, 1, 3, 4, 7, 8, 9, 12, 17, 70])
def test_grown_mask_is_the_square_growth(shape: tuple[int, int], grow: int) -> None:
    rng = np.random.default_rng(shape[0] * 1000 + shape[1] * 10 + grow)
    m = rng.random(shape) < 0.4 / (2 * min(grow, 8) + 1) ** 2
    m[0, -1] = True  # a cell on the edge (the last bit of a packed row)
    got = _dilate(m, grow)
    want = _square_grown(m, grow)
    assert got.dtype == bool and got.shape == m.shape
    np.testing.assert_array_equal(got, want)


def test_an_empty_or_full_mask_stays_so() -> None:
    z = np.zeros((20, 30), dtype=bool)
    np.testing.assert_array_equal(_dilate(z, 4), z)
    o = np.ones((20, 30), dtype=bool)
    np.testing.assert_array_equal(_dilate(o, 4), o)


def test_a_grid_map_area_is_its_known_cells_grown_by_the_margin() -> None:
    rng = np.random.default_rng(3)
    occ = rng.random((61, 203)) < 0.002
    free = np.zeros_like(occ)
    free[10:50, 20:150] = True
    occ[30, 202] = True
    occ[:, :20] = False
    m = Map.from_grid(occ, 0.05, (1.0, -2.0, 0.0), free=free, fit=False)
    area = MappedArea.of(m, None, OutsideConfig())  # margin 0.2 m: 4 cells
    np.testing.assert_array_equal(area.known, _square_grown(occ | free, 4))
    # the free block starts at column 20 (no wall left of it): column 16 (4 cells off) is
    # known, column 15 is not; row 30's cell centres
    assert not occ[:, :20].any()
    y = -2.0 + 30.5 * 0.05
    xy = np.array([[1.0 + 16.5 * 0.05, y], [1.0 + 15.5 * 0.05, y]])
    np.testing.assert_array_equal(area.unmapped(xy), [False, True])


def test_a_point_map_area_is_the_points_grown_by_reach() -> None:
    pts = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 3.0]])

    class Index:
        points = pts

    area = MappedArea.of(object(), Index(), OutsideConfig())
    xy = np.array([[0.0, 0.9], [0.0, 1.3], [2.5, 0.0], [5.0, 3.9]])
    np.testing.assert_array_equal(area.unmapped(xy), [False, True, True, False])


def test_a_grid_whose_free_cells_do_not_match_is_refused() -> None:
    class Bad:
        grid = np.zeros((4, 5), dtype=bool)
        free = np.zeros((5, 4), dtype=bool)
        resolution = 0.05
        origin = (0.0, 0.0, 0.0)

    with pytest.raises(ValueError, match="differ"):
        MappedArea.of(Bad(), None, OutsideConfig())

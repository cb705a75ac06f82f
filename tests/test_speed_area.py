"""The mapped area grown tile by tile on first use (outside.MappedArea) is the mask grown
at once: the same unmapped answer for every point, whichever tiles were grown first."""

from __future__ import annotations

import math

import numpy as np
import pytest
from icploc.maps.map import Map
from icploc.outside import MappedArea, OutsideConfig, _dilate


def _whole(layers: tuple[np.ndarray, ...], r: int) -> np.ndarray:
    m = layers[0].copy()
    for a in layers[1:]:
        m |= a
    return _dilate(m, r)


def _square_grown(m: np.ndarray, r: int) -> np.ndarray:
    """The definition: a cell is known when any cell within r (Chebyshev) is."""
    h, w = m.shape
    out = np.zeros_like(m)
    for y, x in zip(*np.nonzero(m), strict=True):
        out[max(y - r, 0) : min(y + r + 1, h), max(x - r, 0) : min(x + r + 1, w)] = True
    return out


@pytest.mark.parametrize("tile", [1, 3, 7, 16, 256])
@pytest.mark.parametrize("grow", [0, 1, 4, 5])
def test_tiles_grow_as_the_whole_mask(tile: int, grow: int) -> None:
    rng = np.random.default_rng(tile * 10 + grow)
    a = rng.random((37, 53)) < 0.4 / (2 * grow + 1) ** 2
    b = rng.random((37, 53)) < 0.2 / (2 * grow + 1) ** 2
    want = _whole((a, b), grow)
    np.testing.assert_array_equal(want, _square_grown(a | b, grow))
    area = MappedArea((a, b), 0.1, (-1.0, 2.0), 0.3, grow=grow, tile=tile)
    # queried point by point in a random order first: tiles grown piecemeal
    pts = rng.uniform([-3.0, -1.0], [8.0, 9.0], size=(400, 2))
    c, s = math.cos(0.3), math.sin(0.3)
    q = pts - np.array([-1.0, 2.0])
    q = np.column_stack([c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]])
    cell = np.floor(q / 0.1).astype(np.int64)
    inside = (cell[:, 0] >= 0) & (cell[:, 0] < 53) & (cell[:, 1] >= 0) & (cell[:, 1] < 37)
    expect = np.ones(len(pts), dtype=bool)
    expect[inside] = ~want[cell[inside, 1], cell[inside, 0]]
    got = np.concatenate([area.unmapped(pts[i : i + 7]) for i in range(0, len(pts), 7)])
    np.testing.assert_array_equal(got, expect)
    assert inside.any() and (~expect).any() and expect[inside].any()
    np.testing.assert_array_equal(area.known, want)
    np.testing.assert_array_equal(area.unmapped(pts), expect)


def test_a_grid_map_area_grows_only_where_asked() -> None:
    occ = np.zeros((600, 700), dtype=bool)
    free = np.zeros_like(occ)
    occ[100:500, 100] = True
    free[100:500, 101:650] = True
    m = Map.from_grid(occ, 0.05, (0.0, 0.0, 0.0), free=free, fit=False)
    cfg = OutsideConfig()
    area = MappedArea.of(m, None, cfg)
    assert area.grow == 4 and area.shape == (600, 700)
    assert not area._done.any()
    # a wall cell's grown margin (0.2 m) is known, 0.25 m beyond it is not
    xy = np.array([[100 * 0.05 - 0.15, 10.0], [100 * 0.05 - 0.25, 10.0], [20.0, 10.0]])
    np.testing.assert_array_equal(area.unmapped(xy), [False, True, False])
    assert 0 < int(area._done.sum()) < area._done.size
    np.testing.assert_array_equal(area.known, _dilate(occ | free, 4))
    assert area._done.all()


def test_a_point_map_area_is_the_points_grown_by_reach() -> None:
    pts = np.array([[0.0, 0.0], [5.0, 0.0], [5.0, 3.0]])

    class Index:
        points = pts

    area = MappedArea.of(object(), Index(), OutsideConfig())
    xy = np.array([[0.0, 0.9], [0.0, 1.3], [2.5, 0.0], [5.0, 3.9]])
    np.testing.assert_array_equal(area.unmapped(xy), [False, True, True, False])


def test_bad_masks_are_refused() -> None:
    with pytest.raises(ValueError, match="one shape"):
        MappedArea((np.zeros((3, 4), bool), np.zeros((4, 3), bool)), 0.1, (0.0, 0.0))
    with pytest.raises(ValueError, match="grow"):
        MappedArea(np.zeros((3, 4), bool), 0.1, (0.0, 0.0), grow=-1)

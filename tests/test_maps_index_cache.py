"""The closest-point grid of a cached map's index is kept beside the cache entry and read
back: the same index without computing the grid again; a file that does not fit is never used."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from icploc._core import InvalidInputError, MapIndex, grid_runs, index_from_grid_runs
from icploc.maps import Map, cache

WALLS = np.array(
    [[0.0, 0.0, 6.0, 0.0], [6.0, 0.0, 6.0, 4.0], [6.0, 4.0, 0.0, 4.0], [2.0, 1.0, 2.0, 3.0]]
)


@pytest.fixture
def yaml_map(tmp_path: Path, map_cache_dir: Path) -> Path:
    return Map.from_lines(WALLS).to_ros(tmp_path / "m.yaml", 0.05)


def index_files(tmp_path: Path) -> list[Path]:
    return sorted((tmp_path / "xdg" / "icploc" / "maps").glob("*.index-*.npz"))


def runs_of(idx: MapIndex) -> tuple[np.ndarray, np.ndarray, float]:
    got = grid_runs(idx)
    assert got is not None
    return got


def test_the_second_load_reads_the_grid_and_answers_the_same(
    yaml_map: Path, tmp_path: Path
) -> None:
    first = Map.load(yaml_map).index(0.05)
    assert len(index_files(tmp_path)) == 1
    m = Map.load(yaml_map)
    p, n = m.sample(0.05)
    again = cache.load_index(m, 0.05, p, n)
    assert again is not None
    v1, l1, r1 = runs_of(first)
    v2, l2, r2 = runs_of(again)
    np.testing.assert_array_equal(v2, v1)
    np.testing.assert_array_equal(l2, l1)
    assert r2 == r1
    q = np.random.default_rng(3).uniform(-1.0, 7.0, (500, 2))
    np.testing.assert_array_equal(again.nearest(q)[1], first.nearest(q)[1])


def test_an_uncached_map_writes_no_grid(yaml_map: Path, tmp_path: Path) -> None:
    Map.load(yaml_map, cache=False).index(0.05)
    assert index_files(tmp_path) == []


def test_a_grid_for_other_points_is_not_used(yaml_map: Path, tmp_path: Path) -> None:
    Map.load(yaml_map).index(0.05)
    m = Map.load(yaml_map)
    p, n = m.sample(0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert cache.load_index(m, 0.05, p[1:], n[1:]) is None


def test_a_corrupt_grid_file_warns_once_and_the_index_is_built(
    yaml_map: Path, tmp_path: Path
) -> None:
    fresh = Map.load(yaml_map).index(0.05)
    (f,) = index_files(tmp_path)
    f.write_bytes(f.read_bytes()[:200])
    with pytest.warns(RuntimeWarning, match="unreadable index file"):
        idx = Map.load(yaml_map).index(0.05)
    np.testing.assert_array_equal(runs_of(idx)[0], runs_of(fresh)[0])


def test_runs_that_do_not_fit_the_points_are_refused() -> None:
    pts = np.column_stack([np.linspace(0.0, 3.0, 61), np.zeros(61)])
    values, lengths, res = runs_of(MapIndex(pts))
    short = lengths.copy()
    short[-1] -= 1
    with pytest.raises(InvalidInputError, match="cells given"):
        index_from_grid_runs(pts, None, res, values, short)
    bad = values.copy()
    bad[0] = len(pts)
    with pytest.raises(InvalidInputError, match="names point"):
        index_from_grid_runs(pts, None, res, bad, lengths)

"""The likelihood field of the global search over a cached map's index is kept beside the
cache entry and read back: the same GlobalLocalizer without its nearest-point queries; a
file for other points is never used."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from icploc._core import GlobalLocalizer, InvalidInputError, MapIndex
from icploc.maps import Map
from icploc.relocalize import global_localizer

WALLS = np.array(
    [[0.0, 0.0, 6.0, 0.0], [6.0, 0.0, 6.0, 4.0], [6.0, 4.0, 0.0, 4.0], [2.0, 1.0, 2.0, 3.0]]
)
SCAN = np.array([[np.cos(a) * r, np.sin(a) * r] for a, r in zip(
    np.linspace(-1.5, 1.5, 60), np.linspace(1.0, 2.0, 60), strict=True)])  # fmt: skip


@pytest.fixture
def yaml_map(tmp_path: Path, map_cache_dir: Path) -> Path:
    return Map.from_lines(WALLS).to_ros(tmp_path / "m.yaml", 0.05)


def field_files(tmp_path: Path) -> list[Path]:
    return sorted((tmp_path / "xdg" / "icploc" / "maps").glob("*.field-*.npz"))


def test_a_localizer_from_its_distances_searches_the_same() -> None:
    idx = Map.from_lines(WALLS).index(0.05)
    a = GlobalLocalizer(idx, 0.05)
    b = GlobalLocalizer(idx, 0.05, distances=a.distances())
    ra, rb = a.search(SCAN), b.search(SCAN)
    assert [c.to_dict() for c in rb.candidates] == [c.to_dict() for c in ra.candidates]


def test_distances_for_another_grid_are_refused() -> None:
    idx = Map.from_lines(WALLS).index(0.05)
    d = GlobalLocalizer(idx, 0.05).distances()
    with pytest.raises(InvalidInputError, match="distances: .* values for a"):
        GlobalLocalizer(idx, 0.1, distances=d)


def test_the_second_build_reads_the_field_and_searches_the_same(
    yaml_map: Path, tmp_path: Path
) -> None:
    first = global_localizer(Map.load(yaml_map).index(0.05), 0.05)
    assert len(field_files(tmp_path)) == 1
    f = field_files(tmp_path)[0]
    stamp = f.stat().st_mtime_ns
    again = global_localizer(Map.load(yaml_map).index(0.05), 0.05)
    assert f.stat().st_mtime_ns == stamp  # read, not rewritten
    np.testing.assert_array_equal(again.distances(), first.distances())
    r1, r2 = first.search(SCAN), again.search(SCAN)
    assert [c.to_dict() for c in r2.candidates] == [c.to_dict() for c in r1.candidates]


def test_an_uncached_map_writes_no_field(yaml_map: Path, tmp_path: Path) -> None:
    global_localizer(Map.load(yaml_map, cache=False).index(0.05), 0.05)
    assert field_files(tmp_path) == []


def test_a_field_for_other_points_is_not_used(yaml_map: Path, tmp_path: Path) -> None:
    global_localizer(Map.load(yaml_map).index(0.05), 0.05)
    f = field_files(tmp_path)[0]
    with np.load(f) as z:
        bad = {"distances": np.zeros_like(z["distances"]), "digest": np.zeros(20, np.uint8)}
    np.savez(f, **bad)
    m = Map.load(yaml_map)
    got = global_localizer(m.index(0.05), 0.05)
    want = GlobalLocalizer(MapIndex(*m.sample(0.05)), 0.05)
    np.testing.assert_array_equal(got.distances(), want.distances())


def test_a_corrupt_field_file_warns_and_is_computed(yaml_map: Path, tmp_path: Path) -> None:
    first = global_localizer(Map.load(yaml_map).index(0.05), 0.05)
    field_files(tmp_path)[0].write_bytes(b"not a zip")
    with pytest.warns(RuntimeWarning, match="ignoring unreadable likelihood field file"):
        again = global_localizer(Map.load(yaml_map).index(0.05), 0.05)
    np.testing.assert_array_equal(again.distances(), first.distances())

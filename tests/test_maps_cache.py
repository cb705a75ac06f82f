"""The cache of prepared maps: keyed by content, in the XDG cache directory, never fatal."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from icploc.maps import Map, cache

WALLS = np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0], [4.0, 3.0, 0.0, 3.0]])


@pytest.fixture
def yaml_map(tmp_path: Path, map_cache_dir: Path) -> Path:
    return Map.from_lines(WALLS).to_ros(tmp_path / "m.yaml", 0.05)


def entries(tmp_path: Path) -> list[Path]:
    return sorted((tmp_path / "xdg" / "icploc" / "maps").glob("*.npz"))


def test_cache_dir_follows_xdg_cache_home(yaml_map: Path, tmp_path: Path) -> None:
    assert cache.cache_dir() == tmp_path / "xdg" / "icploc" / "maps"


def test_second_load_reads_the_cache_and_gives_the_same_map(yaml_map: Path, tmp_path: Path) -> None:
    first = Map.load(yaml_map)
    assert "cache" not in first.meta
    assert len(entries(tmp_path)) == 1
    second = Map.load(yaml_map)
    assert second.meta["cache"] == str(entries(tmp_path)[0])
    np.testing.assert_array_equal(second.lines, first.lines)
    np.testing.assert_array_equal(second.extra_points, first.extra_points)
    assert second.grid is not None and first.grid is not None
    np.testing.assert_array_equal(second.grid, first.grid)
    assert second.source == str(yaml_map)


def test_settings_and_image_bytes_are_part_of_the_key(yaml_map: Path, tmp_path: Path) -> None:
    Map.load(yaml_map)
    Map.load(yaml_map, min_length=0.5)
    assert len(entries(tmp_path)) == 2
    pgm = yaml_map.with_suffix(".pgm")
    data = bytearray(pgm.read_bytes())
    data[-1] = 0  # one more occupied pixel
    pgm.write_bytes(bytes(data))
    m = Map.load(yaml_map)
    assert "cache" not in m.meta
    assert len(entries(tmp_path)) == 3


def test_no_cache_neither_reads_nor_writes(yaml_map: Path, tmp_path: Path) -> None:
    m = Map.load(yaml_map, cache=False)
    assert "cache" not in m.meta
    assert entries(tmp_path) == []


def test_corrupt_entry_warns_once_and_loads(yaml_map: Path, tmp_path: Path) -> None:
    good = Map.load(yaml_map)
    entries(tmp_path)[0].write_bytes(b"not a zip file")
    with pytest.warns(RuntimeWarning, match="map cache"):
        m = Map.load(yaml_map)
    np.testing.assert_array_equal(m.lines, good.lines)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Map.load(yaml_map)  # warned once per process: no second warning


def test_unwritable_cache_warns_and_loads(yaml_map: Path, tmp_path: Path) -> None:
    (tmp_path / "xdg").write_text("a file where the cache directory should be")
    with pytest.warns(RuntimeWarning, match="cannot write"):
        m = Map.load(yaml_map)
    assert len(m.lines) > 0


def test_cli_no_cache_flag(yaml_map: Path, tmp_path: Path) -> None:
    from icploc.maps.cli import map_app
    from typer.testing import CliRunner

    r = CliRunner().invoke(map_app, ["info", str(yaml_map), "--no-cache"])
    assert r.exit_code == 0, r.output
    assert entries(tmp_path) == []


def test_replay_no_cache_flag_leaves_the_cache_empty(yaml_map: Path, tmp_path: Path) -> None:
    from icploc.cli import app
    from icploc.logs import write_carmen
    from icploc.messages import Scan
    from typer.testing import CliRunner

    angles = np.linspace(-np.pi / 2, np.pi / 2, 181)
    scans = [Scan(stamp=0.1 * k, ranges=np.full(181, 1.5), angles=angles) for k in range(3)]
    log = tmp_path / "r.log"
    write_carmen(log, scans, [])
    r = CliRunner().invoke(
        app,
        ["replay", str(log), "--map", str(yaml_map), "--initial-pose", "0,0,0", "--no-cache",
         "--max-lost", "1"],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert entries(tmp_path) == []

"""The map-format registry (icploc.maps.formats): Map.load picks by suffix from it, a new
format is one register() call, map convert saves through it."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from icploc.maps import FORMATS, Map, MapError, MapFormat, format_for, register


@pytest.fixture
def restore_formats() -> Iterator[None]:
    saved = dict(FORMATS)
    yield
    FORMATS.clear()
    FORMATS.update(saved)


@pytest.mark.parametrize(
    ("name", "fmt"),
    [("a.yaml", "ros"), ("a.YML", "ros"), ("a.geojson", "geojson"), ("a.json", "geojson"),
     ("a.dxf", "dxf"), ("a.npy", "points"), ("a.csv", "points"), ("a.txt", "points"),
     ("a.npz", "prepared")],
)  # fmt: skip
def test_builtin_suffixes(name: str, fmt: str) -> None:
    assert format_for(name).name == fmt


def test_unknown_suffix_names_the_file() -> None:
    with pytest.raises(MapError, match=r"a\.pcd: unknown map format '\.pcd'"):
        Map.load("a.pcd")


def test_a_registered_format_is_loaded_by_map_load(tmp_path: Path, restore_formats: None) -> None:
    def load(path: Path, cache: bool | None, options: dict) -> Map:
        rows = np.loadtxt(path, ndmin=2)
        return Map(rows, source=str(path), meta={"format": "segs"})

    register(MapFormat("segs", (".segs",), load))
    p = tmp_path / "room.segs"
    p.write_text("0 0 4 0\n4 0 4 3\n")
    m = Map.load(p)
    assert (m.meta["format"], len(m.lines)) == ("segs", 2)


def test_a_suffix_belongs_to_one_format(restore_formats: None) -> None:
    with pytest.raises(ValueError, match="suffix '.csv' is 'points'"):
        register(MapFormat("table", (".CSV",), FORMATS["points"].load))


def test_read_only_formats_are_refused_for_writing() -> None:
    with pytest.raises(MapError, match="unknown writable map format '.dxf'"):
        format_for("out.dxf", writing=True)


def test_convert_writes_a_prepared_map(tmp_path: Path) -> None:
    from icploc.maps.cli import map_app
    from typer.testing import CliRunner

    src = tmp_path / "w.geojson"
    Map(np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0]])).to_geojson(src)
    out = tmp_path / "w.npz"
    r = CliRunner().invoke(map_app, ["convert", str(src), "--out", str(out)])
    assert r.exit_code == 0, r.output
    assert len(Map.load(out).lines) == 2

"""``icploc map merge`` (icploc.maps.merge): a map patch into a map_server map."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from icploc.maps.cli import map_app
from icploc.maps.errors import MapError
from icploc.maps.merge import merge_files, merge_grids
from icploc.maps.ros import load_ros, save_ros
from icploc.outputs import OutputClashError
from typer.testing import CliRunner

runner = CliRunner()


def _grids() -> tuple[tuple, tuple]:
    # the map: 10 x 10 cells at 0.1 m from (0, 0); its left half known (free, a wall in
    # column 0), the right half unknown. The patch: 10 x 10 cells from (0.5, 0.5): all
    # free but a wall in its column 4 (x = 0.95) and its column 0 (inside the map's
    # known half: the map wins there)
    mo, mf = np.zeros((10, 10), bool), np.zeros((10, 10), bool)
    mo[:, 0] = True
    mf[:, 1:5] = True
    po, pf = np.zeros((10, 10), bool), np.ones((10, 10), bool)
    po[:, 4] = True
    po[:, 0] = False
    pf[:, 4] = False
    return (mo, mf, (0.0, 0.0, 0.0)), (po, pf, (0.5, 0.5, 0.0))


def test_merge_covers_map_and_patch() -> None:
    (mo, mf, morg), (po, pf, porg) = _grids()
    r = merge_grids(mo, mf, morg, po, pf, porg, 0.1)
    assert [r.occupied.shape, r.origin] == [(15, 15), (0.0, 0.0, 0.0)]


def test_merge_fills_what_the_map_does_not_know_from_the_patch() -> None:
    (mo, mf, morg), (po, pf, porg) = _grids()
    r = merge_grids(mo, mf, morg, po, pf, porg, 0.1)
    # the patch's wall at x = 0.95 (merged column 9), rows 5..14
    assert r.occupied[5:15, 9].all() and not r.occupied[0:5, 9].any()


def test_merge_keeps_the_map_where_it_knows() -> None:
    (mo, mf, morg), (po, pf, porg) = _grids()
    mf2 = mf.copy()
    mf2[:, 5] = True  # the map knows column 5 is free; the patch's column 0 lies there
    po2 = po.copy()
    po2[:, 0] = True
    pf2 = pf.copy()
    pf2[:, 0] = False
    r = merge_grids(mo, mf2, morg, po2, pf2, porg, 0.1)
    assert [bool(r.occupied[5:10, 5].any()), bool(r.free[5:10, 5].all())] == [False, True]


def test_merge_counts_the_cells_the_patch_added() -> None:
    (mo, mf, morg), (po, pf, porg) = _grids()
    r = merge_grids(mo, mf, morg, po, pf, porg, 0.1)
    assert r.added_occupied == 10


def _write(tmp: Path) -> tuple[Path, Path]:
    (mo, mf, morg), (po, pf, porg) = _grids()
    save_ros(tmp / "map.yaml", mo, 0.1, morg, free=mf, surface_offset=0.5)
    save_ros(tmp / "patch.yaml", po, 0.1, porg, free=pf, surface_offset=0.5)
    return tmp / "map.yaml", tmp / "patch.yaml"


def test_merge_files_writes_a_map_server_map_the_loader_reads(tmp_path: Path) -> None:
    m, p = _write(tmp_path)
    merge_files(m, p, tmp_path / "merged.yaml")
    g = load_ros(tmp_path / "merged.yaml")
    assert [g.occupied.shape, int(g.occupied.sum())] == [(15, 15), 20]


def test_merge_refuses_to_overwrite_the_map_and_leaves_it_alone(tmp_path: Path) -> None:
    m, p = _write(tmp_path)
    before = (tmp_path / "map.pgm").read_bytes()
    with pytest.raises(OutputClashError, match="map"):
        merge_files(m, p, tmp_path / "map.yaml")
    assert (tmp_path / "map.pgm").read_bytes() == before


def test_merge_refuses_an_output_image_that_is_the_patch_image(tmp_path: Path) -> None:
    m, p = _write(tmp_path)
    with pytest.raises(OutputClashError, match="image"):
        merge_files(m, p, tmp_path / "patch.yml")


def test_merge_refuses_a_patch_of_another_resolution(tmp_path: Path) -> None:
    m, _ = _write(tmp_path)
    save_ros(tmp_path / "coarse.yaml", np.zeros((4, 4), bool), 0.2, (0.0, 0.0, 0.0))
    with pytest.raises(MapError, match="resolution"):
        merge_files(m, tmp_path / "coarse.yaml", tmp_path / "out.yaml")


def test_cli_map_merge_writes_and_says_what_was_added(tmp_path: Path) -> None:
    m, p = _write(tmp_path)
    r = runner.invoke(map_app, ["merge", str(m), str(p), "--out", str(tmp_path / "out.yaml")])
    assert [r.exit_code, "added 10 occupied" in r.output] == [0, True]


def test_cli_map_merge_names_a_missing_patch(tmp_path: Path) -> None:
    m, _ = _write(tmp_path)
    r = runner.invoke(
        map_app, ["merge", str(m), str(tmp_path / "nope.yaml"), "--out", str(tmp_path / "o.yaml")]
    )
    assert [r.exit_code, "nope.yaml" in r.output] == [1, True]

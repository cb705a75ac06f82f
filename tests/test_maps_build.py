"""Maps built from logs: ray-cast free space, hits for walls, a map_server map out."""

from __future__ import annotations

import math
from pathlib import Path
from types import SimpleNamespace

import maps_clinic as clinic
import numpy as np
import pytest
import yaml
from icploc import raycast
from icploc.maps import Map, MapError
from icploc.maps.build import build_grid, build_map
from icploc.messages import Scan

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


@pytest.fixture(scope="module")
def clinic_log() -> SimpleNamespace:
    rng = np.random.default_rng(5)
    angles = np.linspace(-math.pi / 2, math.pi / 2, 361)
    scans, poses = [], []
    for x in np.arange(1.5, 27.0, 0.5):
        for y, th in ((5.9, 0.0), (5.9, math.pi), (2.5, math.pi / 2), (9.0, -math.pi / 2)):
            if clinic.inside_any(np.array([x]), np.array([y]))[0]:
                continue
            p = (x, y + rng.normal(0, 0.05), th)
            r = raycast(clinic.exact_faces(), p, angles, 20.0)
            scans.append(Scan(stamp=float(len(scans)), ranges=r, angles=angles, max_range=20.0))
            poses.append(p)
    return SimpleNamespace(scans=scans, truth_poses=np.array(poses))


def test_walls_are_hits_and_rooms_are_ray_cast_free(clinic_log: SimpleNamespace) -> None:
    g = build_grid(clinic_log, resolution=0.05)
    assert g.scans_used == len(clinic_log.scans)
    h, w = g.occupied.shape
    yy, xx = np.mgrid[:h, :w]
    cx = g.origin[0] + (xx + 0.5) * g.resolution
    cy = g.origin[1] + (yy + 0.5) * g.resolution
    solid = clinic.inside_any(cx, cy)
    # every occupied cell touches a wall (a hit lies in the cell of the surface it hit)
    near_wall = solid.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near_wall |= np.roll(np.roll(solid, dy, axis=0), dx, axis=1)
    assert near_wall[g.occupied].all()
    # the corridor between the pillars is free; the inside of the 0.2 m outer wall is not
    corridor = (cy > 5.3) & (cy < 5.7) & (cx > 2.0) & (cx < 27.0)
    assert g.free[corridor].mean() > 0.99
    inner_wall = (cy > 0.55) & (cy < 0.65) & (cx > 2.0) & (cx < 27.0)
    assert not g.free[inner_wall].any()


def test_built_map_round_trips_as_map_server_yaml(clinic_log: SimpleNamespace, tmp_path: Path) -> None:
    out = tmp_path / "built.yaml"
    m = build_map(clinic_log, out, resolution=0.05)
    doc = yaml.safe_load(out.read_text())
    assert doc["image"] == "built.pgm" and doc["mode"] == "trinary"
    assert doc["icploc_surface_offset"] == 0.5
    assert m.meta["fit"]["surface_offset"] == 0.5
    assert len(m.lines) > 50
    # the south corridor wall's face (y = 5.0) comes back within half a cell (+ 5 mm)
    face = np.isclose(m.lines[:, 1], 5.0, atol=0.03) & np.isclose(m.lines[:, 3], 5.0, atol=0.03)
    assert np.hypot(*(m.lines[face, 2:] - m.lines[face, :2]).T).sum() > 10.0


def test_bad_settings_are_map_errors(clinic_log: SimpleNamespace) -> None:
    with pytest.raises(MapError, match="field 'min_hits'"):
        build_grid(clinic_log, min_hits=0)
    with pytest.raises(MapError, match="field 'resolution'"):
        build_grid(clinic_log, resolution=-1.0)
    with pytest.raises(MapError, match="field 'poses'"):
        build_grid(clinic_log, poses=np.zeros((3, 3)))


@pytest.mark.shared_data
@pytest.mark.slow
@pytest.mark.skipif(
    not (DATA / "radish_corrected_logs" / "intel-corrected.log.gz").is_file(),
    reason="../shared/data is absent",
)
def test_cli_builds_a_map_from_a_corrected_log(tmp_path: Path) -> None:
    from icploc.maps.cli import map_app
    from typer.testing import CliRunner

    out = tmp_path / "intel.yaml"
    log = DATA / "radish_corrected_logs" / "intel-corrected.log.gz"
    r = CliRunner().invoke(map_app, ["build", str(log), "--out", str(out), "--resolution", "0.1"])
    assert r.exit_code == 0, r.output
    m = Map.load(out, cache=False)
    assert m.resolution == 0.1
    assert m.grid is not None and m.grid.sum() > 1000
    assert len(m.lines) > 100

"""``icploc replay``'s outside-the-map state is on by default: its estimates CSV has
``mapped`` = 0 rows (reason ``outside_map``, never ``tracking``) where the robot drives off
the map; ``--no-partial-map`` (or config ``outside.enabled: false``) turns it off,
``--partial-map`` back on over such a config.

The log: scans 1700-2299 of the simulated building whose map lacks a wing
(tests/partial_world.py, seed 24): the hall, the door at scan ~1890, the corridor and the
wing's room."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from icploc.cli import app
from icploc.logs import write_carmen
from icploc.maps.ros import save_ros
from partial_world import partial_run
from typer.testing import CliRunner

runner = CliRunner()
FIRST, LAST = 1700, 2300


@pytest.fixture(scope="module")
def wing_log(tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp("wingcli")
    r, m = partial_run(24)
    odoms = r.items[0::2][FIRST:LAST]
    scans = r.scans[FIRST:LAST]
    log = d / "wing.log"
    write_carmen(log, scans, odoms, scan_odometry=[o.pose for o in odoms])
    mp = d / "hall.yaml"
    save_ros(mp, m.grid, float(m.resolution), tuple(m.origin), free=m.free, surface_offset=0.5)
    pose = ",".join(f"{v:.6f}" for v in r.truth[FIRST])
    return {"log": log, "map": mp, "pose": pose, "truth": r.truth[FIRST:LAST], "dir": d}


def _replay(wing_log: dict, csv_path: Path, *extra: str) -> list[dict[str, str]]:
    res = runner.invoke(
        app,
        ["replay", str(wing_log["log"]), "--map", str(wing_log["map"]), "--no-progress",
         "--initial-pose", wing_log["pose"], "--estimates", str(csv_path), *extra],
    )  # fmt: skip
    assert res.exit_code == 0, res.output  # the run is never lost for long in this stretch
    return list(csv.DictReader(csv_path.read_text().splitlines()))


def test_the_default_replay_writes_mapped_0_rows_where_the_robot_left_the_map(
    wing_log: dict, tmp_path: Path
) -> None:
    rows = _replay(wing_log, tmp_path / "e.csv")
    assert len(rows) == LAST - FIRST
    off = [r for r in rows if r["mapped"] == "0"]
    deep = wing_log["truth"][:, 0] > 20.5  # the wing's room
    assert [len(off) > 100, all(rows[i]["mapped"] == "0" for i in np.flatnonzero(deep))] == [True, True]
    assert {(r["status"], r["reason"]) for r in off} <= {("degraded", "outside_map"), ("lost", "outside_map")}


def test_no_partial_map_turns_the_outside_state_off(wing_log: dict, tmp_path: Path) -> None:
    rows = _replay(wing_log, tmp_path / "e.csv", "--no-partial-map")
    assert len(rows) == LAST - FIRST
    assert {r["mapped"] for r in rows} == {"1"}
    assert "outside_map" not in {r["reason"] for r in rows}


def test_partial_map_turns_it_on_over_a_config_that_disables_it(
    wing_log: dict, tmp_path: Path
) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("outside:\n  enabled: false\n")
    off = _replay(wing_log, tmp_path / "off.csv", "--config", str(cfg))
    on = _replay(wing_log, tmp_path / "on.csv", "--config", str(cfg), "--partial-map")
    assert [{r["mapped"] for r in off}, "0" in {r["mapped"] for r in on}] == [{"1"}, True]


def test_no_partial_map_with_a_map_patch_is_a_usage_error(wing_log: dict, tmp_path: Path) -> None:
    res = runner.invoke(
        app,
        ["replay", str(wing_log["log"]), "--map", str(wing_log["map"]), "--no-progress",
         "--no-partial-map", "--map-patch", str(tmp_path / "p.yaml")],
    )  # fmt: skip
    assert res.exit_code == 2
    assert "--no-partial-map" in res.output


@pytest.mark.parametrize(
    ("kw", "named"),
    [
        ({"partial_map": False, "map_patch": "p.yaml"}, "partial_map=False"),
        ({"map_patch_open": True}, "map_patch_open needs map_patch"),
        ({"map_patch_confident_only": True}, "map_patch_confident_only needs map_patch"),
    ],
)
def test_the_api_refuses_what_the_cli_refuses_before_any_work(
    tmp_path: Path, kw: dict, named: str
) -> None:
    from icploc.replay import replay

    kw = {k: tmp_path / v if k == "map_patch" else v for k, v in kw.items()}
    # neither the log nor the map exists: the refusal comes first
    with pytest.raises(ValueError, match=named):
        replay(tmp_path / "none.log", tmp_path / "none.yaml", **kw)
    assert list(tmp_path.iterdir()) == []


def test_map_patch_open_without_a_map_patch_is_a_usage_error(wing_log: dict) -> None:
    res = runner.invoke(
        app,
        ["replay", str(wing_log["log"]), "--map", str(wing_log["map"]), "--no-progress",
         "--map-patch-open"],
    )  # fmt: skip
    assert res.exit_code == 2
    assert "--map-patch-open" in res.output

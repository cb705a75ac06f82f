"""The command line: config, replay, run argument checks."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from icploc import worlds
from icploc.cli import app
from icploc.config import LocalizerConfig
from icploc.live import tum_row
from icploc.logs import write_carmen
from icploc.maps import Map
from typer.testing import CliRunner

runner = CliRunner()


def test_config_defaults_prints_yaml() -> None:
    r = runner.invoke(app, ["config", "defaults"])
    assert r.exit_code == 0, r.output
    assert yaml.safe_load(r.output) == LocalizerConfig().to_dict()


def test_config_check_reports_unknown_keys(tmp_path: Path) -> None:
    p = tmp_path / "c.yaml"
    p.write_text("gating:\n  max_jump: 3\n")
    r = runner.invoke(app, ["config", "check", str(p)])
    assert r.exit_code == 2
    assert "unknown key 'max_jump'" in r.output
    p.write_text("gating:\n  max_translation_jump: 0.4\n")
    r = runner.invoke(app, ["config", "check", str(p)])
    assert r.exit_code == 0 and "max_translation_jump: 0.4" in r.output


@pytest.fixture(scope="module")
def carmen_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("cli")
    w = worlds.lab(people=1)
    frames = list(worlds.simulate(w, worlds.lab_random_walk(5.0, seed=2), seed=1, max_frames=120))
    log = d / "run.log.gz"
    write_carmen(
        log,
        [f.scan for f in frames],
        [f.odometry for f in frames],
        scan_odometry=[f.odometry.pose for f in frames],
    )
    truth = d / "truth.tum"
    truth.write_text("".join(tum_row(f.scan.stamp, f.truth) for f in frames))
    return {
        "log": log,
        "truth": truth,
        "map": Map.from_lines(w.lines).to_ros(d / "m.yaml", 0.05),
        "dir": d,
    }


def test_replay_command(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    out, plot = tmp_path / "t.tum", tmp_path / "p.png"
    r = runner.invoke(
        app,
        [
            "replay", str(carmen_run["log"]), "--map", str(carmen_run["map"]),
            "--truth", str(carmen_run["truth"]), "--out", str(out), "--plot", str(plot),
            "--initial-pose", "0,0,0",
        ],
    )  # fmt: skip
    assert r.exit_code == 0, r.output
    assert "120 scans" in r.output and "scans/s" in r.output
    assert "tracking 120" in r.output
    assert "ate_rmse_m" in r.output
    rows = out.read_text().splitlines()
    assert len(rows) == 120
    assert len(rows[0].split()) == 8
    assert plot.stat().st_size > 1000
    vals = np.array([[float(v) for v in row.split()] for row in rows])
    assert np.all(np.isfinite(vals))


def test_replay_command_without_initial_pose_localizes_globally(
    carmen_run: dict[str, Path], tmp_path: Path
) -> None:
    """The issue's promise at the command line: no --initial-pose (and no --truth to take
    one from) -> global localization, then tracking; the TUM rows land on the truth."""
    out = tmp_path / "g.tum"
    r = runner.invoke(
        app, ["replay", str(carmen_run["log"]), "--map", str(carmen_run["map"]), "--out", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "120 scans" in r.output
    rows = np.array([[float(v) for v in row.split()] for row in out.read_text().splitlines()])
    truth = np.array(
        [[float(v) for v in row.split()] for row in carmen_run["truth"].read_text().splitlines()]
    )
    assert rows.shape == (120, 8)
    err = np.hypot(*(rows[:, 1:3] - truth[:, 1:3]).T)
    assert np.all(err[5:] < 0.05), err  # locked within the first 5 scans, then on the truth


def test_replay_bad_initial_pose_and_bad_log(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    r = runner.invoke(
        app,
        [
            "replay",
            str(carmen_run["log"]),
            "--map",
            str(carmen_run["map"]),
            "--initial-pose",
            "1,2",
        ],
    )
    assert r.exit_code == 2
    assert "X,Y,THETA" in r.output
    bad = tmp_path / "bad.log"
    bad.write_text(
        "FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 0.1 h 0.1\nFLASER 3 1.0 oops 1.0 0 0 0 0 0 0 0.2 h 0.2\n"
    )
    r = runner.invoke(app, ["replay", str(bad), "--map", str(carmen_run["map"]), "--no-progress"])
    assert r.exit_code == 1
    assert "bad.log:2" in r.output
    r = runner.invoke(
        app, ["replay", str(tmp_path / "missing.log"), "--map", str(carmen_run["map"])]
    )
    assert r.exit_code == 1
    assert "error" in r.output


def test_replay_with_config_file(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("scan:\n  decimation: 2\nicp:\n  metric: point_to_point\n")
    r = runner.invoke(
        app,
        [
            "replay",
            str(carmen_run["log"]),
            "--map",
            str(carmen_run["map"]),
            "--config",
            str(cfg),
            "--no-progress",
            "--truth",
            str(carmen_run["truth"]),
        ],
    )
    assert r.exit_code == 0, r.output
    assert "tracking 120" in r.output
    cfg.write_text("scan:\n  decimation: 0\n")
    r = runner.invoke(
        app,
        ["replay", str(carmen_run["log"]), "--map", str(carmen_run["map"]), "--config", str(cfg)],
    )
    assert r.exit_code == 2 and "decimation" in r.output


def test_run_needs_ports_unless_simulated() -> None:
    r = runner.invoke(app, ["run"])
    assert r.exit_code != 0
    assert "--map and --laser are required" in r.output


@pytest.mark.slow
def test_run_simulate_live_path(tmp_path: Path) -> None:
    """`icploc run --simulate`: the live path (drivers, threads, one clock) on ptys."""
    out, rec = tmp_path / "live.tum", tmp_path / "live.icpraw"
    r = runner.invoke(
        app, ["run", "--simulate", "--duration", "4", "--out", str(out), "--record", str(rec)]
    )
    assert r.exit_code == 0, r.output
    assert "error vs simulator truth" in r.output
    rows = out.read_text().splitlines()
    assert len(rows) > 20
    assert rec.stat().st_size > 10_000
    median_mm = float(r.output.split("median ")[1].split(" mm")[0])
    assert median_mm < 10.0


@pytest.mark.slow
def test_run_simulate_without_start_pose_localizes_globally(tmp_path: Path) -> None:
    """`icploc run --simulate --global`: the localizer is not told the start; it locks on
    by global search over the live path and then tracks the simulator's truth."""
    from icploc import live

    res, truth = live.run_simulated(timeout=6.0, global_start=True)
    assert res.estimates
    statuses = [str(e.status) for e in res.estimates]
    assert statuses[0].endswith("lost")
    tracked = [e for e in res.estimates if str(e.status).endswith("tracking")]
    assert len(tracked) >= len(res.estimates) // 2
    T = live.truth_at(truth, [e.stamp for e in tracked])
    err = [
        float(np.hypot(e.pose[0] - t[0], e.pose[1] - t[1])) for e, t in zip(tracked, T, strict=True)
    ]
    assert float(np.median(err)) < 0.02

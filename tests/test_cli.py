"""The command line: config, replay, run argument checks."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from icploc import sim as worlds
from icploc.cli import _register, app
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


def test_replay_strict_refuses_a_malformed_line(
    carmen_run: dict[str, Path], tmp_path: Path
) -> None:
    bad = tmp_path / "bad.log"
    bad.write_text(
        "FLASER 3 1.0 1.0 1.0 0 0 0 0 0 0 0.1 h 0.1\nFLASER 3 1.0 oops 1.0 0 0 0 0 0 0 0.2 h 0.2\n"
    )
    r = runner.invoke(
        app, ["replay", str(bad), "--map", str(carmen_run["map"]), "--no-progress", "--strict"]
    )
    assert (r.exit_code, r.output.strip().splitlines()[-1]) == (
        1,
        f"error: {bad}:2: FLASER reading 2: 'oops' is not a number",
    )


def test_replay_missing_log_is_one_error_line(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    missing = tmp_path / "missing.log"
    r = runner.invoke(app, ["replay", str(missing), "--map", str(carmen_run["map"])])
    assert (r.exit_code, r.output) == (1, f"error: {missing}: no such log file\n")


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
    assert (r.exit_code, "--map and --laser are required" in r.output) == (2, True)


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
    from icploc.sim import harness as live

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


# ----------------------------------------------------------------------------- issue 14


def _replay(carmen_run: dict[str, Path], *extra: str) -> Any:
    args = ["replay", str(carmen_run["log"]), "--map", str(carmen_run["map"]), "--no-progress"]
    return runner.invoke(app, [*args, "--initial-pose", "0,0,0", *extra])


def test_help_documents_the_exit_codes() -> None:
    r = runner.invoke(app, ["--help"])
    codes = [ln.split()[0] for ln in r.output.split("Exit codes:")[1].splitlines() if ln.strip()]
    assert codes[:5] == ["0", "1", "2", "3", "130"]


def test_out_pointing_at_the_log_is_refused_and_the_log_kept(
    carmen_run: dict[str, Path],
) -> None:
    before = carmen_run["log"].read_bytes()
    r = _replay(carmen_run, "--out", str(carmen_run["log"]))
    assert (r.exit_code, "is an input" in r.output, carmen_run["log"].read_bytes() == before) == (
        1,
        True,
        True,
    )


def test_plot_pointing_at_the_map_image_is_refused(carmen_run: dict[str, Path]) -> None:
    img = carmen_run["map"].with_suffix(".pgm")
    before = img.read_bytes()
    r = _replay(carmen_run, "--plot", str(img))
    assert (r.exit_code, "is an input" in r.output, img.read_bytes() == before) == (1, True, True)


def test_estimates_pointing_at_the_config_is_refused(
    carmen_run: dict[str, Path], tmp_path: Path
) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("scan:\n  decimation: 1\n")
    r = _replay(carmen_run, "--config", str(cfg), "--estimates", str(cfg))
    assert (r.exit_code, cfg.read_text()) == (1, "scan:\n  decimation: 1\n")


def test_unwritable_output_is_refused_before_any_work(
    carmen_run: dict[str, Path], tmp_path: Path
) -> None:
    r = _replay(carmen_run, "--out", str(tmp_path / "no" / "such" / "dir" / "t.tum"))
    assert (r.exit_code, "does not exist" in r.output, "scans" in r.output) == (1, True, False)


def test_same_path_for_two_outputs_is_refused(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    p = tmp_path / "x"
    r = _replay(carmen_run, "--out", str(p), "--estimates", str(p))
    assert (r.exit_code, "are the same file" in r.output) == (1, True)


def test_estimates_csv_has_one_row_per_scan(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    import csv

    est = tmp_path / "e.csv"
    r = _replay(carmen_run, "--estimates", str(est))
    assert r.exit_code == 0, r.output
    rows = list(csv.DictReader(est.read_text().splitlines()))
    assert [len(rows), {row["status"] for row in rows}] == [120, {"tracking"}]


def test_estimates_csv_header(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    est = tmp_path / "e.csv"
    _replay(carmen_run, "--estimates", str(est))
    head = est.read_text().splitlines()[0]
    assert head.startswith("stamp,x,y,theta,status,reason,inlier_ratio,cov_xx,cov_xy,cov_yy,cov_tt")


def test_replay_that_loses_most_scans_exits_3(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("localizer:\n  relocalization: local\n")
    args = ["replay", str(carmen_run["log"]), "--map", str(carmen_run["map"]), "--no-progress"]
    r = runner.invoke(app, [*args, "--initial-pose", "30,30,0", "--config", str(cfg)])
    assert (r.exit_code, "ended lost, more than --max-lost 0.5" in r.output) == (3, True)


def test_max_lost_1_accepts_a_lost_replay(carmen_run: dict[str, Path], tmp_path: Path) -> None:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("localizer:\n  relocalization: local\n")
    args = ["replay", str(carmen_run["log"]), "--map", str(carmen_run["map"]), "--no-progress"]
    r = runner.invoke(
        app, [*args, "--initial-pose", "30,30,0", "--config", str(cfg), "--max-lost", "1"]
    )
    assert r.exit_code == 0, r.output


def test_ctrl_c_ends_with_summary_and_complete_files(
    carmen_run: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from icploc.localizer import Localizer

    real = Localizer.update
    calls = [0]

    def update(self, scan):  # type: ignore[no-untyped-def]
        calls[0] += 1
        if calls[0] == 50:
            raise KeyboardInterrupt
        return real(self, scan)

    monkeypatch.setattr(Localizer, "update", update)
    out, est = tmp_path / "t.tum", tmp_path / "e.csv"
    r = _replay(carmen_run, "--out", str(out), "--estimates", str(est))
    got = (r.exit_code, "interrupted: 49 of 120 scans" in r.output)
    assert got + (len(out.read_text().splitlines()), len(est.read_text().splitlines())) == (
        130, True, 49, 50,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("icp:\n  robust_scale: 0\n", "icp.robust_scale"),
        ("icp:\n  min_inliers: -5\n", "icp.min_inliers"),
        ("scan:\n  laser_x: .inf\n", "scan.laser_x"),
        ("scan:\n  laser_x: 0.1\n  laser_x: 0.2\n", "c.yaml:3: duplicate key 'laser_x'"),
    ],
)
def test_config_check_rejects_what_replay_rejects(tmp_path: Path, text: str, needle: str) -> None:
    """Issue 14: config check accepted robust_scale 0, min_inliers -5, laser_x .inf."""
    p = tmp_path / "c.yaml"
    p.write_text(text)
    r = runner.invoke(app, ["config", "check", str(p)])
    assert (r.exit_code, needle in r.output) == (2, True)


def test_non_utf8_config_is_a_clear_error(tmp_path: Path) -> None:
    p = tmp_path / "c.yaml"
    p.write_bytes(b"scan:\n  laser_x: 0.1 # \xe9t\xe9\n")
    r = runner.invoke(app, ["config", "check", str(p)])
    assert (r.exit_code, f"{p}:2: not UTF-8" in r.output) == (2, True)


def test_map_convert_write_error_is_one_error_line(
    carmen_run: dict[str, Path], tmp_path: Path
) -> None:
    _register()
    dest = tmp_path / "missing_dir" / "m.geojson"
    r = runner.invoke(app, ["map", "convert", str(carmen_run["map"]), "-o", str(dest)])
    assert (r.exit_code, r.output.startswith("error: "), "Traceback" in r.output) == (
        1,
        True,
        False,
    )


def test_map_prepare_write_error_is_one_error_line(
    carmen_run: dict[str, Path], tmp_path: Path
) -> None:
    _register()
    dest = tmp_path / "missing_dir" / "m.npz"
    r = runner.invoke(app, ["map", "prepare", str(carmen_run["map"]), "--out", str(dest)])
    assert (r.exit_code, r.output.startswith("error: ")) == (1, True)


def test_demo_into_a_file_is_one_error_line(tmp_path: Path) -> None:
    f = tmp_path / "afile"
    f.write_text("x")
    r = runner.invoke(app, ["demo", "--quick", "--out", str(f)])
    assert (r.exit_code, r.output) == (1, f"error: --out {f}: exists and is not a directory\n")


# ----------------------------------------------------------------------------- issue 15


def test_log_info_prints_each_log_and_one_error_line_per_bad_one(tmp_path: Path) -> None:
    import numpy as np
    from icploc.logs.carmen import flaser_angles
    from icploc.messages import Scan

    good = tmp_path / "a.log"
    scans = [
        Scan(stamp=t, ranges=np.ones(180), angles=flaser_angles(180), max_range=8.0)
        for t in (1.0, 2.0)
    ]
    write_carmen(good, scans, [])
    bad = tmp_path / "bad.log"
    bad.write_text("FLASER 3 1 2\n")
    r = runner.invoke(app, ["log", "info", str(good), str(bad), "--strict"])
    assert (
        r.exit_code,
        "2 × 180 beams" in r.stdout,
        f"{bad}:1: FLASER: truncated" in r.stderr,
    ) == (
        1,
        True,
        True,
    )


def _all_commands() -> list[tuple[str, Any]]:
    import typer

    _register()
    out: list[tuple[str, Any]] = []

    def walk(cmd: Any, path: str) -> None:
        if hasattr(cmd, "list_commands"):
            ctx = typer.Context(cmd)
            for name in cmd.list_commands(ctx):
                walk(cmd.get_command(ctx, name), f"{path} {name}")
        else:
            out.append((path.strip(), cmd))

    walk(typer.main.get_command(app), "")
    return out


#: a unit (or what the number counts) in parentheses at the end of a numeric option's help
_UNIT = r"\((?:[^()]*\b(?:m|rad|deg|s|Hz|Bd|count|0-1|an integer|dots per inch)\b[^()]*)\)$"


def _numeric_options() -> list[tuple[str, Any]]:
    from typing import get_args

    found = []
    for name, cmd in _all_commands():
        for p in cmd.params:
            ann = p.type_descriptor.annotation
            if p.param_type_name == "option" and (
                ann in (int, float) or set(get_args(ann)) & {int, float}
            ):
                found.append((f"{name} {p.opts[0]}", p))
    return found


def test_the_cli_has_numeric_options_in_many_commands() -> None:
    names = {n.rsplit(" ", 1)[0] for n, _ in _numeric_options()}
    assert {"replay", "run", "demo", "map build", "map show", "map convert", "batch"} <= names


def test_every_numeric_option_says_its_unit() -> None:
    import re

    missing = [
        f"{n}: {p.help!r}" for n, p in _numeric_options() if not re.search(_UNIT, p.help or "")
    ]
    assert missing == []


@pytest.mark.parametrize(
    "command", [["replay"], ["map", "build"], ["log", "info"], ["config", "check"]]
)
def test_help_shows_plain_argument_names_and_no_bool_type(command: list[str]) -> None:
    r = runner.invoke(app, [*command, "--help"], env={"COLUMNS": "200"})
    usage = next(ln for ln in r.stdout.splitlines() if "Usage:" in ln)
    assert ("{" in usage, "<bool>" in r.stdout, r.exit_code) == (False, False, 0)


def test_units_in_brackets_are_not_eaten_by_the_help_markup() -> None:
    r = runner.invoke(app, ["map", "build", "--help"], env={"COLUMNS": "200"})
    assert "cell size (m)" in r.stdout

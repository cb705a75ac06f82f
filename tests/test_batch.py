"""icploc batch: many logs on a local Dask cluster, each exactly as ``icploc replay``."""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import pytest
from icploc import sim as worlds
from icploc.live import tum_row
from icploc.logs import write_carmen
from icploc.maps import Map
from icploc.replay import replay
from icploc.trajectory import ESTIMATE_COLUMNS

pytest.importorskip("distributed")

from icploc.batch import BatchError, batch_replay, log_stem  # noqa: E402


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> dict:
    d = tmp_path_factory.mktemp("fleet")
    w = worlds.lab(people=1)
    map_yaml = Map.from_lines(w.lines).to_ros(d / "lab.yaml", 0.05)
    truth_dir = d / "truth"
    truth_dir.mkdir()
    logs = []
    for i in range(3):
        path = worlds.lab_random_walk(8.0, seed=40 + i)
        frames = list(worlds.simulate(w, path, seed=50 + i, max_frames=120))
        p = d / f"robot{i}.log"
        write_carmen(
            p,
            [f.scan for f in frames],
            [f.odometry for f in frames],
            poses=np.array([f.truth for f in frames]),
            scan_odometry=np.array([f.odometry.pose for f in frames]),
        )
        if i < 2:  # robot2 has no truth: it localizes globally, as icploc replay would
            (truth_dir / f"robot{i}.tum").write_text(
                "".join(tum_row(f.scan.stamp, f.truth) for f in frames)
            )
        logs.append(p)
    broken = d / "broken.log"
    broken.write_text("FLASER 3 1.0 2.0\n")  # too few readings: a reader error
    out = d / "out"
    seen: list[tuple[int, int, str]] = []
    res = batch_replay(
        [logs[0], broken, logs[1], logs[2]],
        map_yaml,
        out,
        workers=2,
        truth_dir=truth_dir,
        on_progress=lambda done, total, row: seen.append((done, total, row.stem)),
    )
    return {
        "dir": d,
        "map": map_yaml,
        "logs": logs,
        "broken": broken,
        "truth_dir": truth_dir,
        "out": out,
        "res": res,
        "progress": seen,
    }


def _summary(out: Path) -> list[dict[str, str]]:
    with open(out / "summary.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
@pytest.mark.parametrize("i", [0, 1, 2])
def test_each_log_identical_to_replay(fleet: dict, i: int, tmp_path: Path) -> None:
    log = fleet["logs"][i]
    truth = fleet["truth_dir"] / f"{log_stem(log)}.tum"
    ref_tum, ref_csv = tmp_path / "ref.tum", tmp_path / "ref.csv"
    replay(log, fleet["map"], out=ref_tum, estimates=ref_csv, truth=truth if truth.exists() else None)
    assert (fleet["out"] / f"{log_stem(log)}.tum").read_bytes() == ref_tum.read_bytes()
    assert (fleet["out"] / f"{log_stem(log)}.csv").read_bytes() == ref_csv.read_bytes()


@pytest.mark.slow
def test_summary_has_one_row_per_log_in_order(fleet: dict) -> None:
    rows = _summary(fleet["out"])
    assert [r["log"] for r in rows] == [
        str(fleet["logs"][0]),
        str(fleet["broken"]),
        str(fleet["logs"][1]),
        str(fleet["logs"][2]),
    ]


@pytest.mark.slow
def test_broken_log_is_reported_and_the_rest_complete(fleet: dict) -> None:
    rows = {Path(r["log"]).name: r for r in _summary(fleet["out"])}
    assert "broken.log" in rows["broken.log"]["error"]
    assert [rows[f"robot{i}.log"]["error"] for i in range(3)] == ["", "", ""]
    assert not (fleet["out"] / "broken.tum").exists()


@pytest.mark.slow
def test_summary_counts_match_the_replay(fleet: dict) -> None:
    log = fleet["logs"][0]
    ref = replay(log, fleet["map"], truth=fleet["truth_dir"] / "robot0.tum")
    row = next(r for r in _summary(fleet["out"]) if r["log"] == str(log))
    c = ref.status_counts
    got = (int(row["scans"]), int(row["tracking"]), int(row["degraded"]), int(row["lost"]))
    assert got == (ref.scans, c.get("tracking", 0), c.get("degraded", 0), c.get("lost", 0))
    assert float(row["ate_rmse_m"]) == pytest.approx(ref.metrics["ate_rmse_m"], abs=1e-6)


@pytest.mark.slow
def test_ate_only_where_truth_is_known(fleet: dict) -> None:
    rows = {Path(r["log"]).name: r for r in _summary(fleet["out"])}
    assert [rows[f"robot{i}.log"]["ate_rmse_m"] != "" for i in range(3)] == [True, True, False]


@pytest.mark.slow
def test_progress_reported_once_per_log(fleet: dict) -> None:
    seen = fleet["progress"]
    assert [d for d, _, _ in seen] == [1, 2, 3, 4]
    assert sorted(s for _, _, s in seen) == ["broken", "robot0", "robot1", "robot2"]


@pytest.mark.slow
def test_estimates_csv_header(fleet: dict) -> None:
    with open(fleet["out"] / "robot0.csv", newline="") as f:
        assert tuple(next(csv.reader(f))) == ESTIMATE_COLUMNS


@pytest.mark.slow
def test_cli_batch_writes_the_outputs_and_exits_3_on_a_broken_log(
    fleet: dict, tmp_path: Path
) -> None:
    from icploc.cli import app
    from typer.testing import CliRunner

    out = tmp_path / "cli"
    r = CliRunner().invoke(
        app,
        ["batch", str(fleet["logs"][0]), str(fleet["broken"]), "--map", str(fleet["map"]),
         "--out", str(out), "--workers", "1", "--no-progress"],
    )  # fmt: skip
    assert (r.exit_code, sorted(p.name for p in out.iterdir())) == (
        3,
        ["robot0.csv", "robot0.tum", "summary.csv"],
    ), r.output


def test_log_stem_strips_gz_and_log_suffixes() -> None:
    assert [log_stem(p) for p in ("a/intel-corrected.log.gz", "b/run.bag", "c/run_bag2")] == [
        "intel-corrected",
        "run",
        "run_bag2",
    ]


def test_two_logs_with_one_stem_are_refused_before_starting(tmp_path: Path) -> None:
    with pytest.raises(BatchError, match="same outputs"):
        batch_replay([tmp_path / "a/x.log", tmp_path / "b/x.log.gz"], "m.yaml", tmp_path / "o")


def test_missing_dask_is_a_clear_error(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(BatchError, match=r"icploc\[fleet\]"):
        batch_replay([tmp_path / "x.log"], "m.yaml", tmp_path / "o")


def test_unreachable_scheduler_is_a_clear_error(tmp_path: Path) -> None:
    m = Map.from_lines(worlds.lab(people=0).lines)
    with pytest.raises(BatchError, match="no Dask scheduler at tcp://127.0.0.1:9"):
        batch_replay([tmp_path / "x.log"], m, tmp_path / "o", scheduler="tcp://127.0.0.1:9",
                     connect_timeout=1.0)  # fmt: skip


@pytest.mark.slow
def test_runs_on_an_existing_scheduler(fleet: dict, tmp_path: Path) -> None:
    import distributed

    with distributed.LocalCluster(
        n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None
    ) as cluster:
        res = batch_replay(
            [fleet["logs"][2]], fleet["map"], tmp_path, scheduler=cluster.scheduler_address
        )
    assert (res.rows[0].error, (tmp_path / "robot2.tum").read_bytes()) == (
        "",
        (fleet["out"] / "robot2.tum").read_bytes(),
    )


def test_a_map_already_indexed_is_shipped_without_its_index() -> None:
    import pickle

    from icploc.batch import prepare_map

    m = Map.from_lines(worlds.lab(people=0).lines)
    m.index(0.05)  # a k-d tree (a Rust object) is cached in the map now
    shipped = pickle.loads(pickle.dumps(prepare_map(m)))
    assert np.array_equal(shipped.sample(0.05)[0], m.sample(0.05)[0])

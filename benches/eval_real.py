r"""Real-data localization benchmark that does not flatter: icploc, MRPT pf-localization,
nav2 AMCL and a numpy ICP tracker on real scans, realistic raw odometry, sparse scans and
map_server grids built from a different pass.

Usage (from any directory; the interpreter running this script is the one whose
``icploc`` is measured, so a worktree's venv measures that worktree)::

    .venv/bin/python benches/eval_real.py                    # full run (see --help for the set)
    .venv/bin/python benches/eval_real.py --quick            # aces + freiburg-101, 10 cm, both bases
    .venv/bin/python benches/eval_real.py intel --res 0.10 --bases good --methods icploc,numpy
    /work/wt-loc/.venv/bin/python /work/wt-bench/benches/eval_real.py --quick --methods icploc
    .venv/bin/python benches/eval_real.py --laserazos-only
    .venv/bin/python benches/eval_real.py --unseen --methods icploc,mrpt   # logs no one tuned on
    # your worktree's icploc against the committed peers' rows (they are not rerun):
    /work/wt-loc/.venv/bin/python /work/wt-bench/benches/eval_real.py --methods icploc \
        --merge /work/wt-bench/benches/results/real.json --out-dir /tmp/real-loc

Writes ``benches/results/real.md`` (the table, also on stdout) and ``benches/results/real.json``
(``--quick``: ``real-quick.*``; ``--out-dir`` elsewhere). Maps, logs and peer work files go to
a cache outside the project: ``$XDG_CACHE_HOME/icploc-bench-real`` (default
``~/.cache/icploc-bench-real``; ``--cache``); each run's peer work files go to a
``work/<pid>`` folder there, removed at the end unless ``--keep-work``, so runs from several
worktrees at once do not clash. Methods: ``icploc`` (public Python path
``icploc.replay.replay``, the function ``icploc replay`` calls, in a child process: poses,
status and the whole-process time; ``--icploc-cli`` also runs the ``icploc replay`` command
as its own process, reports its time and checks its poses against the API's), ``numpy`` (benches/numpy_tracker.py),
``mrpt`` (``apt-get install mrpt-apps``), ``amcl`` (``pip install amcl``, the ``bench``
extra). A missing peer is reported as such, not silently dropped.

What is done to the data (all seeded, reproducible):

(a) Raw odometry. The corrected logs hold SLAM-corrected poses (the reference) and no raw
    odometry. A per-step error model (benches/real_odometry.py) is fitted to the 2,000 real
    paired motions of ../shared/data/freiburg_course (wheel odometry vs scan matching):
    distance scale, lateral skew, rotation scale, heading bias per metre, and AMCL-style
    noise spreads, with the real standardised residuals kept and resampled. Base ``good`` is
    that fit; base ``bad`` triples the systematic errors (at least 3 % scale, 2 % rotation
    scale, 1°/m heading bias) and doubles the noise. Applied on 0.1 m / 0.05 rad sub-steps
    of the reference path.
(b) Sparse scans: one scan kept per 0.5 m or 0.5 rad of reference travel (the first kept).
(c) Maps: map_server YAML + PGM at 5 and 10 cm (benches/real_grid.py: ray-cast free space,
    occupied by hit counts), from a different pass: the log is cut into ``--folds`` (3) time
    chunks; each chunk is localized (from its first reference pose) against a map of the
    other chunks, less ``--gap`` (5 %) of the log at each seam. Places seen only in the
    localized chunk take held-out scans of that chunk (scans the sparsifier dropped and
    more than 2 scans from a localized one); the JSON gives the share of localized scans
    whose place another pass saw (``revisited_share``).
(d) laserazosSM3 with its own raw odometry and no reference: a reference is made by
    sequential scan-to-submap ICP (benches/real_reference.py, no loop closure); the 5/10 cm
    maps are rasterised from it using the scans more than one scan away from a localized
    one; the score
    is the map-fit residual (per scan, the median distance of the beam endpoints at the
    estimated pose to the nearest occupied cell, capped at 1 m), the share of scans that
    fit poorly (residual > 0.2 m) and icploc's lost share; the error against the made
    reference is shown as a secondary figure.
(e) Every method gets the same CARMEN FLASER file (pose and odometry fields both the raw
    odometry: no reference leaks), the same map, the same start pose. Scores: median / p95
    / max position error against the reference; false ``tracking`` = scans reported
    ``tracking`` while > 0.5 m off (peers have no status: every scan > 0.5 m off counts);
    scans/s for the whole process (interpreter start, imports, map and log load). With
    ``PYTHONDONTWRITEBYTECODE`` set, the measured package is byte-compiled first, as an
    installed one is (``--no-compile``: not). Maps come from the prepared-map cache
    (``~/.cache/icploc/maps``) after the first run of a map: the timed icploc figures are
    warm-cache figures (``benches/replay_speed.py --cold`` gives cold ones).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import real_grid as rg  # noqa: E402
import real_logs as rl  # noqa: E402
import real_metrics as rm  # noqa: E402
import real_odometry as ro  # noqa: E402

DATA = HERE.parents[1] / "shared" / "data"
RESULTS = HERE / "results"
DEFAULT_LOGS = ["intel", "freiburg-101", "freiburg-079", "csail", "aces"]
QUICK_LOGS = ["aces", "freiburg-101"]
#: radish logs no one tuned on (issue 11's "logs we do not ship"; ``--unseen``, results in
#: benches/results/real-unseen.*), read, sparsified and split exactly as the others:
#: fhw (488 scans x 180 beams, 1 deg), edmonton (340 x 180), acapulco (861 x 181, 1 deg
#: inclusive), seattle (241 x 361, 0.5 deg inclusive, ~5 s between scans) and
#: infinite-corridor (1,941 x 180; its stamps are broken, mostly equal with one 2^32 jump,
#: so it gets 10 Hz stamps by index as campus and Örebro do)
UNSEEN_LOGS = ["fhw", "edmonton", "acapulco", "seattle", "infinite-corridor"]
METHODS = ["icploc", "numpy", "mrpt", "amcl"]
POOR_FIT_M = 0.2
#: bump when the map / localize split changes (cached maps are keyed by it)
SPLIT_VERSION = "s2"


def cache_dir() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "icploc-bench-real"


def compile_measured_package(python: str) -> None:
    """Byte-compile the measured interpreter's ``icploc`` package when the environment says not
    to write ``.pyc`` files (``PYTHONDONTWRITEBYTECODE``, as on the team's machines): an
    installed package has them, and without them every child process recompiles the
    package's source (~80 ms of a whole-process time). Nothing else changes."""
    if not os.environ.get("PYTHONDONTWRITEBYTECODE"):
        return
    got = subprocess.run([python, "-c", "import icploc, os; print(os.path.dirname(icploc.__file__))"],
                         capture_output=True, text=True)  # fmt: skip
    if got.returncode == 0 and got.stdout.strip():
        subprocess.run([python, "-m", "compileall", "-q", got.stdout.strip()], capture_output=True)


def fit_bases(data: Path) -> dict[str, ro.OdometryErrorModel]:
    fc = data / "freiburg_course"
    good = ro.fit_model(
        ro.load_motions(fc / "odom_motions.dat"), ro.load_motions(fc / "scanmatched_motions.dat"), "good"
    )
    return {"good": good, "bad": good.worse(name="bad")}


def _seed(*parts: Any) -> int:
    return zlib.crc32("/".join(str(p) for p in parts).encode())


def _stamps(log: rl.FlaserLog) -> NDArray[np.float64]:
    # logs with broken stamps (all 0, rounded, out of order) get 10 Hz stamps by index
    return log.stamps.copy() if log.stamps_usable else 1000.0 + 0.1 * np.arange(len(log))


# --------------------------------------------------------------------------- running methods


def _child(cmd: list[str], timeout: float) -> tuple[float, subprocess.CompletedProcess[str]]:
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL)
    return time.perf_counter() - t0, proc


def _load_child(out: Path) -> dict:
    got = json.loads(out.read_text())
    got["poses"] = [[math.nan if v is None else v for v in p] for p in got["poses"]]
    return got


def run_method(
    method: str,
    work: Path,
    log_path: Path,
    ranges: NDArray[np.float64],
    odom: NDArray[np.float64],
    map_yaml: Path,
    pose: tuple[float, float, float],
    max_range: float,
    python: str,
    seed: int,
    timeout: float,
    icploc_cli: bool = False,
) -> dict:
    """Run one method on one log; returns poses, status (or None), time_s (whole process).

    icploc: the child process runs ``icploc.replay.replay`` (what ``icploc replay`` calls);
    with ``icploc_cli`` the ``icploc replay`` command also runs as its own process, its time
    is the one reported and its TUM poses are checked against the API's."""
    work.mkdir(parents=True, exist_ok=True)
    pose_s = ",".join(f"{v:.9f}" for v in pose)
    runner = str(HERE / "real_runners.py")
    if method == "mrpt":
        import real_mrpt

        if not real_mrpt.available():
            raise RuntimeError("MRPT tools not found (apt-get install mrpt-apps)")
        return real_mrpt.run_mrpt(work, ranges, odom, map_yaml, pose, max_range, timeout)
    out = work / f"{method}.json"
    extra = ["--max-range", str(max_range), "--seed", str(seed)]
    dt, proc = _child([python, runner, method, str(log_path), str(map_yaml), str(out), f"--pose={pose_s}", *extra], timeout)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-6:]
        raise RuntimeError(f"{method} exit {proc.returncode}: " + " | ".join(tail))
    res = _load_child(out)
    res["time_s"] = dt
    if method == "icploc":
        res["api_time_s"] = dt
        cli = Path(python).parent / "icploc"
        if icploc_cli and cli.exists():
            tum = work / "icploc_cli.tum"
            cmd = [str(cli), "replay", str(log_path), "--map", str(map_yaml), f"--initial-pose={pose_s}",
                   "--out", str(tum), "--no-progress"]  # fmt: skip
            dt_cli, p2 = _child(cmd, timeout)
            if p2.returncode == 0 and tum.exists():
                rows = [ln.split() for ln in tum.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
                cli_xy = np.array([[float(r[1]), float(r[2])] for r in rows])
                api_xy = np.asarray(res["poses"])[:, :2]
                res["cli_time_s"] = dt_cli
                res["time_s"] = dt_cli
                if cli_xy.shape == api_xy.shape:
                    res["cli_vs_api_max_m"] = float(np.nanmax(np.hypot(*(cli_xy - api_xy).T)))
            else:
                res["cli_error"] = (p2.stderr or p2.stdout).strip()[-300:]
    if len(res["poses"]) != len(ranges):
        raise RuntimeError(f"{method}: {len(res['poses'])} poses for {len(ranges)} scans")
    return res


# --------------------------------------------------------------------------- radish logs


def find_logs(data: Path, names: list[str]) -> list[Path]:
    logs = sorted((data / "radish_corrected_logs").glob("*-corrected.log.gz"))
    return [p for p in logs if any(n in p.name for n in names)]


def build_map(
    cache: Path, tag: str, log: rl.FlaserLog, scans: NDArray[np.int64], res: float, max_range: float
) -> Path:
    yaml_path = cache / "maps" / f"{tag}_{int(round(res * 100))}cm.yaml"
    if not yaml_path.exists():
        grid = rg.rasterise(log.ranges[scans], log.angles, log.poses[scans], res, min(max_range, log.no_return))
        rg.write_map_server(grid, yaml_path)
    return yaml_path


def evaluate_log(
    path: Path, bases: dict[str, ro.OdometryErrorModel], args: argparse.Namespace
) -> list[dict]:
    log = rl.read_flaser(path)
    name = path.name.replace("-corrected.log.gz", "")
    ref = log.poses
    keep = rl.sparsify(ref, distance=0.5, angle=0.5)
    gap = max(1, int(round(args.gap * len(log))))
    folds = rl.split_folds(ref[:, :2], args.folds, gap)
    stamps = _stamps(log)
    rows: list[dict] = []
    fold_info = []
    ends = rl.endpoints_world(log, args.max_range)
    for f in folds:
        map_idx, loc, covered = rl.map_scans_for(f, ends, keep)
        fold_info.append((f, loc, map_idx, covered))
    for base_name in args.bases:
        model = bases[base_name]
        odom = ro.apply_model(model, ref, seed=_seed(args.seed, name, base_name))
        for res in args.res:
            per_method: dict[str, dict[str, Any]] = {
                m: {"est": [], "ref": [], "status": [], "time": 0.0, "errors": []} for m in args.methods
            }
            for f, loc, map_idx, _covered in fold_info:
                if len(loc) < 2:
                    continue
                tag = f"{name}_k{args.folds}_g{gap}_f{f.index}_r{args.max_range:g}_{SPLIT_VERSION}"
                yaml_path = build_map(args.cache, tag, log, map_idx, res, args.max_range)
                log_path = args.cache / "logs" / f"{name}_{base_name}_k{args.folds}_f{f.index}_s{args.seed}_{SPLIT_VERSION}.log"
                if not log_path.exists():
                    rl.write_flaser(log_path, log.ranges[loc], odom[loc], stamps[loc])
                pose = tuple(float(v) for v in ref[loc[0]])
                for m in args.methods:
                    work = args.work / f"{name}_{base_name}_{int(res * 100)}cm_f{f.index}" / m
                    acc = per_method[m]
                    try:
                        got = run_method(
                            m, work, log_path, log.ranges[loc], odom[loc], yaml_path, pose,  # type: ignore[arg-type]
                            min(args.max_range, log.no_return), args.python, _seed(args.seed, name, f.index), args.timeout,
                            args.icploc_cli,
                        )  # fmt: skip
                    except Exception as e:  # one failing method must not hide the others
                        acc["errors"].append(f"fold {f.index}: {type(e).__name__}: {e}")
                        continue
                    acc["est"].append(np.asarray(got["poses"], dtype=np.float64))
                    acc["ref"].append(ref[loc])
                    acc["status"].extend(got["status"] if got.get("status") is not None else [None] * len(loc))
                    acc["time"] += got["time_s"]
                    for k in ("api_time_s", "cli_time_s", "cli_vs_api_max_m", "cli_error", "convert_s", "parse_s", "localize_s"):
                        if k in got:
                            acc.setdefault(k, []).append(got[k])
                    print(f"  {name} {base_name} {int(res * 100)} cm fold {f.index} {m}: "
                          f"{len(loc)} scans {got['time_s']:.1f} s", file=sys.stderr, flush=True)  # fmt: skip
            n_loc = sum(len(x[1]) for x in fold_info)
            for m in args.methods:
                acc = per_method[m]
                row: dict[str, Any] = {
                    "log": name, "map_res_m": res, "base": base_name, "method": m,
                    "scans_localized": n_loc, "folds": args.folds,
                    "revisited_share": float(np.average([x[3] for x in fold_info], weights=[max(1, len(x[1])) for x in fold_info])),
                }  # fmt: skip
                if acc["errors"] or not acc["est"]:
                    row["error"] = "; ".join(acc["errors"]) or "no result"
                if acc["est"]:
                    est = np.vstack(acc["est"])
                    rf = np.vstack(acc["ref"])
                    st = acc["status"]
                    status = None if any(s is None for s in st) else st
                    row.update(rm.summarise(est, rf, status))
                    row["time_s"] = acc["time"]
                    row["scans_per_s"] = len(est) / acc["time"] if acc["time"] > 0 else None
                    for k in ("api_time_s", "cli_time_s", "convert_s", "parse_s", "localize_s"):
                        if k in acc:
                            row[k] = float(np.sum(acc[k]))
                    if "cli_vs_api_max_m" in acc:
                        row["cli_vs_api_max_m"] = float(np.max(acc["cli_vs_api_max_m"]))
                    if "cli_error" in acc:
                        row["cli_error"] = acc["cli_error"][0]
                rows.append(row)
                print(_md_row(row), flush=True)
    return rows


# --------------------------------------------------------------------------- laserazos


def evaluate_laserazos(args: argparse.Namespace) -> list[dict]:
    from real_reference import build_reference

    path = args.data / "laserazosSM3" / "laserazosSM3.log"
    log = rl.read_flaser(path)
    rmax = min(args.max_range, log.no_return)
    odom = log.odom
    ref_file = args.cache / "laserazos_reference.npy"
    if ref_file.exists():
        ref = np.load(ref_file)
    else:
        ref = build_reference(log.ranges, log.angles, odom, rmax)
        ref_file.parent.mkdir(parents=True, exist_ok=True)
        np.save(ref_file, ref)
    loc = rl.sparsify(odom, distance=0.5, angle=0.5)
    near = np.zeros(len(log), dtype=bool)
    for g in (-1, 0, 1):
        i = loc + g
        near[i[(i >= 0) & (i < len(log))]] = True
    map_idx = np.nonzero(~near)[0]
    stamps = _stamps(log)
    log_path = args.cache / "logs" / "laserazos.log"
    if not log_path.exists():
        rl.write_flaser(log_path, log.ranges[loc], odom[loc], stamps[loc])
    pose = tuple(float(v) for v in ref[loc[0]])
    rows = []
    for res in args.res:
        yaml_path = args.cache / "maps" / f"laserazos_{int(round(res * 100))}cm.yaml"
        if not yaml_path.exists():
            grid = rg.rasterise(log.ranges[map_idx], log.angles, ref[map_idx], res, rmax)
            rg.write_map_server(grid, yaml_path)
        occ = rg.read_map_server(yaml_path).occupied_centres()
        for m in args.methods:
            work = args.work / f"laserazos_{int(res * 100)}cm" / m
            row: dict[str, Any] = {"log": "laserazosSM3", "map_res_m": res, "base": "real", "method": m,
                                   "scans_localized": len(loc), "reference": "our ICP reference"}  # fmt: skip
            try:
                got = run_method(m, work, log_path, log.ranges[loc], odom[loc], yaml_path, pose,  # type: ignore[arg-type]
                                 rmax, args.python, _seed(args.seed, "laserazos"), args.timeout,
                                 args.icploc_cli)  # fmt: skip
            except Exception as e:
                row["error"] = f"{type(e).__name__}: {e}"
                rows.append(row)
                print(_md_row(row), flush=True)
                continue
            est = np.asarray(got["poses"], dtype=np.float64)
            row.update(rm.summarise(est, ref[loc], got.get("status")))
            fit = rm.map_fit(est, log.ranges[loc], log.angles, occ, rmax)
            row["fit_median_m"] = float(np.median(fit))
            row["fit_p95_m"] = float(np.percentile(fit, 95))
            row["poor_fit_share"] = float(np.mean(fit > POOR_FIT_M))
            row["time_s"] = got["time_s"]
            row["scans_per_s"] = len(loc) / got["time_s"]
            rows.append(row)
            print(_md_row(row), flush=True)
    return rows


def evaluate(path: Path, split: str, seed: int = 0, **kw: Any) -> dict[str, Any]:
    """The former dense held-out check (benches/real_dense_check.py), kept for
    tests/test_replay_real.py; not part of this benchmark."""
    from real_dense_check import evaluate as dense

    return dense(path, split, seed, **kw)


# --------------------------------------------------------------------------- output


def _cm(v: Any) -> str:
    return "–" if v is None else ("inf" if not math.isfinite(v) else f"{v * 100:.1f}")


def _md_row(r: dict) -> str:
    if "median_m" not in r:
        return f"| {r['log']} | {int(r['map_res_m'] * 100)} cm | {r['base']} | {r['method']} | – | – | – | – | – | – | – | {r.get('error', '')} |"
    lost = "–" if r.get("lost_share") is None else f"{r['lost_share'] * 100:.0f} %"
    sps = "–" if r.get("scans_per_s") is None else f"{r['scans_per_s']:,.0f}"
    note = r.get("error", "")
    if "fit_median_m" in r:
        note = (f"fit {r['fit_median_m'] * 100:.1f} / {r['fit_p95_m'] * 100:.1f} cm, "
                f"poor fit {r['poor_fit_share'] * 100:.0f} %") + (f"; {note}" if note else "")  # fmt: skip
    return (
        f"| {r['log']} | {int(round(r['map_res_m'] * 100))} cm | {r['base']} | {r['method']} | {r['scans']} | "
        f"{_cm(r['median_m'])} | {_cm(r['p95_m'])} | {_cm(r['max_m'])} | {r['false_tracking']} | {lost} | {sps} | {note} |"
    )


HEADER = (
    "| log | map | odometry | method | scans | median cm | p95 cm | max cm | false tracking | lost | scans/s | notes |\n"
    "|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|"
)


def laserazos_table(rows: list[dict]) -> list[str]:
    """laserazosSM3 (its own raw odometry, no reference): map fit first."""
    if not rows:
        return []
    out = [
        "laserazosSM3, its own wheel odometry; no reference exists, so: map-fit residual (median distance of the beam "
        f"endpoints to the map, per scan), share of scans fitting worse than {POOR_FIT_M * 100:.0f} cm, icploc's lost "
        "share, and (secondary) the error against our ICP-made reference:",
        "",
        "| map | method | scans | fit median cm | fit p95 cm | poor fit | lost | vs reference median / p95 / max cm | scans/s |",
        "|---|---|---:|---:|---:|---:|---:|---|---:|",
    ]
    for r in rows:
        res = f"{int(round(r['map_res_m'] * 100))} cm"
        if "fit_median_m" not in r:
            out.append(f"| {res} | {r['method']} | – | – | – | – | – | {r.get('error', '')} | – |")
            continue
        lost = "–" if r.get("lost_share") is None else f"{r['lost_share'] * 100:.0f} %"
        out.append(
            f"| {res} | {r['method']} | {r['scans']} | {_cm(r['fit_median_m'])} | {_cm(r['fit_p95_m'])} | "
            f"{r['poor_fit_share'] * 100:.0f} % | {lost} | {_cm(r['median_m'])} / {_cm(r['p95_m'])} / {_cm(r['max_m'])} | "
            f"{r['scans_per_s']:,.0f} |"
        )
    return [*out, ""]


def pooled(rows: list[dict]) -> list[str]:
    """One line per method: the medians over the (log, map, base) cells of the radish logs,
    worst max, summed false tracking, total scans / total time."""
    out = []
    for m in sorted({r["method"] for r in rows}):
        rr = [r for r in rows if r["method"] == m and "median_m" in r and r["base"] != "real"]
        if not rr:
            continue
        t = sum(r["time_s"] for r in rr)
        n = sum(r["scans"] for r in rr)
        out.append(
            f"| {m} | {len(rr)} | {_cm(float(np.median([r['median_m'] for r in rr])))} | "
            f"{_cm(float(np.median([r['p95_m'] for r in rr])))} | {_cm(max(r['max_m'] for r in rr))} | "
            f"{sum(r['false_tracking'] for r in rr)} | {n / t:,.0f} |"
        )
    return out


def targets(rows: list[dict], method: str = "icploc", peer: str | None = "mrpt") -> list[str]:
    """Issue 11's targets per radish cell against ``peer`` (MRPT pf-localization, the best
    peer on these logs; None: per figure the lowest of the peers measured in the cell): max
    at most half of it, p95 at least 25 % below it, median no worse. One line per cell with
    ``method``'s figures, the peer's and whether each target is met; then how many cells
    meet each."""
    cells: dict[tuple[Any, Any, Any], dict[str, dict]] = {}
    for r in rows:
        if "median_m" in r and r.get("base") != "real":
            cells.setdefault((r["log"], r["map_res_m"], r["base"]), {})[r["method"]] = r
    out: list[str] = []
    met = [0, 0, 0]
    n = 0
    for (log, res, base), by in cells.items():
        mine = by.get(method)
        peers = [r for m, r in by.items() if m != method and (peer is None or m == peer)]
        if mine is None or not peers:
            continue
        n += 1
        best = {k: min(r[k] for r in peers) for k in ("median_m", "p95_m", "max_m")}
        who = {k: min(peers, key=lambda r: r[k])["method"] for k in best}  # noqa: B023
        ok = (
            mine["max_m"] <= 0.5 * best["max_m"],
            mine["p95_m"] <= 0.75 * best["p95_m"],
            mine["median_m"] <= best["median_m"],
        )
        met = [a + int(b) for a, b in zip(met, ok, strict=True)]
        mark = ["yes" if b else "no" for b in ok]
        tag = {k: "" if peer else f" ({who[k]})" for k in who}
        out.append(
            f"| {log} | {int(round(res * 100))} cm | {base} | {_cm(mine['median_m'])} / {_cm(mine['p95_m'])} / "
            f"{_cm(mine['max_m'])} | {_cm(best['median_m'])}{tag['median_m']} / {_cm(best['p95_m'])}{tag['p95_m']} / "
            f"{_cm(best['max_m'])}{tag['max_m']} | {mark[0]} | {mark[1]} | {mark[2]} |"
        )
    if not out:
        return []
    return [
        f"Issue 11's targets per cell, {method} against "
        + (f"{peer}:" if peer else "the best peer (per figure, the lowest of the peers in the cell):"),
        "",
        f"| log | map | odometry | {method} median / p95 / max cm | {peer or 'best peer'} median / p95 / max cm | "
        "max <= half | p95 <= 75 % | median no worse |",
        "|---|---|---|---|---|---|---|---|",
        *out,
        f"| **cells meeting it** | | | | | {met[0]} / {n} | {met[1]} / {n} | {met[2]} / {n} |",
        "",
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*", help=f"radish logs whose name contains one of these (default {DEFAULT_LOGS})")
    ap.add_argument("--quick", action="store_true", help=f"{QUICK_LOGS}, 10 cm, both bases, no laserazos")
    ap.add_argument("--unseen", action="store_true",
                    help=f"the logs no one tuned on, {UNSEEN_LOGS}: no laserazos, --stem real-unseen")  # fmt: skip
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--cache", type=Path, default=cache_dir())
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    ap.add_argument("--res", type=lambda s: [float(v) for v in s.split(",")], default=None,
                    help="map resolutions in m (default 0.05,0.10)")  # fmt: skip
    ap.add_argument("--bases", type=lambda s: s.split(","), default=["good", "bad"])
    ap.add_argument("--methods", type=lambda s: s.split(","), default=METHODS)
    ap.add_argument("--folds", type=int, default=3)
    ap.add_argument("--gap", type=float, default=0.05, help="share of the log left out at each seam")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-range", type=float, default=30.0, help="range limit of maps and peers (m)")
    ap.add_argument("--python", default=sys.executable, help="interpreter whose icploc is measured")
    ap.add_argument("--timeout", type=float, default=1800.0, help="per child process (s)")
    ap.add_argument("--no-laserazos", dest="laserazos", action="store_false")
    ap.add_argument("--icploc-cli", action="store_true",
                    help="also run the `icploc replay` command per log and report its whole-process time")  # fmt: skip
    ap.add_argument("--laserazos-only", action="store_true")
    ap.add_argument("--no-compile", dest="compile", action="store_false",
                    help="do not byte-compile the measured icploc first (see compile_measured_package)")  # fmt: skip
    ap.add_argument("--stem", default=None,
                    help="name of the written table files (default real, with --quick real-quick), e.g. real-heldout")  # fmt: skip
    ap.add_argument("--merge-only", action="store_true", help="run nothing: write the --merge rows as one table")
    ap.add_argument("--keep-work", action="store_true", help="keep the per-run work folder (peer inputs, logs)")
    ap.add_argument("--merge", nargs="+", default=[], metavar="JSON",
                    help="include the rows of earlier real.json files (this run's rows win for the same log, map, base, method; "
                         "then the later file's)")  # fmt: skip
    args = ap.parse_args(argv)
    bad = [m for m in args.methods if m not in METHODS]
    if bad:
        ap.error(f"unknown method(s) {bad}; choose from {METHODS}")
    if not args.data.exists():
        print(f"no data at {args.data}", file=sys.stderr)
        return 1
    if args.unseen:
        args.names = args.names or UNSEEN_LOGS
        args.laserazos = False
        args.stem = args.stem or "real-unseen"
    if args.quick:
        names = args.names or QUICK_LOGS
        args.res = args.res or [0.10]
        args.laserazos = False
    else:
        names = args.names or DEFAULT_LOGS
        args.res = args.res or [0.05, 0.10]
    args.cache.mkdir(parents=True, exist_ok=True)
    args.work = args.cache / "work" / str(os.getpid())
    if args.compile:
        compile_measured_package(args.python)
    bases = fit_bases(args.data)
    t0 = time.perf_counter()
    print(HEADER)
    rows: list[dict] = []
    if args.merge_only:
        args.laserazos = args.laserazos_only = False
    elif not args.laserazos_only:
        for p in find_logs(args.data, names):
            try:
                rows.extend(evaluate_log(p, bases, args))
            except Exception as e:  # report and go on
                rows.append({"log": p.name, "map_res_m": 0.0, "base": "-", "method": "-", "error": f"{type(e).__name__}: {e}"})
                print(f"{p.name}: {type(e).__name__}: {e}", file=sys.stderr)
    if args.laserazos or args.laserazos_only:
        rows.extend(evaluate_laserazos(args))
    wall = time.perf_counter() - t0
    commands = [" ".join([Path(sys.executable).name, *sys.argv]) if argv is None else " ".join(argv)]
    if args.merge:
        # rows of earlier runs, replaced by this run's rows for the same cell and method
        key = lambda r: (r.get("log"), r.get("map_res_m"), r.get("base"), r.get("method"))  # noqa: E731
        # (and a later --merge file's rows replace an earlier one's: with --merge-only,
        # ``--merge results.json new.json`` puts new.json's cells into the table)
        mine = {key(r) for r in rows}
        old: list[dict] = []
        for f in reversed(args.merge):
            got = json.loads(Path(f).read_text())
            old.extend(r for r in got["rows"] if key(r) not in mine)
            mine |= {key(r) for r in got["rows"]}
            commands[:0] = [got["meta"]["command"]]
            wall += float(got["meta"].get("wall_s", 0.0))
        order = {m: i for i, m in enumerate(METHODS)}
        base_order = {"good": 0, "bad": 1, "real": 2}
        rows = sorted(
            old + rows,
            key=lambda r: (str(r.get("log")), base_order.get(r.get("base"), 3), r.get("map_res_m") or 0, order.get(r.get("method"), 9)),
        )
    stem = args.stem or ("real-quick" if args.quick else "real")
    args.out_dir.mkdir(parents=True, exist_ok=True)
    icploc_version = subprocess.run(
        [args.python, "-c", "import icploc, sys; sys.stdout.write(getattr(icploc, '__version__', '?') + ' ' + icploc.__file__)"],
        capture_output=True, text=True,
    ).stdout  # fmt: skip
    meta = {
        "command": " + ".join(commands),
        "amcl_settings": __import__("real_runners").AMCL_SETTINGS,
        "wall_s": wall,
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
        "icploc": icploc_version,
        "odometry_models": {k: v.summary() for k, v in bases.items()},
        "settings": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()},
        "mrpt": shutil.which("pf-localization"),
    }
    (args.out_dir / f"{stem}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1, default=float))
    md = [
        "# Real-data localization benchmark (benches/eval_real.py)",
        "",
        f"Command: `{meta['command']}`; {wall / 60:.1f} min of runs on {os.cpu_count()} shared cores. "
        "See the docstring of benches/eval_real.py for what is done to the data.",
        "",
        HEADER,
        *[_md_row(r) for r in rows if "map_res_m" in r and r.get("base") != "real"],
        "",
        *laserazos_table([r for r in rows if r.get("base") == "real"]),
        "Pooled over the radish cells (median of the per-cell medians and p95s, worst max, summed false tracking, "
        "total scans / total whole-process time):",
        "",
        "| method | cells | median cm | p95 cm | max cm | false tracking | scans/s |",
        "|---|---:|---:|---:|---:|---:|---:|",
        *pooled(rows),
        "",
        *targets(rows),
        "Odometry bases (fitted to freiburg_course odom vs scan-matched motions): "
        + "; ".join(
            f"{k}: scale {v.scale * 100:+.2f} %, rotation scale {v.turn_scale * 100:+.2f} %, "
            f"heading bias {math.degrees(v.bias):+.2f}°/m"
            for k, v in bases.items()
        ),
        "",
    ]
    (args.out_dir / f"{stem}.md").write_text("\n".join(md))
    if not args.keep_work:
        shutil.rmtree(args.work, ignore_errors=True)
    print("\n".join(md[-8:]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

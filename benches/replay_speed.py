r"""Whole-process speed of ``icploc replay`` on the real-data benchmark's cells, stage by
stage, side by side with MRPT ``pf-localization`` on the same files (ratios from one run).

    .venv/bin/python benches/replay_speed.py                       # aces + freiburg-101, 10 cm, good + bad
    .venv/bin/python benches/replay_speed.py aces --bases good --res 10 --no-mrpt
    .venv/bin/python benches/replay_speed.py --save /tmp/before.json      # keep the poses ...
    .venv/bin/python benches/replay_speed.py --check /tmp/before.json     # ... and compare later
    .venv/bin/python benches/replay_speed.py --cold                # no prepared-map cache
    .venv/bin/python benches/replay_speed.py --long intel          # a whole log, one process

The cells are those of ``benches/eval_real.py`` (3 folds per log: each fold is one log file,
one map and one start pose, read from its cache ``~/.cache/icploc-bench-real``; run
eval_real once to fill it). Every fold runs as its own process, as in eval_real, and that
process times its stages:

* ``start``: interpreter start until the child's first line (parent's launch clock to the
  child's ``time.time()``);
* ``import``: ``import icploc.cli`` (the command's process set-up, ``start_command_process``)
  and ``icploc.replay`` (+ the log and map readers it uses);
* ``map``: ``icploc.replay.load_map`` (YAML + PGM, line fit, or a prepared-map cache hit:
  the ``cache`` column says which; ``--cold`` sets ``ICPLOC_NO_CACHE``);
* ``index``: the map's ``MapIndex`` (k-d tree + closest-point grid) at the configured spacing;
* ``log``: reading and parsing the log (``ReplayResult.load_time``);
* ``loc``: the localize loop incl. the Localizer's set-up (``ReplayResult.localize_time``);
* ``rest``: the remainder of the whole process (result handling, the command's
  ``end_command_process``, interpreter exit).

``wall`` is the whole process as the parent saw it; ``cpu`` its user + system time. MRPT:
``pf-localization``'s own process (after the conversions, which are not counted), as in
eval_real. The machine is shared: compare the ratios of one run, not figures across runs.

``--long NAME,...``: instead of the folds, each named log as ONE process over the whole log (its
scans 0.5 m / 0.5 rad apart, as real logs keep them, with the ``--bases`` odometry), against a
map rasterised at ``--res`` from all its scans at the reference poses (as the issue's real
2-hour run was); short folds are dominated by the interpreter's start, a long run by the
localize loop. Its log and map are written once to ``~/.cache/icploc-bench-real/long``.

Python source files are byte-compiled first (``compileall``) when the environment says not
to write ``.pyc`` files (``PYTHONDONTWRITEBYTECODE``): an installed package has them, and
without them every process recompiles ~80 ms of source; ``--no-compile`` skips that.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

STAGES = ("start", "import", "map", "index", "log", "loc", "rest")


def child(log: str, map_yaml: str, pose: list[float], out: str, launched: float) -> None:
    t_first = time.time()
    p0 = time.process_time()  # CPU of the interpreter start (and up to here)
    c0 = time.perf_counter()
    # the process as the ``icploc`` command sets it up (and ends it): icploc.cli.main
    try:
        from icploc.cli import end_command_process, start_command_process
    except ImportError:  # a --before version without them: its command did neither

        def start_command_process() -> None:
            pass

        end_command_process = start_command_process
    start_command_process()
    import icploc.logs
    import icploc.maps  # noqa: F401
    from icploc.config import LocalizerConfig
    from icploc.replay import load_map, replay

    c1, p1 = time.perf_counter(), time.process_time()
    m = load_map(map_yaml)
    c2, p2 = time.perf_counter(), time.process_time()
    m.index(LocalizerConfig().map.spacing)
    c3, p3 = time.perf_counter(), time.process_time()
    res = replay(log, m, initial_pose=pose)
    c4, p4 = time.perf_counter(), time.process_time()
    got = {
        "poses": [[float(v) for v in e.pose] for e in res.estimates],
        "status": [str(e.status.value) for e in res.estimates],
        "cache": "hit" if "cache" in m.meta else "miss",
        "t": {
            "start": t_first - launched,
            "import": c1 - c0,
            "map": c2 - c1,
            "index": c3 - c2,
            "log": res.load_time,
            "loc": res.localize_time,
            "replay_other": (c4 - c3) - res.load_time - res.localize_time,
        },
        # CPU seconds (user + system) of the same stages; log + loc together
        "cpu": {
            "start": p0,
            "import": p1 - p0,
            "map": p2 - p1,
            "index": p3 - p2,
            "log+loc": p4 - p3,
        },
    }
    for p in got["poses"]:
        p[:] = [v if math.isfinite(v) else None for v in p]
    Path(out).write_text(json.dumps(got))
    end_command_process()


def _children_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def run_cli(python: str, cell: dict, tmp: Path, cold: bool) -> tuple[float, float]:
    """(wall s, CPU s) of the ``icploc replay`` command itself on the cell (its TUM file and
    summary written, as a user runs it), beside the interpreter ``python``."""
    env = dict(os.environ)
    if cold:
        env["ICPLOC_NO_CACHE"] = "1"
    exe = Path(python).parent / "icploc"
    cmd = [str(exe), "replay", cell["log_path"], "--map", cell["map"],
           "--initial-pose=" + ",".join(repr(v) for v in cell["pose"]),
           "--out", str(tmp / "cli.tum"), "--no-progress"]  # fmt: skip
    cpu0 = _children_cpu()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    if proc.returncode not in (0, 3):  # 3: finished, lost more than --max-lost
        raise RuntimeError(f"icploc replay exit {proc.returncode}: {proc.stderr.strip()[-400:]}")
    return wall, _children_cpu() - cpu0


def run_icploc(python: str, cell: dict, tmp: Path, cold: bool) -> dict:
    out = tmp / "icploc.json"
    env = dict(os.environ)
    if cold:
        env["ICPLOC_NO_CACHE"] = "1"
    cmd = [python, str(Path(__file__).resolve()), "--child", cell["log_path"], cell["map"],
           ",".join(repr(v) for v in cell["pose"]), str(out)]  # fmt: skip
    cpu0 = _children_cpu()
    launched = time.time()
    t0 = time.perf_counter()
    env["REPLAY_SPEED_LAUNCHED"] = repr(launched)
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, stdin=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    cpu = _children_cpu() - cpu0
    if proc.returncode != 0:
        raise RuntimeError(f"icploc child exit {proc.returncode}: {proc.stderr.strip()[-400:]}")
    got = json.loads(out.read_text())
    t = got["t"]
    t["loc"] += t.pop("replay_other")
    t["rest"] = wall - sum(t[k] for k in STAGES if k != "rest")
    got["wall"] = wall
    got["cpu"]["rest"] = cpu - sum(got["cpu"].values())
    got["cpu"]["total"] = cpu
    return got


def sparse_logs(names: list[str]) -> Iterator[tuple[str, Any, Any]]:
    """(name, corrected log, indices of the scans kept 0.5 m / 0.5 rad apart) of each log."""
    import eval_real as er
    import real_logs as rl

    for p in er.find_logs(er.DATA, names):
        log = rl.read_flaser(p)
        yield p.name.replace("-corrected.log.gz", ""), log, rl.sparsify(log.poses, distance=0.5, angle=0.5)


def cells_for(names: list[str], bases: list[str], res: list[int]) -> list[dict]:
    """(log, map, start pose) of every fold of eval_real's cells (reads the corrected logs)."""
    import eval_real as er
    import real_logs as rl

    cache = er.cache_dir()
    out = []
    for name, log, keep in sparse_logs(names):
        ref = log.poses
        gap = max(1, int(round(0.05 * len(log))))
        ends = rl.endpoints_world(log, 30.0)
        for f in rl.split_folds(ref[:, :2], 3, gap):
            _map_idx, loc, _covered = rl.map_scans_for(f, ends, keep)
            if len(loc) < 2:
                continue
            tag = f"{name}_k3_g{gap}_f{f.index}_r30_{er.SPLIT_VERSION}"
            for base in bases:
                for r in res:
                    cell = {
                        "log": name, "base": base, "res": r, "fold": f.index, "scans": len(loc),
                        "log_path": str(cache / "logs" / f"{name}_{base}_k3_f{f.index}_s0_{er.SPLIT_VERSION}.log"),
                        "map": str(cache / "maps" / f"{tag}_{r}cm.yaml"),
                        "pose": [float(v) for v in ref[loc[0]]],
                        "ranges": log.ranges[loc], "max_range": min(30.0, log.no_return),
                    }  # fmt: skip
                    if Path(cell["log_path"]).exists() and Path(cell["map"]).exists():
                        out.append(cell)
                    else:
                        print(f"skipping {name} {base} {r} cm fold {f.index}: not in the cache "
                              "(run benches/eval_real.py once)", file=sys.stderr)  # fmt: skip
    return out


def long_cells(names: list[str], bases: list[str], res: list[int]) -> list[dict]:
    """One cell per log, base and resolution: the whole log (sparsified) as one process."""
    import eval_real as er
    import real_grid as rg
    import real_logs as rl
    import real_odometry as ro

    out_dir = er.cache_dir() / "long"
    (out_dir / "maps").mkdir(parents=True, exist_ok=True)
    models = er.fit_bases(er.DATA)
    out = []
    for name, log, keep in sparse_logs(names):
        ref = log.poses
        max_range = min(30.0, log.no_return)
        stamps = er._stamps(log)
        for base in bases:
            log_path = out_dir / f"{name}_{base}_all_s0.log"
            if not log_path.exists():
                odom = ro.apply_model(models[base], ref, seed=er._seed(0, name, base))
                rl.write_flaser(log_path, log.ranges[keep], odom[keep], stamps[keep])
            for r in res:
                map_yaml = out_dir / "maps" / f"{name}_all_{r}cm.yaml"
                if not map_yaml.exists():
                    grid = rg.rasterise(log.ranges, log.angles, ref, r / 100.0, max_range)
                    rg.write_map_server(grid, map_yaml)
                out.append({
                    "log": name, "base": base, "res": r, "fold": "all", "scans": len(keep),
                    "log_path": str(log_path), "map": str(map_yaml),
                    "pose": [float(v) for v in ref[keep[0]]],
                    "ranges": log.ranges[keep], "max_range": max_range,
                })  # fmt: skip
    return out


def run_mrpt(cell: dict, tmp: Path) -> tuple[float, float]:
    """(wall s, CPU s) of pf-localization's own process on the cell."""
    import numpy as np
    import real_logs as rl
    import real_mrpt

    data = rl.read_flaser(Path(cell["log_path"]))
    got = real_mrpt.run_mrpt(
        tmp / "mrpt", np.asarray(cell["ranges"]), data.odom, Path(cell["map"]),
        tuple(cell["pose"]), cell["max_range"], 1800.0,
    )  # fmt: skip
    return float(got["time_s"]), float(got.get("cpu_s", math.nan))


def _same(a: dict, b: dict) -> tuple[float, int]:
    """(largest pose difference (m or rad), scans whose status differs)."""
    worst = 0.0
    for p, q in zip(a["poses"], b["poses"], strict=True):
        for u, v in zip(p, q, strict=True):
            if u is None or v is None:
                worst = max(worst, 0.0 if u is v else math.inf)
            else:
                d = abs(u - v)
                worst = max(worst, d if d < math.pi else abs(d - 2 * math.pi))
    return worst, sum(s != t for s, t in zip(a["status"], b["status"], strict=True))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        log, map_yaml, pose, out = argv[1:5]
        child(log, map_yaml, [float(v) for v in pose.split(",")], out,
              float(os.environ.get("REPLAY_SPEED_LAUNCHED", time.time())))  # fmt: skip
        return 0
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("names", nargs="*", default=["aces", "freiburg-101"])
    ap.add_argument("--bases", type=lambda s: s.split(","), default=["good", "bad"])
    ap.add_argument("--res", type=lambda s: [int(v) for v in s.split(",")], default=[10], help="cm")
    ap.add_argument("--python", default=sys.executable, help="interpreter whose icploc is measured")
    ap.add_argument("--before", metavar="PYTHON",
                    help="also run this interpreter's icploc on every cell (e.g. the base commit's), "
                    "interleaved, and report the speed-up from the same run")  # fmt: skip
    ap.add_argument("--no-mrpt", dest="mrpt", action="store_false")
    ap.add_argument("--cold", action="store_true", help="no prepared-map cache (ICPLOC_NO_CACHE=1)")
    ap.add_argument("--no-compile", dest="compile", action="store_false")
    ap.add_argument("--save", type=Path, help="write the poses and times (JSON)")
    ap.add_argument("--check", type=Path, help="compare the poses and status with a --save file")
    ap.add_argument("--cli", action="store_true",
                    help="also time the icploc replay command itself on every cell (typer's "
                    "option parsing included) and give its ratio to MRPT")  # fmt: skip
    ap.add_argument("--long", type=lambda s: s.split(","), metavar="NAME,...",
                    help="each named log whole, as one process (instead of the folds)")  # fmt: skip
    a = ap.parse_args(argv)
    if a.compile:
        from eval_real import compile_measured_package

        compile_measured_package(a.python)
        if a.before:
            compile_measured_package(a.before)
    cells = long_cells(a.long, a.bases, a.res) if a.long else cells_for(a.names, a.bases, a.res)
    if a.mrpt:
        import real_mrpt

        if not real_mrpt.available():
            print(
                "MRPT tools not found (apt-get install mrpt-apps): no MRPT column", file=sys.stderr
            )
            a.mrpt = False
    ref = json.loads(a.check.read_text()) if a.check else None
    cpu_rows: list[str] = []
    cli_rows: list[str] = []
    cli_tot = [0.0, 0.0, 0.0, 0.0]  # wall, CPU, MRPT wall, MRPT CPU
    befores: list[tuple[str, int, dict, dict, float, int]] = []
    print("| cell | scans | cache | " + " | ".join(f"{s} ms" for s in STAGES)
          + " | icploc wall s | cpu s | scans/s | MRPT s | MRPT scans/s | icploc / MRPT | same as --check |")  # fmt: skip
    print("|---|---:|---|" + "---:|" * len(STAGES) + "---:|---:|---:|---:|---:|---:|---|")
    rows = []
    mrpt_cpu_of: dict[str, float] = {}
    tot: dict[str, float] = {s: 0.0 for s in STAGES}
    tot_wall = tot_cpu = tot_mrpt = 0.0
    n_all = 0
    with tempfile.TemporaryDirectory(prefix="replay-speed-") as td:
        tmp = Path(td)
        for cell in cells:
            key = f"{cell['log']} {cell['base']} {cell['res']} cm f{cell['fold']}"
            if cell["fold"] == "all":
                key = f"{cell['log']} {cell['base']} {cell['res']} cm whole log"
            old = run_icploc(a.before, cell, tmp, a.cold) if a.before else None
            got = run_icploc(a.python, cell, tmp, a.cold)
            if old is not None:
                d, ns = _same(got, old)
                befores.append((key, cell["scans"], old, got, d, ns))
            mrpt_s, mrpt_cpu = run_mrpt(cell, tmp) if a.mrpt else (math.nan, math.nan)
            n = cell["scans"]
            if a.cli:
                cw, cc = run_cli(a.python, cell, tmp, a.cold)
                cli_tot = [cli_tot[0] + cw, cli_tot[1] + cc, cli_tot[2] + mrpt_s, cli_tot[3] + mrpt_cpu]
                cli_rows.append(f"| {key} | {n} | {cw:.3f} | {cc:.3f} | {got['wall']:.3f} | "
                                f"{mrpt_s:.3f} | {mrpt_cpu:.3f} | {mrpt_s / cw:.2f} | {mrpt_cpu / cc:.2f} |")  # fmt: skip
            same = "–"
            if ref is not None and key in ref:
                d, ns = _same(got, ref[key])
                same = f"max diff {d:.2g}, status diffs {ns}"
            rows.append((key, got, mrpt_s, same))
            mrpt_cpu_of[key] = mrpt_cpu
            for s in STAGES:
                tot[s] += got["t"][s]
            tot_wall += got["wall"]
            tot_cpu += got["cpu"]["total"]
            tot_mrpt += mrpt_s
            n_all += n
            sps = n / got["wall"]
            msps = n / mrpt_s if a.mrpt else math.nan
            cpu_rows.append(
                f"| {key} | " + " | ".join(f"{v * 1000:.0f}" for v in got["cpu"].values()) + " |"
            )
            print(f"| {key} | {n} | {got['cache']} | " + " | ".join(f"{got['t'][s] * 1000:.0f}" for s in STAGES)
                  + f" | {got['wall']:.3f} | {got['cpu']['total']:.3f} | {sps:,.0f} | {mrpt_s:.3f} | {msps:,.0f} | "
                  f"{sps / msps:.2f} | {same} |", flush=True)  # fmt: skip
    k = len(rows)
    if k:
        print(f"| all ({k} processes) | {n_all} | | " + " | ".join(f"{tot[s] / k * 1000:.0f}" for s in STAGES)
              + f" | {tot_wall:.3f} | {tot_cpu:.3f} | {n_all / tot_wall:,.0f} | {tot_mrpt:.3f} | "
              f"{n_all / tot_mrpt:,.0f} | {(n_all / tot_wall) / (n_all / tot_mrpt):.2f} | |")  # fmt: skip
        print(
            "(the stage columns of 'all' are per-process means; MRPT columns are nan without MRPT)"
        )
        print("\nCPU ms (user + system) per stage of each icploc process:\n")
        print("| cell | " + " | ".join(f"{k}" for k in rows[0][1]["cpu"]) + " |")
        print("|---|" + "---:|" * len(rows[0][1]["cpu"]))
        print("\n".join(cpu_rows))
        keys = list(rows[0][1]["cpu"])
        print(
            f"| mean of {k} | "
            + " | ".join(f"{sum(r[1]['cpu'][c] for r in rows) / k * 1000:.0f}" for c in keys)
            + " |"
        )
    if cli_rows:
        print("\nThe icploc replay command itself on the same cells (wall / CPU s of its process; "
              "the staged API process's wall beside it):\n")  # fmt: skip
        print("| cell | scans | command wall | command CPU | API wall | MRPT wall | MRPT CPU | "
              "MRPT / command, wall | MRPT / command, CPU |")  # fmt: skip
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
        print("\n".join(cli_rows))
        print(f"| all | {n_all} | {cli_tot[0]:.3f} | {cli_tot[1]:.3f} | {tot_wall:.3f} | "
              f"{cli_tot[2]:.3f} | {cli_tot[3]:.3f} | {cli_tot[2] / cli_tot[0]:.2f} | "
              f"{cli_tot[3] / cli_tot[1]:.2f} |")  # fmt: skip
    if befores:
        print(f"\nBefore ({a.before}) and after, the same cells in the same run (wall s / CPU s of the "
              "whole process; poses compared):\n")  # fmt: skip
        print("| cell | scans | before wall | after wall | before CPU | after CPU | speed-up wall | "
              "speed-up CPU | MRPT wall | after / MRPT | before / MRPT | MRPT CPU | CPU: MRPT / after | "
              "CPU: MRPT / before | same poses |")  # fmt: skip
        print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|")
        mrpt_of = {key: m for key, _g, m, _s in rows}
        tb = ta = cb = ca = tm = tmc = 0.0
        for key, n, old, got, d, ns in befores:
            m, mc = mrpt_of[key], mrpt_cpu_of[key]
            tb, ta, tm, tmc = tb + old["wall"], ta + got["wall"], tm + m, tmc + mc
            cb, ca = cb + old["cpu"]["total"], ca + got["cpu"]["total"]
            print(f"| {key} | {n} | {old['wall']:.3f} | {got['wall']:.3f} | {old['cpu']['total']:.3f} | "
                  f"{got['cpu']['total']:.3f} | {old['wall'] / got['wall']:.2f} | "
                  f"{old['cpu']['total'] / got['cpu']['total']:.2f} | {m:.3f} | {m / got['wall']:.2f} | "
                  f"{m / old['wall']:.2f} | {mc:.3f} | {mc / got['cpu']['total']:.2f} | "
                  f"{mc / old['cpu']['total']:.2f} | max diff {d:.2g}, status diffs {ns} |")  # fmt: skip
        print(f"| all | {n_all} | {tb:.3f} | {ta:.3f} | {cb:.3f} | {ca:.3f} | {tb / ta:.2f} | {cb / ca:.2f} | "
              f"{tm:.3f} | {tm / ta:.2f} | {tm / tb:.2f} | {tmc:.3f} | {tmc / ca:.2f} | {tmc / cb:.2f} | |")  # fmt: skip
        print(
            "('after / MRPT' is icploc's whole-process speed over MRPT's: MRPT time / icploc time; "
            "'CPU: MRPT / after' the same in CPU seconds, which the machine's load inflates far less)"
        )
        keys = list(befores[0][2]["cpu"])
        k = len(befores)
        print("\nMean CPU ms per process and stage, before -> after:\n")
        print("| stage | " + " | ".join(keys) + " |")
        print("|---|" + "---:|" * len(keys))
        for label, j in (("before", 2), ("after", 3)):
            print(f"| {label} | " + " | ".join(
                f"{sum(b[j]['cpu'][c] for b in befores) / k * 1000:.0f}" for c in keys) + " |")  # fmt: skip
    if a.save:
        a.save.write_text(json.dumps({key: got for key, got, _m, _s in rows}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What ``--mcap`` costs: a 2,000-scan replay with and without the Foxglove MCAP.

    .venv/bin/python benches/mcap_bench.py                 # simulated lab log
    .venv/bin/python benches/mcap_bench.py --real intel    # + a real log (../shared/data)

Logs:

* ``lab``: a simulated CARMEN log of the lab (2,000 scans x 361 beams, drifting
  odometry), the lab as a 5 cm ROS grid map (read back through ``Map.load``).
* ``--real NAME``: the first 2,000 scans (fewer if the log is shorter) of the corrected
  Radish log whose name contains NAME, its odometry as recorded, against a point map
  built from the log's odd-numbered scans at their corrected poses (as
  ``benches/eval_real.py`` does). Only the cost of the MCAP is measured here.

Times, alternating the variants ``--repeats`` times, medians reported:

* in-process ``icploc.replay.replay`` (parse + localize [+ MCAP, closed]) without and with
  the MCAP;
* the whole ``icploc replay LOG --map MAP [--mcap F]`` process (start-up included).

Target (issue 16): MCAP <= 20 % extra replay time.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from icploc import sim as worlds
from icploc.logs import open_log, write_carmen
from icploc.maps import Map
from icploc.mcap_export import McapRecorder, attach
from icploc.replay import replay

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def lab_log(d: Path, scans: int) -> tuple[Path, Path]:
    w = worlds.lab(people=2)
    map_yaml = Path(Map.from_lines(w.lines).to_ros(d / "lab.yaml", 0.05))
    path = worlds.tour_path(worlds.lab_random_walk(20.0, seed=100), laps=20)
    frames = list(worlds.simulate(w, path, seed=200, max_frames=scans))
    log = d / "lab.log"
    write_carmen(
        log,
        [f.scan for f in frames],
        [f.odometry for f in frames],
        poses=np.array([f.truth for f in frames]),
        scan_odometry=np.array([f.odometry.pose for f in frames]),
    )
    return log, map_yaml


def real_log(d: Path, name: str, scans: int) -> tuple[Path, Path]:
    sys.path.insert(0, str(Path(__file__).parent))
    from eval_real import build_map

    src = next(
        p for p in sorted((DATA / "radish_corrected_logs").glob("*.log.gz")) if name in p.name
    )
    data = open_log(src)
    ss = list(data.scans)[:scans]
    poses = np.asarray(data.truth_poses, dtype=np.float64)[: len(ss)]
    m = build_map(ss[1::2], poses[1::2], 30.0, 0.05)
    map_path = Path(m.save(d / f"{name}.npz"))
    odo = np.asarray(data.scan_odometry, dtype=np.float64)[: len(ss)]
    log = d / f"{name}.log"
    write_carmen(log, ss, [], poses=poses, scan_odometry=odo)
    return log, map_path


def bench(log: Path, map_path: Path, repeats: int, exe: str, d: Path) -> None:
    m = Map.load(map_path)
    n = replay(log, m).scans  # warm-up (and the scan count)
    t: dict[str, list[float]] = {"plain": [], "mcap": []}
    for _ in range(repeats):
        t0 = time.perf_counter()
        replay(log, m)
        t["plain"].append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        rec = McapRecorder(d / "bench.mcap")
        replay(log, m, on_localizer=lambda loc, r=rec: attach(loc, r))
        rec.close()
        t["mcap"].append(time.perf_counter() - t0)
    base = statistics.median(t["plain"])
    print(f"{log.name}: {n} scans, {os.path.getsize(d / 'bench.mcap') / 1e6:.1f} MB MCAP")
    for k, v in t.items():
        med = statistics.median(v)
        print(f"  replay() {k:16s} {med:.3f} s (median of {len(v)}), "
              f"{med / base - 1:+.0%} vs plain")  # fmt: skip
    cmd = [exe, "replay", str(log), "--map", str(map_path), "--no-progress"]
    proc: dict[str, list[float]] = {"plain": [], "mcap": []}
    for _ in range(repeats):
        for k, extra in (("plain", []), ("mcap", ["--mcap", str(d / "cli.mcap")])):
            t0 = time.perf_counter()
            subprocess.run(cmd + extra, check=True, stdout=subprocess.DEVNULL)
            proc[k].append(time.perf_counter() - t0)
    pb, pm = statistics.median(proc["plain"]), statistics.median(proc["mcap"])
    print(f"  icploc replay process: {pb:.2f} s plain, {pm:.2f} s with --mcap "
          f"({pm / pb - 1:+.0%})")  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scans", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--real", action="append", default=[], help="a corrected log name part")
    a = ap.parse_args()
    exe = shutil.which("icploc", path=str(Path(sys.executable).parent)) or "icploc"
    d = Path(tempfile.mkdtemp(prefix="icploc-mcap-bench-"))
    try:
        print(f"{os.cpu_count()} cores, load {os.getloadavg()[0]:.1f}")
        bench(*lab_log(d, a.scans), a.repeats, exe, d)
        for name in a.real:
            if not DATA.exists():
                print(f"{DATA} not found: skipping --real {name}")
                continue
            bench(*real_log(d, name, a.scans), a.repeats, exe, d)
        print(f"load after: {os.getloadavg()[0]:.1f}")
    finally:
        shutil.rmtree(d, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``icploc batch`` on a local Dask cluster vs the same logs replayed one after the other.

    .venv/bin/python benches/fleet_bench.py                # 8 logs x 2,500 scans
    .venv/bin/python benches/fleet_bench.py --logs 8 --scans 2500 --workers 2

Writes ``--logs`` simulated CARMEN logs of the lab (different random walks and noise
seeds, 361 beams, drifting odometry) and the lab as a 5 cm ROS grid map into a temporary
directory, then times, each as a whole process from the shell:

* sequential: ``icploc replay LOG --map MAP --out SEQ/<stem>.tum`` for every log in turn;
* batch: ``icploc batch LOG... --map MAP --out DIR --workers N`` (LocalCluster start-up
  and shut-down included).

and checks that every batch trajectory is byte-identical to its sequential replay.
Target (issue 16): batch <= 0.7 x sequential on a 2-core machine.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from icploc import sim as worlds
from icploc.logs import write_carmen
from icploc.maps import Map


def make_logs(d: Path, n_logs: int, scans: int) -> tuple[list[Path], Path]:
    w = worlds.lab(people=2)
    map_yaml = Map.from_lines(w.lines).to_ros(d / "lab.yaml", 0.05)
    logs = []
    for i in range(n_logs):
        path = worlds.tour_path(worlds.lab_random_walk(20.0, seed=100 + i), laps=20)
        frames = list(worlds.simulate(w, path, seed=200 + i, max_frames=scans))
        p = d / f"robot{i:02d}.log"
        write_carmen(
            p,
            [f.scan for f in frames],
            [f.odometry for f in frames],
            poses=np.array([f.truth for f in frames]),
            scan_odometry=np.array([f.odometry.pose for f in frames]),
        )
        logs.append(p)
    return logs, Path(map_yaml)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--logs", type=int, default=8)
    ap.add_argument("--scans", type=int, default=2500)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--keep", action="store_true", help="keep the temporary directory")
    a = ap.parse_args()
    exe = shutil.which("icploc", path=str(Path(sys.executable).parent)) or "icploc"
    d = Path(tempfile.mkdtemp(prefix="icploc-fleet-bench-"))
    try:
        logs, map_yaml = make_logs(d, a.logs, a.scans)
        print(f"{a.logs} logs x {a.scans} scans in {d}; {os.cpu_count()} cores, "
              f"load {os.getloadavg()[0]:.1f}")  # fmt: skip
        seq = d / "seq"
        seq.mkdir()
        t0 = time.perf_counter()
        for p in logs:
            subprocess.run(
                [exe, "replay", str(p), "--map", str(map_yaml), "--out",
                 str(seq / f"{p.stem}.tum"), "--no-progress"],
                check=True, stdout=subprocess.DEVNULL,
            )  # fmt: skip
        t_seq = time.perf_counter() - t0
        out = d / "batch"
        t0 = time.perf_counter()
        subprocess.run(
            [exe, "batch", *map(str, logs), "--map", str(map_yaml), "--out", str(out),
             "--workers", str(a.workers), "--no-progress"],
            check=True, stdout=subprocess.DEVNULL,
        )  # fmt: skip
        t_batch = time.perf_counter() - t0
        same = all(
            filecmp.cmp(seq / f"{p.stem}.tum", out / f"{p.stem}.tum", shallow=False) for p in logs
        )
        print(f"sequential replays: {t_seq:.2f} s")
        print(f"batch ({a.workers} workers): {t_batch:.2f} s")
        print(f"ratio batch / sequential: {t_batch / t_seq:.2f} (target <= 0.70)")
        print(f"trajectories identical: {same}")
        print(f"load after: {os.getloadavg()[0]:.1f}")
        return 0 if same else 1
    finally:
        if a.keep:
            print(f"kept {d}")
        else:
            shutil.rmtree(d, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())

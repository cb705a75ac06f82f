"""Log-reading throughput (scans/s, one core) of the CARMEN reader, and of the other logs.

    .venv/bin/python benches/read_throughput.py [--scans 5000] [--repeat 5] [--json]

* a generated CARMEN log: ``--scans`` FLASER lines × 361 beams (3 decimals, like real
  logs, 10 % max-range readings) with one ODOM line per scan, plain and gzipped; and its
  float fields alone through the reader's one float parser (the core's ``parse_floats``)
  and through ``numpy.fromstring`` (the pure-numpy engine it replaced);
* the time to iterate the merged Scan/Odometry stream (``for msg in log``);
* every log in ``../shared/data`` when present (parse only, best of ``--repeat``).

Context: a whole replay (parse + localize) must reach ≥ 5,000 scans/s on one core, so the
reader has to be several times faster than that.
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
from icploc.logs import open_log
from icploc.logs.carmen import flaser_angles, read_carmen, write_carmen
from icploc.messages import Odometry, Scan

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


def make_log(path: Path, n_scans: int, beams: int = 361, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    ang = flaser_angles(beams)
    scans = []
    odoms = []
    for k in range(n_scans):
        r = np.round(rng.uniform(0.3, 30.0, beams), 3)
        r[rng.random(beams) < 0.1] = np.inf
        scans.append(Scan(stamp=1000.0 + 0.1 * k, ranges=r, angles=ang, max_range=81.91))
        odoms.append(Odometry(stamp=1000.05 + 0.1 * k, pose=(0.01 * k, 0.0, 0.001 * k)))
    poses = np.column_stack(
        (np.arange(n_scans) * 0.01, np.zeros(n_scans), np.arange(n_scans) * 1e-3)
    )
    write_carmen(path, scans, odoms, poses=np.round(poses, 6), precision=3)


def best_of(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """(best wall time, best CPU time of this process) over ``repeat`` runs. On a shared
    machine the CPU time is the better estimate of what one free core would do."""
    ts = []
    cs = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        c0 = time.process_time()
        fn()
        cs.append(time.process_time() - c0)
        ts.append(time.perf_counter() - t0)
    return min(ts), min(cs)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--scans", type=int, default=5000)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--json", action="store_true", help="print the results as JSON")
    ap.add_argument("--no-shared", action="store_true", help="skip the logs in ../shared/data")
    args = ap.parse_args(argv)

    rows: list[dict[str, object]] = []

    def record(name: str, n: int, best: float, cpu: float, extra: str = "") -> None:
        cpu = max(cpu, 1e-9)
        rows.append(
            {
                "log": name,
                "scans": n,
                "wall_s": round(best, 4),
                "cpu_s": round(cpu, 4),
                "scans_per_s_wall": round(n / best),
                "scans_per_s_cpu": round(n / cpu),
                "note": extra,
            }
        )
        if not args.json:
            print(f"{name:42s} {n:6d} scans  wall {best * 1e3:7.1f} ms {n / best:8.0f}/s  "
                  f"cpu {cpu * 1e3:7.1f} ms {n / cpu:8.0f}/s  {extra}", flush=True)  # fmt: skip

    with tempfile.TemporaryDirectory() as td:
        plain = Path(td) / "gen361.log"
        gz = Path(td) / "gen361.log.gz"
        make_log(plain, args.scans)
        make_log(gz, args.scans)
        size_mb = plain.stat().st_size / 1e6
        if not args.json:
            print(f"generated: {args.scans} FLASER × 361 + {args.scans} ODOM, {size_mb:.1f} MB "
                  f"({gz.stat().st_size / 1e6:.1f} MB gz)")  # fmt: skip
        b, m = best_of(lambda: read_carmen(plain), args.repeat)
        record("generated 361-beam", args.scans, b, m)
        b, m = best_of(lambda: read_carmen(gz), args.repeat)
        record("generated 361-beam .gz", args.scans, b, m)
        # the reader's one float parser (the core's parse_floats) against numpy.fromstring,
        # the pure-numpy alternative it replaced, on the same text
        from icploc._core import parse_floats

        text = "\n".join(ln for ln in plain.read_text().splitlines() if ln.startswith("FLASER"))
        text = "\n".join(ln.split(None, 1)[1].rsplit(None, 2)[0] for ln in text.splitlines())
        b, m = best_of(lambda: parse_floats(text), args.repeat)
        record("floats: core parse_floats", args.scans, b, m, f"{len(text) / 1e6:.1f} MB")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            b, m = best_of(lambda: np.fromstring(text, dtype=np.float64, sep=" "), args.repeat)
        record("floats: numpy.fromstring (replaced)", args.scans, b, m, f"{len(text) / 1e6:.1f} MB")
        log = read_carmen(plain)
        b, m = best_of(lambda: sum(1 for _ in log), args.repeat)
        record("iterate merged stream (scans+odometry)", args.scans, b, m, f"{len(log)} messages")
        b, m = best_of(lambda: [s.points() for s in log.scans], max(1, args.repeat // 2))
        record("Scan.points() for every scan", args.scans, b, m)

    if SHARED.is_dir() and not args.no_shared:
        logs = sorted((SHARED / "radish_corrected_logs").glob("*.log.gz"))
        logs += [
            SHARED / "laserazosSM3" / "laserazosSM3.log",
            SHARED / "freiburg_course" / "csail.log",
        ]
        logs += [SHARED / "ros1_bag" / "laser_scan_matcher_demo.bag"]
        for p in logs:
            if not p.exists():
                continue
            d = open_log(p)
            b, m = best_of(functools.partial(open_log, p), max(1, min(args.repeat, 3)))
            i = d.info
            note = f"{'/'.join(map(str, i.beams))} beams, {i.n_odometry} odom, stamps {i.stamps}"
            record(p.name, i.n_scans, b, m, note)

    if args.json:
        json.dump({"python": sys.version.split()[0], "results": rows}, sys.stdout, indent=1)
        print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

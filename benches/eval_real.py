"""Localization on real laser data: the corrected logs in ../shared/data.

    .venv/bin/python benches/eval_real.py                  # every corrected log
    .venv/bin/python benches/eval_real.py intel aces       # logs whose name contains these
    .venv/bin/python benches/eval_real.py --split halves   # map from the first half only

These logs hold SLAM-corrected laser poses and **no raw odometry** (their ODOM stream
follows the corrected path; see ../shared/data/MANIFEST.md). So, honestly stated:

* the map is built from real scans at the corrected poses — but only from scans held out
  of the localization: ``--split alternate`` (default) maps with the odd-numbered scans
  and localizes the even-numbered ones; ``--split halves`` maps with the first half of
  the run and localizes the second half (areas first seen in the second half are then
  missing from the map, which the figures include);
* the map is the point cloud thinned to one point per 5 cm cell, normals estimated from
  neighbours (``Map.from_points``);
* odometry is synthesised from the corrected motion between localized scans with drift:
  +1 % distance scale, 0.5°/m heading bias, 1 cm/√m and 0.25°/√m random walk (seeded);
* the localizer starts at the first corrected pose and runs with default settings, except
  the range limit (the same for map and scans, ``--max-range``) and ``--metric``;
* ATE = position error against the corrected poses (both in the map frame, no alignment).

Logs without usable stamps are fine: odometry is handed to each scan directly.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
from icploc.config import LocalizerConfig
from icploc.localizer import Localizer
from icploc.logs import open_log
from icploc.maps import Map
from icploc.se2 import between, compose, transform_points
from numpy.typing import NDArray

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def corrected_logs(data: Path) -> list[Path]:
    logs = sorted((data / "radish_corrected_logs").glob("*-corrected.log.gz"))
    csail = data / "freiburg_course" / "csail.log"
    if csail.exists():
        logs.append(csail)
    return logs


def thin(points: NDArray[np.float64], cell: float) -> NDArray[np.float64]:
    """One point (the cell mean) per ``cell``-sized grid cell."""
    keys = np.floor(points / cell).astype(np.int64)
    _, inv, counts = np.unique(keys, axis=0, return_inverse=True, return_counts=True)
    inv = inv.reshape(-1)
    sums = np.zeros((counts.shape[0], 2))
    np.add.at(sums, inv, points)
    return sums / counts[:, None]


def build_map(scans: list[Any], poses: NDArray[np.float64], max_range: float, cell: float) -> Map:
    pts = []
    for s, p in zip(scans, poses, strict=True):
        xy = s.points(max_range=min(s.max_range, max_range))
        if len(xy):
            pts.append(transform_points(p, xy))
    return Map.from_points(thin(np.vstack(pts), cell))


def drifting_odometry(poses: NDArray[np.float64], seed: int) -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(seed)
    odo = [(0.0, 0.0, 0.0)]
    for a, b in zip(poses[:-1], poses[1:], strict=True):
        d = between(a, b)
        dist = math.hypot(d[0], d[1])
        scale = 1.01
        dth = (
            d[2]
            + math.radians(0.5) * dist
            + rng.normal(0.0, math.radians(0.25) * math.sqrt(dist) + 1e-6)
        )
        dx = d[0] * scale + rng.normal(0.0, 0.01 * math.sqrt(dist) + 1e-6)
        dy = d[1] * scale + rng.normal(0.0, 0.01 * math.sqrt(dist) + 1e-6)
        odo.append(compose(odo[-1], (dx, dy, dth)))
    return odo


def evaluate(
    path: Path,
    split: str,
    seed: int = 0,
    max_range: float = 30.0,
    metric: str = "point_to_line",
    relocalize: bool = True,
) -> dict[str, Any]:
    t0 = time.perf_counter()
    data = open_log(path)
    scans = list(data.scans)
    truth = np.asarray(data.truth_poses, dtype=np.float64)
    if len(truth) != len(scans) or len(scans) < 10:
        return {
            "log": path.name,
            "error": f"{len(scans)} scans, {len(truth)} corrected poses: skipped",
        }
    n = len(scans)
    if split == "alternate":
        map_idx = np.arange(1, n, 2)
        loc_idx = np.arange(0, n, 2)
    else:
        map_idx = np.arange(0, n // 2)
        loc_idx = np.arange(n // 2, n)
    m = build_map([scans[i] for i in map_idx], truth[map_idx], max_range, 0.05)
    t_load = time.perf_counter() - t0
    # localize with the same range limit the map was built with
    # relocalize: lost detection + global multi-hypothesis relocalization (the Localizer's
    # default); without it only the local recovery near the dead-reckoned pose
    cfg = LocalizerConfig().replace(
        scan={"max_range": max_range},
        icp={"metric": metric},
        localizer={"relocalization": "global" if relocalize else "local"},
    )
    P_true = truth[loc_idx]
    odo = drifting_odometry(P_true, seed)
    loc = Localizer(m, cfg, initial_pose=tuple(P_true[0]))
    est = []
    t1 = time.perf_counter()
    bad = 0
    for k, i in enumerate(loc_idx):
        e = loc.update(scans[i], odo[k])
        if not all(math.isfinite(v) for v in e.pose):
            bad += 1
        est.append(e)
    t_loc = time.perf_counter() - t1
    P = np.array([e.pose for e in est])
    err = np.hypot(*(P[:, :2] - P_true[:, :2]).T)
    eth = np.degrees(np.abs(np.angle(np.exp(1j * (P[:, 2] - P_true[:, 2])))))
    odo_map = np.array([compose(P_true[0], between(odo[0], o)) for o in odo])
    oerr = np.hypot(*(odo_map[:, :2] - P_true[:, :2]).T)
    dist = float(np.sum(np.hypot(*np.diff(P_true[:, :2], axis=0).T)))
    counts: dict[str, int] = {}
    for e in est:
        counts[e.status.value] = counts.get(e.status.value, 0) + 1
    return {
        "log": path.name,
        "scans_localized": len(loc_idx),
        "beams": len(scans[0]),
        "distance_m": dist,
        "map_points": len(m.sample(0.05)[0]) if hasattr(m, "sample") else None,
        "ate_rmse_m": float(np.sqrt(np.mean(err**2))),
        "ate_median_m": float(np.median(err)),
        "ate_p95_m": float(np.percentile(err, 95)),
        "ate_max_m": float(err.max()),
        "heading_max_deg": float(eth.max()),
        "odometry_ate_rmse_m": float(np.sqrt(np.mean(oerr**2))),
        "status": counts,
        "nan_poses": bad,
        "localize_scans_per_s": len(loc_idx) / t_loc,
        "load_and_map_s": t_load,
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("names", nargs="*", help="only logs whose file name contains one of these")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--split", choices=["alternate", "halves"], default="alternate")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--metric", choices=["point_to_line", "point_to_point"], default="point_to_line"
    )
    ap.add_argument(
        "--max-range", type=float, default=30.0, help="range limit for map and scans (m)"
    )
    ap.add_argument(
        "--local",
        dest="relocalize",
        action="store_false",
        help="localizer.relocalization: local (no kidnap detection, no global recovery; "
        "the default is the Localizer's: global)",
    )
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    if not args.data.exists():
        print(f"no data at {args.data}", file=sys.stderr)
        return 1
    logs = [
        p
        for p in corrected_logs(args.data)
        if not args.names or any(n in p.name for n in args.names)
    ]
    rows = []
    print(
        f"split: {args.split}; ICP {args.metric}; range limit {args.max_range} m; "
        "odometry synthesised with drift from the corrected motion\n"
    )
    print(
        "| log | scans | distance | ATE rmse | median | p95 | max | max heading | odometry ATE rmse | status | scans/s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|")
    for p in logs:
        try:
            r = evaluate(p, args.split, args.seed, args.max_range, args.metric, args.relocalize)
        except Exception as e:  # report and go on: one bad log must not hide the others
            r = {"log": p.name, "error": f"{type(e).__name__}: {e}"}
        rows.append(r)
        if "error" in r:
            print(f"| {r['log']} | – | – | – | – | – | – | – | – | {r['error']} | – |")
        else:
            print(
                f"| {r['log']} | {r['scans_localized']} | {r['distance_m']:.0f} m | {r['ate_rmse_m'] * 100:.1f} cm | "
                f"{r['ate_median_m'] * 100:.1f} cm | {r['ate_p95_m'] * 100:.1f} cm | {r['ate_max_m'] * 100:.1f} cm | "
                f"{r['heading_max_deg']:.1f}° | {r['odometry_ate_rmse_m']:.2f} m | {r['status']} | {r['localize_scans_per_s']:,.0f} |"
            )
        sys.stdout.flush()
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

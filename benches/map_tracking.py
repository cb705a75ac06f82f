"""Scan tracking on real 10 cm maps: the extracted map (lines + leftover points, point-to-line)
against point-to-point on the raw occupied cells of the same grid.

    .venv/bin/python benches/map_tracking.py [--log NAME ...] [--resolution 0.1]

For each corrected radish log: the map is built (``icploc map build``'s ray casting) from
the scans of the FIRST half at their corrected poses; the SECOND half is tracked: each scan
is aligned starting from a pose moved by the corrected motion plus drift (1 % scale,
0.5 deg/m heading, noise; the corrected logs hold no raw odometry). ``step``: from the
previous corrected pose (the one-step error of a fit); ``track``: from the previous
estimate (errors accumulate once a fit fails; plain ICP, no lost detection or recovery).
Error = distance to the corrected pose.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import icploc
import numpy as np
from icploc.logs import open_log
from icploc.maps import Map
from icploc.maps.build import build_grid
from icploc.se2 import between, compose
from icploc.trajectory import ErrorStats

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "radish_corrected_logs"


def track(scans, truth, index, cfg, seed: int, max_range: float, step: bool) -> np.ndarray:
    """Errors after each alignment; ``step``: every alignment starts from the previous
    *corrected* pose moved by the drifting motion (one-step error, nothing accumulates)."""
    rng = np.random.default_rng(seed)
    est = tuple(truth[0])
    errs = []
    for k in range(1, len(scans)):
        d = between(truth[k - 1], truth[k])
        dist = math.hypot(d[0], d[1])
        noisy = (
            d[0] * 1.01 + rng.normal(0, 0.01 * math.sqrt(dist) + 1e-6),
            d[1] * 1.01 + rng.normal(0, 0.01 * math.sqrt(dist) + 1e-6),
            d[2] + math.radians(0.5) * dist + rng.normal(0, math.radians(0.25) * math.sqrt(dist) + 1e-6),
        )
        guess = compose(tuple(truth[k - 1]) if step else est, noisy)
        xy = scans[k].points(max_range=min(scans[k].max_range, max_range))
        if len(xy) >= 10:
            try:
                r = icploc.icp(xy, index, guess, cfg)
                est = r.pose if r.converged else guess
            except icploc.IcpError:
                est = guess
        else:
            est = guess
        errs.append(math.hypot(est[0] - truth[k][0], est[1] - truth[k][1]))
    return np.array(errs)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--log", action="append", help="log name, e.g. intel (default: intel, aces, fhw)")
    ap.add_argument("--resolution", type=float, default=0.1)
    ap.add_argument("--max-range", type=float, default=30.0)
    a = ap.parse_args()
    for name in a.log or ["intel", "aces", "fhw"]:
        data = open_log(DATA / f"{name}-corrected.log.gz")
        scans = list(data.scans)
        truth = np.asarray(data.truth_poses)
        n = len(scans)
        g = build_grid(data, resolution=a.resolution, scans=slice(0, n // 2), max_range=a.max_range)
        extracted = g.to_map()
        raw = Map.from_points(extracted.cells_to_world(np.argwhere(g.occupied)[:, ::-1]))
        res = {}
        for label, m, metric in (
            ("extracted_point_to_line", extracted, "point_to_line"),
            ("extracted_point_to_point", extracted, "point_to_point"),
            ("raw_cells_point_to_point", raw, "point_to_point"),
        ):
            cfg = icploc.IcpConfig(metric=metric)
            for mode in ("step", "track"):
                e = track(
                    scans[n // 2 :], truth[n // 2 :], m.index(a.resolution), cfg, 0,
                    a.max_range, mode == "step",
                )
                stats = ErrorStats.of(e)
                res[f"{label}_{mode}"] = {
                    "median_m": round(stats.median, 4),
                    "p95_m": round(stats.p95, 4),
                    "over_10cm": round(float((e > 0.1).mean()), 4),
                }
        fit = extracted.meta["fit"]
        print(json.dumps({"log": name, "scans_tracked": n - n // 2, "grid": list(g.occupied.shape),
                          "lines": fit["lines"], "explained": fit["explained_fraction"], **res}))


if __name__ == "__main__":
    main()

"""The former benches/eval_real.py check, kept for tests/test_replay_real.py: the localizer
on held-out scans of a *dense* corrected log (map = 5 cm point cloud of the odd-numbered
scans at their corrected poses, localize the even-numbered ones with synthesised drifting
odometry). It flatters (same pass, exact point map, scans centimetres apart): it is a
regression check that the localizer works on real scans, not the benchmark; the benchmark
is benches/eval_real.py.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import numpy as np
from icploc.config import LocalizerConfig
from icploc.localizer import Localizer
from icploc.logs import open_log
from icploc.maps import Map
from icploc.se2 import between, compose, transform_points
from icploc.trajectory import ErrorStats, Trajectory, pose_errors
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
    err, hd = pose_errors(P, P_true)
    seq = np.arange(len(P_true), dtype=np.float64)
    odo_map = Trajectory(seq, np.asarray(odo, dtype=np.float64)).started_at(P_true[0]).poses
    oerr, _ = pose_errors(odo_map, P_true)
    dist = Trajectory(seq, P_true).path_length()
    ate, oate, eth = ErrorStats.of(err), ErrorStats.of(oerr), ErrorStats.of(hd)
    counts: dict[str, int] = {}
    for e in est:
        counts[e.status.value] = counts.get(e.status.value, 0) + 1
    return {
        "log": path.name,
        "scans_localized": len(loc_idx),
        "beams": len(scans[0]),
        "distance_m": dist,
        "map_points": len(m.sample(0.05)[0]) if hasattr(m, "sample") else None,
        "ate_rmse_m": ate.rmse,
        "ate_median_m": ate.median,
        "ate_p95_m": ate.p95,
        "ate_max_m": ate.max,
        "heading_max_deg": math.degrees(eth.max),
        "odometry_ate_rmse_m": oate.rmse,
        "status": counts,
        "nan_poses": bad,
        "localize_scans_per_s": len(loc_idx) / t_loc,
        "load_and_map_s": t_load,
    }

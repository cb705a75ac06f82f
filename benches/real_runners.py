"""Child processes of the real-data benchmark, one localizer per process so the parent
times the whole process (interpreter start, imports, map load, log parse, localization).

    python real_runners.py icploc LOG MAP.yaml OUT.json --pose=X,Y,THETA
    python real_runners.py numpy  LOG MAP.yaml OUT.json --pose=X,Y,THETA [--max-range R]
    python real_runners.py amcl   LOG MAP.yaml OUT.json --pose=X,Y,THETA [--max-range R] [--seed S]

Each writes ``{"poses": [[x, y, theta], ...], "status": [...] or null}``, one row per
FLASER line of LOG, in order.

* ``icploc``: the package's public Python path, ``icploc.replay.replay(LOG, MAP,
  initial_pose=...)`` with the default configuration (the function ``icploc replay``
  calls); the status is the Estimate's.
* ``numpy``: ``numpy_tracker.NumpyTracker`` (odometry predict + cKDTree point-to-point ICP)
  on the map's occupied cell centres.
* ``amcl``: nav2 AMCL through PyPI ``amcl`` (GPL: the ``bench`` extra only); see
  :func:`run_amcl` for its settings and the traps handled.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))


def _pose(text: str) -> tuple[float, float, float]:
    x, y, t = (float(v) for v in text.split(","))
    return (x, y, t)


def run_icploc(log: Path, map_yaml: Path, pose: tuple[float, float, float]) -> dict:
    from icploc.replay import replay

    res = replay(log, map_yaml, initial_pose=pose)
    poses = [[float(v) for v in e.pose] for e in res.estimates]
    status = [str(getattr(e.status, "value", e.status)) for e in res.estimates]
    return {
        "poses": poses,
        "status": status,
        "stamps": [float(e.stamp) for e in res.estimates],
        "parse_s": float(res.load_time),
        "localize_s": float(res.localize_time),
    }


def _scan_points(r, angles, max_range):  # type: ignore[no-untyped-def]
    import numpy as np

    v = (r > 0.05) & (r < max_range)
    return np.column_stack([r[v] * np.cos(angles[v]), r[v] * np.sin(angles[v])])


def run_numpy(log: Path, map_yaml: Path, pose: tuple[float, float, float], max_range: float) -> dict:
    from numpy_tracker import NumpyTracker
    from real_grid import read_map_server
    from real_logs import read_flaser

    grid = read_map_server(map_yaml)
    data = read_flaser(log)
    rmax = min(max_range, data.no_return)
    tr = NumpyTracker(grid.occupied_centres(), pose)
    ang = data.angles
    poses = []
    for r, o in zip(data.ranges, data.odom, strict=True):
        poses.append([float(v) for v in tr.update(_scan_points(r, ang, rmax), tuple(o))])
    return {"poses": poses, "status": None}


#: nav2 AMCL settings (PEERS.md: what worked best on real logs; nav2's defaults otherwise)
AMCL_SETTINGS = {
    "min_particles": 500,
    "max_particles": 2000,
    "alpha_slow": 0.0,
    "alpha_fast": 0.0,
    "alphas": (0.02, 0.02, 0.02, 0.02, 0.02),
    "update_min_d": 0.0,
    "update_min_a": 0.0,
    "max_beams": 180,  # PEERS.md: 180 beams worked best (nav2 default 60 was poor here too)
    "z_hit": 0.9,
    "z_rand": 0.1,
    "z_short": 0.0,
    "z_max": 0.0,
    "sigma_hit": 0.05,
    "lambda_short": 0.1,
    "init_std_xy": 0.1,
    "init_std_th": 0.05,
}


def _amcl_grid(grid, amcl):  # type: ignore[no-untyped-def]
    """nav2 grid: 0 free, 100 occupied, -1 unknown, rows = y; nav2 takes the map_server
    origin as the centre of cell 0, so a corner origin is given + res/2 (PEERS.md)."""
    import numpy as np

    data = np.full(grid.occupied.shape, -1, dtype=np.int64)
    data[grid.free] = 0
    data[grid.occupied] = 100
    half = grid.resolution / 2
    return amcl.create_occupancy_grid_from_list(
        data.tolist(), grid.resolution, grid.origin[0] + half, grid.origin[1] + half
    )


def run_amcl(
    log: Path, map_yaml: Path, pose: tuple[float, float, float], max_range: float, seed: int
) -> dict:
    """nav2 AMCL (PyPI ``amcl``): beam model (the wheel's only one), every scan updates
    (the logs are already 0.5 m / 0.5 rad apart, nav2's motion gating would pass each),
    recovery off (alpha_slow = alpha_fast = 0: the binding returns the mean of all
    particles, which with recovery on lands between hypotheses). Every beam is passed, a
    no-return as ``range_max`` (as nav2 gets them); ``max_beams`` is kept at most the beam
    count: with fewer beams than ``max_beams`` the binding's beam step is 0 and its update
    never returns.
    The binding is seeded by nav2's own code, not by ``seed``."""
    import amcl
    import numpy as np
    from real_grid import read_map_server
    from real_logs import read_flaser

    S = AMCL_SETTINGS
    grid = read_map_server(map_yaml)
    data = read_flaser(log)
    rmax = min(max_range, data.no_return)
    motion = amcl.MotionParameters(*S["alphas"])  # type: ignore[misc]
    laser = amcl.LaserParameters(
        S["z_hit"], S["z_short"], S["z_max"], S["z_rand"], S["sigma_hit"], S["lambda_short"],
        0.0, min(int(S["max_beams"]), data.ranges.shape[1]),
    )  # fmt: skip
    pf = amcl.AMCL(
        S["min_particles"], S["max_particles"], S["alpha_slow"], S["alpha_fast"], motion, laser, "differential"
    )  # fmt: skip
    pf.set_map(_amcl_grid(grid, amcl))
    pf.set_laser_pose(amcl.Vector3D(0.0, 0.0, 0.0))
    pf.set_initial_pose(
        amcl.Vector3D(*pose),
        amcl.create_diagonal_covariance(S["init_std_xy"] ** 2, S["init_std_xy"] ** 2, S["init_std_th"] ** 2),
    )
    ang = data.angles
    poses = []
    for r, o in zip(data.ranges, data.odom, strict=True):
        rr = np.where((r > 0.05) & (r < rmax), r, rmax)
        pairs = np.column_stack([rr, ang]).tolist()
        pf.update(amcl.create_laser_scan_from_list(pairs, rmax), amcl.Vector3D(*(float(x) for x in o)))
        m = pf.get_pose_mean()
        poses.append([float(m.x), float(m.y), float(m.theta)])
    return {"poses": poses, "status": None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("method", choices=["icploc", "numpy", "amcl"])
    ap.add_argument("log", type=Path)
    ap.add_argument("map", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--pose", type=_pose, required=True, help="X,Y,THETA start pose (m, m, rad)")
    ap.add_argument("--max-range", type=float, default=30.0)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    if a.method == "icploc":
        res = run_icploc(a.log, a.map, a.pose)
    elif a.method == "numpy":
        res = run_numpy(a.log, a.map, a.pose, a.max_range)
    else:
        res = run_amcl(a.log, a.map, a.pose, a.max_range, a.seed)
    for p in res["poses"]:
        for i, v in enumerate(p):
            if not math.isfinite(v):
                p[i] = None
    a.out.write_text(json.dumps(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

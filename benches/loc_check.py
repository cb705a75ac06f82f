"""Quick realistic localization check on real logs (issue 11), until benches/eval_real.py
is rebuilt.

    .venv/bin/python benches/loc_check.py intel fr079 csail       # names are substrings
    .venv/bin/python benches/loc_check.py intel --resolution 0.05 --seed 3 --json out.json

What it does, per log (a radish "corrected" log, or freiburg_course/csail.log):

* the scans are sparsified as real logs keep them: one per 0.5 m or 0.5 rad of the
  corrected path (``--step``, ``--turn``);
* the map is a map_server occupancy grid (YAML + PGM in a temporary directory) at
  ``--resolution`` (10 cm), rasterised from the **other** scans of the run (those not
  localized; on a log already that sparse — Intel, ACES, CSAIL — every other sparse scan
  goes to the map and the rest, ~1 m apart, are localized) at their corrected poses: a cell is occupied when at least ``--min-hits``
  beam endpoints fall in it, free when a beam crosses it; it is loaded by ``Map.load``
  like any user's map (the default, line-fitted path);
* odometry carries **real** odometry errors: the 2,000 paired motions of
  ../shared/data/freiburg_course (wheel odometry vs scan-matched) are walked in order from
  a seeded random start; each corrected step is split into sub-steps and each sub-step gets
  the relative error of the next real pair (its scale, lateral and heading error, scaled by
  how far the sub-step goes against how far the real motion went), so the systematic scale
  and heading bias of that base are kept;
* the localizer starts at the first corrected pose, default settings except the range limit;
* figures: position error median / p95 / max against the corrected poses, the count of
  scans reported ``tracking`` while more than 0.5 m off (false tracking), the share of lost
  scans, NEES of the tracking scans (mean of e' P^-1 e, 3 when the covariance is right), and
  the localize loop's scans/s (plus the whole process: map load included).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from icploc.config import LocalizerConfig
from icploc.localizer import Localizer
from icploc.logs import open_log
from icploc.maps import Map
from icploc.maps.ros import save_ros
from icploc.se2 import between, compose, transform_points
from icploc.trajectory import ErrorStats, Trajectory, pose_errors
from numpy.typing import NDArray

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ALIASES = {"fr079": "freiburg-079", "fr101": "freiburg-101", "campus": "freiburg-campus"}


def find_logs(data: Path, names: list[str]) -> list[Path]:
    logs = sorted((data / "radish_corrected_logs").glob("*-corrected.log.gz"))
    csail = data / "freiburg_course" / "csail.log"
    if csail.exists():
        logs.append(csail)
    if not names:
        return logs
    want = [ALIASES.get(n, n) for n in names]
    out = []
    for w in want:
        hit = [p for p in logs if w in p.name and p not in out]
        if w == "csail":  # the course log has real stamps; prefer it
            hit = [p for p in hit if p.parent.name == "freiburg_course"] or hit
        out.extend(hit[:1])
    return out


def sparsify(truth: NDArray[np.float64], step: float, turn: float) -> NDArray[np.int64]:
    keep = [0]
    for i in range(1, len(truth)):
        d = between(tuple(truth[keep[-1]]), tuple(truth[i]))
        if math.hypot(d[0], d[1]) >= step or abs(d[2]) >= turn:
            keep.append(i)
    return np.asarray(keep, dtype=np.int64)


def rasterise(
    scans: list[Any],
    poses: NDArray[np.float64],
    res: float,
    max_range: float,
    min_hits: int,
    out: Path,
) -> Path:
    """A map_server grid from scans at poses: occupied by endpoint hits, free where a beam
    passes (every 4th beam traced at half-cell steps)."""
    ends, origins = [], []
    for s, p in zip(scans, poses, strict=True):
        xy = s.points(max_range=min(s.max_range, max_range))
        if len(xy):
            ends.append(transform_points(tuple(p), xy))
            origins.append(np.repeat(np.asarray(p[:2])[None], len(xy), axis=0))
    E = np.vstack(ends)
    orig = np.vstack(origins)
    lo = E.min(axis=0) - 1.0
    hi = E.max(axis=0) + 1.0
    ox = math.floor(lo[0] / res) * res
    oy = math.floor(lo[1] / res) * res
    w = int(math.ceil((hi[0] - ox) / res)) + 1
    h = int(math.ceil((hi[1] - oy) / res)) + 1
    hits = np.zeros((h, w), dtype=np.int32)
    ij = np.floor((E - (ox, oy)) / res).astype(np.int64)
    np.add.at(hits, (ij[:, 1], ij[:, 0]), 1)
    occ = hits >= min_hits
    free = np.zeros((h, w), dtype=bool)
    sel = np.arange(0, len(E), 4)
    for a in range(0, len(sel), 20000):
        k = sel[a : a + 20000]
        v = E[k] - orig[k]
        L = np.hypot(v[:, 0], v[:, 1])
        n = np.maximum(1, (L / (res * 0.5)).astype(np.int64))
        tot = int(n.sum())
        rep = np.repeat(np.arange(len(k)), n)
        frac = (np.arange(tot) - np.repeat(np.cumsum(n) - n, n)) / np.repeat(n, n)
        pts = orig[k][rep] + v[rep] * frac[:, None]
        c = np.floor((pts - (ox, oy)) / res).astype(np.int64)
        free[c[:, 1], c[:, 0]] = True
    free &= ~occ
    yaml_path = out / "map.yaml"
    save_ros(yaml_path, occ, res, (ox, oy, 0.0), free=free)
    return yaml_path


def real_odometry(
    truth: NDArray[np.float64], data: Path, seed: int, scale_errors: float = 1.0
) -> NDArray[np.float64]:
    """Odometry along ``truth`` with the real errors of the freiburg_course base."""
    o = np.loadtxt(data / "freiburg_course" / "odom_motions.dat")
    s = np.loadtxt(data / "freiburg_course" / "scanmatched_motions.dat")
    size = np.hypot(s[:, 0], s[:, 1]) + 0.3 * np.abs(s[:, 2])
    moving = np.nonzero(size > 0.05)[0]  # motions big enough for a relative error
    pairs = []
    for i in moving:
        e = between(tuple(s[i]), tuple(o[i]))  # odometry relative to the true motion
        pairs.append((e, float(size[i])))
    rng = np.random.default_rng(seed)
    j = int(rng.integers(len(pairs)))
    odo = [(0.0, 0.0, 0.0)]
    for a, b in zip(truth[:-1], truth[1:], strict=True):
        d = between(tuple(a), tuple(b))
        dist, rot = math.hypot(d[0], d[1]), abs(d[2])
        n = max(1, math.ceil(dist / 0.12), math.ceil(rot / 0.1))
        sub = _root(d, n)  # n of these composed make d
        ssize = math.hypot(sub[0], sub[1]) + 0.3 * abs(sub[2])
        step = (0.0, 0.0, 0.0)
        for _ in range(n):
            e, esize = pairs[j]
            j = (j + 1) % len(pairs)
            f = scale_errors * min(1.5, ssize / esize)
            step = compose(step, compose(sub, (e[0] * f, e[1] * f, e[2] * f)))
        odo.append(compose(odo[-1], step))
    return np.asarray(odo)


def _root(d: tuple[float, float, float], n: int) -> tuple[float, float, float]:
    """The SE(2) motion whose n-fold composition is ``d`` (exp(log(d) / n))."""
    x, y, th = d
    if abs(th) < 1e-9:
        return (x / n, y / n, 0.0)
    # log: d = exp(v, w) with (x, y) = V(w) v, V = [[sin w, -(1 - cos w)], [1 - cos w, sin w]] / w
    a, b = math.sin(th) / th, (1.0 - math.cos(th)) / th
    det = a * a + b * b
    vx, vy = (a * x + b * y) / det, (-b * x + a * y) / det
    w = th / n
    a2, b2 = math.sin(w) / w, (1.0 - math.cos(w)) / w
    return (a2 * vx / n - b2 * vy / n, b2 * vx / n + a2 * vy / n, w)


def evaluate(
    path: Path,
    *,
    data: Path,
    res: float,
    step: float,
    turn: float,
    seed: int,
    max_range: float,
    min_hits: int,
    split: str,
    overrides: dict[str, dict[str, Any]],
    dump: Path | None = None,
    odom_scale: float = 1.0,
) -> dict[str, Any]:
    t0 = time.perf_counter()
    log = open_log(path)
    scans = list(log.scans)
    truth = np.asarray(log.truth_poses, dtype=np.float64)
    if len(truth) != len(scans):
        return {"log": path.name, "error": f"{len(scans)} scans, {len(truth)} poses"}
    n = len(scans)
    if split == "halves":
        half = n // 2
        loc_idx = half + sparsify(truth[half:], step, turn)
        if len(loc_idx) > (n - half) // 2:
            loc_idx = loc_idx[0::2]
        map_idx = np.arange(0, half)
    else:
        loc_idx = sparsify(truth, step, turn)
        if len(loc_idx) > n // 2:
            # an already sparse log: every other sparse scan goes to the map instead
            loc_idx = loc_idx[0::2]
        mask = np.ones(n, dtype=bool)
        mask[loc_idx] = False
        map_idx = np.nonzero(mask)[0]
    with tempfile.TemporaryDirectory(prefix="loc_check_") as tmp:
        yaml_path = rasterise(
            [scans[i] for i in map_idx], truth[map_idx], res, max_range, min_hits, Path(tmp)
        )
        t_map = time.perf_counter() - t0
        t1 = time.perf_counter()
        m = Map.load(yaml_path)
        cfg = LocalizerConfig().replace(scan={"max_range": max_range}, **overrides)
        P_true = truth[loc_idx]
        odo = real_odometry(P_true, data, seed, odom_scale)
        loc = Localizer(m, cfg, initial_pose=tuple(P_true[0]))
        t_setup = time.perf_counter() - t1
        est = []
        t2 = time.perf_counter()
        for k, i in enumerate(loc_idx):
            est.append(loc.update(scans[i], tuple(odo[k])))
        t_loc = time.perf_counter() - t2
    P = np.array([e.pose for e in est])
    err, _ = pose_errors(P, P_true)
    status = np.array([e.status.value for e in est])
    tracking = status == "tracking"
    false_tracking = int(np.sum(tracking & (err > 0.5)))
    first_false = int(np.argmax(tracking & (err > 0.5))) if false_tracking else -1
    nees = []
    for e, t in zip(est, P_true, strict=True):
        if e.status.value != "tracking":
            continue
        v = np.array(
            [t[0] - e.pose[0], t[1] - e.pose[1], math.remainder(t[2] - e.pose[2], math.tau)]
        )
        try:
            nees.append(float(v @ np.linalg.solve(e.covariance, v)))
        except np.linalg.LinAlgError:
            pass
    stamps = np.arange(len(odo), dtype=np.float64)
    odo_map = Trajectory(stamps, np.asarray(odo, dtype=np.float64)).started_at(P_true[0]).poses
    oerr, _ = pose_errors(odo_map, P_true)
    stats = ErrorStats.of(err)
    counts = {s: int(np.sum(status == s)) for s in ("tracking", "degraded", "lost")}
    lost = status == "lost"
    calib = getattr(est[-1], "calibration", None)
    row = {
        "log": path.name,
        "scans": len(loc_idx),
        "map_scans": len(map_idx),
        "distance_m": float(np.sum(np.hypot(*np.diff(P_true[:, :2], axis=0).T))),
        "median_cm": stats.median * 100,
        "p95_cm": stats.p95 * 100,
        "max_cm": stats.max * 100,
        "false_tracking": false_tracking,
        "first_false_tracking": first_false,
        "max_lost_err_cm": float(err[lost].max()) * 100 if lost.any() else 0.0,
        "status": counts,
        "nees_mean": float(np.mean(nees)) if nees else float("nan"),
        "nees_in_95": float(np.mean(np.array(nees) < 7.815)) if nees else float("nan"),
        "odometry_final_err_m": float(oerr[-1]),
        "odometry_max_err_m": float(oerr.max()),
        "scans_per_s": len(loc_idx) / t_loc,
        "setup_s": t_setup,
        "map_build_s": t_map,
        "calibration": None if calib is None else [float(v) for v in calib],
    }
    if dump is not None:
        with open(dump, "w") as fh:
            fh.write(
                "k,err,eth_deg,status,reason,nis,hit,rms,sig_xy,sig_th_deg,meas_err,inl,npts\n"
            )
            for k, (e, t) in enumerate(zip(est, P_true, strict=True)):
                me = (
                    math.hypot(e.measurement[0] - t[0], e.measurement[1] - t[1])
                    if e.measurement is not None
                    else float("nan")
                )
                eth = math.degrees(math.remainder(e.pose[2] - t[2], math.tau))
                sxy = math.sqrt(max(np.linalg.eigvalsh(e.covariance[:2, :2])[-1], 0.0))
                fh.write(
                    f"{k},{err[k]:.3f},{eth:.2f},{e.status.value},{e.reason},{e.nis:.1f},"
                    f"{e.hit_ratio:.2f},{e.residual:.3f},{sxy:.3f},"
                    f"{math.degrees(math.sqrt(e.covariance[2, 2])):.2f},{me:.3f},"
                    f"{e.inlier_ratio:.2f},{e.num_points}\n"
                )
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "names", nargs="*", help="logs whose file name contains these (intel, fr079, csail)"
    )
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--resolution", type=float, default=0.10)
    ap.add_argument("--step", type=float, default=0.5)
    ap.add_argument("--turn", type=float, default=0.5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-range", type=float, default=30.0)
    ap.add_argument("--min-hits", type=int, default=2)
    ap.add_argument("--split", choices=["interleaved", "halves"], default="interleaved")
    ap.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="a config override, e.g. localizer.fuse_odometry=false",
    )
    ap.add_argument("--json", type=Path)
    ap.add_argument("--dump", type=Path, help="per-scan CSV (one log)")
    ap.add_argument(
        "--odom-error-scale",
        type=float,
        default=1.0,
        help="multiply the real odometry errors (2: a worse base)",
    )
    args = ap.parse_args(argv)
    import yaml

    overrides: dict[str, dict[str, Any]] = {}
    for s in args.set:
        k, v = s.split("=", 1)
        sec, key = k.split(".", 1)
        overrides.setdefault(sec, {})[key] = yaml.safe_load(v)
    rows = []
    print(
        "| log | scans | median | p95 | max | false tracking | lost max | status | NEES | scans/s |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---|---:|---:|")
    for p in find_logs(args.data, args.names):
        r = evaluate(
            p,
            data=args.data,
            res=args.resolution,
            step=args.step,
            turn=args.turn,
            seed=args.seed,
            max_range=args.max_range,
            min_hits=args.min_hits,
            split=args.split,
            overrides=overrides,
            dump=args.dump,
            odom_scale=args.odom_error_scale,
        )
        rows.append(r)
        if "error" in r:
            print(f"| {r['log']} | {r['error']} |")
            continue
        print(
            f"| {r['log']} | {r['scans']} | {r['median_cm']:.1f} cm | {r['p95_cm']:.1f} cm | "
            f"{r['max_cm']:.0f} cm | {r['false_tracking']} (first {r['first_false_tracking']}) | "
            f"{r['max_lost_err_cm']:.0f} cm | {r['status']} | {r['nees_mean']:.1f} "
            f"({r['nees_in_95'] * 100:.0f}% <7.8) | {r['scans_per_s']:,.0f} |"
        )
        sys.stdout.flush()
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

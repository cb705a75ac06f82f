r"""Start refinement on real scans: correct and false locks from perturbed starts.

Usage::

    nice .venv/bin/python benches/startrefine_real.py                 # intel, freiburg-101, csail, aces, freiburg-079
    nice .venv/bin/python benches/startrefine_real.py aces --starts 6 # one log, fewer starts per fold

Maps: the 10 cm map_server grids ``benches/eval_real.py`` builds (same cache, same split:
each fold's starts are scans of that fold, localized against a map of the *other* folds).
Starts: per fold ``--starts`` scans spread over the fold; at each, two perturbations of
the reference pose per kind:

* ``in``: an error drawn from the covariance the localizer is told (sigma 0.3 m per axis,
  0.1 rad): the window (3 sigma) holds the truth;
* ``gross``: 1.5-3 m in a random direction and +-0.3 rad, the same stated covariance: the
  truth lies outside the window, the right answer is not to lock there.

The radish logs hold no stationary stretch (consecutive scans are centimetres to metres
apart), so each start feeds its one real scan ``--repeat`` (5) times with zero odometry:
the robot standing still, its scans' noise not averaged (the median of identical scans is
the scan). Outcomes after those scans:

* ``refine``: the verdict of :mod:`icploc.startrefine`; a lock is correct within 0.15 m and
  3 deg of the reference, false otherwise;
The "truth" of a start is the pose the map gives for its scan: the plain localizer
started at the reference pose, fed the scan; starts where that does not track (or lands
more than 0.3 m / 5 deg from the reference) are skipped and counted (the reference comes
from a SLAM run, the map from other passes: they disagree by up to decimetres in places).

* ``plain``: the Localizer without refinement, the same scans: ``tracking`` on the last one
  and right (correct) or wrong (a false lock: tracking promised, > 0.15 m / 3 deg off).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import eval_real as ev  # noqa: E402
import real_logs as rl  # noqa: E402

LOGS = ["intel", "freiburg-101", "csail", "aces", "freiburg-079"]
SIGMA_XY, SIGMA_TH = 0.3, 0.1
OK_XY, OK_TH = 0.15, math.radians(3.0)


def _ok(p: tuple[float, float, float], ref: np.ndarray) -> bool:
    d = math.hypot(p[0] - ref[0], p[1] - ref[1])
    a = abs(math.remainder(p[2] - ref[2], 2 * math.pi))
    return d <= OK_XY and a <= OK_TH


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("names", nargs="*")
    ap.add_argument("--starts", type=int, default=8, help="start scans per fold")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--res", type=float, default=0.10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--verbose", action="store_true", help="print each false lock")
    args = ap.parse_args(argv)

    from icploc.config import LocalizerConfig
    from icploc.localizer import Localizer, Status
    from icploc.maps import Map
    from icploc.messages import Scan
    from icploc.relocalize import GlobalRelocalization

    cache = ev.cache_dir()
    names = args.names or LOGS
    rng = np.random.default_rng(args.seed)
    tally: dict[tuple[str, str], dict[str, int]] = {}
    per_log: list[str] = []
    skipped: dict[str, int] = {}
    ref_shift: list[float] = []
    refine_times: list[float] = []
    t_all = time.perf_counter()
    for path in ev.find_logs(ev.DATA, names):
        log = rl.read_flaser(path)
        name = path.name.replace("-corrected.log.gz", "")
        ref = log.poses
        keep = rl.sparsify(ref, distance=0.5, angle=0.5)
        gap = max(1, int(round(0.05 * len(log))))
        folds = rl.split_folds(ref[:, :2], 3, gap)
        ends = rl.endpoints_world(log, 30.0)
        angles = log.angles
        mr = min(30.0, log.no_return)
        t_log = time.perf_counter()
        log_tally: dict[tuple[str, str], dict[str, int]] = {}
        for f in folds:
            map_idx, loc_idx, _ = rl.map_scans_for(f, ends, keep)
            if len(loc_idx) < 2:
                continue
            tag = f"{name}_k3_g{gap}_f{f.index}_r30_{ev.SPLIT_VERSION}"
            yaml = ev.build_map(cache, tag, log, map_idx, args.res, 30.0)
            m = Map.load(yaml)
            cfg = LocalizerConfig()
            rec = GlobalRelocalization.deferred()
            picks = np.asarray(loc_idx)[np.linspace(0, len(loc_idx) - 1, args.starts).round().astype(int)]
            for k in picks:
                r = log.ranges[k].astype(np.float64).copy()
                r[~(r < log.no_return)] = np.inf
                r[r > mr] = np.inf
                # the pose the map gives for this scan: the plain localizer started at the
                # reference and fed the scan; a start where it does not track, or lands
                # more than 0.3 m / 5 deg from the reference, is skipped (the map from the
                # other passes does not pin the place down there)
                probe = Localizer(m, cfg, initial_pose=tuple(ref[k]), recovery=rec)
                for j in range(args.repeat):
                    pe = probe.update(Scan(float(j) * 0.2, r, angles, max_range=mr), (0.0, 0.0, 0.0))
                d_ref = math.hypot(pe.pose[0] - ref[k][0], pe.pose[1] - ref[k][1])
                a_ref = abs(math.remainder(pe.pose[2] - ref[k][2], 2 * math.pi))
                if pe.status is not Status.TRACKING or d_ref > 0.3 or a_ref > math.radians(5.0):
                    skipped[name] = skipped.get(name, 0) + 1
                    continue
                truth = np.asarray(pe.pose)
                ref_shift.append(d_ref)
                for kind in ("in", "in", "gross", "gross"):
                    if kind == "in":
                        off = rng.normal(0.0, [SIGMA_XY, SIGMA_XY, SIGMA_TH])
                    else:
                        a = rng.uniform(-math.pi, math.pi)
                        d = rng.uniform(1.5, 3.0)
                        off = np.array([d * math.cos(a), d * math.sin(a), rng.uniform(-0.3, 0.3)])
                    given = (float(truth[0] + off[0]), float(truth[1] + off[1]),
                             float(math.remainder(truth[2] + off[2], 2 * math.pi)))  # fmt: skip
                    cov = np.diag([SIGMA_XY**2, SIGMA_XY**2, SIGMA_TH**2])
                    for method in ("plain", "refine"):
                        loc = Localizer(m, cfg, initial_pose=given, recovery=rec)
                        loc.reset(given, cov)
                        ref_ = loc.refine_start() if method == "refine" else None
                        e = None
                        t0 = time.perf_counter()
                        for j in range(args.repeat):
                            scan = Scan(float(j) * 0.2, r, angles, max_range=mr)
                            e = loc.update(scan, (0.0, 0.0, 0.0))
                            if ref_ is not None and ref_.verdict is not None:
                                break
                        assert e is not None
                        if method == "refine":
                            refine_times.append(time.perf_counter() - t0)
                        if method == "plain":
                            tracking = e.status is Status.TRACKING
                            right = _ok(e.pose, truth)
                            out = "correct" if tracking and right else ("false" if tracking else "no_lock")
                        else:
                            v = ref_.verdict if ref_ is not None else None
                            if v is None:
                                out = "undecided"
                            elif v.verdict == "refined":
                                out = "correct" if _ok(v.pose, truth) else "false"
                                if out == "false" and args.verbose:
                                    err = (v.pose[0] - truth[0], v.pose[1] - truth[1],
                                           math.degrees(math.remainder(v.pose[2] - truth[2], 2 * math.pi)))  # fmt: skip
                                    print(f"    false lock {name} scan {k} {kind}: off {np.round(off, 2)}, "
                                          f"error {np.round(err, 2)}; sd {np.round(np.sqrt(np.linalg.eigvalsh(v.covariance[:2, :2])), 3)} {math.degrees(math.sqrt(v.covariance[2, 2])):.2f}deg; {v.summary()}")  # fmt: skip
                            else:
                                out = v.verdict
                        for t in (tally, log_tally):
                            t.setdefault((kind, method), {}).setdefault(out, 0)
                            t[(kind, method)][out] += 1
        dt = time.perf_counter() - t_log
        per_log.append(f"{name}: {dt:.1f} s " + "; ".join(
            f"{k}/{me}: " + ", ".join(f"{o} {c}" for o, c in sorted(v.items()))
            for (k, me), v in sorted(log_tally.items())
        ))  # fmt: skip
        print(per_log[-1] + f" (starts skipped: {skipped.get(name, 0)})", flush=True)
    print(f"\nall logs ({time.perf_counter() - t_all:.0f} s); starts skipped (no map fix there): "
          f"{sum(skipped.values())}; map fix vs reference: median {np.median(ref_shift) * 100:.1f} cm; "
          f"refinement time per start (to the verdict, incl. the first global grid build): median "
          f"{np.median(refine_times) * 1000:.0f} ms, p95 {np.percentile(refine_times, 95) * 1000:.0f} ms")  # fmt: skip
    for (kind, method), v in sorted(tally.items()):
        n = sum(v.values())
        parts = ", ".join(f"{o} {c} ({c / n:.0%})" for o, c in sorted(v.items()))
        print(f"  {kind:5s} {method:6s} n={n}: {parts}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Where icploc's large errors on the real-data benchmark come from, scan by scan.

    .venv/bin/python benches/real_breakdown.py csail:0.05:good intel:0.05:bad [--csv DIR]

Each cell ``log:resolution:base`` is replayed in this process (``icploc.replay.replay``, the
default configuration, the same cached logs, maps and start poses as ``benches/eval_real.py``
uses; run that once first so the cache holds them). Per cell it prints median / p95 / max
position error and, for the scans at or above the p95, what the localizer did there: the
status and reason, whether the scan match was accepted, how far the scan match itself and the
odometry prediction were from the reference; the CSV also holds the evidence at the
reference pose itself on tracking scans (``hit_truth``, ``truth_verified``: whether the scan
could verify there at all, i.e. whether the information to correct a drift was there). It
also prints the consistency of the covariances against the reference: the NEES (3 dof; mean 3 when a covariance is right) of the
scan match's covariance ``R`` on accepted fits, of the prediction's ``P`` and of the reported
pose's covariance on tracking scans.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from icploc.status import LOCK_REASONS
from numpy.typing import NDArray

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import eval_real as ev  # noqa: E402
import real_logs as rl  # noqa: E402


def _nees(e: NDArray[np.float64], cov: NDArray[np.float64]) -> float:
    try:
        return float(e @ np.linalg.solve(cov, e))
    except np.linalg.LinAlgError:
        return math.inf


def cell_rows(name: str, res: float, base: str, config: Any = None, cache: Path | None = None) -> list[dict]:
    """Replay one cell (all folds); one dict per localized scan."""
    from icploc.replay import replay
    from icploc.se2 import wrap_angle

    cache = cache or ev.cache_dir()
    path = next(p for p in ev.find_logs(ev.DATA, [name]) if p.name.startswith(name + "-"))
    log = rl.read_flaser(path)
    stamps = ev._stamps(log)
    gap = max(1, int(round(0.05 * len(log))))
    rows: list[dict] = []
    for f in range(3):
        log_path = cache / "logs" / f"{name}_{base}_k3_f{f}_s0_{ev.SPLIT_VERSION}.log"
        map_path = cache / "maps" / f"{name}_k3_g{gap}_f{f}_r30_{ev.SPLIT_VERSION}_{int(round(res * 100))}cm.yaml"
        if not (log_path.exists() and map_path.exists()):
            raise FileNotFoundError(f"{log_path} / {map_path}: run benches/eval_real.py on this cell first")
        sub = rl.read_flaser(log_path)
        loc = np.searchsorted(stamps, sub.stamps - 1e-4)
        ref = log.poses[loc]
        quality = _record_quality(ref)
        try:
            out = replay(log_path, map_path, config=config, initial_pose=tuple(float(v) for v in ref[0]))
        finally:
            quality.stop()
        moved = 0.0
        for k, e in enumerate(out.estimates):
            r = ref[k]
            err = np.array([e.pose[0] - r[0], e.pose[1] - r[1], wrap_angle(e.pose[2] - r[2])])
            row: dict[str, Any] = {
                "fold": f, "k": k, "err": float(math.hypot(err[0], err[1])), "err_th": float(err[2]),
                "status": e.status.value, "reason": str(e.reason), "accepted": bool(e.accepted),
                "nis": float(e.nis), "hit": float(e.hit_ratio), "residual": float(e.residual), "inlier_ratio": float(e.inlier_ratio),
                "degeneracy": float(e.degeneracy), "nees": _nees(err, e.covariance),
            }  # fmt: skip
            # errors split along / across the reference heading (a corridor's axis when driving along it)
            c, s_ = math.cos(r[2]), math.sin(r[2])
            row["err_fwd"], row["err_lat"] = float(c * err[0] + s_ * err[1]), float(-s_ * err[0] + c * err[1])
            if k > 0:
                d_ref = ref[k, :2] - ref[k - 1, :2]
                d_odo = sub.poses[k, :2] - sub.poses[k - 1, :2]
                row["step_ref"], row["step_odo"] = float(np.hypot(*d_ref)), float(np.hypot(*d_odo))
            p = e.prediction
            pe = np.array([p[0] - r[0], p[1] - r[1], wrap_angle(p[2] - r[2])])
            row["pred_err"] = float(math.hypot(pe[0], pe[1]))
            row["pred_th"] = float(pe[2])
            row["pred_fwd"] = float(c * pe[0] + s_ * pe[1])
            row["cal_scale"], row["cal_turn"], row["cal_drift"] = (float(v) for v in e.calibration)
            row["sig_xy"] = float(math.sqrt(max(e.covariance[0, 0] + e.covariance[1, 1], 0.0)))
            row["sig_th"] = float(math.sqrt(max(e.covariance[2, 2], 0.0)))
            if e.measurement is not None and e.measurement_covariance is not None:
                z = e.measurement
                ze = np.array([z[0] - r[0], z[1] - r[1], wrap_angle(z[2] - r[2])])
                row["meas_err"] = float(math.hypot(ze[0], ze[1]))
                row["meas_nees"] = _nees(ze, e.measurement_covariance)
                row["meas_th"] = float(ze[2])
                R = e.measurement_covariance
                row["meas_fwd"] = float(c * ze[0] + s_ * ze[1])
                w, v = np.linalg.eigh(np.asarray(R[:2, :2], dtype=float))
                row["meas_sig_weak"] = float(math.sqrt(max(w[-1], 0.0)))
                row["meas_weak_vs_heading"] = float(wrap_angle(math.atan2(v[1, -1], v[0, -1]) - r[2]))
                row["meas_sig_xy"] = float(math.sqrt(max(R[0, 0] + R[1, 1], 0.0)))
                row["meas_sig_th"] = float(math.sqrt(max(R[2, 2], 0.0)))
                row["meas_nees_xy"] = _nees(ze[:2], R[:2, :2])
                row["meas_nees_th"] = float(ze[2] ** 2 / R[2, 2]) if R[2, 2] > 0 else math.inf
            if k < len(quality.seen):
                # the map quality after the scan (what the next scan is checked against)
                row["sigma"], row["hit_ref"], row["hit_measured"] = quality.seen[k]
            if k in quality.fits:
                row["hit_fit"], row["hit_pred"], row["fit_verified"] = quality.fits[k]
            if k in quality.truth:
                # the evidence at the reference pose itself: whether the scan could verify here at all
                row["hit_truth"], row["truth_verified"] = quality.truth[k]
            if k in quality.coasts:
                # while lost: how far the coasting fit moved the pose from the dead reckoning
                row["coast_fused"], row["coast_move"] = quality.coasts[k]
            # while lost: how far the coasting fits moved the pose from the dead reckoning since
            # the localizer was declared lost, summed (0: the dead-reckoned continuation)
            if e.status.value == "lost":
                moved += row.get("coast_move", 0.0) if row.get("coast_fused") else 0.0
                row["coast_total"] = moved
            else:
                moved = 0.0
            rows.append(row)
    return rows


class _record_quality:
    """Records ``Localizer.quality`` (sigma, usual hit share, measured) after each update
    while active (the replay builds its own Localizer)."""

    def __init__(self, ref: Any = None) -> None:
        from icploc.localizer import Localizer

        self.seen: list[tuple[float, float, bool]] = []
        self._cls = Localizer
        self._orig = Localizer.update
        orig, seen = self._orig, self.seen

        def update(loc: Any, *a: Any, **kw: Any) -> Any:
            out = orig(loc, *a, **kw)
            q = loc.quality
            seen.append((float(q.sigma), float(q.hit_reference), bool(q.hit_measured)))
            return out

        #: per tracking scan: (hit share at the fit, at the prediction, whether the fit verified)
        self.fits: dict[int, tuple[float, float, bool]] = {}
        #: per tracking scan, given the reference poses ``ref``: (hit share at the reference
        #: pose, whether it verifies)
        self.truth: dict[int, tuple[float, bool]] = {}
        truth = self.truth
        self._orig_tr = Localizer._update_tracking
        orig_tr, fits = self._orig_tr, self.fits

        def update_tracking(loc: Any, scan: Any, pts: Any, pred: Any, *a: Any, **kw: Any) -> Any:
            est = orig_tr(loc, scan, pts, pred, *a, **kw)
            if est.measurement is not None:
                at_z = loc.checker.check(pts, est.measurement)
                at_pred = loc.checker.check(pts, pred)
                fits[len(seen)] = (float(at_z.hit), float(at_pred.hit), bool(loc._verified(at_z)))
            if ref is not None and len(seen) < len(ref):
                r = tuple(float(v) for v in ref[len(seen)])
                at_ref = loc.checker.check(pts, r)
                truth[len(seen)] = (float(at_ref.hit), bool(loc._verified(at_ref)))
            return est

        #: per lost scan that tried a coasting fit: (fused, distance the pose moved)
        self.coasts: dict[int, tuple[bool, float]] = {}
        self._orig_coast = Localizer._coast
        orig_coast, coasts = self._orig_coast, self.coasts

        def coast(loc: Any, pts: Any, pred: Any, *a: Any, **kw: Any) -> Any:
            out = orig_coast(loc, pts, pred, *a, **kw)
            coasts[len(seen)] = (bool(out[2]), float(math.hypot(out[0][0] - pred[0], out[0][1] - pred[1])))
            return out

        Localizer.update = update  # type: ignore[method-assign]
        Localizer._update_tracking = update_tracking  # type: ignore[method-assign]
        Localizer._coast = coast  # type: ignore[method-assign]

    def stop(self) -> None:
        self._cls.update = self._orig  # type: ignore[method-assign]
        self._cls._update_tracking = self._orig_tr  # type: ignore[method-assign]
        self._cls._coast = self._orig_coast  # type: ignore[method-assign]


def describe(rows: list[dict], label: str) -> str:
    err = np.array([r["err"] for r in rows])
    p95 = float(np.percentile(err, 95, method="higher"))
    false = sum(1 for r in rows if r["status"] == "tracking" and r["err"] > 0.5)
    lines = [
        f"## {label}: {len(rows)} scans, median {np.median(err) * 100:.1f} / p95 {p95 * 100:.1f} / max {err.max() * 100:.1f} cm,"
        f" false tracking {false}"
    ]
    st = Counter(r["status"] for r in rows)
    lines.append("status: " + ", ".join(f"{k} {v}" for k, v in sorted(st.items())))
    far = [r for r in rows if r["status"] == "lost" and r["err"] > 5.0]
    if far:
        lines.append(
            f"lost > 5 m off: {len(far)} (coasting fits moved the pose > 1 m since lost on "
            f"{sum(1 for r in far if r.get('coast_total', 0.0) > 1.0)}; the rest dead-reckoned)"
        )
    tail = [r for r in rows if r["err"] >= p95]
    lines.append("at or above p95: " + ", ".join(f"{k} {v}" for k, v in Counter(f"{r['status']}/{r['reason'] or '-'}" for r in tail).most_common()))
    acc = [r for r in rows if r["accepted"] and "meas_nees" in r and r["reason"] not in LOCK_REASONS]
    if acc:
        mn = np.array([r["meas_nees"] for r in acc])
        lines.append(f"scan-match NEES (accepted, n={len(acc)}): median {np.median(mn):.2f}, mean {np.mean(np.minimum(mn, 1e3)):.2f}, share > chi2(0.99) {np.mean(mn > 11.345) * 100:.0f} %")
    tr = [r for r in rows if r["status"] == "tracking"]
    if tr:
        nn = np.array([r["nees"] for r in tr])
        lines.append(f"reported NEES (tracking, n={len(tr)}): median {np.median(nn):.2f}, share > chi2(0.99) {np.mean(nn > 11.345) * 100:.0f} %")
    worst = sorted(rows, key=lambda r: -r["err"])[:8]
    lines.append("worst: " + "; ".join(
        f"f{r['fold']}#{r['k']} {r['err'] * 100:.0f}cm {r['status']}/{r['reason'] or '-'} pred {r['pred_err'] * 100:.0f} meas "
        f"{r.get('meas_err', math.nan) * 100:.0f} nis {r['nis']:.1f} hit {r['hit']:.2f}" for r in worst))  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cells", nargs="+", help="log:resolution:base, e.g. csail:0.05:good")
    ap.add_argument("--csv", type=Path, help="write each cell's per-scan rows here")
    ap.add_argument("--config", type=Path, help="a localizer config file (default: the defaults)")
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one setting (YAML value), e.g. localizer.scan_independent_beams=3")
    args = ap.parse_args(argv)
    config = None
    if args.config or args.set:
        import yaml
        from icploc.config import LocalizerConfig

        data: dict[str, dict[str, Any]] = yaml.safe_load(args.config.read_text()) if args.config else {}
        for kv in args.set:
            key, value = kv.split("=", 1)
            sec, field = key.split(".")
            try:
                v: Any = float(value)  # YAML reads 4e-3 as a string
            except ValueError:
                v = yaml.safe_load(value)
            data.setdefault(sec, {})[field] = v
        config = LocalizerConfig.from_dict(data)
    for c in args.cells:
        name, res, base = c.split(":")
        rows = cell_rows(name, float(res), base, config)
        print(describe(rows, c), flush=True)
        if args.csv:
            import csv

            args.csv.mkdir(parents=True, exist_ok=True)
            keys = sorted({k for r in rows for k in r})
            with open(args.csv / f"{name}_{int(float(res) * 100)}cm_{base}.csv", "w", newline="") as fh:
                w = csv.DictWriter(fh, keys)
                w.writeheader()
                w.writerows(rows)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

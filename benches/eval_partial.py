r"""Partial maps on real data (issue 17): a map of the first half of a log, the whole log
localized against it.

Usage::

    .venv/bin/python benches/eval_partial.py                  # aces, intel, freiburg-101
    .venv/bin/python benches/eval_partial.py aces --methods icploc,icploc-plain,mrpt
    .venv/bin/python benches/eval_partial.py aces freiburg-101 --methods icploc,icploc-full,icploc-crop --seeds 0-7

What is done (reusing benches/eval_real.py, seeded):

* the radish corrected log's poses are the reference; raw odometry from the real error model
  of benches/real_odometry.py (base ``good``); scans kept sparsely (0.5 m / 0.5 rad);
* the **partial map**: a 10 cm map_server grid (benches/real_grid.py ray casting) from the
  **first half**: every second kept scan there and the dense scans the localization does
  not use (more than one scan from a localized one); the **full map** the same from the
  whole log (for "the same figures as on a full map": compare the first half; in the
  second half the full map holds every second localized scan's neighbour);
* every method localizes the whole log from the first reference pose: the first half's
  other kept scans, all kept scans of the second half;
* scores: inside the map = the first half: median / p95; *revisits* = second-half scans within
  1 m of a first-half reference position: share within 0.5 m; false ``tracking`` = scans
  ``tracking`` > 0.5 m off (MRPT has no status: every scan > 0.5 m off counts); for
  icploc ``--partial-map`` also the stretches outside the map, the re-entry scans (counted
  of the stretches the robot comes back from, an assumption: a revisit, within 1 m of the
  first half's trajectory, at or after the stretch's start; one still open at the log's
  end with no revisit after it is taken as never come back, not measured off the map),
  the scans
  from the first re-entering scan the map *explains at its reference pose* (the
  localizer's own verification from the true pose) to the lock (a lock cannot come
  earlier: how late it is, not how long the robot walked on space the map saw only from
  afar), and its
  ``--map-patch``: the share of the patch's occupied cells within 10 / 20 cm of an
  occupied cell of the full log's map at the reference poses; the same for the patch's
  *confident* cells (the sigma of where their walls are drawn, from the pose graph's
  covariance, at most ``icploc.mappatch.PATCH_SIGMA_BOUND``, 5 cm: the patch's
  ``.sigma.pgm``); and the same scans drawn as the patch is but at their reference poses
  (the drawing's and the measure's own ceiling: the gap to it is the patch's pose error).

Methods: ``icploc`` (``replay(..., partial_map=True)``: the default, with a map patch),
``icploc-plain`` (``replay(..., partial_map=False)``, partial map: its first half is the
control of "inside the map", the same map without the outside-the-map state),
``icploc-full`` (default replay, full map), ``icploc-crop`` (default replay on the full
map cropped to the partial map's known cells: the same mapped area, the walls the whole
log saw there; its first half against ``icploc``'s tells the missing walls inside the
mapped area from the missing area: aces 3.5 / 7.7 cm, the full map's 3.6 / 7.5, the
partial map's 3.8 / 9.8), ``mrpt`` (pf-localization, partial map; as eval_real runs
it). Writes ``benches/results/partial.md`` / ``.json``.

``--seeds A-B`` (or ``A,B,...``): the same for each odometry seed (one run is one draw of
the odometry noise: freiburg-101's inside median at seed 0, 3.1 cm against the full map's
2.7, is 2.91 against 2.85 over seeds 0-7), every seed's rows and a table of the inside
figures per log and method averaged over the seeds, with how many seeds put each method at
or below ``icploc-full``; written as ``partial-seeds.md`` / ``.json`` (the one-seed files
are left alone).
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
from numpy.typing import NDArray

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import eval_real as er  # noqa: E402
import real_grid as rg  # noqa: E402
import real_logs as rl  # noqa: E402
import real_odometry as ro  # noqa: E402

DEFAULT_LOGS = ["aces", "intel", "freiburg-101"]
METHODS = ["icploc", "icploc-plain", "icploc-full", "icploc-crop", "mrpt"]
RES = 0.10
REVISIT_M = 1.0
GOOD_M = 0.5
VERSION = "p1"


def cropped(full: Any, partial: Any) -> Any:
    """The full map's grid with every cell the partial map does not know (neither free nor
    occupied there, or beyond it) made unknown: the partial map's mapped area with the
    walls the whole log saw in it (both grids ``RES`` wide, their origins multiples of
    it)."""
    res = full.resolution
    h, w = full.occupied.shape
    rows, cols = np.mgrid[0:h, 0:w]
    pc = np.floor((full.origin[0] + (cols + 0.5) * res - partial.origin[0]) / res).astype(int)
    pr = np.floor((full.origin[1] + (rows + 0.5) * res - partial.origin[1]) / res).astype(int)
    ph, pw = partial.occupied.shape
    ok = (pc >= 0) & (pc < pw) & (pr >= 0) & (pr < ph)
    known = np.zeros((h, w), dtype=bool)
    known[ok] = (partial.occupied | partial.free)[pr[ok], pc[ok]]
    occ = full.occupied & known
    return rg.Grid(
        occupied=occ, free=full.free & known & ~occ, resolution=res, origin=full.origin
    )


def held_out(n: int, keep: NDArray[np.int64], stop: int, guard: int = 1) -> NDArray[np.int64]:
    """Dense scans in [0, stop) more than ``guard`` scans from a kept (localized) one."""
    near = np.zeros(n, dtype=bool)
    for g in range(-guard, guard + 1):
        i = keep + g
        near[i[(i >= 0) & (i < n)]] = True
    idx = np.arange(stop)
    return idx[~near[:stop]]


def first_explained(stretch: dict, explained: dict[int, bool]) -> int | None:
    """The first scan of a stretch's re-entry (its last one, after the last time it went
    out again) the map explains at the reference pose (``explained``: scan -> verified at
    its reference pose, for the re-entering scans); None: none of them."""
    end = stretch["end"] if stretch["end"] is not None else math.inf
    ks = sorted(k for k in explained if stretch["start"] <= k <= end)
    # the re-entry that locked: the last unbroken run of re-entering scans
    run: list[int] = []
    for k in ks:
        run = [*run, k] if run and k == run[-1] + 1 else [k]
    for k in run:
        if explained[k]:
            return k
    return None


def came_back(stretches: list[dict], rev: NDArray[np.bool_]) -> list[bool]:
    """Per stretch outside the map: does the robot come back into the mapped area after
    its start (a *revisit* scan, within ``REVISIT_M`` of a first-half place, at or after
    the stretch's first outside scan)? A stretch still open at the log's end with no
    revisit after it never came back: the log ended outside (or at the map's far edge,
    away from every place the map was made from); its missing lock is no failed
    re-entry."""
    idx = np.flatnonzero(rev)
    return [bool(s["end"] is not None or (idx >= s["start"]).any()) for s in stretches]


def revisits(ref: NDArray[np.float64], keep: NDArray[np.int64], half: int) -> NDArray[np.bool_]:
    """Per kept scan: in the second half and within REVISIT_M of a first-half place."""
    from scipy.spatial import cKDTree

    tree = cKDTree(ref[:half, :2])
    d, _ = tree.query(ref[keep, :2], k=1)
    return (keep >= half) & (d <= REVISIT_M)


def reentry_observer(ref: NDArray[np.float64], explained: dict[int, bool]) -> Any:
    """An :attr:`icploc.outside.OutsideMonitor.observer` filling ``explained``: per
    re-entering scan ``k``, does the map explain it at its reference pose ``ref[k]``
    (Localizer.verify_pose; it changes neither the localizer nor the monitor)."""

    def watched(mon: Any, loc: Any, est: Any, pts: Any) -> None:
        k = loc.scans_processed  # this scan's index (counted after the hooks)
        if mon.state == "reentering" and 0 <= k < len(ref):
            ok, _, _ = loc.verify_pose(pts, tuple(float(v) for v in ref[k]))
            explained[k] = bool(ok)

    return watched


def run_icploc(
    log_path: Path,
    map_yaml: Path,
    pose: tuple[float, float, float],
    partial: bool | None,
    patch: Path | None = None,
    ref: NDArray[np.float64] | None = None,
) -> dict:
    from icploc.replay import replay

    got: dict[str, Any] = {}
    #: per re-entering scan (``ref``: the reference poses of the replayed scans): does the
    #: map explain the scan at its reference pose (the localizer's own verification,
    #: Localizer.verify_pose, from the true pose)? A lock cannot come before that.
    explained: dict[int, bool] = {}

    def observe(mon: Any) -> None:  # this replay's monitor only (its observer hook)
        if ref is not None:
            mon.observer = reentry_observer(ref, explained)

    t0 = time.perf_counter()
    res = replay(
        log_path,
        map_yaml,
        initial_pose=pose,
        partial_map=partial,
        map_patch=patch,
        on_localizer=lambda loc: got.setdefault("loc", loc),
        on_outside=observe,
    )
    out: dict[str, Any] = {
        "poses": [list(e.pose) for e in res.estimates],
        "status": [e.status.value for e in res.estimates],
        "mapped": [bool(getattr(e, "mapped", True)) for e in res.estimates],
        "reason": [str(e.reason) for e in res.estimates],
        "time_s": time.perf_counter() - t0,
        "notes": list(res.notes),
    }
    mon = getattr(got["loc"], "outside", None)
    if mon is not None:
        out["stretches"] = [
            {"start": s.start, "end": s.end, "outside_scans": s.outside_scans,
             "reentry_scans": s.reentry_scans, "distance_m": s.distance,
             "max_sigma_m": s.max_sigma_xy, "sudden": s.sudden, "jumped": s.jumped,
             "correction_m": None if s.correction is None else math.hypot(*s.correction[:2])}
            for s in mon.stretches
        ]  # fmt: skip
        if ref is not None:
            for st in out["stretches"]:
                st["explained_from"] = first_explained(st, explained)
        if patch is not None and ref is not None:
            out["truth_patch"] = truth_patch(got["loc"], mon, ref)
    return out


def truth_patch(loc: Any, mon: Any, ref: NDArray[np.float64]) -> Any:
    """The patch's scans (those of the stretches it draws) ray-cast as the patch is, but at
    their reference poses: what the patch would be with perfect poses (its drawing's and
    the measure's own ceiling; the gap to the patch is its poses' error). None without
    one."""
    from icploc.mappatch import PATCH_PEAK_SHARE, grid_from_scans, in_patch, patch_layout

    res, align = patch_layout(loc.map)
    scans, poses = [], []
    for st in mon.stretches:
        if in_patch(st):
            for k, pts, _ in st.scans:
                scans.append(pts)
                poses.append(tuple(float(v) for v in ref[k]))
    if not scans:
        return None
    return grid_from_scans(
        scans, poses, resolution=res, align=align, mounting=loc.config.scan.mounting,
        peak_share=PATCH_PEAK_SHARE,
    )  # fmt: skip


def wall_distances(occupied: NDArray[np.bool_], res: float, origin: Any, full: Any) -> Any:
    """Per occupied cell of a grid (row 0 = lowest y), the distance to the nearest occupied
    cell of the full log's map ``full``."""
    from scipy.spatial import cKDTree

    rc = np.argwhere(occupied)
    xy = np.column_stack(
        [origin[0] + (rc[:, 1] + 0.5) * res, origin[1] + (rc[:, 0] + 0.5) * res]
    )
    return cKDTree(full.occupied_centres()).query(xy, k=1)[0]


def patch_quality(patch: Path, full_map: Path) -> dict[str, Any]:
    """The map patch's walls against the map of the whole log at the reference poses: per
    occupied patch cell outside the partial map's walls, the distance to the nearest
    occupied cell of the full map."""
    from icploc.mappatch import PATCH_SIGMA_BOUND, read_sigma_image, sigma_path
    from scipy.spatial import cKDTree

    p = rg.read_map_server(patch)
    f = rg.read_map_server(full_map)
    d, _ = cKDTree(f.occupied_centres()).query(p.occupied_centres(), k=1)
    out: dict[str, Any] = {
        "patch_cells": int(len(d)),
        "patch_wall_median_m": float(np.median(d)) if len(d) else None,
        "patch_wall_within_0_1m": float(np.mean(d <= 0.1 + 1e-9)) if len(d) else None,
        "patch_wall_within_0_2m": float(np.mean(d <= 0.2 + 1e-9)) if len(d) else None,
    }
    sp = sigma_path(patch)
    if sp.exists() and len(d):
        # the same cells, those the patch is sure of (sigma within the bound)
        sig = read_sigma_image(sp)[p.occupied]
        ok = sig <= PATCH_SIGMA_BOUND + 1e-9
        out["patch_confident_cells"] = int(ok.sum())
        if ok.any():
            out["patch_confident_within_0_1m"] = float(np.mean(d[ok] <= 0.1 + 1e-9))
            out["patch_confident_within_0_2m"] = float(np.mean(d[ok] <= 0.2 + 1e-9))
    return out


def score(
    est: NDArray[np.float64],
    ref: NDArray[np.float64],
    status: list[str] | None,
    first: NDArray[np.bool_],
    rev: NDArray[np.bool_],
) -> dict[str, Any]:
    e = np.hypot(est[:, 0] - ref[:, 0], est[:, 1] - ref[:, 1])
    e = np.where(np.isfinite(e), e, np.inf)
    claimed = np.ones(len(e), bool) if status is None else np.asarray(status) == "tracking"
    return {
        "scans": len(e),
        "inside_median_m": float(np.median(e[first])),
        "inside_p95_m": float(np.percentile(e[first], 95, method="higher")),
        "second_half_median_m": float(np.median(e[~first])) if (~first).any() else None,
        "revisits": int(rev.sum()),
        "revisits_within_0_5m": float(np.mean(e[rev] <= GOOD_M)) if rev.any() else None,
        "false_tracking": int(np.sum(claimed & (e > GOOD_M))),
        "tracking_share": None if status is None else float(np.mean(claimed)),
        "lost_share": None if status is None else float(np.mean(np.asarray(status) == "lost")),
    }


def write_scans(
    path: Path,
    keep: NDArray[np.int64],
    ref: NDArray[np.float64],
    est: NDArray[np.float64],
    got: dict[str, Any],
    first: NDArray[np.bool_],
    rev: NDArray[np.bool_],
) -> None:
    """One method's run scan by scan (``--scans DIR``): the log index, the reference and
    estimated poses, the position error, status, reason, mapped, first half, revisit."""
    n = len(keep)
    status = got.get("status") or [""] * n
    reason = got.get("reason") or [""] * n
    mapped = got.get("mapped") or [True] * n
    e = np.hypot(est[:, 0] - ref[:, 0], est[:, 1] - ref[:, 1])
    lines = ["i,log_index,ref_x,ref_y,ref_th,x,y,th,err_m,status,reason,mapped,first_half,revisit"]
    for i in range(n):
        lines.append(
            f"{i},{int(keep[i])},{ref[i, 0]:.4f},{ref[i, 1]:.4f},{ref[i, 2]:.5f},"
            f"{est[i, 0]:.4f},{est[i, 1]:.4f},{est[i, 2]:.5f},{e[i]:.4f},{status[i]},"
            f"{reason[i]},{int(bool(mapped[i]))},{int(first[i])},{int(rev[i])}"
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")


def evaluate(
    path: Path,
    methods: list[str],
    cache: Path,
    seed: int,
    max_range: float,
    scans_dir: Path | None = None,
) -> list[dict]:
    name = path.name.replace("-corrected.log.gz", "")
    log = rl.read_flaser(path)
    ref = log.poses
    n = len(log)
    half = n // 2
    kept = rl.sparsify(ref, distance=0.5, angle=0.5)
    # the first half's kept scans alternate: localized / put in the map (the logs are
    # sparse already: a map of the localized scans themselves would flatter)
    k1, k2 = kept[kept < half], kept[kept >= half]
    keep = np.concatenate([k1[::2], k2])
    model = er.fit_bases(er.DATA)["good"]
    odom = ro.apply_model(model, ref, seed=er._seed(seed, name, "good"))
    stamps = er._stamps(log)
    mr = min(max_range, log.no_return)
    maps = {}
    for kind, stop in (("partial", half), ("full", n)):
        y = cache / "partial" / f"{name}_{kind}_{int(RES * 100)}cm_{VERSION}.yaml"
        if not y.exists():
            y.parent.mkdir(parents=True, exist_ok=True)
            extra = k1[1::2] if kind == "partial" else np.concatenate([k1[1::2], k2[1::2]])
            idx = np.union1d(held_out(n, keep, stop), extra)
            grid = rg.rasterise(log.ranges[idx], log.angles, ref[idx], RES, mr)
            rg.write_map_server(grid, y)
        maps[kind] = y
    y = cache / "partial" / f"{name}_crop_{int(RES * 100)}cm_{VERSION}.yaml"
    if "icploc-crop" in methods and not y.exists():
        grid = cropped(rg.read_map_server(maps["full"]), rg.read_map_server(maps["partial"]))
        rg.write_map_server(grid, y)
    maps["crop"] = y
    log_path = cache / "partial" / f"{name}_good_s{seed}_{VERSION}.log"
    if not log_path.exists():
        rl.write_flaser(log_path, log.ranges[keep], odom[keep], stamps[keep])
    pose = tuple(float(v) for v in ref[0])
    first = keep < half
    rev = revisits(ref, keep, half)
    rows = []
    ests: dict[str, NDArray[np.float64]] = {}
    for m in methods:
        row: dict[str, Any] = {"log": name, "method": m, "map_res_m": RES, "scans_in_log": n}
        try:
            if m.startswith("icploc"):
                # the patch in a directory of this run's own (the cache is shared)
                with tempfile.TemporaryDirectory(prefix="icploc-patch-") as tmp:
                    patch = Path(tmp) / f"{name}_patch.yaml" if m == "icploc" else None
                    got = run_icploc(
                        log_path,
                        maps[{"icploc-full": "full", "icploc-crop": "crop"}.get(m, "partial")],
                        pose,
                        # icploc-full, icploc-crop: the default replay (its
                        # outside-the-map state on by default); icploc-plain: turned off
                        {"icploc": True, "icploc-plain": False}.get(m),
                        patch,
                        ref[keep] if m == "icploc" else None,
                    )
                    if patch is not None and patch.exists():
                        got["patch"] = patch_quality(patch, maps["full"])
                    tp = got.pop("truth_patch", None)
                    if tp is not None and "patch" in got:
                        d = wall_distances(
                            tp.occupied, tp.resolution, tp.origin,
                            rg.read_map_server(maps["full"]),
                        )  # fmt: skip
                        got["patch"]["truth_patch_cells"] = int(len(d))
                        got["patch"]["truth_patch_within_0_1m"] = (
                            float(np.mean(d <= 0.1 + 1e-9)) if len(d) else None
                        )
            elif m == "mrpt":
                import real_mrpt

                if not real_mrpt.available():
                    raise RuntimeError("MRPT tools not found (apt-get install mrpt-apps)")
                work = cache / "work" / f"partial_{name}_{seed}"
                got = real_mrpt.run_mrpt(
                    work, log.ranges[keep], odom[keep], maps["partial"], pose, mr
                )
                got["status"] = None
            else:
                raise ValueError(f"unknown method {m}")
        except Exception as e:  # noqa: BLE001 - one failing method must not hide the others
            row["error"] = f"{type(e).__name__}: {e}"
            rows.append(row)
            print(f"  {name} {m}: {row['error']}", file=sys.stderr)
            continue
        est = np.asarray(got["poses"], dtype=np.float64).reshape(-1, 3)
        row.update(score(est, ref[keep], got.get("status"), first, rev))
        if scans_dir is not None:
            write_scans(scans_dir / f"{name}_{m}.csv", keep, ref[keep], est, got, first, rev)
        row["time_s"] = got.get("time_s")
        if "mapped" in got:
            row["outside_scans"] = int(np.sum(~np.asarray(got["mapped"])))
        if "patch" in got:
            row.update(got["patch"])
        if "stretches" in got:
            row["stretches"] = got["stretches"]
            ents = [s["reentry_scans"] for s in got["stretches"] if s["reentry_scans"] is not None]
            row["reentries"] = len(ents)
            back = came_back(got["stretches"], rev)
            for st, b in zip(got["stretches"], back, strict=True):
                st["came_back"] = b
            # re-entries are counted of the stretches the robot comes back from
            row["stretches_back"] = int(sum(back))
            # the scans from the first the map explains at the reference pose to the lock
            lag = [
                s["end"] - s["explained_from"] + 1
                for s in got["stretches"]
                if s["end"] is not None and s.get("explained_from") is not None
            ]
            row["lock_after_explained_median"] = float(np.median(lag)) if lag else None
            row["lock_after_explained_max"] = int(max(lag)) if lag else None
            row["reentry_scans_median"] = float(np.median(ents)) if ents else None
        rows.append(row)
        ests[m] = est
    if "icploc" in ests and "icploc-plain" in ests:
        # inside the map the outside-the-map state must cost nothing: the first half scan
        # by scan against the default replay on the same map
        same = np.all(np.abs(ests["icploc"][first] - ests["icploc-plain"][first]) <= 1e-9, axis=1)
        for row in rows:
            if row["method"] == "icploc" and "scans" in row:
                row["inside_same_as_plain"] = [int(same.sum()), int(len(same))]
    for row in rows:
        if "scans" in row:
            print(md_row(row), flush=True)
    return rows


def _cm(v: Any) -> str:
    return "–" if v is None else ("inf" if not math.isfinite(v) else f"{v * 100:.1f}")


def _pct(v: Any) -> str:
    return "–" if v is None else f"{v * 100:.0f} %"


HEADER = (
    "| log | method | scans | inside median cm | inside p95 cm | inside scans as icploc-plain's | revisits | revisits within 0.5 m "
    "| false tracking | lost | outside scans | re-entries locked of stretches come back (median scans from re-entry; from the first scan the map explains at its true pose) | patch walls within 10 / 20 cm "
    "| confident patch walls (sigma <= 5 cm) within 10 / 20 cm |\n"
    "|---|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---|---|---|"
)


NOTE = (
    "Re-entries are counted of the stretches the robot comes back from, an assumption: "
    '"comes back" = a *revisit* scan (within 1 m of a first-half reference position) at or '
    "after the stretch's start, not a measure of being back on the map (a stretch open at "
    "the log's end with no such scan is left out of the denominator). *inside scans as "
    "icploc-plain's* is a diagnostic (the outside-the-map state costs nothing inside), not "
    "the target: the yardstick is the full map's figures."
)


def md_row(r: dict) -> str:
    if "scans" not in r:
        return f"| {r['log']} | {r['method']} | – | – | – | – | – | – | – | – | – | – | – | {r.get('error', '')} |"
    sp = r.get("inside_same_as_plain")
    same = "–" if sp is None else f"{sp[0]} of {sp[1]} identical"
    re_ = "–"
    if r.get("reentries") is not None:
        med = r.get("reentry_scans_median")
        back = r.get("stretches_back", len(r["stretches"]))
        re_ = f"{r['reentries']} of {back} ({'–' if med is None else f'{med:g}'})"
        lag = r.get("lock_after_explained_median")
        if lag is not None:
            re_ += f", {lag:g} (max {r['lock_after_explained_max']}) from the first explained"
        if len(r["stretches"]) > back:
            re_ += f"; {len(r['stretches']) - back} open at the end, no revisit after"
    return (
        f"| {r['log']} | {r['method']} | {r['scans']} | {_cm(r['inside_median_m'])} | "
        f"{_cm(r['inside_p95_m'])} | {same} | {r['revisits']} | {_pct(r['revisits_within_0_5m'])} | "
        f"{r['false_tracking']} | {_pct(r.get('lost_share'))} | {r.get('outside_scans', '–')} | {re_} | "
        + (
            f"{_pct(r['patch_wall_within_0_1m'])} / {_pct(r['patch_wall_within_0_2m'])} "
            f"of {r['patch_cells']}"
            + (
                f" (at the reference poses {_pct(r['truth_patch_within_0_1m'])} / 10 cm)"
                if r.get("truth_patch_within_0_1m") is not None
                else ""
            )
            if r.get("patch_cells")
            else "–"
        )
        + " | "
        + (
            f"{_pct(r['patch_confident_within_0_1m'])} / {_pct(r['patch_confident_within_0_2m'])} "
            f"of {r['patch_confident_cells']}"
            if r.get("patch_confident_cells")
            else "–"
        )
        + " |"
    )


def parse_seeds(text: str) -> list[int]:
    """``--seeds``: ``A-B`` (inclusive) or ``A,B,...``, non-negative integers, no repeats."""
    try:
        if "-" in text and "," not in text:
            a, b = (int(v) for v in text.split("-"))
            seeds = list(range(a, b + 1))
        else:
            seeds = [int(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"--seeds: expected A-B or A,B,..., got {text!r}") from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds: non-negative, distinct seeds, at least one; got {text!r}")
    return seeds


SEEDS_HEADER = (
    "| log | method | seeds | inside median cm, mean | inside p95 cm, mean | median at or below "
    "icploc-full's | p95 at or below icploc-full's |\n|---|---|---:|---:|---:|---:|---:|"
)


def seed_summary(rows: list[dict]) -> list[dict]:
    """Per log and method (in the rows' order): the inside median / p95 averaged over the
    seeds it ran with, and on how many of them it was at or below ``icploc-full``'s."""
    runs: dict[tuple[str, str], dict[int, dict]] = {}
    for r in rows:
        if "scans" in r:
            runs.setdefault((r["log"], r["method"]), {})[r["seed"]] = r
    out = []
    for (log, method), by_seed in runs.items():
        full = runs.get((log, "icploc-full"), {})
        both = [s for s in by_seed if s in full]
        out.append({
            "log": log, "method": method, "seeds": sorted(by_seed),
            "inside_median_m": float(np.mean([r["inside_median_m"] for r in by_seed.values()])),
            "inside_p95_m": float(np.mean([r["inside_p95_m"] for r in by_seed.values()])),
            "median_le_full": [sum(by_seed[s]["inside_median_m"] <= full[s]["inside_median_m"] for s in both), len(both)],
            "p95_le_full": [sum(by_seed[s]["inside_p95_m"] <= full[s]["inside_p95_m"] for s in both), len(both)],
        })  # fmt: skip
    return out


def seeds_md_row(r: dict) -> str:
    le = [f"{a} of {b}" if b else "–" for a, b in (r["median_le_full"], r["p95_le_full"])]
    return (
        f"| {r['log']} | {r['method']} | {len(r['seeds'])} | {r['inside_median_m'] * 100:.2f} | "
        f"{r['inside_p95_m'] * 100:.2f} | {le[0]} | {le[1]} |"
    )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("logs", nargs="*", default=DEFAULT_LOGS)
    ap.add_argument("--methods", default=",".join(METHODS))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--seeds", default=None, metavar="A-B|A,B,...",
        help="run each of these odometry seeds (instead of --seed); adds the inside figures "
        "averaged over them; writes partial-seeds.md / .json",
    )  # fmt: skip
    ap.add_argument("--max-range", type=float, default=30.0)
    ap.add_argument("--cache", type=Path, default=er.cache_dir())
    ap.add_argument("--out-dir", type=Path, default=er.RESULTS)
    ap.add_argument(
        "--scans", type=Path, default=None, metavar="DIR",
        help="also write each method's run scan by scan to DIR/LOG_METHOD.csv",
    )  # fmt: skip
    a = ap.parse_args(argv)
    methods = [m for m in a.methods.split(",") if m]
    try:
        seeds = None if a.seeds is None else parse_seeds(a.seeds)
    except ValueError as e:
        ap.error(str(e))
    paths = er.find_logs(er.DATA, a.logs)
    if not paths:
        print(
            f"no radish logs matching {a.logs} in {er.DATA / 'radish_corrected_logs'}",
            file=sys.stderr,
        )
        return 2
    print(HEADER)
    rows: list[dict] = []
    for seed in seeds or [a.seed]:
        for p in paths:
            scans = a.scans if seeds is None or a.scans is None else a.scans / f"seed{seed}"
            got = evaluate(p, methods, a.cache, seed, a.max_range, scans)
            for r in got:
                r["seed"] = seed
            rows += got
    a.out_dir.mkdir(parents=True, exist_ok=True)
    cmd = " ".join(["python benches/eval_partial.py", *(sys.argv[1:] if argv is None else argv)])
    if seeds is not None:
        summary = seed_summary(rows)
        body = "\n".join([SEEDS_HEADER, *(seeds_md_row(r) for r in summary)])
        every = "\n".join(
            [HEADER.replace("| log |", "| log (seed) |", 1)]
            + [md_row({**r, "log": f"{r['log']} ({r['seed']})"}) for r in rows]
        )
        print(body)
        (a.out_dir / "partial-seeds.md").write_text(
            "Partial maps (benches/eval_partial.py) over odometry seeds: the inside-the-map "
            "figures (the first half) averaged per log and method, then every seed's rows.\n\n"
            f"Command: `{cmd}`\n\n" + body + "\n\n" + every + "\n\n" + NOTE + "\n"
        )
        (a.out_dir / "partial-seeds.json").write_text(
            json.dumps({"summary": summary, "rows": rows}, indent=1)
        )
        return 0
    table = "\n".join([HEADER, *(md_row(r) for r in rows)])
    (a.out_dir / "partial.md").write_text(
        "Partial maps (benches/eval_partial.py): a 10 cm map of each log's first half, the whole "
        "log localized, raw odometry of the real error model (good), sparse scans.\n\n"
        f"Command: `{cmd}`\n\n"
        + table
        + "\n\n"
        + NOTE
        + "\n"
    )
    (a.out_dir / "partial.json").write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""icploc side by side with the registration libraries users would pick instead.

One command regenerates the table (Markdown on stdout and in ``benches/results/peers.md``,
raw numbers in ``benches/results/peers.json``)::

    python benches/peers.py            # full run: 1k/10k/100k/1M points, 50 poses, both thread modes
    python benches/peers.py --quick    # smoke run: 1k/10k points, 10 poses

Scenario (``benches/scenario.py``): an office floor plan of line segments sampled to about
1k / 10k / 100k / 1M map points with exact 2D normals; 361-beam 180 degree scans, 1 cm
range noise, 20 % of beams on unmapped obstacles (boxes, people); start errors
(0.3 m, 0.3 m, 10 deg) and (1.0 m, 0.5 m, 25 deg) with random signs. Success means a final
error within 2 cm and 0.5 deg.

Each thread mode runs in its own child process so thread environment variables are set
before any library is imported: ``single`` pins every library to one thread
(OMP/OpenBLAS/MKL/Rayon env vars and each library's thread option); ``default`` leaves each
library at its default or, where the library asks for a number, gives it every core.
icploc runs one alignment per call on one thread in both modes.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import scenario as sc  # noqa: E402
from numpy_icp import NumpyIcp  # noqa: E402

#: The correspondence-distance schedule every method gets: 1.0 m, then 0.25 m. Every method
#: runs two stages (two calls with a fixed distance, each to convergence), which beat a
#: per-iteration geometric decay from the large start error for every method tried; the
#: "icploc p2l 1-call" row shows icploc's own per-iteration schedule (x0.6) for comparison.
D_MAX = 1.0
D_MIN = 0.25
DECAY = 0.6
STAGES = (D_MAX, D_MIN)
ROBUST_SCALE = 0.05  # Huber / kernel scale (m) where a method has a robust loss
SUCCESS_T = 0.02  # m
SUCCESS_R = math.radians(0.5)

SINGLE_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "RAYON_NUM_THREADS": "1",
    "NUMEXPR_NUM_THREADS": "1",
    "VECLIB_MAXIMUM_THREADS": "1",
}


def _pose_from_T(t: NDArray[np.float64]) -> tuple[float, float, float]:
    t = np.asarray(t)
    return float(t[0, 3]), float(t[1, 3]), math.atan2(float(t[1, 0]), float(t[0, 0]))


def _T_from_pose(p: Any) -> NDArray[np.float64]:
    x, y, th = (float(v) for v in p)
    c, s = math.cos(th), math.sin(th)
    t = np.eye(4)
    t[0, 0], t[0, 1], t[1, 0], t[1, 1] = c, -s, s, c
    t[0, 3], t[1, 3] = x, y
    return t


def _lift(xy: NDArray[np.float64], z: float = 0.0) -> NDArray[np.float64]:
    return np.column_stack((xy, np.full(len(xy), z)))


def _extrude(xy: NDArray[np.float64], dz: float) -> NDArray[np.float64]:
    """Three copies of 2D points at z = -dz, 0, +dz: vertical walls, so that 3D normal /
    covariance estimation finds the in-plane normal instead of the z axis."""
    return np.vstack([_lift(xy, -dz), _lift(xy, 0.0), _lift(xy, dz)])


# --------------------------------------------------------------------------- methods


@dataclass
class Method:
    """One registration method. ``build`` prepares the map once (timed); ``align`` runs one
    alignment of a sensor-frame scan from a start pose and returns the map-frame pose."""

    name: str
    library: str
    settings: str
    make: Callable[[NDArray[np.float64], NDArray[np.float64], float, bool], Callable[[NDArray[np.float64], Any], tuple[float, float, float]]]
    is_icploc: bool = False
    slow_on_big_maps: bool = False
    extra: dict[str, Any] = field(default_factory=dict)


HEADING_SEARCH = 0.5  # rad: icploc's built-in multi-heading start (first stage), covers 25 deg


def _icploc_configs(metric: str, one_call: bool, heading_search: float = 0.0) -> list[Any]:
    import icploc

    # the protocol every method gets: plain ICP (icploc's verified start off; see "icploc default")
    common = dict(metric=metric, max_iterations=50, robust="huber", robust_scale=ROBUST_SCALE, window_search=False)
    if one_call:
        return [icploc.IcpConfig(max_correspondence_distance=D_MAX, min_correspondence_distance=D_MIN, threshold_decay=DECAY, **common)]
    cfgs = [icploc.IcpConfig(max_correspondence_distance=d, min_correspondence_distance=d, **common) for d in STAGES]
    if heading_search > 0.0:
        cfgs[0] = icploc.IcpConfig(max_correspondence_distance=D_MAX, min_correspondence_distance=D_MAX, heading_search=heading_search, **common)
    return cfgs


def _icploc_search_method() -> Method:
    """icploc's own one-call path for unknown start errors: its default threshold schedule
    with the start search on (headings ±30° every 10°, positions ±0.5 m on a 3 × 3 grid)."""
    import icploc

    cfg = icploc.IcpConfig(
        metric="point_to_line",
        heading_search=math.radians(30),
        heading_step=math.radians(10),
        position_search=0.5,
        window_search=False,
    )

    def make(pts: NDArray[np.float64], nrm: NDArray[np.float64], spacing: float, single: bool):
        index = icploc.MapIndex(pts, nrm)

        def align(scan: NDArray[np.float64], init: Any) -> tuple[float, float, float]:
            return icploc.icp(scan, index, init, cfg).pose

        return align

    return Method(
        name="icploc p2l +search",
        library=f"icploc {icploc.__version__}",
        settings="icp(metric=point_to_line), one call, default schedule 1.0→0.1 m ×0.6/iter, heading_search=30° step 10°, position_search=0.5 m, window_search off; one thread per call",
        make=make,
        is_icploc=True,
    )


def _icploc_default_method() -> Method:
    """What a user calls first: ``icp(scan, index, pose)`` with no config (the core's
    defaults: point-to-line, 1.0 -> 0.1 m, the verified start with its window search)."""
    import icploc

    def make(pts: NDArray[np.float64], nrm: NDArray[np.float64], spacing: float, single: bool):
        index = icploc.MapIndex(pts, nrm)
        # the window search's likelihood pyramid is built on first use: build it here, in
        # the timed build, with one call
        icploc.icp(pts[:: max(1, len(pts) // 50)][:50] - pts.mean(axis=0), index, (*pts.mean(axis=0), 0.0))

        def align(scan: NDArray[np.float64], init: Any) -> tuple[float, float, float]:
            return icploc.icp(scan, index, init).pose

        return align

    return Method(
        name="icploc default",
        library=f"icploc {icploc.__version__}",
        settings="icp(scan, index, pose): no config, the core's defaults (point-to-line 1.0→0.1 m ×0.6/iter, verified start with the ±1 m / ±30° window search when the fit does not explain the scan); one thread per call",
        make=make,
        is_icploc=True,
    )


def _icploc_method(metric: str, one_call: bool = False, heading_search: float = 0.0) -> Method:
    import icploc

    def make(pts: NDArray[np.float64], nrm: NDArray[np.float64], spacing: float, single: bool):
        index = icploc.MapIndex(pts, nrm)
        cfgs = _icploc_configs(metric, one_call, heading_search)

        def align(scan: NDArray[np.float64], init: Any) -> tuple[float, float, float]:
            pose = init
            for cfg in cfgs:
                pose = icploc.icp(scan, index, pose, cfg).pose
            return pose

        return align

    short = "p2p" if metric == "point_to_point" else "p2l"
    sched = f"one call, 1.0→0.25 m ×{DECAY}/iter" if one_call else "two calls at 1.0 then 0.25 m"
    if heading_search:
        sched += f", heading_search={heading_search} rad (step 5°) in the first"
    return Method(
        name=f"icploc {short}" + (" 1-call" if one_call else "") + (" +heading" if heading_search else ""),
        library=f"icploc {icploc.__version__}",
        settings=f"icp(metric={metric}), {sched}, ≤50 iter each, Huber {ROBUST_SCALE} m, given 2D normals, window_search off (plain ICP: the peers' protocol); one thread per call",
        make=make,
        is_icploc=True,
    )


def _numpy_method() -> Method:
    import scipy

    def make(pts, nrm, spacing, single):
        icp = NumpyIcp(pts, max_iterations=50, workers=1 if single else -1)

        def align(scan, init):
            pose = init
            for d in STAGES:
                icp.max_distance = icp.min_distance = d
                pose = icp.align(scan, pose).pose
            return pose

        return align

    return Method(
        name="numpy+cKDTree p2p",
        library=f"numpy {np.__version__}, scipy {scipy.__version__}",
        settings="SVD point-to-point, distance gate 1.0 then 0.25 m (two stages), ≤50 iter each, no robust loss; cKDTree workers=1 (single) / -1 (default)",
        make=make,
    )


def _o3d_method(plane: bool) -> Method:
    import open3d as o3d

    reg = o3d.pipelines.registration
    est = (
        reg.TransformationEstimationPointToPlane(reg.HuberLoss(ROBUST_SCALE))
        if plane
        else reg.TransformationEstimationPointToPoint()  # it takes no robust kernel
    )
    crit = reg.ICPConvergenceCriteria(relative_fitness=1e-7, relative_rmse=1e-7, max_iteration=30)

    def make(pts, nrm, spacing, single):
        target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_lift(pts)))
        target.normals = o3d.utility.Vector3dVector(_lift(nrm))  # the true 2D normals, z = 0

        def align(scan, init):
            src = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_lift(scan)))
            t = _T_from_pose(init)
            for d in STAGES:
                t = reg.registration_icp(src, target, d, t, est, crit).transformation
            return _pose_from_T(t)

        return align

    kind = "point-to-plane" if plane else "point-to-point"
    return Method(
        name=f"Open3D {'p2plane' if plane else 'p2p'}",
        library=f"open3d {o3d.__version__}",
        settings=f"registration_icp {kind}, two calls at 1.0 then 0.25 m, ≤30 iter each, rel. fitness/rmse 1e-7"
        + (f", Huber {ROBUST_SCALE} m, target normals = given 2D normals (z=0)" if plane else "")
        + "; rebuilds its k-d tree inside every call (cost included)",
        make=make,
        slow_on_big_maps=True,
    )


def _o3d_tree_build_seconds(pts: NDArray[np.float64]) -> float:
    """What Open3D pays inside every registration_icp call for the target k-d tree."""
    import open3d as o3d

    target = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(_lift(pts)))
    t0 = time.perf_counter()
    o3d.geometry.KDTreeFlann(target)
    return time.perf_counter() - t0


def _small_gicp_method(kind: str) -> Method:
    import small_gicp

    try:
        from importlib.metadata import version

        ver = version("small_gicp")
    except Exception:  # pragma: no cover
        ver = "?"
    nthreads_default = os.cpu_count() or 1

    def make(pts, nrm, spacing, single):
        nt = 1 if single else nthreads_default
        if kind == "ICP":
            target = small_gicp.PointCloud(_lift(pts))
        else:
            # vertical walls so the estimated normals / covariances lie in the plane
            target = small_gicp.PointCloud(_extrude(pts, spacing))
        tree = small_gicp.KdTree(target, num_threads=nt)
        if kind == "PLANE_ICP":
            small_gicp.estimate_normals(target, tree, num_neighbors=10, num_threads=nt)
        elif kind == "GICP":
            small_gicp.estimate_covariances(target, tree, num_neighbors=10, num_threads=nt)

        def align(scan, init):
            if kind == "GICP":
                src = small_gicp.PointCloud(_extrude(scan, 0.05))
                stree = small_gicp.KdTree(src, num_threads=nt)
                small_gicp.estimate_covariances(src, stree, num_neighbors=10, num_threads=nt)
            else:
                src = small_gicp.PointCloud(_lift(scan))
            t = _T_from_pose(init)
            for d in STAGES:
                r = small_gicp.align(
                    target, src, tree, t, registration_type=kind,
                    max_correspondence_distance=d, num_threads=nt, max_iterations=30,
                    rotation_epsilon=math.radians(0.01), translation_epsilon=1e-4,
                )
                t = r.T_target_source
            return _pose_from_T(t)

        return align

    extra = {
        "ICP": "map as z=0 points",
        "PLANE_ICP": "map extruded to 3 layers (z=0, ±spacing) so estimated normals (k=10) are the 2D normals",
        "GICP": "map extruded to 3 layers (z=0, ±spacing), scan to 3 layers (±5 cm), covariances k=10 (scan's per call, included)",
    }[kind]
    return Method(
        name=f"small_gicp {kind}",
        library=f"small_gicp {ver}",
        settings=f"align(registration_type={kind}) with a prebuilt KdTree, two calls at 1.0 then 0.25 m, ≤30 iter each, "
        f"eps 1e-4 m / 0.01°; {extra}; num_threads=1 (single) / {nthreads_default} (default)",
        make=make,
        slow_on_big_maps=kind == "GICP",
    )


def _kiss_method() -> Method:
    from importlib.metadata import version

    from kiss_icp.mapping import VoxelHashMap
    from kiss_icp.registration import Registration

    voxel = D_MAX  # its neighbour search only reaches the adjacent voxels: voxel >= distance

    def make(pts, nrm, spacing, single):
        res = max(spacing, 0.01)
        per_voxel = int(math.ceil((voxel / res) ** 2))  # its point spacing is voxel/sqrt(this)
        vmap = VoxelHashMap(voxel_size=voxel, max_distance=1e4, max_points_per_voxel=per_voxel)
        vmap.add_points(_lift(pts))
        reg = Registration(max_num_iterations=500, convergence_criterion=1e-4, max_num_threads=1 if single else 0)

        def align(scan, init):
            s3 = _lift(scan)
            t = _T_from_pose(init)
            for d in STAGES:
                kernel = d / 3.0 if d == D_MAX else ROBUST_SCALE
                t = reg.align_points_to_map(s3, vmap, t, max_correspondance_distance=d, kernel=kernel)
            return _pose_from_T(t)

        return align

    return Method(
        name="KISS-ICP",
        library=f"kiss-icp {version('kiss-icp')}",
        settings=f"Registration.align_points_to_map (point-to-point, Geman-McClure kernel 1/3 m then {ROBUST_SCALE} m), "
        "two calls at 1.0 then 0.25 m, ≤500 iter, convergence 1e-4; VoxelHashMap voxel 1.0 m "
        "(= the largest distance), max_points_per_voxel so its map keeps max(spacing, 1 cm) spacing; "
        "max_num_threads=1 (single) / 0 = all (default)",
        make=make,
    )


def available_methods(only: set[str] | None = None) -> tuple[list[Method], dict[str, str]]:
    """Every method whose library imports; the others with the reason they were skipped."""
    factories: list[tuple[str, Callable[[], Method]]] = [
        ("icploc default", _icploc_default_method),
        ("icploc p2p", lambda: _icploc_method("point_to_point")),
        ("icploc p2l", lambda: _icploc_method("point_to_line")),
        ("icploc p2l 1-call", lambda: _icploc_method("point_to_line", one_call=True)),
        ("icploc p2l +heading", lambda: _icploc_method("point_to_line", heading_search=HEADING_SEARCH)),
        ("icploc p2l +search", _icploc_search_method),
        ("numpy+cKDTree p2p", _numpy_method),
        ("Open3D p2p", lambda: _o3d_method(False)),
        ("Open3D p2plane", lambda: _o3d_method(True)),
        ("small_gicp ICP", lambda: _small_gicp_method("ICP")),
        ("small_gicp PLANE_ICP", lambda: _small_gicp_method("PLANE_ICP")),
        ("small_gicp GICP", lambda: _small_gicp_method("GICP")),
        ("KISS-ICP", _kiss_method),
    ]
    methods, skipped = [], {}
    for name, fac in factories:
        if only and not any(o.lower() in name.lower() for o in only):
            continue
        try:
            methods.append(fac())
        except Exception as e:  # ImportError, missing shared libraries, ...
            skipped[name] = f"{type(e).__name__}: {e}"
    return methods, skipped


# --------------------------------------------------------------------------- running


def pose_errors(est: NDArray[np.float64], truth: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    d = est - truth
    te = np.hypot(d[:, 0], d[:, 1])
    re = np.abs(np.remainder(d[:, 2] + math.pi, 2.0 * math.pi) - math.pi)
    return te, re


def run_mode(args: argparse.Namespace, mode: str) -> dict[str, Any]:
    """Run every method on every family, map size and start error in this process."""
    methods, skipped = available_methods(set(args.methods.split(",")) if args.methods else None)
    loaded_build = icploc_build_stamp()  # the module this process imported (just now)
    rows: list[dict[str, Any]] = []
    for family in args.families:
        rows.extend(_run_family(args, mode, methods, skipped, family))
    return {
        "mode": mode,
        "icploc_build": loaded_build,
        "rows": rows,
        "skipped": skipped,
        "settings": {m.name: {"library": m.library, "settings": m.settings} for m in methods},
    }


def _run_family(args: argparse.Namespace, mode: str, methods: list[Method], skipped: dict[str, str], family: str) -> list[dict[str, Any]]:
    single = mode == "single"
    scen = sc.make_scenario(num_poses=args.poses, seed=args.seed, family=family)
    scans = [scen.scan_points(i) for i in range(args.poses)]
    rows: list[dict[str, Any]] = []
    for size in args.sizes:
        pts, nrm, spacing = sc.map_for_size(scen.segments, size)
        o3d_tree = None
        for m in methods:
            n_poses = args.poses
            if m.slow_on_big_maps and size >= 1_000_000:
                n_poses = min(n_poses, args.big_map_poses)
            t0 = time.perf_counter()
            try:
                align = m.make(pts, nrm, spacing, single)
            except Exception as e:
                skipped[f"{m.name} @ {size}"] = f"{type(e).__name__}: {e}"
                continue
            build = time.perf_counter() - t0
            note = ""
            if m.library.startswith("open3d"):
                if o3d_tree is None:
                    o3d_tree = _o3d_tree_build_seconds(pts)
                note = f"k-d tree rebuilt in each of its {len(STAGES)} calls: {o3d_tree * 1e3:.1f} ms each"
                build += o3d_tree
            align(scans[0], scen.starts["small"][0])  # warm-up (caches, lazy init)
            passes = [(m.name, "")]
            if m.name == "icploc p2l":  # a second pass over the same poses (caches warm)
                passes.append(("icploc p2l warm", "second pass over the same poses (CPU caches warm)"))
            for (name, warm_note), level in [(ps, lv) for ps in passes for lv in sc.ERROR_LEVELS]:
                est = np.empty((n_poses, 3))
                times = np.empty(n_poses)
                for i in range(n_poses):
                    start = scen.starts[level][i]
                    t1 = time.perf_counter()
                    try:
                        est[i] = align(scans[i], start)
                    except Exception:
                        est[i] = start
                    times[i] = time.perf_counter() - t1
                te, re = pose_errors(est, scen.poses[:n_poses])
                rows.append(
                    {
                        "method": name, "library": m.library, "threads": mode, "family": family, "map_points": int(len(pts)),
                        "size": size, "start": level, "poses": n_poses, "build_s": build,
                        "median_ms": float(np.median(times) * 1e3), "times_ms": (times * 1e3).tolist(),
                        "median_te_mm": float(np.median(te) * 1e3), "median_re_deg": float(np.degrees(np.median(re))),
                        "success": float(np.mean((te < SUCCESS_T) & (re < SUCCESS_R))),
                        "te_m": te.tolist(), "re_rad": re.tolist(), "note": warm_note or note,
                    }
                )  # fmt: skip
                print(
                    f"  [{mode}] {family:9} {size:>8} {level:5} {name:22} {rows[-1]['median_ms']:9.3f} ms "
                    f"te {rows[-1]['median_te_mm']:7.2f} mm succ {rows[-1]['success'] * 100:5.1f}%",
                    file=sys.stderr, flush=True,
                )
            del align
            if m.name == "icploc p2l" and not single:
                for r in _icploc_batch_rows(pts, nrm, size, scen, scans, mode, args.poses):
                    r["family"] = family
                    rows.append(r)
    return rows


def _icploc_batch_rows(pts, nrm, size, scen, scans, mode, n_poses) -> list[dict[str, Any]]:
    """icploc's own way to use every core: ``icp_batch`` over all poses of a cell (GIL
    released, one alignment per thread). Reported as wall time / alignments (a mean)."""
    import icploc

    t0 = time.perf_counter()
    index = icploc.MapIndex(pts, nrm)
    build = time.perf_counter() - t0
    cfgs = _icploc_configs("point_to_line", one_call=False)
    out = []
    for level in sc.ERROR_LEVELS:
        starts = scen.starts[level][:n_poses]
        icploc.icp_batch(scans[:2], index, starts[:2], cfgs[0])  # warm-up (thread pool)
        t1 = time.perf_counter()
        est = np.asarray(starts, dtype=np.float64)
        for cfg in cfgs:
            est = np.array([r.pose for r in icploc.icp_batch(scans[:n_poses], index, est, cfg)])
        wall = time.perf_counter() - t1
        te, re = pose_errors(est, scen.poses[:n_poses])
        per = wall / n_poses * 1e3
        out.append(
            {
                "method": "icploc p2l icp_batch", "library": f"icploc {icploc.__version__}", "threads": mode,
                "map_points": int(len(pts)), "size": size, "start": level, "poses": n_poses, "build_s": build,
                "median_ms": per, "times_ms": [per] * n_poses,
                "median_te_mm": float(np.median(te) * 1e3), "median_re_deg": float(np.degrees(np.median(re))),
                "success": float(np.mean((te < SUCCESS_T) & (re < SUCCESS_R))),
                "te_m": te.tolist(), "re_rad": re.tolist(),
                "note": "icp_batch (two stages) over all poses, all cores; ms/align = wall time / alignments",
            }
        )  # fmt: skip
    return out


# --------------------------------------------------------------------------- end to end


def replay_throughput(num_scans: int, single: bool = True) -> dict[str, Any]:
    """Replay one generated log (odometry + scans) through the numpy tracker and, when it
    exists, ``icploc.Localizer``; scans per second and position errors for each."""
    from numpy_tracker import NumpyTracker

    log = sc.make_replay_log(num_scans=num_scans)
    pts, nrm, _ = sc.map_for_size(log.segments, 10_000)
    out: dict[str, Any] = {"scans": num_scans, "map_points": int(len(pts))}

    tracker = NumpyTracker(pts, initial_pose=tuple(log.truth[0]), workers=1 if single else -1)
    scans = [s.points() for s in log.scans]
    t0 = time.perf_counter()
    est = np.array([tracker.update(scans[i], tuple(log.odometry[i])) for i in range(num_scans)])
    dt = time.perf_counter() - t0
    te, re = pose_errors(est, log.truth)
    out["numpy tracker"] = {
        "scans_per_s": num_scans / dt, "median_te_mm": float(np.median(te) * 1e3),
        "max_te_mm": float(te.max() * 1e3), "max_re_deg": float(np.degrees(re.max())),
    }  # fmt: skip
    try:
        import icploc

        localizer_cls = getattr(icploc, "Localizer", None)
        if localizer_cls is None:
            from icploc.localizer import Localizer as localizer_cls
    except (ImportError, AttributeError) as e:
        out["icploc Localizer"] = {"skipped": f"icploc.Localizer not available ({type(e).__name__}: {e})"}
        return out
    try:
        from icploc.messages import Odometry, Scan

        loc = _make_localizer(localizer_cls, pts, nrm, log)
        scan_objs = [
            Scan(stamp=float(log.stamps[i]), ranges=s.ranges, angles=s.angles, seq=i, max_range=sc.MAX_RANGE)
            for i, s in enumerate(log.scans)
        ]
        odo_objs = [Odometry(stamp=float(log.stamps[i]), pose=tuple(log.odometry[i])) for i in range(num_scans)]
        t0 = time.perf_counter()
        ests = [loc.update(scan_objs[i], odo_objs[i]) for i in range(num_scans)]
        dt = time.perf_counter() - t0
        est = np.array([tuple(e.pose) for e in ests])
        te, re = pose_errors(est, log.truth)
        out["icploc Localizer"] = {
            "scans_per_s": num_scans / dt, "median_te_mm": float(np.median(te) * 1e3),
            "max_te_mm": float(te.max() * 1e3), "max_re_deg": float(np.degrees(re.max())),
        }  # fmt: skip
    except Exception as e:  # the Localizer is young; say why instead of dying
        out["icploc Localizer"] = {"skipped": f"{type(e).__name__}: {e}"}
    return out


def _make_localizer(cls: Any, pts: NDArray[np.float64], nrm: NDArray[np.float64], log: sc.ReplayLog) -> Any:
    """Build ``icploc.Localizer`` for the generated map, starting at the true first pose."""
    import icploc

    index = icploc.MapIndex(pts, nrm)
    init = tuple(float(v) for v in log.truth[0])
    errors = []
    for attempt in (
        lambda: cls(index, initial_pose=init),
        lambda: cls(index, None, initial_pose=init),
        lambda: cls.from_points(pts, nrm, initial_pose=init),
    ):
        try:
            return attempt()
        except Exception as e:
            errors.append(f"{type(e).__name__}: {e}")
    raise RuntimeError("could not construct icploc.Localizer: " + " | ".join(errors))


# --------------------------------------------------------------------------- report


def _fmt_ms(v: float) -> str:
    return f"{v:.3g}" if v < 100 else f"{v:.0f}"


def _fmt_ratio(v: float) -> str:
    return f"{v:.2g}×" if v < 10 else f"{v:.0f}×"


def render_markdown(result: dict[str, Any]) -> str:
    rows = [r for m in result["modes"] for r in m["rows"]]
    lines: list[str] = []
    lines.append("## icploc vs peers: 2D scan-to-map ICP\n")
    lines.append(f"Machine: {result['machine']}. Command: `{result['command']}`. "
                 f"Poses per cell: {result['poses']} (Open3D and small_gicp GICP at 1M points: {result['big_map_poses']}, they take 0.5–2 s per alignment there). "
                 "Success = within 2 cm and 0.5°. Times are medians per alignment. "
                 f"icploc native module built {result.get('icploc_build')}.\n")  # fmt: skip
    if result.get("warning"):
        lines.append(f"**Warning: {result['warning']}.**\n")
    lines.append("| threads | family | map pts | start | method | build ms | ms/align | p95 ms | med. err mm | med. err ° | success | icploc default is ×faster |")
    lines.append("|---|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|")
    key = lambda r: (r["threads"], r.get("family", "office"), r["size"], r["start"])  # noqa: E731
    ref = {key(r): r for r in rows if r["method"] == "icploc default"}
    for r in rows:
        base = ref.get(key(r))
        ratio = _fmt_ratio(r["median_ms"] / base["median_ms"]) if base and r is not base else ""
        p95 = _fmt_ms(float(np.percentile(r["times_ms"], 95))) if r.get("times_ms") else ""
        lines.append(
            f"| {r['threads']} | {r.get('family', 'office')} | {r['map_points']:,} | {r['start']} | {r['method']} | {r['build_s'] * 1e3:.3g} | "
            f"{_fmt_ms(r['median_ms'])} | {p95} | {r['median_te_mm']:.2f} | {r['median_re_deg']:.3f} | "
            f"{r['success'] * 100:.1f}% | {ratio} |"
        )
    # speed ratio of each icploc variant to each peer
    peers = sorted({r["method"] for r in rows if not r["method"].startswith("icploc")}, key=lambda n: [x["method"] for x in rows].index(n))
    for ic in ("icploc default", "icploc p2l", "icploc p2l warm", "icploc p2p"):
        if not any(r["method"] == ic for r in rows):
            continue
        lines.append(f"\n**Speed-up of {ic}** (peer median time / {ic} median time, same run; "
                     "bold: the peer's success rate is ≥ icploc's):\n")  # fmt: skip
        lines.append("| threads | family | map pts | start | " + " | ".join(peers) + " | fastest peer at ≥ its success |")
        lines.append("|---|---|---:|---|" + "---:|" * (len(peers) + 1))
        fam_order = {f: i for i, f in enumerate(sc.FAMILIES)}
        for k in sorted({key(r) for r in rows}, key=lambda k: (k[0] != "single", fam_order.get(k[1], 9), k[2], k[3] != "small")):
            mine = next((r for r in rows if key(r) == k and r["method"] == ic), None)
            if mine is None:
                continue
            cells, best = [], None
            for p in peers:
                pr = next((r for r in rows if key(r) == k and r["method"] == p), None)
                if pr is None:
                    cells.append("—")
                    continue
                ratio = pr["median_ms"] / mine["median_ms"]
                s = _fmt_ratio(ratio)
                as_good = pr["success"] >= mine["success"]
                cells.append(f"**{s}**" if as_good else s)
                if as_good and (best is None or pr["median_ms"] < best[1]):
                    best = (p, pr["median_ms"], ratio)
            fastest = f"{best[0]}: {_fmt_ratio(best[2])}" if best else "none as successful"
            lines.append(f"| {k[0]} | {k[1]} | {mine['map_points']:,} | {k[3]} | " + " | ".join(cells) + f" | {fastest} |")
    lines.append("\n**Settings** (each peer's best reasonable settings for this problem):\n")
    settings = {}
    for m in result["modes"]:
        settings.update(m["settings"])
    for name, s in settings.items():
        lines.append(f"- **{name}** ({s['library']}): {s['settings']}")
    notes = {r["method"]: r["note"] for r in rows if r.get("note")}
    for name, n in notes.items():
        lines.append(f"- {name}: {n}" + (" (last map size)" if "ms each" in n else ""))
    lines.append("- icploc's build time includes its closest-point grid (2 cm cells over the map + 2 m), "
                 "computed at build: every correspondence afterwards is one array read.")  # fmt: skip
    skipped = {}
    for m in result["modes"]:
        skipped.update(m["skipped"])
    for name, why in skipped.items():
        lines.append(f"- skipped **{name}**: {why}")
    rep = result.get("replay")
    if rep:
        lines.append(f"\n**End to end** (replay of one generated log, {rep['scans']} scans, odometry drifting 2 %, "
                     f"map {rep['map_points']:,} points, one thread):\n")  # fmt: skip
        lines.append("| tracker | scans/s | median err mm | max err mm | max err ° |")
        lines.append("|---|---:|---:|---:|---:|")
        for name in ("icploc Localizer", "numpy tracker"):
            v = rep.get(name, {})
            if "skipped" in v:
                lines.append(f"| {name} | skipped: {v['skipped']} | | | |")
            elif v:
                lines.append(f"| {name} | {v['scans_per_s']:.0f} | {v['median_te_mm']:.2f} | {v['max_te_mm']:.1f} | {v['max_re_deg']:.2f} |")
    return "\n".join(lines) + "\n"


def icploc_build_stamp() -> str | None:
    """Modification time of the installed native module (to catch a rebuild mid-run)."""
    try:
        import importlib.util

        spec = importlib.util.find_spec("icploc._core")
        if spec is None or spec.origin is None:
            return None
        return time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(Path(spec.origin).stat().st_mtime))
    except Exception:
        return None


def machine_description() -> str:
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{cpu}, {os.cpu_count()} logical cores, {platform.system()} {platform.release()}, Python {platform.python_version()}"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="smoke run: 1k and 10k points, 10 poses, short replay")
    p.add_argument("--sizes", default=None, help="comma-separated map sizes (default 1000,10000,100000,1000000)")
    p.add_argument("--poses", type=int, default=None, help="poses per cell (default 50)")
    p.add_argument("--big-map-poses", type=int, default=15, help="poses for slow peers (Open3D, small_gicp GICP) at 1M points")
    p.add_argument("--threads", choices=("single", "default", "both"), default="both")
    p.add_argument("--methods", default=None, help="comma-separated substrings of method names to run")
    p.add_argument("--replay-scans", type=int, default=None, help="scans in the end-to-end replay (0: skip)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--families", default=",".join(sc.FAMILIES), help=f"comma-separated scenario families (default {','.join(sc.FAMILIES)})")
    p.add_argument("--out", default=str(HERE / "results"), help="directory for peers.md / peers.json")
    p.add_argument("--tag", default="", help="suffix of the output file names (peers<tag>.md), e.g. -reduced")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.sizes is None:
        a.sizes = "1000,10000" if a.quick else ",".join(str(s) for s in sc.MAP_SIZES)
    a.sizes = [int(float(s)) for s in str(a.sizes).split(",") if s]
    if a.poses is None:
        a.poses = 10 if a.quick else 50
    if a.replay_scans is None:
        a.replay_scans = 200 if a.quick else 2000
    a.families = [f for f in str(a.families).split(",") if f]
    for f in a.families:
        if f not in sc.FAMILIES:
            p.error(f"--families: unknown family {f!r} (choose from {', '.join(sc.FAMILIES)})")
    return a


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.child:  # inside one thread mode: run and dump JSON to the given path
        mode, path = args.child.split(":", 1)
        res = run_mode(args, mode)
        if mode == "single" and args.replay_scans > 0:
            res["replay"] = replay_throughput(args.replay_scans, single=True)
        Path(path).write_text(json.dumps(res))
        return 0
    modes = ["single", "default"] if args.threads == "both" else [args.threads]
    argv_child = [a for a in (argv if argv is not None else sys.argv[1:])]
    result: dict[str, Any] = {
        "machine": machine_description(),
        "command": "python benches/peers.py " + " ".join(argv_child),
        "poses": args.poses,
        "big_map_poses": args.big_map_poses,
        "sizes": args.sizes,
        "modes": [],
    }
    result["icploc_build"] = icploc_build_stamp()
    with tempfile.TemporaryDirectory() as tmp:
        for mode in modes:
            path = Path(tmp) / f"{mode}.json"
            env = dict(os.environ)
            if mode == "single":
                env.update(SINGLE_ENV)
            else:
                for k in SINGLE_ENV:
                    env.pop(k, None)
            print(f"== {mode}-thread run", file=sys.stderr, flush=True)
            cmd = [sys.executable, str(Path(__file__).resolve()), *argv_child, "--child", f"{mode}:{path}"]
            subprocess.run(cmd, env=env, check=True)
            res = json.loads(path.read_text())
            if "replay" in res:
                result["replay"] = res.pop("replay")
            result["modes"].append(res)
    loaded = sorted({str(m.get("icploc_build")) for m in result["modes"]})
    result["icploc_build"] = loaded[0] if len(loaded) == 1 else result["icploc_build"]
    if len(loaded) > 1:
        result["warning"] = f"the thread modes ran different icploc builds ({', '.join(loaded)})"
        print("WARNING: " + result["warning"], file=sys.stderr)
    md = render_markdown(result)
    print(md)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    suffix = args.tag or ("-quick" if args.quick else "")
    (out / f"peers{suffix}.md").write_text(md)
    (out / f"peers{suffix}.json").write_text(json.dumps(result, indent=1))
    print(f"wrote {out / f'peers{suffix}.md'} and {out / f'peers{suffix}.json'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

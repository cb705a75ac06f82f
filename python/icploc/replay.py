"""``icploc replay``: localize a recorded log against a map, deterministically, as fast
as the machine allows.

The log (CARMEN, ROS 1 / ROS 2 bag, or our raw-byte recording; :func:`icploc.logs.open_log`)
is merged in time order; each scan is localized with the odometry interpolated to its
stamp (a scan waits for the first odometry sample at or after it). One TUM row is
written per scan with the scan's stamp, also while lost (the best guess).

Nothing is lost: the readers skip and count malformed lines and turn impossible readings
into invalid beams (``strict=True`` refuses instead); the TUM and estimates CSV rows are
written and flushed as the replay goes; Ctrl-C ends the loop with the files complete up to
there and ``ReplayResult.interrupted`` set; an output path that is an input (the log, the
map or its image, the truth, the config) or cannot be written is refused before any work.
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from icploc.config import LocalizerConfig
from icploc.localizer import Estimate, Localizer, Status, run
from icploc.types import Odometry, Scan

if TYPE_CHECKING:
    from icploc.logs import LogInfo

__all__ = ["ReplayResult", "load_map", "parse_pose", "read_tum", "replay"]


@dataclass
class ReplayResult:
    log: str
    estimates: list[Estimate]
    odometry: list[Odometry]
    load_time: float  #: seconds to read and parse the log
    localize_time: float  #: seconds in the localization loop
    status_counts: dict[str, int]
    metrics: dict[str, float] = field(default_factory=dict)
    files: dict[str, Path] = field(default_factory=dict)
    #: what the log reader read, dropped and repaired (None for an in-memory log)
    log_info: LogInfo | None = None
    #: scans in the log (``scans`` is fewer when the replay was interrupted)
    scans_in_log: int = 0
    #: messages of an in-memory log dropped for a non-finite stamp
    dropped_stamps: int = 0
    #: the replay was stopped by Ctrl-C (the files hold every scan localized until then)
    interrupted: bool = False
    #: more summary lines (icploc.outside: the stretches outside the map)
    notes: list[str] = field(default_factory=list)

    @property
    def scans(self) -> int:
        return len(self.estimates)

    @property
    def lost_share(self) -> float:
        """Share of the localized scans reported ``lost`` (0 when there are none)."""
        return self.status_counts.get("lost", 0) / self.scans if self.scans else 0.0

    @property
    def total_time(self) -> float:
        return self.load_time + self.localize_time

    @property
    def rate(self) -> float:
        """Scans per second end to end (parse + localize)."""
        return self.scans / self.total_time if self.total_time > 0 else float("inf")

    @property
    def poses(self) -> NDArray[np.float64]:
        return np.array([e.pose for e in self.estimates], dtype=np.float64).reshape(-1, 3)

    @property
    def stamps(self) -> NDArray[np.float64]:
        return np.array([e.stamp for e in self.estimates], dtype=np.float64)

    def summary(self) -> str:
        c = self.status_counts
        parts = [
            f"{self.scans} scans in {self.total_time:.2f} s "
            f"({self.rate:,.0f} scans/s end to end; parse {self.load_time:.2f} s, "
            f"localize {self.localize_time:.2f} s)",
            "status: " + ", ".join(f"{k} {c.get(k, 0)}" for k in ("tracking", "degraded", "lost")),
        ]
        amb = sum(1 for e in self.estimates if e.status.value == "lost" and e.reason == "ambiguous")
        if amb:
            parts[-1] += f" ({amb} of them ambiguous: several places fit the scans equally well)"
        if self.interrupted:
            parts.append(
                f"interrupted: {self.scans} of {self.scans_in_log} scans localized; "
                "the output files hold all of them"
            )
        if self.log_info is not None:
            parts.extend("log: " + d.strip() for d in self.log_info.damage_lines())
        if self.dropped_stamps:
            parts.append(f"log: dropped {self.dropped_stamps} message(s) with a non-finite stamp")
        cal = getattr(self.estimates[-1], "calibration", None) if self.estimates else None
        if cal is not None:
            s_, t_, d_ = cal
            parts.append(
                f"odometry calibration (learned): distance x{s_:.4f}, turns x{t_:.4f}, "
                f"heading drift {math.degrees(d_):+.2f} deg/m"
            )
        parts.extend(self.notes)
        if self.metrics:
            parts.append(
                "vs truth: "
                + ", ".join(
                    f"{k} {v * 1000:.1f} mm" if k.endswith("_m") else f"{k} {v:.3f}"
                    for k, v in self.metrics.items()
                )
            )
        return "\n".join(parts)


def parse_pose(text: str) -> tuple[float, float, float]:
    """``"X,Y,THETA"`` (metres, radians) → a pose; a clear error otherwise."""
    parts = [p for p in text.replace(" ", ",").split(",") if p]
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        raise ValueError(f"initial pose must be X,Y,THETA (numbers), got {text!r}") from None
    if len(vals) != 3 or not all(math.isfinite(v) for v in vals):
        raise ValueError(f"initial pose must be three finite numbers X,Y,THETA, got {text!r}")
    return (vals[0], vals[1], vals[2])


def read_tum(path: str | Path) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """A TUM trajectory as (stamps (N,), poses (N, 3)); uses :mod:`icploc.trajectory`
    when present. Errors name the file and line."""
    try:
        from icploc import trajectory as tr

        reader = getattr(tr, "read_tum", None)
        if reader is not None:
            got = reader(path)
            if isinstance(got, tuple) and len(got) == 2:
                return np.asarray(got[0], dtype=np.float64), np.asarray(got[1], dtype=np.float64)
            if hasattr(got, "stamps") and hasattr(got, "poses"):
                return np.asarray(got.stamps, dtype=np.float64), np.asarray(
                    got.poses, dtype=np.float64
                )
    except ImportError:
        pass
    stamps: list[float] = []
    poses: list[tuple[float, float, float]] = []
    with open(path) as f:
        for n, line in enumerate(f, 1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            tok = s.split()
            if len(tok) != 8:
                raise ValueError(
                    f"{path}:{n}: a TUM row has 8 fields (stamp x y z qx qy qz qw), got {len(tok)}"
                )
            try:
                t, x, y, _z, qx, qy, qz, qw = (float(v) for v in tok)
            except ValueError:
                raise ValueError(f"{path}:{n}: not a number in {s!r}") from None
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            stamps.append(t)
            poses.append((x, y, yaw))
    return np.array(stamps), np.array(poses).reshape(-1, 3)


def load_map(map_arg: Any, cache: bool | None = None) -> Any:
    """A Map from a path (anything ``icploc.Map.load`` reads; ``cache`` as there: None uses
    the prepared-map cache unless ICPLOC_NO_CACHE is set, False neither reads nor writes it),
    or pass a Map / MapIndex through."""
    if isinstance(map_arg, (str, Path)):
        from icploc.maps import Map

        return Map.load(map_arg, cache=cache)
    return map_arg


def _metrics(
    stamps: NDArray[np.float64],
    poses: NDArray[np.float64],
    t_true: NDArray[np.float64],
    p_true: NDArray[np.float64],
) -> dict[str, float]:
    """ATE (positions, both in the map frame: no alignment) and RPE over 1 m segments."""
    if len(t_true) < 2 or len(stamps) == 0:
        return {}
    order = np.argsort(t_true)
    t_true, p_true = t_true[order], p_true[order]
    inside = (stamps >= t_true[0]) & (stamps <= t_true[-1])
    if not inside.any():
        return {}
    st, ps = stamps[inside], poses[inside]
    tx = np.interp(st, t_true, p_true[:, 0])
    ty = np.interp(st, t_true, p_true[:, 1])
    th_u = np.unwrap(p_true[:, 2])
    tth = np.interp(st, t_true, th_u)
    e = np.hypot(ps[:, 0] - tx, ps[:, 1] - ty)
    eth = np.abs(np.angle(np.exp(1j * (ps[:, 2] - tth))))
    out = {
        "ate_rmse_m": float(np.sqrt(np.mean(e**2))),
        "ate_median_m": float(np.median(e)),
        "ate_p95_m": float(np.percentile(e, 95)),
        "ate_max_m": float(e.max()),
        "heading_max_deg": float(np.degrees(eth.max())),
    }
    # RPE: relative translation error over ~1 m of travel
    d = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(tx), np.diff(ty)))])
    j = np.searchsorted(d, d + 1.0)
    ok = j < len(d)
    if ok.any():
        i = np.nonzero(ok)[0]
        j = j[ok]
        rel_true = np.column_stack([tx[j] - tx[i], ty[j] - ty[i]])
        rel_est = ps[j, :2] - ps[i, :2]
        out["rpe_1m_rmse_m"] = float(np.sqrt(np.mean(np.sum((rel_est - rel_true) ** 2, axis=1))))
    return out


def replay(
    log: str | Path | Sequence[Scan | Odometry],
    map_: Any,
    *,
    config: LocalizerConfig | None = None,
    initial_pose: Sequence[float] | None = None,
    out: str | Path | None = None,
    truth: str | Path | tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
    plot: str | Path | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    log_options: dict[str, Any] | None = None,
    odometry: str = "auto",
    global_localize: bool = False,
    estimates: str | Path | None = None,
    strict: bool = False,
    inputs: Sequence[str | Path] = (),
    on_localizer: Callable[[Localizer], None] | None = None,
    map_cache: bool | None = None,
    partial_map: bool = False,
    map_patch: str | Path | None = None,
) -> ReplayResult:
    """Replay ``log`` (a path, or a time-ordered sequence of Scan / Odometry) against
    ``map_`` (a path or a Map). Initial pose: ``initial_pose``, else the first truth pose,
    else ``config.localizer.initial_pose``, else none: global localization
    (:func:`icploc.relocalize.attach`), also forced by ``global_localize=True``.
    ``odometry``: ``"auto"`` uses the odometry the log records with each scan when it has
    one for every scan (CARMEN), else the odometry stream; ``"stream"`` / ``"scan"`` force one.

    ``out`` (TUM) and ``estimates`` (CSV, :data:`icploc.trajectory.ESTIMATE_COLUMNS`) are
    written row by row as the replay goes. ``strict``: a malformed line or an impossible
    reading in the log is an error instead of being skipped and counted. ``inputs``: more
    files the run reads (a config file) that no output may overwrite. Raises
    :class:`icploc.outputs.OutputError` before any work for an unusable output path."""
    from icploc.outputs import check_outputs, map_inputs
    from icploc.trajectory import EstimatesWriter, TumWriter

    if odometry not in ("auto", "stream", "scan"):
        raise ValueError(f"odometry must be 'auto', 'stream' or 'scan', got {odometry!r}")
    ins: list[str | Path] = [*inputs]
    if isinstance(log, (str, Path)):
        ins.append(log)
    if isinstance(map_, (str, Path)):
        ins.extend(map_inputs(map_))
    if isinstance(truth, (str, Path)):
        ins.append(truth)
    outs: dict[str, Any] = {"--out": out, "--estimates": estimates, "--plot": plot}
    if map_patch is not None:  # icploc.outside / icploc.mappatch: the map's missing parts
        from icploc.mappatch import patch_outputs

        outs.update(patch_outputs(map_patch))
    check_outputs(outs, ins)

    cfg = config or LocalizerConfig()
    t0 = time.perf_counter()
    name = str(log) if isinstance(log, (str, Path)) else "<memory>"
    info = None
    dropped_stamps = 0
    if isinstance(log, (str, Path)):
        from icploc.logs import open_log

        opts = dict(log_options or {})
        if strict:
            opts["strict"] = True
        data = open_log(log, **opts)
        info = data.info
        scans = list(data.scans)
        odoms = list(data.odometry)
        per_scan = np.asarray(data.scan_odometry, dtype=np.float64).reshape(-1, 3)
        if odometry == "scan" and len(per_scan) != len(scans):
            raise ValueError(f"{name}: the log has no odometry recorded with its scans")
        if (
            odometry in ("auto", "scan")
            and len(per_scan) == len(scans)
            and len(scans)
            and np.isfinite(per_scan).all()
        ):
            # the odometry the log recorded with each scan (CARMEN FLASER / ROBOTLASER1): in
            # step with the scan by construction, unlike an ODOM stream whose stamps may
            # have been repaired
            odoms = [
                Odometry(s.stamp, (p[0], p[1], p[2])) for s, p in zip(scans, per_scan, strict=True)
            ]
    else:
        scans = [m for m in log if isinstance(m, Scan)]
        odoms = [m for m in log if isinstance(m, Odometry)]
        # a message without a usable stamp cannot be placed in time: dropped, counted
        ok_s = [s for s in scans if math.isfinite(s.stamp)]
        ok_o = [o for o in odoms if math.isfinite(o.stamp) and all(map(math.isfinite, o.pose))]
        dropped_stamps = len(scans) - len(ok_s) + len(odoms) - len(ok_o)
        if dropped_stamps and strict:
            raise ValueError(f"{name}: {dropped_stamps} message(s) with a non-finite stamp or pose")
        scans, odoms = ok_s, ok_o
    load_time = time.perf_counter() - t0
    if not scans:
        why = "; ".join(d.strip() for d in info.damage_lines()) if info is not None else ""
        raise ValueError(f"{name}: the log holds no laser scans" + (f" ({why})" if why else ""))

    t_true = p_true = None
    if truth is not None:
        t_true, p_true = read_tum(truth) if isinstance(truth, (str, Path)) else truth
        t_true = np.asarray(t_true, dtype=np.float64)
        p_true = np.asarray(p_true, dtype=np.float64).reshape(-1, 3)

    if initial_pose is None and not global_localize:
        if t_true is not None and len(t_true):
            k = int(np.argmin(np.abs(t_true - scans[0].stamp)))
            initial_pose = tuple(p_true[k])  # type: ignore[index]
        elif cfg.localizer.initial_pose is not None:
            initial_pose = cfg.localizer.initial_pose

    m = load_map(map_, map_cache)
    t1 = time.perf_counter()
    loc = Localizer(m, cfg, initial_pose=initial_pose)
    if initial_pose is None:
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:  # global_localize over a configured pose
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:  # hooks: icploc.mcap_export (--mcap)
        on_localizer(loc)
    outside = None
    if partial_map or map_patch is not None:
        from icploc.outside import attach as attach_outside

        outside = attach_outside(loc, record=map_patch is not None)
    n = len(scans)
    step = max(1, n // 200)
    got: list[Estimate] = []
    writers: list[Any] = []
    tum = est_csv = None
    interrupted = False
    try:
        # opened only now: a log or map that fails to load leaves an existing file alone
        if out is not None:
            tum = TumWriter(out)
            writers.append(tum)
        if estimates is not None:
            est_csv = EstimatesWriter(estimates)
            writers.append(est_csv)

        def each(e: Estimate) -> None:
            got.append(e)
            if tum is not None:
                tum.write(e.stamp, e.pose)
            if est_csv is not None:
                est_csv.write(e)
            k = len(got)
            if on_progress is not None and (k % step == 0 or k == n):
                on_progress(k, n)

        from icploc.logs import merge_in_time

        try:
            run(loc, merge_in_time(scans, odoms), each)
        except KeyboardInterrupt:
            interrupted = True
    finally:
        for w in writers:
            w.close()
    localize_time = time.perf_counter() - t1
    res = ReplayResult(
        log=name,
        estimates=got,
        odometry=odoms,
        load_time=load_time,
        localize_time=localize_time,
        status_counts=dict(Counter(e.status.value for e in got)),
        log_info=info,
        scans_in_log=n,
        dropped_stamps=dropped_stamps,
        interrupted=interrupted,
    )
    if out is not None:
        res.files["trajectory"] = Path(out)
    if estimates is not None:
        res.files["estimates"] = Path(estimates)
    if t_true is not None and p_true is not None:
        res.metrics = _metrics(res.stamps, res.poses, t_true, p_true)
    if outside is not None:
        outside.finish(res, m, map_patch)
    if plot is not None and got:
        res.files["plot"] = plot_replay(
            res, m, plot, truth=(t_true, p_true) if t_true is not None else None
        )
    return res


def plot_replay(
    res: ReplayResult,
    map_: Any,
    path: str | Path,
    truth: tuple[Any, Any] | None = None,
) -> Path:
    """The map with the odometry, localized (and true) trajectories, like Fig. 9–11."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from icploc.se2 import between, compose

    fig, ax = plt.subplots(figsize=(8, 8), constrained_layout=True)
    lines = getattr(map_, "lines", None)
    if lines is not None and len(lines):
        for x1, y1, x2, y2 in np.asarray(lines):
            ax.plot([x1, x2], [y1, y2], color="k", lw=0.8)
    elif hasattr(map_, "points"):
        pts = np.asarray(map_.points)
        ax.plot(pts[:, 0], pts[:, 1], ",", color="k")
    P = res.poses
    ests = res.estimates
    odo0 = next((e.odometry for e in ests if e.odometry is not None), None)
    if odo0 is not None:
        start = ests[0].pose
        odo = np.array(
            [compose(start, between(odo0, e.odometry)) for e in ests if e.odometry is not None]
        )
        ax.plot(odo[:, 0], odo[:, 1], color="tab:red", lw=0.8, label="odometry")
    if truth is not None:
        ax.plot(truth[1][:, 0], truth[1][:, 1], color="0.5", ls="--", lw=0.8, label="truth")
    # lost stretches are drawn as such (the dead-reckoned pose, dotted), never as part of
    # the localized line
    lost = np.array([e.status.value == "lost" for e in ests], dtype=bool)
    ok_xy = P[:, :2].astype(float, copy=True)
    ok_xy[lost] = np.nan
    ax.plot(ok_xy[:, 0], ok_xy[:, 1], color="tab:blue", lw=1.0, label="localized")
    if lost.any():
        lost_xy = P[:, :2].astype(float, copy=True)
        keep = lost.copy()
        keep[1:] |= lost[:-1]  # join each lost stretch to the scan before it
        lost_xy[~keep] = np.nan
        ax.plot(lost_xy[:, 0], lost_xy[:, 1], ":", color="tab:orange", lw=1.0,
                label=f"lost, dead-reckoned ({int(lost.sum())} scans)")  # fmt: skip
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(Path(res.log).name)
    p = Path(path)
    fig.savefig(p, dpi=110)
    plt.close(fig)
    return p

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
from icploc.messages import Odometry, Scan
from icploc.trajectory import Evaluation, Trajectory, evaluate, read_tum

if TYPE_CHECKING:
    from icploc.logs import LogInfo

__all__ = ["ReplayResult", "load_map", "parse_pose", "replay"]


@dataclass
class ReplayResult:
    log: str
    estimates: list[Estimate]
    odometry: list[Odometry]
    load_time: float  #: seconds to read and parse the log
    localize_time: float  #: seconds in the localization loop
    status_counts: dict[str, int]
    #: figures against ``truth`` (:meth:`icploc.trajectory.Evaluation.metrics`)
    metrics: dict[str, float] = field(default_factory=dict)
    #: the whole evaluation against ``truth`` (None without one, or none overlapping)
    evaluation: Evaluation | None = None
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

    @property
    def finite(self) -> NDArray[np.bool_]:
        """Which estimates have a finite stamp and pose (all of them, unless the localizer
        failed its promise; a non-finite one cannot be scored or drawn)."""
        return np.isfinite(self.stamps) & np.isfinite(self.poses).all(axis=1)

    @property
    def trajectory(self) -> Trajectory:
        """The estimates as a :class:`~icploc.trajectory.Trajectory`: one pose per scan
        (the :attr:`finite` ones)."""
        ok = self.finite
        return Trajectory(self.stamps[ok], self.poses[ok])

    def odometry_trajectory(self) -> Trajectory:
        """The odometry of the localized scans, started at the first estimate's pose (how
        far dead reckoning alone would have gone, in the map frame)."""
        ests = [
            e
            for e in self.estimates
            if e.odometry is not None and np.isfinite(e.stamp) and np.isfinite(e.odometry).all()
        ]
        if not ests:
            return Trajectory.empty()
        odo = Trajectory(
            np.array([e.stamp for e in ests]), np.array([e.odometry for e in ests])
        )
        return odo.started_at(self.estimates[0].pose)

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
            parts.extend("log: " + n for n in self.log_info.notes)
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


def load_map(map_arg: Any, cache: bool | None = None) -> Any:
    """A Map from a path (anything ``icploc.Map.load`` reads; ``cache`` as there: None uses
    the prepared-map cache unless ICPLOC_NO_CACHE is set, False neither reads nor writes it),
    or pass a Map / MapIndex through."""
    if isinstance(map_arg, (str, Path)):
        from icploc.maps import Map

        return Map.load(map_arg, cache=cache)
    return map_arg


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
    partial_map: bool | None = None,
    map_patch: str | Path | None = None,
    map_patch_open: bool = False,
    map_patch_confident_only: bool = False,
    on_outside: Callable[[Any], None] | None = None,
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
    files the run reads (a config file) that no output may overwrite.

    ``partial_map``: the outside-the-map state (:mod:`icploc.outside`: a scan outside the
    map coasts on the odometry, reason ``outside_map``, ``mapped`` False, never
    ``tracking``). None (default): the config's ``outside.enabled`` (true by default; the
    :class:`Localizer` attaches it); True / False: on / off whatever the config says.
    ``map_patch`` needs it and turns it on (with ``partial_map=False`` a ValueError, as
    ``--no-partial-map --map-patch`` is a usage error; ``map_patch_open`` and
    ``map_patch_confident_only`` need ``map_patch``). Raises
    :class:`icploc.outputs.OutputError` before any work for an unusable output path."""
    from icploc.outputs import check_outputs, map_inputs
    from icploc.trajectory import EstimatesWriter, TumWriter

    if odometry not in ("auto", "stream", "scan"):
        raise ValueError(f"odometry must be 'auto', 'stream' or 'scan', got {odometry!r}")
    # the same refusals as ``icploc replay``'s usage errors (--no-partial-map with
    # --map-patch; --map-patch-open / --confident-only without --map-patch)
    if partial_map is False and map_patch is not None:
        raise ValueError(
            "map_patch needs the outside-the-map state, which partial_map=False turns off "
            "(leave partial_map None or True)"
        )
    if map_patch is None and (map_patch_open or map_patch_confident_only):
        which = "map_patch_open" if map_patch_open else "map_patch_confident_only"
        raise ValueError(f"{which} needs map_patch (it changes only what the patch draws)")
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
        from icploc.logs import detect_format as open_log_format
        from icploc.logs import open_log

        opts = dict(log_options or {})
        if strict:
            opts["strict"] = True
        if cfg.scan.lasers and open_log_format(log) == "carmen":  # hook: icploc.multilaser
            opts.setdefault("rear_laser", True)
        data = open_log(log, **opts)
        info = data.info
        if info.format == "recorded":  # hook (sim): the laser mounting the recording carries
            from icploc.logs.recorded import replay_config

            cfg, mounting_note = replay_config(log, cfg, config is not None)
            info.notes.append(mounting_note)
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

    truth_tr: Trajectory | None = None
    if truth is not None:
        if isinstance(truth, (str, Path)):
            truth_tr = read_tum(truth)
        else:
            truth_tr = Trajectory(
                np.asarray(truth[0], dtype=np.float64),
                np.asarray(truth[1], dtype=np.float64).reshape(-1, 3),
            )

    if initial_pose is None and not global_localize:
        if truth_tr is not None and len(truth_tr):
            k = int(np.argmin(np.abs(truth_tr.stamps - scans[0].stamp)))
            initial_pose = tuple(truth_tr.poses[k])
        elif cfg.localizer.initial_pose is not None:
            initial_pose = cfg.localizer.initial_pose

    m = load_map(map_, map_cache)
    t1 = time.perf_counter()
    if partial_map is False and cfg.outside.enabled:
        # off: the Localizer does not build the mapped area only for it to be dropped
        cfg = cfg.replace(outside={"enabled": False})
    if cfg.scan.lasers:  # hook: several lasers merged into one scan (icploc.multilaser)
        from icploc.multilaser import localizer_config

        loc = Localizer(m, localizer_config(cfg), initial_pose=initial_pose)
    else:
        loc = Localizer(m, cfg, initial_pose=initial_pose)
    if initial_pose is None:
        from icploc.relocalize import attach

        if loc.status is not Status.LOST:  # global_localize over a configured pose
            loc.reset(loc.pose, loc.covariance, Status.LOST)
        attach(loc)
    if on_localizer is not None:  # hooks: icploc.mcap_export (--mcap)
        on_localizer(loc)
    # the outside-the-map state: the Localizer's own (config ``outside.enabled``, on by
    # default; turned off above for ``partial_map`` False); ``partial_map`` True forces it
    # on; a map patch needs it
    if loc.outside is None and (partial_map or map_patch is not None):
        from icploc.outside import attach as attach_outside

        attach_outside(loc)
    outside = loc.outside
    if outside is not None:
        outside.record = map_patch is not None
        if on_outside is not None:  # hooks on the monitor (benches/eval_partial.py)
            on_outside(outside)
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

        stream: Any = merge_in_time(scans, odoms)
        if cfg.scan.lasers:  # hook: icploc.multilaser
            from icploc.multilaser import merge_stream

            stream = merge_stream(stream, cfg)
        try:
            run(loc, stream, each)
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
    if truth_tr is not None and len(truth_tr) >= 2 and got:
        # the truth interpolated at each scan's stamp; scans outside its span are left out
        res.evaluation = evaluate(res.trajectory, truth_tr)
        if res.evaluation is not None:
            res.metrics = res.evaluation.metrics()
    if outside is not None:
        outside.finish(
            res, m, map_patch, include_open=map_patch_open, confident_only=map_patch_confident_only
        )
    if plot is not None and got:
        from icploc.plotting import plot_run

        plot_run(
            plot,
            map=m,
            truth=truth_tr,
            odometry=res.odometry_trajectory(),
            localized=res.trajectory,
            status=[e.status for e, ok in zip(got, res.finite, strict=True) if ok],
            errors=res.evaluation.ate if res.evaluation is not None else None,
            title=Path(res.log).name,
        )
        res.files["plot"] = Path(plot)
    return res

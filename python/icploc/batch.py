"""``icploc batch``: replay many logs against one map in parallel on Dask distributed.

Each log is replayed by :func:`icploc.replay.replay` on a Dask worker, exactly as
``icploc replay LOG --map MAP`` (with ``--truth TRUTH_DIR/<stem>.tum`` when that file
exists) would: the same trajectory and per-scan estimates. For every log the client writes
``OUT/<stem>.tum`` (TUM trajectory) and ``OUT/<stem>.csv`` (per-scan estimates,
the columns of ``icploc replay --estimates``,
:data:`icploc.trajectory.ESTIMATE_COLUMNS`), and at the end ``OUT/summary.csv`` with one row per log. A log
that fails (unreadable, no scans, a worker that died) gets a row with its error; the others
go on.

The map is loaded (and sampled for the ICP index) once on the client and sent to every
worker once (``Client.scatter(..., broadcast=True)``). Without ``scheduler`` a
``LocalCluster`` of ``workers`` single-threaded processes is started (default: one per
core; forked from a server process with icploc loaded, where the platform can) and stopped
at the end; with ``scheduler="tcp://host:8786"`` the batch runs on that
cluster. Workers need icploc installed and must be able to read the log paths; the
outputs are written by the client.

Dask is an optional dependency (``pip install 'icploc[fleet]'``), imported only here.
"""

from __future__ import annotations

import contextlib
import copy
import csv
import math
import multiprocessing
import os
import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from icploc.config import LocalizerConfig
from icploc.errors import IcplocError

__all__ = [
    "BatchError",
    "BatchResult",
    "LogRow",
    "SUMMARY_HEADER",
    "batch_replay",
    "log_stem",
    "prepare_map",
]

SUMMARY_HEADER = (
    "log",
    "scans",
    "tracking",
    "degraded",
    "lost",
    "scans_per_s",
    "ate_rmse_m",
    "ate_max_m",
    "error",
)

_LOG_SUFFIXES = (".log", ".clf", ".bag", ".db3", ".mcap", ".raw", ".txt")


class BatchError(IcplocError, RuntimeError):
    """The batch cannot start (Dask missing, no scheduler at the address, bad arguments)."""


@dataclass
class LogRow:
    """One log's outcome: a summary row (``error`` is "" when the replay succeeded)."""

    log: str
    stem: str
    scans: int = 0
    tracking: int = 0
    degraded: int = 0
    lost: int = 0
    scans_per_s: float = math.nan
    ate_rmse_m: float = math.nan
    ate_max_m: float = math.nan
    error: str = ""
    files: dict[str, Path] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return not self.error

    def cells(self) -> list[str]:
        def num(v: float, fmt: str) -> str:
            return "" if math.isnan(v) else format(v, fmt)

        return [
            self.log,
            str(self.scans),
            str(self.tracking),
            str(self.degraded),
            str(self.lost),
            num(self.scans_per_s, ".1f"),
            num(self.ate_rmse_m, ".6f"),
            num(self.ate_max_m, ".6f"),
            self.error,
        ]


@dataclass
class BatchResult:
    rows: list[LogRow]  #: in the order the logs were given
    summary: Path
    wall_time: float

    @property
    def failed(self) -> list[LogRow]:
        return [r for r in self.rows if not r.ok]


def log_stem(path: str | Path) -> str:
    """The output name of a log: its file name without ``.gz`` and a log suffix
    (``intel-corrected.log.gz`` -> ``intel-corrected``; a ROS 2 bag folder keeps its name)."""
    name = Path(path).name
    if name.lower().endswith(".gz"):
        name = name[:-3]
    for s in _LOG_SUFFIXES:
        if name.lower().endswith(s) and len(name) > len(s):
            return name[: -len(s)]
    return name


def prepare_map(map_: Any, config: LocalizerConfig | None = None) -> Any:
    """Load ``map_`` (a path, or a Map passed through) and compute its ICP samples at the
    configured spacing, so workers receive a ready map (they only build the k-d tree)."""
    from icploc.replay import load_map

    cfg = config or LocalizerConfig()
    m = load_map(map_)
    sample = getattr(m, "sample", None)
    if callable(sample):
        sample(cfg.map.spacing)
    return _without_indexes(m)


def _without_indexes(m: Any) -> Any:
    """``m``, or a shallow copy without its cached k-d trees (Rust objects that do not
    pickle; each worker builds its own from the samples)."""
    from icploc._core import MapIndex

    if isinstance(m, MapIndex):
        raise BatchError("batch: give a Map (or a map file), not a MapIndex: it cannot be shipped")
    attrs = getattr(m, "__dict__", {})
    cached = [
        k
        for k, v in attrs.items()
        if isinstance(v, dict) and any(isinstance(x, MapIndex) for x in v.values())
    ]
    if not cached:
        return m
    c = copy.copy(m)
    for k in cached:
        setattr(c, k, {})
    return c


def _import_dask() -> Any:
    try:
        import distributed
    except ImportError:
        raise BatchError(
            "icploc batch needs Dask distributed, which is not installed: "
            "pip install 'icploc[fleet]'"
        ) from None
    return distributed


#: what the local workers' fork server imports once, so that each worker starts ready
_WORKER_PRELOAD = ["distributed", "icploc.batch", "icploc.replay", "icploc.localizer", "icploc.maps"]


@contextlib.contextmanager
def _worker_start_method() -> Iterator[None]:
    """Start LocalCluster workers from a fork server that has Dask and icploc imported
    (~0.1 s a worker after the server's one import, instead of ~2 s each when spawned on
    a loaded 2-core machine; the server is a clean process: no threads are forked)."""
    import dask
    import distributed.utils

    if "forkserver" not in multiprocessing.get_all_start_methods():
        yield
        return
    with dask.config.set({"distributed.worker.multiprocessing-method": "forkserver"}):
        ctx = distributed.utils.get_mp_context()  # Dask sets its preload list once ...
        ctx.set_forkserver_preload(_WORKER_PRELOAD)  # ... ours replaces it
        yield


def _replay_one(
    log: str,
    map_: Any,
    config: LocalizerConfig,
    truth: str | None,
    options: dict[str, Any],
) -> dict[str, Any]:
    """Runs on a worker: replay one log; never raises (the error goes in the row)."""
    from icploc.replay import replay

    row: dict[str, Any] = {"log": log}
    try:
        with tempfile.TemporaryDirectory(prefix="icploc-batch-") as d:
            tum, est = Path(d) / "trajectory.tum", Path(d) / "estimates.csv"
            res = replay(log, map_, config=config, out=tum, estimates=est, truth=truth, **options)
            row["tum"] = tum.read_text()
            row["csv"] = est.read_text()
        c = res.status_counts
        row.update(
            scans=res.scans,
            tracking=c.get("tracking", 0),
            degraded=c.get("degraded", 0),
            lost=c.get("lost", 0),
            scans_per_s=res.rate,
            ate_rmse_m=res.metrics.get("ate_rmse_m", math.nan),
            ate_max_m=res.metrics.get("ate_max_m", math.nan),
        )
    except Exception as e:  # one broken log must not stop the batch: report it
        row["error"] = f"{type(e).__name__}: {e}"
    return row


def _check_outputs(logs: Sequence[str | Path]) -> list[str]:
    stems = [log_stem(p) for p in logs]
    seen: dict[str, str] = {}
    for p, s in zip(logs, stems, strict=True):
        if s in seen:
            raise BatchError(
                f"two logs would write the same outputs {s}.tum / {s}.csv: {seen[s]} and {p}"
            )
        if s == "summary":
            raise BatchError(f"{p}: a log named 'summary' would overwrite summary.csv")
        seen[s] = str(p)
    return stems


def _row_from(log: str, stem: str, got: dict[str, Any], out: Path) -> LogRow:
    row = LogRow(log=log, stem=stem)
    if got.get("error"):
        row.error = str(got["error"])
        return row
    for key in ("scans", "tracking", "degraded", "lost"):
        setattr(row, key, int(got[key]))
    for key in ("scans_per_s", "ate_rmse_m", "ate_max_m"):
        setattr(row, key, float(got[key]))
    for kind in ("tum", "csv"):
        p = out / f"{stem}.{kind}"
        p.write_text(got[kind])
        row.files[kind] = p
    return row


def write_summary(path: str | Path, rows: Sequence[LogRow]) -> Path:
    p = Path(path)
    with open(p, "w", newline="") as f:
        w = csv.writer(f, lineterminator="\n")
        w.writerow(SUMMARY_HEADER)
        for r in rows:
            w.writerow(r.cells())
    return p


def batch_replay(
    logs: Sequence[str | Path],
    map_: Any,
    out: str | Path,
    *,
    config: LocalizerConfig | None = None,
    scheduler: str | None = None,
    workers: int | None = None,
    truth_dir: str | Path | None = None,
    on_progress: Callable[[int, int, LogRow], None] | None = None,
    replay_options: dict[str, Any] | None = None,
    connect_timeout: float = 10.0,
) -> BatchResult:
    """Replay ``logs`` against ``map_`` (a path or a Map) on Dask; write the per-log
    trajectories and estimates and ``summary.csv`` into ``out``. ``scheduler``: the address
    of a running Dask scheduler (default: a LocalCluster of ``workers`` processes).
    ``truth_dir``: where ``<stem>.tum`` true trajectories are (for the start pose and the
    ATE, as ``icploc replay --truth``). ``on_progress(done, total, row)`` after each log.
    ``replay_options``: more keyword arguments of :func:`icploc.replay.replay`
    (``odometry``, ``initial_pose``, ``global_localize``, ``log_options``).
    ``connect_timeout``: seconds to wait for the scheduler at ``scheduler``."""
    t0 = time.perf_counter()
    if not logs:
        raise BatchError("no logs given")
    distributed = _import_dask()
    if workers is not None and workers < 1:
        raise BatchError(f"workers must be >= 1, got {workers}")
    cfg = (config or LocalizerConfig()).validate()
    stems = _check_outputs(logs)
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    tdir = Path(truth_dir) if truth_dir is not None else None
    if tdir is not None and not tdir.is_dir():
        raise BatchError(f"--truth-dir {tdir}: not a directory")
    truths = [
        str(tdir / f"{s}.tum") if tdir is not None and (tdir / f"{s}.tum").is_file() else None
        for s in stems
    ]
    m = prepare_map(map_, cfg)  # a bad map stops here, before any cluster starts
    opts = dict(replay_options or {})

    cluster = None
    try:
        if scheduler is None:
            n = workers or len(os.sched_getaffinity(0))
            with _worker_start_method():
                cluster = distributed.LocalCluster(
                    n_workers=n,
                    threads_per_worker=1,
                    processes=True,
                    dashboard_address=None,
                    silence_logs=40,  # logging.ERROR
                )
            client = distributed.Client(cluster)
        else:
            try:
                client = distributed.Client(scheduler, timeout=f"{connect_timeout}s")
            except (OSError, TimeoutError) as e:
                raise BatchError(f"no Dask scheduler at {scheduler}: {e}") from None
        with client:
            map_future = client.scatter(m, broadcast=True)
            futures = {
                client.submit(_replay_one, str(log), map_future, cfg, truth, opts, pure=False): i
                for i, (log, truth) in enumerate(zip(logs, truths, strict=True))
            }
            rows: list[LogRow | None] = [None] * len(logs)
            done = 0
            for fut in distributed.as_completed(futures):
                i = futures[fut]
                if fut.status == "error":
                    exc = fut.exception()
                    got: dict[str, Any] = {"error": f"{type(exc).__name__}: {exc}"}
                else:
                    got = fut.result()
                row = _row_from(str(logs[i]), stems[i], got, out_dir)
                rows[i] = row
                done += 1
                if on_progress is not None:
                    on_progress(done, len(logs), row)
    finally:
        if cluster is not None:
            cluster.close()
    final = [r for r in rows if r is not None]
    summary = write_summary(out_dir / "summary.csv", final)
    return BatchResult(rows=final, summary=summary, wall_time=time.perf_counter() - t0)

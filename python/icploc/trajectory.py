"""2D trajectories: TUM files, association by stamp, ATE and RPE.

A :class:`Trajectory` is ``stamps`` (N,) and ``poses`` (N, 3) = x, y, theta. TUM rows are
``stamp x y z qx qy qz qw``; we write z = qx = qy = 0 and read the yaw back from the
quaternion. Errors are computed in the fixed map frame (no alignment) unless asked to
align with the best SE(2) transform first.

This module is the one place that reads and writes trajectories and scores them
(:func:`ate`, :func:`rpe`, :func:`evaluate`, :func:`pose_errors`, :class:`ErrorStats`);
replay, the demo, live runs, the CLI and the benches use it, and :mod:`icploc.plotting`
draws what it computes.
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import IO, Any, Literal, TypeVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from icploc.errors import FileFormatError

__all__ = [
    "ESTIMATE_COLUMNS",
    "AteResult",
    "Association",
    "EstimatesWriter",
    "ErrorStats",
    "Evaluation",
    "RpeResult",
    "Trajectory",
    "TrajectoryFormatError",
    "TumWriter",
    "align_se2",
    "associate",
    "ate",
    "evaluate",
    "pose_errors",
    "read_tum",
    "rpe",
    "tum_line",
    "wrap",
    "write_tum",
]

F64 = NDArray[np.float64]


class TrajectoryFormatError(FileFormatError):
    """A malformed trajectory file; says which file and line."""

    path: str


def wrap(a: ArrayLike) -> F64:
    """Angles wrapped to [-pi, pi)."""
    x = np.asarray(a, dtype=np.float64)
    return np.asarray((x + np.pi) % (2.0 * np.pi) - np.pi, dtype=np.float64)


@dataclass(frozen=True)
class Trajectory:
    """Stamped 2D poses. Stamps need not be sorted; :meth:`sorted` sorts them."""

    stamps: F64
    poses: F64

    def __post_init__(self) -> None:
        t = np.asarray(self.stamps, dtype=np.float64).reshape(-1)
        p = np.asarray(self.poses, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] != t.shape[0]:
            raise ValueError(
                f"Trajectory: poses must be (N, 3) with N = {t.shape[0]}, got {p.shape}"
            )
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
            raise ValueError("Trajectory: stamps and poses must be finite")
        object.__setattr__(self, "stamps", t)
        object.__setattr__(self, "poses", p)

    @classmethod
    def empty(cls) -> Trajectory:
        return cls(np.zeros(0), np.zeros((0, 3)))

    @classmethod
    def from_poses(cls, stamps: ArrayLike, poses: ArrayLike) -> Trajectory:
        return cls(np.asarray(stamps, dtype=np.float64), np.asarray(poses, dtype=np.float64))

    def __len__(self) -> int:
        return int(self.stamps.shape[0])

    @property
    def xy(self) -> F64:
        return self.poses[:, :2]

    @property
    def theta(self) -> F64:
        return self.poses[:, 2]

    def sorted(self) -> Trajectory:
        o = np.argsort(self.stamps, kind="stable")
        return Trajectory(self.stamps[o], self.poses[o])

    def path_length(self) -> float:
        if len(self) < 2:
            return 0.0
        return float(np.sum(np.hypot(*np.diff(self.sorted().xy, axis=0).T)))

    def transformed(self, pose: ArrayLike) -> Trajectory:
        """Every pose premultiplied by ``pose`` (x, y, theta): T ⊕ p."""
        x, y, th = (float(v) for v in np.asarray(pose, dtype=np.float64))
        c, s = math.cos(th), math.sin(th)
        p = self.poses
        out = np.column_stack(
            (x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1], wrap(p[:, 2] + th))
        )
        return Trajectory(self.stamps.copy(), out)

    def started_at(self, pose: ArrayLike) -> Trajectory:
        """The same motion started from ``pose``: pose k becomes ``pose ⊕ (p0⁻¹ ⊕ p_k)``
        with p0 the first pose in the given order (odometry drawn in the map frame)."""
        if len(self) == 0:
            return self
        p0 = self.poses[:1]
        rel = _between(np.repeat(p0, len(self), axis=0), self.poses)
        return Trajectory(self.stamps.copy(), rel).transformed(pose)

    def at(
        self,
        stamps: ArrayLike,
        *,
        method: Literal["nearest", "interpolate"] = "interpolate",
        max_dt: float = 0.02,
        max_gap: float = 1.0,
    ) -> tuple[F64, NDArray[np.bool_]]:
        """Poses at ``stamps`` and a mask of which could be found.

        ``nearest``: the closest pose within ``max_dt``. ``interpolate``: linear in x, y and
        along the short arc in theta between the poses around the stamp, when they are at
        most ``max_gap`` apart; stamps up to ``max_dt`` outside the trajectory take the end pose.
        """
        q = np.asarray(stamps, dtype=np.float64).reshape(-1)
        tr = self.sorted()
        t, p = tr.stamps, tr.poses
        out = np.zeros((q.shape[0], 3))
        ok = np.zeros(q.shape[0], dtype=bool)
        if len(t) == 0 or q.shape[0] == 0:
            return out, ok
        j = np.searchsorted(t, q, side="left")
        lo = np.clip(j - 1, 0, len(t) - 1)
        hi = np.clip(j, 0, len(t) - 1)
        if method == "nearest":
            pick = np.where(np.abs(t[lo] - q) <= np.abs(t[hi] - q), lo, hi)
            ok = np.abs(t[pick] - q) <= max_dt
            out = p[pick].copy()
        elif method == "interpolate":
            exact = t[hi] == q
            inside = (q > t[0]) & (q < t[-1])
            gap = t[hi] - t[lo]
            ok_in = inside & (gap <= max_gap)
            denom = np.where(gap > 0, gap, 1.0)
            f = np.where(gap > 0, (q - t[lo]) / denom, 0.0)
            dth = wrap(p[hi, 2] - p[lo, 2])
            out = np.column_stack(
                (
                    p[lo, 0] + f * (p[hi, 0] - p[lo, 0]),
                    p[lo, 1] + f * (p[hi, 1] - p[lo, 1]),
                    wrap(p[lo, 2] + f * dth),
                )
            )
            before = (q <= t[0]) & (t[0] - q <= max_dt)
            after = (q >= t[-1]) & (q - t[-1] <= max_dt)
            out[before] = p[0]
            out[after] = p[-1]
            out[exact] = p[hi[exact]]
            ok = ok_in | before | after | exact
        else:
            raise ValueError(f"method must be 'nearest' or 'interpolate', got {method!r}")
        return out, ok


# ----------------------------------------------------------------------------- TUM files


def _quat_to_yaw(qx: F64, qy: F64, qz: F64, qw: F64) -> F64:
    return np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))


#: the comment line :func:`write_tum` starts a file with
TUM_HEADER = "# timestamp x y z qx qy qz qw\n"


def tum_line(stamp: float, pose: Sequence[float], precision: int = 6) -> str:
    """One TUM row ``stamp x y 0 0 0 qz qw`` (the format ``icploc replay --out`` writes):
    stamp and position with ``precision`` decimals, the quaternion with 9 or more."""
    h = 0.5 * float(pose[2])
    q = max(9, precision)
    return (
        f"{stamp:.{precision}f} {float(pose[0]):.{precision}f} {float(pose[1]):.{precision}f} "
        f"0 0 0 {math.sin(h):.{q}f} {math.cos(h):.{q}f}\n"
    )


def write_tum(path: str | os.PathLike[str], traj: Trajectory, *, precision: int = 9) -> None:
    """Write a whole trajectory: :data:`TUM_HEADER`, then one :func:`tum_line` per pose
    (in the given order)."""
    with TumWriter(path, header=True, precision=precision) as w:
        for k in range(len(traj)):
            w.write(float(traj.stamps[k]), traj.poses[k])


_W = TypeVar("_W", bound="_RowWriter")


class _RowWriter:
    """A text file written one row at a time and flushed at least every ``flush_every``
    seconds and on close, so an interrupted run keeps every row written before.

    ``target``: a path (opened for writing, closed by :meth:`close`) or an open text file
    (left open). ``on_error="raise"`` lets an OSError out of :meth:`write`;
    ``"stop"`` (a live run: a full disk must not end it) stops writing, keeps the message
    in :attr:`error` and lets the caller go on."""

    def __init__(
        self,
        target: str | os.PathLike[str] | IO[str],
        flush_every: float = 0.2,
        *,
        on_error: Literal["raise", "stop"] = "raise",
        name: str | None = None,
    ) -> None:
        if on_error not in ("raise", "stop"):
            raise ValueError(f"on_error must be 'raise' or 'stop', got {on_error!r}")
        if isinstance(target, (str, os.PathLike)):
            self.path: str | None = os.fspath(target)
            self._fh: IO[str] | None = open(self.path, "w", encoding="ascii", newline="")  # noqa: SIM115
            self._owned = True
        else:
            self.path = getattr(target, "name", None)
            self._fh = target
            self._owned = False
        self.name = name or self.path or "output"
        self._every = flush_every
        self._on_error = on_error
        self._last = time.monotonic()
        self.rows = 0
        #: why writing stopped (``on_error="stop"``), else None
        self.error: str | None = None

    def _failed(self, e: OSError) -> None:
        if self._on_error == "raise":
            raise e
        self.error = f"{self.name}: writing stopped: {e.strerror or e}"
        self._fh = None

    def _put(self, text: str) -> None:
        if self._fh is None:
            return
        try:
            self._fh.write(text)
            self.rows += 1
            now = time.monotonic()
            if now - self._last >= self._every:
                self._fh.flush()
                self._last = now
        except OSError as e:
            self._failed(e)

    def flush(self) -> None:
        if self._fh is None:
            return
        try:
            self._fh.flush()
        except OSError as e:
            self._failed(e)

    def close(self) -> None:
        fh, self._fh = self._fh, None
        if fh is None or fh.closed:
            return
        try:
            fh.flush()
            if self._owned:
                fh.close()
        except OSError as e:
            if self._on_error == "raise":
                raise
            self.error = self.error or f"{self.name}: writing stopped: {e.strerror or e}"

    def __enter__(self: _W) -> _W:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TumWriter(_RowWriter):
    """A TUM trajectory written as it is produced: ``write(stamp, pose)`` per row
    (:func:`tum_line`); ``header=True`` starts it with :data:`TUM_HEADER`. See
    :class:`_RowWriter` for ``target``, ``flush_every`` and ``on_error``."""

    def __init__(
        self,
        target: str | os.PathLike[str] | IO[str],
        flush_every: float = 0.2,
        *,
        header: bool = False,
        precision: int = 6,
        on_error: Literal["raise", "stop"] = "raise",
        name: str | None = None,
    ) -> None:
        super().__init__(target, flush_every, on_error=on_error, name=name)
        self._precision = precision
        if header:
            self._put(TUM_HEADER)
            self.rows = 0

    def write(self, stamp: float, pose: Sequence[float]) -> None:
        self._put(tum_line(stamp, pose, self._precision))


#: the columns of ``icploc replay --estimates``: one row per scan
ESTIMATE_COLUMNS = (
    "stamp", "x", "y", "theta", "status", "reason", "inlier_ratio",
    "cov_xx", "cov_xy", "cov_yy", "cov_tt", "cov_xt", "cov_yt",
    "accepted", "iterations", "num_points", "degeneracy", "mapped",
)  # fmt: skip


class EstimatesWriter(_RowWriter):
    """The localizer's estimates as CSV (:data:`ESTIMATE_COLUMNS`), one row per scan as it
    is produced. ``status`` is ``tracking``, ``degraded`` or ``lost``."""

    def __init__(self, path: str | os.PathLike[str], flush_every: float = 0.2) -> None:
        super().__init__(path, flush_every)
        assert self._fh is not None
        self._csv = csv.writer(self._fh, lineterminator="\n")
        self._csv.writerow(ESTIMATE_COLUMNS)
        self.rows = 0

    def write(self, e: Any) -> None:
        c = e.covariance
        st = getattr(e.status, "value", e.status)
        self._csv.writerow(
            (
                f"{e.stamp:.6f}", f"{e.pose[0]:.6f}", f"{e.pose[1]:.6f}", f"{e.pose[2]:.6f}",
                st, e.reason, f"{e.inlier_ratio:.4f}",
                f"{c[0][0]:.6g}", f"{c[0][1]:.6g}", f"{c[1][1]:.6g}", f"{c[2][2]:.6g}",
                f"{c[0][2]:.6g}", f"{c[1][2]:.6g}",
                int(bool(e.accepted)), int(e.iterations), int(e.num_points), f"{e.degeneracy:.4g}",
                int(bool(getattr(e, "mapped", True))),  # 0: outside the map (icploc.outside)
            )
        )  # fmt: skip
        self.rows += 1
        now = time.monotonic()
        if now - self._last >= self._every:
            self.flush()
            self._last = now


def read_tum(path: str | os.PathLike[str]) -> Trajectory:
    """Read a TUM file (``#`` comments and blank lines allowed; commas also separate).

    The yaw is taken from the quaternion; a quaternion far from unit norm is an error.
    """
    rows: list[list[float]] = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            s = line.strip()
            if not s or s.startswith("#"):
                continue
            toks = s.replace(",", " ").split()
            if len(toks) != 8:
                raise TrajectoryFormatError(
                    path, f"expected 8 values (stamp x y z qx qy qz qw), got {len(toks)}", lineno
                )
            try:
                vals = [float(v) for v in toks]
            except ValueError:
                raise TrajectoryFormatError(path, f"not a number in {s!r}", lineno) from None
            if not all(math.isfinite(v) for v in vals):
                raise TrajectoryFormatError(path, "non-finite value", lineno)
            n = math.sqrt(sum(v * v for v in vals[4:8]))
            if abs(n - 1.0) > 1e-3:
                raise TrajectoryFormatError(path, f"quaternion norm {n:.6f} is not 1", lineno)
            rows.append(vals)
    if not rows:
        return Trajectory.empty()
    a = np.array(rows, dtype=np.float64)
    yaw = _quat_to_yaw(a[:, 4], a[:, 5], a[:, 6], a[:, 7])
    return Trajectory(a[:, 0], np.column_stack((a[:, 1], a[:, 2], yaw)))


# ----------------------------------------------------------------------------- metrics


@dataclass(frozen=True)
class Association:
    """Pairs of poses at the same stamps: ``est[k]`` and ``ref[k]`` at ``stamps[k]``."""

    stamps: F64
    est: F64
    ref: F64
    n_unmatched: int = 0


def associate(
    est: Trajectory,
    ref: Trajectory,
    *,
    method: Literal["nearest", "interpolate"] = "nearest",
    max_dt: float = 0.02,
    max_gap: float = 1.0,
) -> Association:
    """Pair each estimate with the reference at its stamp (see :meth:`Trajectory.at`)."""
    e = est.sorted()
    r, ok = ref.at(e.stamps, method=method, max_dt=max_dt, max_gap=max_gap)
    return Association(e.stamps[ok], e.poses[ok], r[ok], int((~ok).sum()))


def align_se2(est_xy: ArrayLike, ref_xy: ArrayLike) -> tuple[float, float, float]:
    """The rigid transform T (x, y, theta) minimising sum |T(est) - ref|² (2D Kabsch)."""
    a = np.asarray(est_xy, dtype=np.float64).reshape(-1, 2)
    b = np.asarray(ref_xy, dtype=np.float64).reshape(-1, 2)
    if a.shape != b.shape or len(a) == 0:
        raise ValueError("align_se2: need two non-empty (N, 2) arrays of the same shape")
    ma, mb = a.mean(axis=0), b.mean(axis=0)
    da, db = a - ma, b - mb
    sxx = float(np.sum(da[:, 0] * db[:, 0] + da[:, 1] * db[:, 1]))
    sxy = float(np.sum(da[:, 0] * db[:, 1] - da[:, 1] * db[:, 0]))
    th = math.atan2(sxy, sxx) if (sxx or sxy) else 0.0
    c, s = math.cos(th), math.sin(th)
    tx = mb[0] - (c * ma[0] - s * ma[1])
    ty = mb[1] - (s * ma[0] + c * ma[1])
    return (float(tx), float(ty), th)


def pose_errors(est: ArrayLike, ref: ArrayLike) -> tuple[F64, F64]:
    """Position error (m) and absolute heading error (rad, wrapped) of paired (N, 3)
    poses: row k of ``est`` against row k of ``ref``."""
    e = np.asarray(est, dtype=np.float64).reshape(-1, 3)
    r = np.asarray(ref, dtype=np.float64).reshape(-1, 3)
    if e.shape != r.shape:
        raise ValueError(f"pose_errors: {len(e)} estimates for {len(r)} reference poses")
    pos = np.hypot(e[:, 0] - r[:, 0], e[:, 1] - r[:, 1])
    return np.asarray(pos, dtype=np.float64), np.abs(wrap(e[:, 2] - r[:, 2]))


@dataclass(frozen=True)
class ErrorStats:
    """Statistics of absolute errors (NaN for none)."""

    rmse: float
    mean: float
    median: float
    p95: float
    max: float

    @classmethod
    def of(cls, e: ArrayLike) -> ErrorStats:
        x = np.abs(np.asarray(e, dtype=np.float64))
        if x.size == 0:
            return cls(math.nan, math.nan, math.nan, math.nan, math.nan)
        return cls(
            rmse=float(np.sqrt(np.mean(x * x))),
            mean=float(np.mean(x)),
            median=float(np.median(x)),
            p95=float(np.percentile(x, 95)),
            max=float(np.max(x)),
        )


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error: position (m) and heading (rad) statistics."""

    position: ErrorStats
    heading: ErrorStats
    n: int
    n_unmatched: int
    alignment: tuple[float, float, float] = (0.0, 0.0, 0.0)
    position_errors: F64 = field(default_factory=lambda: np.zeros(0), repr=False)
    heading_errors: F64 = field(default_factory=lambda: np.zeros(0), repr=False)
    stamps: F64 = field(default_factory=lambda: np.zeros(0), repr=False)

    def metrics(self) -> dict[str, float]:
        """Flat figures, metres and degrees: ``ate_rmse_m``, ``ate_median_m``, ``ate_p95_m``,
        ``ate_max_m``, ``heading_max_deg``."""
        p = self.position
        return {
            "ate_rmse_m": p.rmse,
            "ate_median_m": p.median,
            "ate_p95_m": p.p95,
            "ate_max_m": p.max,
            "heading_max_deg": math.degrees(self.heading.max),
        }

    def summary(self) -> str:
        p, h = self.position, self.heading
        return (
            f"ATE over {self.n} poses: position rmse {p.rmse * 100:.2f} cm, median "
            f"{p.median * 100:.2f} cm, p95 {p.p95 * 100:.2f} cm, max {p.max * 100:.2f} cm; "
            f"heading rmse {math.degrees(h.rmse):.3f}°, max {math.degrees(h.max):.3f}°"
        )


def ate(
    est: Trajectory,
    ref: Trajectory,
    *,
    align: bool = False,
    method: Literal["nearest", "interpolate"] = "nearest",
    max_dt: float = 0.02,
    max_gap: float = 1.0,
) -> AteResult:
    """ATE of ``est`` against ``ref`` in the fixed map frame (or after SE(2) alignment)."""
    a = associate(est, ref, method=method, max_dt=max_dt, max_gap=max_gap)
    if len(a.stamps) == 0:
        raise ValueError("ate: no estimate could be associated with the reference")
    e = a.est
    T = (0.0, 0.0, 0.0)
    if align:
        T = align_se2(e[:, :2], a.ref[:, :2])
        e = Trajectory(a.stamps, e).transformed(T).poses
    pos, hd = pose_errors(e, a.ref)
    return AteResult(
        position=ErrorStats.of(pos),
        heading=ErrorStats.of(hd),
        n=len(pos),
        n_unmatched=a.n_unmatched,
        alignment=T,
        position_errors=pos,
        heading_errors=hd,
        stamps=a.stamps,
    )


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error over ``delta`` (metres travelled or seconds)."""

    translation: ErrorStats
    rotation: ErrorStats
    n: int
    delta: float
    unit: str

    def metrics(self) -> dict[str, float]:
        """``rpe_<delta><unit>_rmse_m`` (e.g. ``rpe_1m_rmse_m``); nothing without pairs."""
        if self.n == 0:
            return {}
        return {f"rpe_{self.delta:g}{self.unit}_rmse_m": self.translation.rmse}

    def summary(self) -> str:
        return (
            f"RPE over {self.delta:g} {self.unit} ({self.n} pairs): translation rmse "
            f"{self.translation.rmse * 100:.2f} cm, max {self.translation.max * 100:.2f} cm; "
            f"rotation rmse {math.degrees(self.rotation.rmse):.3f}°"
        )


def _between(a: F64, b: F64) -> F64:
    """Row-wise a⁻¹ ⊕ b for (N, 3) arrays."""
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    dx, dy = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    return np.column_stack((c * dx + s * dy, -s * dx + c * dy, wrap(b[:, 2] - a[:, 2])))


def rpe(
    est: Trajectory,
    ref: Trajectory,
    *,
    delta: float = 1.0,
    unit: Literal["m", "s"] = "m",
    method: Literal["nearest", "interpolate"] = "nearest",
    max_dt: float = 0.02,
    max_gap: float = 1.0,
) -> RpeResult:
    """RPE: for each pose i, the pose j first reaching ``delta`` further (path length of the
    reference in metres, or time in seconds); error of est's motion i→j against ref's."""
    if not delta > 0:
        raise ValueError("rpe: delta must be positive")
    if unit not in ("m", "s"):
        raise ValueError(f"rpe: unit must be 'm' or 's', got {unit!r}")
    a = associate(est, ref, method=method, max_dt=max_dt, max_gap=max_gap)
    if unit == "m":
        d = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(a.ref[:, :2], axis=0).T))))
    else:
        d = a.stamps
    i = np.arange(len(d))
    j = np.searchsorted(d, d + delta, side="left")
    ok = j < len(d)
    i, j = i[ok], j[ok]
    if len(i) == 0:
        return RpeResult(ErrorStats.of([]), ErrorStats.of([]), 0, delta, unit)
    de = _between(a.est[i], a.est[j])
    dr = _between(a.ref[i], a.ref[j])
    err = _between(dr, de)
    return RpeResult(
        translation=ErrorStats.of(np.hypot(err[:, 0], err[:, 1])),
        rotation=ErrorStats.of(np.abs(err[:, 2])),
        n=len(i),
        delta=delta,
        unit=unit,
    )



@dataclass(frozen=True)
class Evaluation:
    """An estimated trajectory scored against a reference: ATE and RPE."""

    ate: AteResult
    rpe: RpeResult

    def metrics(self) -> dict[str, float]:
        """:meth:`AteResult.metrics` and :meth:`RpeResult.metrics` in one dict."""
        return {**self.ate.metrics(), **self.rpe.metrics()}


def evaluate(
    est: Trajectory,
    ref: Trajectory,
    *,
    method: Literal["nearest", "interpolate"] = "interpolate",
    max_dt: float = 0.0,
    max_gap: float = math.inf,
    rpe_delta: float = 1.0,
) -> Evaluation | None:
    """ATE (map frame, no alignment) and RPE over ``rpe_delta`` metres of ``est`` against
    ``ref``, or None when no estimate falls within the reference. The defaults score a
    run against a simulator's or a log's truth: the truth interpolated at each estimate's
    stamp, estimates outside its time span left out."""
    a = associate(est, ref, method=method, max_dt=max_dt, max_gap=max_gap)
    if len(a.stamps) == 0:
        return None
    kw: dict[str, Any] = {"method": method, "max_dt": max_dt, "max_gap": max_gap}
    return Evaluation(ate(est, ref, **kw), rpe(est, ref, delta=rpe_delta, unit="m", **kw))

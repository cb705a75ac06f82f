"""The benchmark's own small CARMEN ``FLASER`` reader and writer, the scan sparsifier and
the map / localize split (no icploc import: the harness must not depend on the package it
measures).

``FLASER n r_1 .. r_n x y theta odom_x odom_y odom_theta ts host logger_ts``: n readings over
180°, n = 180 / 360 a 1° / 0.5° step from −90°, n = 181 / 361 from −90° to +90° inclusive.
"""

from __future__ import annotations

import gzip
import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

#: the reading written for a NaN / inf reading of a log that has no saturation value
NO_RETURN_FILL = 81.91

__all__ = [
    "FlaserLog",
    "beam_angles",
    "read_flaser",
    "sparsify",
    "split_folds",
    "write_flaser",
]


@dataclass
class FlaserLog:
    path: Path
    ranges: NDArray[np.float64]  #: (N, n) metres
    poses: NDArray[np.float64]  #: (N, 3) the laser line's pose (corrected logs: the reference)
    odom: NDArray[np.float64]  #: (N, 3) the laser line's odometry pose
    stamps: NDArray[np.float64]  #: (N,) seconds
    no_return: float  #: readings at or above this are no-returns (inf: none seen)

    def __len__(self) -> int:
        return len(self.ranges)

    @property
    def angles(self) -> NDArray[np.float64]:
        return beam_angles(self.ranges.shape[1])

    @property
    def stamps_usable(self) -> bool:
        """Stamps strictly increasing and not all equal (campus, Örebro: all 0)."""
        return bool(len(self.stamps) > 1 and np.all(np.diff(self.stamps) > 0))


def beam_angles(n: int) -> NDArray[np.float64]:
    if n % 2 == 0:
        return -math.pi / 2 + np.arange(n) * (math.pi / n)
    return np.linspace(-math.pi / 2, math.pi / 2, n)


def _open(path: Path) -> list[str]:
    if path.suffix == ".gz":
        with gzip.open(path, "rt", errors="replace") as f:
            return f.read().splitlines()
    return path.read_text(errors="replace").splitlines()


def read_flaser(path: str | Path) -> FlaserLog:
    """Every ``FLASER`` line of a CARMEN log (other lines ignored). Errors name the line."""
    path = Path(path)
    rows: list[list[float]] = []
    n_beams: int | None = None
    for lineno, line in enumerate(_open(path), 1):
        if not line.startswith("FLASER "):
            continue
        tok = line.split()
        try:
            n = int(tok[1])
            vals = [float(v) for v in tok[2 : 2 + n + 7]]
        except (ValueError, IndexError):
            raise ValueError(f"{path}:{lineno}: malformed FLASER line") from None
        if len(vals) != n + 7:
            raise ValueError(f"{path}:{lineno}: FLASER with {n} readings is truncated")
        if n_beams is None:
            n_beams = n
        elif n != n_beams:
            raise ValueError(f"{path}:{lineno}: {n} readings, earlier lines had {n_beams}")
        rows.append(vals)
    if not rows or n_beams is None:
        raise ValueError(f"{path}: no FLASER line")
    m = np.asarray(rows, dtype=np.float64)
    r = m[:, :n_beams]
    if not np.all(np.isfinite(m[:, n_beams:])):
        raise ValueError(f"{path}: non-finite FLASER pose or timestamp")
    bad = ~np.isfinite(r)
    top = float(r[~bad].max()) if (~bad).any() else 0.0
    # a saturation value (no return) repeats exactly; a real far wall does not
    no_return = top if np.mean(r[~bad] >= top - 1e-6) > 0.002 and top > 5.0 else math.inf
    if bad.any():
        # NaN / inf readings (laserazosSM3) are no-returns: written as a saturation value
        no_return = no_return if math.isfinite(no_return) else NO_RETURN_FILL
        r = np.where(bad, no_return, r)
    return FlaserLog(
        path=path,
        ranges=r,
        poses=m[:, n_beams : n_beams + 3].copy(),
        odom=m[:, n_beams + 3 : n_beams + 6].copy(),
        stamps=m[:, n_beams + 6].copy(),
        no_return=no_return,
    )


def write_flaser(
    path: str | Path,
    ranges: NDArray[np.float64],
    odom: NDArray[np.float64],
    stamps: NDArray[np.float64],
) -> None:
    """A CARMEN log of ``FLASER`` lines whose pose and odometry fields are both the raw
    odometry ``odom`` (no reference pose is left in the file for any localizer to see)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    with open(tmp, "w") as f:
        f.write("# icploc benches/eval_real.py: real scans, synthesised raw odometry\n")
        for r, o, t in zip(ranges, odom, stamps, strict=True):
            rs = " ".join(f"{v:.3f}" for v in r)
            p = f"{o[0]:.6f} {o[1]:.6f} {o[2]:.6f}"
            f.write(f"FLASER {len(r)} {rs} {p} {p} {t:.6f} bench {t:.6f}\n")
    tmp.replace(path)


def sparsify(
    poses: NDArray[np.float64],
    stamps: NDArray[np.float64] | None = None,
    distance: float = 0.5,
    angle: float = 0.5,
    period: float | None = None,
) -> NDArray[np.int64]:
    """Indices of the scans a real logger would keep: the first, then each scan once the
    robot has travelled ``distance`` metres or turned ``angle`` radians since the last kept
    one, or (``period`` given) ``period`` seconds have passed."""
    p = np.asarray(poses, dtype=np.float64)
    if len(p) == 0:
        return np.zeros(0, dtype=np.int64)
    keep = [0]
    last = p[0]
    last_t = None if stamps is None else float(stamps[0])
    for i in range(1, len(p)):
        d = math.hypot(p[i, 0] - last[0], p[i, 1] - last[1])
        a = abs(math.remainder(p[i, 2] - last[2], 2 * math.pi))
        due = period is not None and stamps is not None and last_t is not None and float(stamps[i]) - last_t >= period
        if d >= distance or a >= angle or due:
            keep.append(i)
            last = p[i]
            last_t = None if stamps is None else float(stamps[i])
    return np.asarray(keep, dtype=np.int64)


@dataclass(frozen=True)
class Fold:
    index: int
    localize: tuple[int, int]  #: [start, stop) dense scan range localized in this fold
    map_scans: NDArray[np.int64]  #: dense scans the map is built from


def split_folds(positions: NDArray[np.float64], folds: int, gap: int) -> list[Fold]:
    """Leave-one-chunk-out: the log cut into ``folds`` time chunks; each chunk is localized
    against a map of the other chunks (minus ``gap`` scans at each seam, so the map never
    holds the localized pass's own scans of the same place). Places the robot saw only in
    the localized chunk would be missing from that map: see :func:`map_scans_for`."""
    n = len(positions)
    edges = np.linspace(0, n, folds + 1).astype(int)
    out = []
    for k in range(folds):
        a, b = int(edges[k]), int(edges[k + 1])
        others = np.r_[0 : max(0, a - gap), min(n, b + gap) : n].astype(np.int64)
        out.append(Fold(index=k, localize=(a, b), map_scans=others))
    return out


def endpoints_world(log: FlaserLog, max_range: float, every: int = 3) -> list[NDArray[np.float64]]:
    """Per scan, every ``every``-th beam endpoint (valid readings) at the log's pose."""
    ang = log.angles[::every]
    ca, sa = np.cos(ang), np.sin(ang)
    out = []
    for p, r in zip(log.poses, log.ranges[:, ::every], strict=True):
        v = (r > 0.05) & (r < min(max_range, log.no_return))
        c, s = math.cos(p[2]), math.sin(p[2])
        bx, by = c * ca[v] - s * sa[v], s * ca[v] + c * sa[v]
        out.append(np.column_stack([p[0] + r[v] * bx, p[1] + r[v] * by]))
    return out


def map_scans_for(
    fold: Fold,
    endpoints: list[NDArray[np.float64]],
    kept: NDArray[np.int64],
    seen_share: float = 0.5,
    tolerance: float = 0.2,
    guard: int = 1,
) -> tuple[NDArray[np.int64], NDArray[np.int64], float]:
    """The fold's map scans and localized scans.

    ``endpoints``: per scan, its beam endpoints in the world (:func:`endpoints_world`);
    ``kept``: the sparsified scans (whole log). A kept scan of the chunk *revisits* when at
    least ``seen_share`` of its endpoints lie within ``tolerance`` of an endpoint of the
    other passes (the fold's map scans): the map there comes from another pass. Where a
    kept scan does not revisit, every second such scan is held out of the localization and
    put in the map instead (with the dense scans the sparsifier dropped, if more than
    ``guard`` scans from a localized one), so places seen once are not missing from the
    map. Returns (map scans, localized scans, share of localized scans that revisit)."""
    from scipy.spatial import cKDTree

    base = fold.map_scans
    a, b = fold.localize
    chunk_kept = kept[(kept >= a) & (kept < b)]
    chunk = np.arange(a, b)
    pts = [endpoints[i] for i in base if len(endpoints[i])]
    tree = cKDTree(np.vstack(pts)) if pts else None

    def revisits(i: int) -> bool:
        e = endpoints[i]
        if tree is None or len(e) == 0:
            return False
        d, _ = tree.query(e, k=1, distance_upper_bound=tolerance)
        return bool(np.mean(np.isfinite(d)) >= seen_share)

    rev_kept = np.array([revisits(int(i)) for i in chunk_kept], dtype=bool)
    held = np.zeros(len(chunk_kept), dtype=bool)
    held[np.nonzero(~rev_kept)[0][1::2]] = True
    localized = chunk_kept[~held]
    near = np.zeros(len(endpoints), dtype=bool)
    for g in range(-guard, guard + 1):
        idx = localized + g
        near[idx[(idx >= 0) & (idx < len(endpoints))]] = True
    dropped = chunk[~np.isin(chunk, chunk_kept) & ~near[chunk]]
    lonely_dropped = np.array([i for i in dropped if not revisits(int(i))], dtype=np.int64)
    extra = np.concatenate([chunk_kept[held], lonely_dropped]).astype(np.int64)
    share = float(np.mean(rev_kept[~held])) if len(localized) else 0.0
    return np.unique(np.concatenate([base, extra])).astype(np.int64), localized, share

"""Per-scan estimates as CSV: one row per scan, the same columns wherever they are written
(``icploc batch`` writes ``DIR/<log>.csv``; ``icploc replay --estimates`` can share
:func:`write_estimates_csv`).

Columns: ``stamp,x,y,theta,status,reason,inlier_ratio,cov_xx,cov_xy,cov_yy,cov_tt``
(seconds, metres, radians; the covariance entries of (x, y, theta)).
"""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import IO, Any

__all__ = ["ESTIMATES_HEADER", "write_estimates_csv"]

ESTIMATES_HEADER = (
    "stamp",
    "x",
    "y",
    "theta",
    "status",
    "reason",
    "inlier_ratio",
    "cov_xx",
    "cov_xy",
    "cov_yy",
    "cov_tt",
)


def _row(e: Any) -> list[str]:
    c = e.covariance
    return [
        f"{e.stamp:.6f}",
        f"{e.pose[0]:.6f}",
        f"{e.pose[1]:.6f}",
        f"{e.pose[2]:.6f}",
        str(getattr(e.status, "value", e.status)),
        e.reason,
        f"{e.inlier_ratio:.4f}",
        f"{c[0][0]:.6e}",
        f"{c[0][1]:.6e}",
        f"{c[1][1]:.6e}",
        f"{c[2][2]:.6e}",
    ]


def write_estimates_csv(dest: str | Path | IO[str], estimates: Iterable[Any]) -> int:
    """Write ``estimates`` (:class:`icploc.localizer.Estimate`) to ``dest`` (a path, or an
    open text file) under :data:`ESTIMATES_HEADER`; returns the number of rows."""
    if isinstance(dest, (str, Path)):
        with open(dest, "w", newline="") as f:
            return write_estimates_csv(f, estimates)
    w = csv.writer(dest, lineterminator="\n")
    w.writerow(ESTIMATES_HEADER)
    n = 0
    for e in estimates:
        w.writerow(_row(e))
        n += 1
    return n

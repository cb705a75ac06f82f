"""Point maps: ``.npy`` (N, 2) or (N, 4) arrays and ``.csv`` files of x, y (optionally nx, ny)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from .errors import MapError

FloatArray = NDArray[np.float64]


def _check(path: Path, a: NDArray[np.float64], field: str) -> tuple[FloatArray, FloatArray | None]:
    if a.ndim != 2 or a.shape[1] not in (2, 4):
        raise MapError(
            path,
            field,
            f"expected an (N, 2) array of x, y (or (N, 4) with nx, ny), got shape {a.shape}",
        )
    if a.shape[0] == 0:
        raise MapError(path, field, "no points")
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        raise MapError(path, field, f"row {int(np.flatnonzero(bad)[0])} is not finite")
    pts = np.ascontiguousarray(a[:, :2])
    if a.shape[1] == 2:
        return pts, None
    nrm = a[:, 2:4]
    ln = np.hypot(nrm[:, 0], nrm[:, 1])
    if np.any(ln < 1e-9):
        raise MapError(path, field, f"normal in row {int(np.flatnonzero(ln < 1e-9)[0])} is zero")
    return pts, np.ascontiguousarray(nrm / ln[:, None])


def load_npy(path: str | Path) -> tuple[FloatArray, FloatArray | None]:
    path = Path(path)
    try:
        a = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise MapError(path, None, f"cannot read .npy array: {e}") from e
    if not np.issubdtype(a.dtype, np.number):
        raise MapError(path, "dtype", f"expected numbers, got {a.dtype}")
    return _check(path, np.asarray(a, dtype=np.float64), "array")


def load_csv(path: str | Path) -> tuple[FloatArray, FloatArray | None]:
    """CSV (comma, semicolon, tab or space separated) with columns x, y[, nx, ny]; an optional
    header row naming them (then the columns are found by name); ``#`` comments."""
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise MapError(path, None, f"cannot read file: {e}") from e
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        raise MapError(path, "rows", "no points")
    try:
        dialect: type[csv.Dialect] | csv.Dialect = csv.Sniffer().sniff(rows[0], delimiters=",;\t ")
    except csv.Error:
        dialect = csv.excel
    table = [
        [c.strip() for c in r if c.strip() != ""]
        for r in csv.reader(io.StringIO("\n".join(rows)), dialect)
    ]
    cols = [0, 1]
    start = 0

    def numeric(cells: list[str]) -> bool:
        try:
            [float(c) for c in cells]
        except ValueError:
            return False
        return True

    if not numeric(table[0]):
        header = [c.lower() for c in table[0]]
        if "x" not in header or "y" not in header:
            raise MapError(path, "header", f"needs columns named x and y, got {table[0]}")
        cols = [header.index("x"), header.index("y")]
        if "nx" in header and "ny" in header:
            cols += [header.index("nx"), header.index("ny")]
        start = 1
    elif len(table[0]) >= 4:
        cols = [0, 1, 2, 3]
    out = np.empty((len(table) - start, len(cols)))
    for i, r in enumerate(table[start:]):
        line = i + start + 1
        if len(r) <= max(cols):
            raise MapError(
                path, f"row {line}", f"expected at least {max(cols) + 1} columns, got {len(r)}"
            )
        try:
            out[i] = [float(r[c]) for c in cols]
        except ValueError as e:
            raise MapError(path, f"row {line}", f"not a number: {e}") from e
    return _check(path, out, "rows")


def save_csv(path: str | Path, points: FloatArray, normals: FloatArray | None = None) -> None:
    path = Path(path)
    if normals is None:
        np.savetxt(path, points, delimiter=",", header="x,y", comments="", fmt="%.9g")
    else:
        np.savetxt(
            path,
            np.column_stack([points, normals]),
            delimiter=",",
            header="x,y,nx,ny",
            comments="",
            fmt="%.9g",
        )

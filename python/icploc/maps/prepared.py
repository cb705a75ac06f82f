"""Prepared maps: one ``.npz`` file with the fitted lines, grid, fallback points, samples for
chosen spacings and JSON metadata, loaded without refitting (no pickle)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .errors import MapError

if TYPE_CHECKING:
    from .map import Map

MAGIC = "icploc-prepared-map"
VERSION = 1


def save_prepared(
    m: Map, path: str | Path, spacings: list[float], *, compress: bool = True
) -> Path:
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise MapError(path, None, "prepared maps are .npz files")
    arrays: dict[str, np.ndarray] = {
        "lines": m.lines,
        "extra_points": m.extra_points,
        "extra_normals": m.extra_normals,
    }
    meta: dict[str, Any] = {
        "format": MAGIC,
        "version": VERSION,
        "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "source": m.source,
        "meta": m.meta,
        "resolution": m.resolution,
        "origin": list(m.origin),
        "spacings": [],
    }
    if m.grid is not None:
        arrays["grid"] = np.packbits(m.grid, axis=None)
        meta["grid_shape"] = list(m.grid.shape)
        if m.free is not None:
            arrays["free"] = np.packbits(m.free, axis=None)
    if m.occupancy is not None:
        arrays["occupancy"] = m.occupancy
    if m.points is not None:
        arrays["points"] = m.points
        if m.point_normals is not None:
            arrays["point_normals"] = m.point_normals
    for i, s in enumerate(spacings):
        p, n = m.sample(s)
        arrays[f"samples{i}_points"] = p
        arrays[f"samples{i}_normals"] = n
        meta["spacings"].append({"spacing": s, "counts": m.sample_counts(s)})
    arrays["meta"] = np.array(json.dumps(meta, default=str))
    with open(path, "wb") as fh:
        if compress:
            np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
        else:
            np.savez(fh, **arrays)  # type: ignore[arg-type]
    return path


def load_prepared(path: str | Path) -> Map:
    from .map import Map

    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise MapError(path, None, f"not a readable .npz file: {e}") from e
    with z:
        if "meta" not in z.files:
            raise MapError(path, "meta", "missing: not an icploc prepared map")
        try:
            meta = json.loads(str(z["meta"]))
        except (json.JSONDecodeError, ValueError) as e:
            raise MapError(path, "meta", f"not valid JSON: {e}") from e
        if not isinstance(meta, dict) or meta.get("format") != MAGIC:
            raise MapError(path, "meta.format", f"expected {MAGIC!r}")
        if meta.get("version") != VERSION:
            raise MapError(
                path,
                "meta.version",
                f"unsupported version {meta.get('version')!r} (expected {VERSION})",
            )
        for key in ("lines", "extra_points", "extra_normals"):
            if key not in z.files:
                raise MapError(path, key, "missing")
        grid = free = None
        if "grid" in z.files:
            shape = tuple(meta.get("grid_shape") or ())
            if len(shape) != 2:
                raise MapError(path, "meta.grid_shape", f"invalid {shape!r}")
            n = shape[0] * shape[1]
            # unpackbits gives 0 / 1 bytes: viewed as bool, not copied
            grid = np.unpackbits(z["grid"], count=n).view(bool).reshape(shape)
            if "free" in z.files:
                free = np.unpackbits(z["free"], count=n).view(bool).reshape(shape)
        m = Map(
            z["lines"],
            grid=grid,
            free=free,
            resolution=meta.get("resolution"),
            origin=meta.get("origin"),
            points=z["points"] if "points" in z.files else None,
            point_normals=z["point_normals"] if "point_normals" in z.files else None,
            extra_points=z["extra_points"],
            extra_normals=z["extra_normals"],
            source=meta.get("source"),
            meta=dict(meta.get("meta") or {}, prepared=str(path)),
        )
        if "occupancy" in z.files:
            m.occupancy = z["occupancy"]
        for i, entry in enumerate(meta.get("spacings", [])):
            p, nrm = z[f"samples{i}_points"], z[f"samples{i}_normals"]
            p.flags.writeable = False
            nrm.flags.writeable = False
            m._samples[float(entry["spacing"])] = (p, nrm, dict(entry["counts"]))
    return m

"""The benchmark's own occupancy-grid rasteriser and map_server (YAML + PGM) reader/writer.

A map as users have one: every scan ray-cast into a grid at the reference pose; a cell
is *occupied* when beams ended in it at least ``min_hits`` times and in at least
``occupied_ratio`` of the beams that reached it (ended in it or passed through), *free*
when beams passed through and it is not occupied, *unknown* otherwise. Beams with no
return add nothing. Written as map_server trinary PGM (0 occupied, 254 free, 205 unknown)
with ``origin`` = the lower-left corner of the lower-left cell, a multiple of the
resolution.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["Grid", "rasterise", "read_map_server", "write_map_server"]

OCC, FREE, UNKNOWN = 0, 254, 205


@dataclass
class Grid:
    occupied: NDArray[np.bool_]  #: (H, W), row 0 = lowest y
    free: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float]  #: world x, y of the lower-left corner of cell (0, 0)

    def occupied_centres(self) -> NDArray[np.float64]:
        r, c = np.nonzero(self.occupied)
        return np.column_stack(
            [self.origin[0] + (c + 0.5) * self.resolution, self.origin[1] + (r + 0.5) * self.resolution]
        )


def _cells(xy: NDArray[np.float64], origin: tuple[float, float], res: float) -> NDArray[np.int64]:
    c = np.floor((xy[:, 0] - origin[0]) / res).astype(np.int64)
    r = np.floor((xy[:, 1] - origin[1]) / res).astype(np.int64)
    return np.column_stack([r, c])


def rasterise(
    ranges: NDArray[np.float64],
    angles: NDArray[np.float64],
    poses: NDArray[np.float64],
    resolution: float,
    max_range: float,
    min_range: float = 0.05,
    min_hits: int = 2,
    occupied_ratio: float = 0.3,
    pad: float = 1.0,
) -> Grid:
    """Ray-cast scans (``ranges`` (N, n) at ``poses`` (N, 3), beams at ``angles``) into a
    grid. Readings outside ``[min_range, max_range)`` are no-returns. Each scan is one
    vectorised pass over all its beams; a cell counts once per scan for hits and for
    pass-throughs."""
    ranges = np.asarray(ranges, dtype=np.float64)
    poses = np.asarray(poses, dtype=np.float64)
    ca, sa = np.cos(angles), np.sin(angles)
    valid = (ranges >= min_range) & (ranges < max_range)
    # bounds over every endpoint and pose
    lo = np.array([np.inf, np.inf])
    hi = -lo
    for p, r, v in zip(poses, ranges, valid, strict=True):
        if not v.any():
            continue
        c, s = math.cos(p[2]), math.sin(p[2])
        ex = p[0] + r[v] * (c * ca[v] - s * sa[v])
        ey = p[1] + r[v] * (s * ca[v] + c * sa[v])
        lo = np.minimum(lo, [ex.min(), ey.min()])
        hi = np.maximum(hi, [ex.max(), ey.max()])
    lo = np.minimum(lo, poses[:, :2].min(axis=0))
    hi = np.maximum(hi, poses[:, :2].max(axis=0))
    origin = (
        math.floor((lo[0] - pad) / resolution) * resolution,
        math.floor((lo[1] - pad) / resolution) * resolution,
    )
    W = int(math.ceil((hi[0] + pad - origin[0]) / resolution))
    H = int(math.ceil((hi[1] + pad - origin[1]) / resolution))
    hits = np.zeros(H * W, dtype=np.int32)
    through = np.zeros(H * W, dtype=np.int32)
    step = 0.75 * resolution
    for p, r, v in zip(poses, ranges, valid, strict=True):
        if not v.any():
            continue
        c, s = math.cos(p[2]), math.sin(p[2])
        bx = c * ca[v] - s * sa[v]
        by = s * ca[v] + c * sa[v]
        rv = r[v]
        end = _cells(np.column_stack([p[0] + rv * bx, p[1] + rv * by]), origin, resolution)
        end_flat = np.unique(end[:, 0] * W + end[:, 1])
        hits[end_flat] += 1
        # free samples from the sensor to one step short of the endpoint, all beams at once
        n = np.maximum(0, np.floor((rv - resolution) / step).astype(np.int64))
        if n.sum():
            beam = np.repeat(np.arange(len(rv)), n)
            k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
            t = k * step
            cells = _cells(np.column_stack([p[0] + t * bx[beam], p[1] + t * by[beam]]), origin, resolution)
            flat = np.unique(cells[:, 0] * W + cells[:, 1])
            through[flat] += 1
    total = hits + through
    occ = (hits >= min_hits) & (hits >= occupied_ratio * total)
    free = (through > 0) & ~occ
    return Grid(occupied=occ.reshape(H, W), free=free.reshape(H, W), resolution=resolution, origin=origin)


def write_map_server(grid: Grid, yaml_path: str | Path) -> Path:
    """``NAME.yaml`` + ``NAME.pgm`` (binary P5, row 0 = top = highest y)."""
    yaml_path = Path(yaml_path)
    yaml_path.parent.mkdir(parents=True, exist_ok=True)
    pgm = yaml_path.with_suffix(".pgm")
    img = np.full(grid.occupied.shape, UNKNOWN, dtype=np.uint8)
    img[grid.free] = FREE
    img[grid.occupied] = OCC
    img = img[::-1]
    H, W = img.shape
    # written to temporary names and renamed, the YAML last: a reader in another process
    # never sees half a map
    tmp_pgm = pgm.with_name(pgm.name + f".{os.getpid()}.tmp")
    with open(tmp_pgm, "wb") as f:
        f.write(f"P5\n{W} {H}\n255\n".encode())
        f.write(img.tobytes())
    tmp_pgm.replace(pgm)
    tmp_yaml = yaml_path.with_name(yaml_path.name + f".{os.getpid()}.tmp")
    tmp_yaml.write_text(
        f"image: {pgm.name}\nresolution: {grid.resolution}\n"
        f"origin: [{grid.origin[0]:.6f}, {grid.origin[1]:.6f}, 0.0]\n"
        "negate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    tmp_yaml.replace(yaml_path)
    return yaml_path


def _read_pgm(path: Path) -> NDArray[np.uint8]:
    data = path.read_bytes()
    tokens: list[bytes] = []
    pos = 0
    while len(tokens) < 4:
        while data[pos : pos + 1].isspace():
            pos += 1
        if data[pos : pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        start = pos
        while not data[pos : pos + 1].isspace():
            pos += 1
        tokens.append(data[start:pos])
    if tokens[0] != b"P5":
        raise ValueError(f"{path}: only binary PGM (P5) is read here, got {tokens[0]!r}")
    W, H, maxv = int(tokens[1]), int(tokens[2]), int(tokens[3])
    if maxv > 255:
        raise ValueError(f"{path}: 16-bit PGM not supported")
    pos += 1
    img = np.frombuffer(data, dtype=np.uint8, count=W * H, offset=pos)
    return img.reshape(H, W)


def read_map_server(yaml_path: str | Path) -> Grid:
    """A map_server YAML + PGM (trinary thresholds, ``negate`` honoured)."""
    import yaml

    yaml_path = Path(yaml_path)
    meta = yaml.safe_load(yaml_path.read_text())
    for key in ("image", "resolution", "origin"):
        if key not in meta:
            raise ValueError(f"{yaml_path}: no '{key}'")
    img = _read_pgm(yaml_path.parent / meta["image"]).astype(np.float64)
    p = img / 255.0 if meta.get("negate", 0) else (255.0 - img) / 255.0
    occ = p > float(meta.get("occupied_thresh", 0.65))
    free = p < float(meta.get("free_thresh", 0.196))
    return Grid(
        occupied=occ[::-1].copy(),
        free=free[::-1].copy(),
        resolution=float(meta["resolution"]),
        origin=(float(meta["origin"][0]), float(meta["origin"][1])),
    )

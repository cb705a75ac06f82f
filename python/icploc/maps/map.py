"""The :class:`Map`: walls as line segments (given or fitted from a grid), the grid they came
from, and the uniformly sampled points + normals the ICP core matches against."""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import MapError
from .formats import MapFormat, format_for, register
from .linefit import fit_lines
from .sampling import estimate_normals, sample_lines, thin_points

if TYPE_CHECKING:
    from matplotlib.axes import Axes

    from icploc._core import MapIndex

FloatArray = NDArray[np.float64]

#: line-fit settings of grid maps (lengths in metres; see :mod:`icploc.maps.linefit`):
#: shortest line, share of surface cells lines must explain (else points only), largest
#: door-sized gap across which collinear pieces are fitted jointly, snapping to the
#: dominant direction, and the face offset into the occupied side in cells (None: the
#: ROS YAML's ``icploc_surface_offset``, else :data:`icploc.maps.ros.DEFAULT_SURFACE_OFFSET`
#: for map_server maps and 0 for arrays given to :meth:`Map.from_grid`)
DEFAULT_FIT: dict[str, Any] = {
    "min_length": 0.15,
    "min_explained": 0.2,
    "max_gap": 1.0,
    "snap": True,
    "surface_offset": None,
}

#: most samples :meth:`Map.sample` makes (a bound against absurd spacings)
MAX_SAMPLES = 20_000_000


def _lines_array(lines: ArrayLike, what: str = "lines") -> FloatArray:
    a = np.asarray(lines, dtype=np.float64)
    if a.size == 0:
        return np.zeros((0, 4))
    if a.ndim != 2 or a.shape[1] != 4:
        raise MapError(None, what, f"must be a (K, 4) array [x1, y1, x2, y2], got shape {a.shape}")
    if not np.isfinite(a).all():
        raise MapError(None, what, "contains NaN or inf")
    return np.ascontiguousarray(a)


def _check_spacing(spacing: float) -> float:
    s = float(spacing)
    if not (math.isfinite(s) and s > 0):
        raise MapError(None, "spacing", f"must be a positive finite number, got {spacing!r}")
    return s


class Map:
    """A 2D map in the map frame (metres).

    Build one with :meth:`load` (format by file suffix), :meth:`from_lines`,
    :meth:`from_grid` or :meth:`from_points`.

    * ``lines`` — (K, 4) wall segments ``[x1, y1, x2, y2]`` (given, or fitted from a grid);
      for fitted lines the left normal (direction turned +90°) faces free space.
    * ``grid`` — boolean occupied cells ``grid[iy, ix]`` (row 0 at the origin, as in
      ``nav_msgs/OccupancyGrid``) or ``None``; ``free`` the free cells; ``resolution`` metres per
      cell; ``origin`` ``(x, y, yaw)`` of the outer corner of cell (0, 0).
    * ``sample(spacing)`` — points every ``spacing`` along the lines with unit normals, plus
      (for grids) the wall-surface cells no line explains; ``index(spacing)`` — the Rust
      :class:`icploc.MapIndex` over them.
    """

    def __init__(
        self,
        lines: ArrayLike | None = None,
        *,
        grid: NDArray[np.bool_] | None = None,
        free: NDArray[np.bool_] | None = None,
        resolution: float | None = None,
        origin: Sequence[float] | None = None,
        points: ArrayLike | None = None,
        point_normals: ArrayLike | None = None,
        extra_points: ArrayLike | None = None,
        extra_normals: ArrayLike | None = None,
        source: str | None = None,
        meta: dict[str, Any] | None = None,
    ) -> None:
        self.lines: FloatArray = _lines_array([] if lines is None else lines)
        self.grid = None if grid is None else np.ascontiguousarray(grid, dtype=bool)
        self.free = None if free is None else np.ascontiguousarray(free, dtype=bool)
        self.resolution = None if resolution is None else float(resolution)
        o = (0.0, 0.0, 0.0) if origin is None else tuple(float(v) for v in origin)
        if len(o) == 2:
            o = (o[0], o[1], 0.0)
        if len(o) != 3 or not all(math.isfinite(v) for v in o):
            raise MapError(source, "origin", f"must be finite (x, y[, yaw]), got {origin!r}")
        self.origin: tuple[float, float, float] = (o[0], o[1], o[2])
        self.points = (
            None if points is None else np.asarray(points, dtype=np.float64).reshape(-1, 2)
        )
        self.point_normals = (
            None
            if point_normals is None
            else np.asarray(point_normals, dtype=np.float64).reshape(-1, 2)
        )
        self.extra_points = (
            np.zeros((0, 2))
            if extra_points is None
            else np.asarray(extra_points, dtype=np.float64).reshape(-1, 2)
        )
        self.extra_normals = (
            np.zeros((0, 2))
            if extra_normals is None
            else np.asarray(extra_normals, dtype=np.float64).reshape(-1, 2)
        )
        self.occupancy: NDArray[np.int8] | None = (
            None  # ROS values (-1, 0..100) when loaded from ROS
        )
        self.source = source
        self.meta: dict[str, Any] = dict(meta or {})
        self._samples: dict[float, tuple[FloatArray, FloatArray, dict[str, int]]] = {}
        self._indexes: dict[float, MapIndex] = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def load(cls, path: str | Path, *, cache: bool | None = None, **options: Any) -> Map:
        """Load a map, choosing the reader by suffix (:mod:`icploc.maps.formats`):
        ``.yaml``/``.yml`` (ROS map_server),
        ``.geojson``/``.json``, ``.dxf``, ``.npy``/``.csv``/``.txt`` (points), ``.npz``
        (prepared, see :meth:`save`). ``options`` go to the reader / line fit (e.g.
        ``units="mm"`` for DXF, ``min_length=0.3`` for grids).

        Grid maps are fitted once and kept in the cache of prepared maps (see
        :mod:`icploc.maps.cache`); ``cache=False`` neither reads nor writes it (``None``, the
        default, uses it unless ``ICPLOC_NO_CACHE`` is set in the environment)."""
        path = Path(path)
        fmt = format_for(path)
        if not path.exists():
            raise MapError(path, None, "file not found")
        return fmt.load(path, cache, options)

    @classmethod
    def _load_ros(cls, path: Path, cache: bool | None, options: dict[str, Any]) -> Map:
        import os

        from .ros import load_ros, read_yaml

        unknown = set(options) - set(DEFAULT_FIT) - {"fit"}
        if unknown:
            raise MapError(path, None, f"unknown map option(s) {sorted(unknown)}")
        use_cache = (not os.environ.get("ICPLOC_NO_CACHE")) if cache is None else bool(cache)
        key = None
        if use_cache:
            from . import cache as map_cache

            fields = read_yaml(path)
            settings = {**DEFAULT_FIT, **options}
            try:
                key = map_cache.cache_key([path, fields["image"]], settings)
            except OSError as e:
                raise MapError(path, None, f"cannot read: {e.strerror or e}") from e
            hit = map_cache.load_cached(key, str(path))
            if hit is not None:
                return hit
        g = load_ros(path)
        opts = dict(options)
        if opts.get("surface_offset") is None:
            opts["surface_offset"] = g.meta.get("surface_offset", 0.0)
        m = cls.from_grid(g.occupied, g.resolution, g.origin, free=g.free, source=str(path), **opts)
        m.meta.update({"format": "ros", "ros": g.meta})
        m.occupancy = g.occupancy
        if key is not None:
            from . import cache as map_cache

            map_cache.store(key, m)
        return m

    @classmethod
    def from_lines(cls, lines: ArrayLike, **meta: Any) -> Map:
        """A map of the given (K, 4) wall segments in metres."""
        return cls(lines, meta={"format": "lines", **meta})

    @classmethod
    def from_points(cls, points: ArrayLike, normals: ArrayLike | None = None) -> Map:
        """A point map: (N, 2) points (optionally with (N, 2) normals)."""
        p = np.asarray(points, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 2 or len(p) == 0 or not np.isfinite(p).all():
            raise MapError(
                None, "points", f"must be a non-empty finite (N, 2) array, got shape {p.shape}"
            )
        n = None
        if normals is not None:
            n = np.asarray(normals, dtype=np.float64)
            if n.shape != p.shape:
                raise MapError(None, "normals", f"shape {n.shape} != points shape {p.shape}")
            ln = np.hypot(n[:, 0], n[:, 1])
            if not (np.isfinite(ln).all() and (ln > 1e-9).all()):
                raise MapError(None, "normals", "must be finite and non-zero")
            n = n / ln[:, None]
        return cls(points=p, point_normals=n, meta={"format": "points"})

    @classmethod
    def from_grid(
        cls,
        occupancy: ArrayLike,
        resolution: float,
        origin: Sequence[float] = (0.0, 0.0, 0.0),
        *,
        free: ArrayLike | None = None,
        fit: bool = True,
        min_length: float = DEFAULT_FIT["min_length"],
        min_explained: float = DEFAULT_FIT["min_explained"],
        max_gap: float = DEFAULT_FIT["max_gap"],
        snap: bool = DEFAULT_FIT["snap"],
        surface_offset: float | None = DEFAULT_FIT["surface_offset"],
        source: str | None = None,
    ) -> Map:
        """A map from an occupancy grid ``occupancy[iy, ix]`` (row 0 at ``origin``).

        ``occupancy`` is boolean (True = occupied; then ``free`` defaults to ``~occupancy``) or
        OccupancyGrid-style numbers (-1 unknown, 0..100: > 65 occupied, < 19.6 free). Walls are
        fitted as lines where occupied meets free (``fit=False`` skips that; see
        :mod:`icploc.maps.linefit` and :data:`DEFAULT_FIT` for ``max_gap``, ``snap`` and
        ``surface_offset``); pieces shorter than ``min_length`` metres stay as surface points.
        If the lines explain less than ``min_explained`` of the surface cells, samples are all
        surface points instead (``meta['sample_mode'] == 'points'``).
        """
        occ_in = np.asarray(occupancy)
        if occ_in.ndim != 2 or occ_in.size == 0:
            raise MapError(
                source, "grid", f"must be a non-empty 2-D array, got shape {occ_in.shape}"
            )
        if occ_in.dtype == bool:
            occupied = occ_in
            free_m = ~occupied if free is None else np.asarray(free, dtype=bool)
        else:
            v = occ_in.astype(np.float64)
            if not np.isfinite(v).all():
                raise MapError(source, "grid", "contains NaN or inf")
            occupied = v > 65
            free_m = (v >= 0) & (v < 19.6) if free is None else np.asarray(free, dtype=bool)
        if free_m.shape != occupied.shape:
            raise MapError(source, "free", f"shape {free_m.shape} != grid shape {occupied.shape}")
        res = float(resolution)
        if not (math.isfinite(res) and res > 0):
            raise MapError(
                source, "resolution", f"must be a positive finite number, got {resolution!r}"
            )
        m = cls(
            grid=occupied,
            free=free_m,
            resolution=res,
            origin=origin,
            source=source,
            meta={"format": "grid"},
        )
        m.refit(
            min_length=min_length,
            min_explained=min_explained,
            max_gap=max_gap,
            snap=snap,
            surface_offset=surface_offset,
            lines=fit,
        )
        return m

    def refit(
        self,
        *,
        min_length: float = DEFAULT_FIT["min_length"],
        min_explained: float = DEFAULT_FIT["min_explained"],
        max_gap: float = DEFAULT_FIT["max_gap"],
        snap: bool = DEFAULT_FIT["snap"],
        surface_offset: float | None = DEFAULT_FIT["surface_offset"],
        lines: bool = True,
    ) -> None:
        """(Re)fit the wall lines of a grid map; updates ``lines``, the surface points no
        line explains and ``meta['fit']`` (see :meth:`from_grid`)."""
        if self.grid is None or self.resolution is None:
            raise MapError(self.source, "grid", "map has no occupancy grid to fit")
        res = self.resolution
        for name, v in (("min_length", min_length), ("max_gap", max_gap)):
            if not (math.isfinite(float(v)) and float(v) >= 0):
                raise MapError(self.source, name, f"must be a finite number >= 0, got {v!r}")
        offset = 0.0 if surface_offset is None else float(surface_offset)
        if not 0.0 <= offset <= 0.5:
            raise MapError(self.source, "surface_offset", f"must lie in [0, 0.5] cells, got {offset!r}")
        settings = {
            "min_length": max(3.0, min_length / res),
            "max_gap": max_gap / res,
            "snap": bool(snap),
            "surface_offset": offset,
        }
        f = fit_lines(self.grid, self.free, **settings)
        explained = f.explained_fraction if lines else 0.0
        mode = "lines" if len(f.points) == 0 else "lines+points"
        if explained < min_explained or not lines:
            # not enough is straight: every surface cell becomes a point
            mode = "points"
            everything = dict(settings, min_length=float(sum(self.grid.shape)) * 4)
            pts = fit_lines(self.grid, self.free, **everything)
            self.lines = np.zeros((0, 4))
            self.extra_points = self.cells_to_world(pts.points)
            self.extra_normals = self._rotate(pts.normals)
        else:
            self.lines = self.cells_to_world(f.lines.reshape(-1, 2)).reshape(-1, 4)
            self.extra_points = self.cells_to_world(f.points)
            self.extra_normals = self._rotate(f.normals)
        self.meta["sample_mode"] = mode
        self.meta["fit"] = {
            "lines": int(len(f.lines)),
            "surface_cells": f.surface_cells,
            "explained_fraction": round(float(f.explained_fraction), 4),
            "rms_cells_median": round(float(np.median(f.rms)), 4) if len(f.rms) else None,
            "snapped": int(f.snapped.sum()),
            "dominant_direction_deg": None
            if f.dominant_direction is None
            else round(math.degrees(f.dominant_direction), 4),
            "min_length": min_length,
            "max_gap": max_gap,
            "surface_offset": offset,
        }
        self._samples.clear()
        self._indexes.clear()

    # ------------------------------------------------------------------ geometry
    def _rotate(self, v: FloatArray) -> FloatArray:
        c, s = math.cos(self.origin[2]), math.sin(self.origin[2])
        v = np.asarray(v, dtype=np.float64).reshape(-1, 2)
        return np.column_stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1]])

    def cells_to_world(self, xy: ArrayLike) -> FloatArray:
        """Cell-centre coordinates (x = ix, y = iy, fractional allowed) to metres."""
        if self.resolution is None:
            raise MapError(self.source, "grid", "map has no grid")
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        w = self._rotate((xy + 0.5) * self.resolution)
        return w + np.array(self.origin[:2])

    def world_to_cells(self, xy: ArrayLike) -> FloatArray:
        """Inverse of :meth:`cells_to_world` (round to get integer cell indices)."""
        if self.resolution is None:
            raise MapError(self.source, "grid", "map has no grid")
        q = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.array(self.origin[:2])
        c, s = math.cos(self.origin[2]), math.sin(self.origin[2])
        local = np.column_stack([c * q[:, 0] + s * q[:, 1], -s * q[:, 0] + c * q[:, 1]])
        return local / self.resolution - 0.5

    @property
    def grid_corners(self) -> FloatArray | None:
        """(4, 2) world corners of the grid, or None."""
        if self.grid is None or self.resolution is None:
            return None
        h, w = self.grid.shape
        return self.cells_to_world(
            [[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]]
        )

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the walls and points (of the grid if there are none)."""
        parts = [self.lines.reshape(-1, 2), self.extra_points]
        if self.points is not None:
            parts.append(self.points)
        xy = np.concatenate(parts)
        if len(xy) == 0:
            corners = self.grid_corners
            if corners is None:
                raise MapError(self.source, "bounds", "empty map")
            xy = corners
        lo, hi = xy.min(axis=0), xy.max(axis=0)
        return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))

    # ------------------------------------------------------------------ sampling
    def sample(self, spacing: float) -> tuple[FloatArray, FloatArray]:
        """Map points every ``spacing`` metres with unit normals: ``(points (N, 2), normals (N, 2))``.

        Lines are sampled uniformly (see :func:`icploc.maps.sampling.sample_lines`); for grid
        maps the wall-surface cells no line explains are added, thinned to one per
        ``spacing`` square, with normals from their neighbourhood (facing free space); point
        maps are thinned the same way, normals given or estimated by local PCA.
        Results are cached per spacing (treat them as read-only).
        """
        s = _check_spacing(spacing)
        if s in self._samples:
            p, n, _ = self._samples[s]
            return p, n
        if len(self.lines):
            length = float(np.hypot(*(self.lines[:, 2:] - self.lines[:, :2]).T).sum())
            if length / s + len(self.lines) > MAX_SAMPLES:
                raise MapError(
                    self.source,
                    "spacing",
                    f"{spacing!r} m would give about {length / s:.3g} samples along "
                    f"{length:.1f} m of walls (limit {MAX_SAMPLES:,}); use a spacing of at "
                    f"least {length / MAX_SAMPLES:.2g} m",
                )
        lp, ln, _ = sample_lines(self.lines, s)
        counts = {"lines": int(len(lp))}
        parts_p, parts_n = [lp], [ln]
        if len(self.extra_points):
            keep = thin_points(self.extra_points, s)
            parts_p.append(self.extra_points[keep])
            parts_n.append(self.extra_normals[keep])
            counts["boundary"] = int(len(keep))
        if self.points is not None:
            keep = thin_points(self.points, s)
            pts = self.points[keep]
            if self.point_normals is not None:
                nrm = self.point_normals[keep]
            else:
                nrm = estimate_normals(self.points, radius=max(3 * s, 1e-9))[keep]
            parts_p.append(pts)
            parts_n.append(nrm)
            counts["points"] = int(len(keep))
        p = np.ascontiguousarray(np.concatenate(parts_p))
        n = np.ascontiguousarray(np.concatenate(parts_n))
        counts["total"] = int(len(p))
        p.flags.writeable = False
        n.flags.writeable = False
        self._samples[s] = (p, n, counts)
        return p, n

    def sample_counts(self, spacing: float) -> dict[str, int]:
        """How many samples :meth:`sample` gives, by source (lines / boundary / points / total)."""
        s = _check_spacing(spacing)
        self.sample(s)
        return dict(self._samples[s][2])

    def index(self, spacing: float) -> MapIndex:
        """The Rust :class:`icploc.MapIndex` (k-d tree) over ``sample(spacing)``, cached."""
        s = _check_spacing(spacing)
        if s not in self._indexes:
            from icploc._core import MapIndex

            p, n = self.sample(s)
            if len(p) == 0:
                raise MapError(self.source, "lines", "map has no points to index")
            from . import cache as map_cache  # a cached map's grid is kept beside it

            idx = map_cache.load_index(self, s, p, n)
            if idx is None:
                idx = MapIndex(p, n)
                map_cache.store_index(self, s, p, n, idx)
            if idx.cache_fallback is not None:  # said once: the index is kept
                warnings.warn(f"{self.source}: {idx.cache_fallback}", RuntimeWarning, stacklevel=2)
            self._indexes[s] = idx
        return self._indexes[s]

    # ------------------------------------------------------------------ visibility
    def visible(
        self,
        pose: Sequence[float],
        fov: float = 2 * math.pi,
        max_range: float = 30.0,
        spacing: float = 0.05,
        *,
        exact: bool = False,
        point_radius: float | None = None,
        tolerance: float = 0.05,
    ) -> NDArray[np.int64]:
        """Indices into ``sample(spacing)`` of the points a scanner at ``pose`` (x, y, theta)
        with field of view ``fov`` (radians, centred on theta) and ``max_range`` could see.

        Default: the Rust z-buffer (:meth:`icploc.MapIndex.visible`) — fast, per scan; each
        sample hides an arc of half-width ``point_radius`` (default ``spacing / 2``: the
        piece of wall it stands for). ``exact=True``: ray-segment tests in numpy
        against the lines plus a ``spacing``-long piece of wall at every non-line sample
        (slower; a reference). For grid maps with unknown cells, a point behind unknown cells
        is hidden too (:func:`icploc.maps.visibility.visible_in_grid`).
        """
        s = _check_spacing(spacing)
        idx = self._visible_lines(pose, fov, max_range, s, exact, point_radius, tolerance)
        if self.grid is None or self.free is None or self.resolution is None:
            return idx
        unknown = ~(self.grid | self.free)
        if not unknown.any() or len(idx) == 0:
            return idx
        # unknown cells occlude as walls do; the ray stops short of the point by the rim of
        # unknown cells a wall may have (see linefit) plus a cell
        from .linefit import classes, defaults
        from .visibility import visible_in_grid

        p, _ = self.sample(s)
        reach = (int(defaults()["unknown_rim"]) + 1) * self.resolution
        ok = visible_in_grid(
            classes(self.grid, self.free),
            self.resolution,
            self.origin,
            pose,
            p[idx],
            max(tolerance, reach),
        )
        return idx[ok]

    def _visible_lines(
        self,
        pose: Sequence[float],
        fov: float,
        max_range: float,
        s: float,
        exact: bool,
        point_radius: float | None,
        tolerance: float,
    ) -> NDArray[np.int64]:
        if exact:
            from .visibility import visible_exact

            p, n = self.sample(s)
            walls = self.lines
            k = self._samples[s][2].get("lines", 0)
            if k < len(p):
                q, m = p[k:], n[k:]
                tangent = np.column_stack([m[:, 1], -m[:, 0]]) * (0.5 * s)
                walls = np.concatenate([walls, np.column_stack([q - tangent, q + tangent])])
            return visible_exact(p, walls, pose, fov, max_range, tolerance=tolerance)
        radius = 0.5 * s if point_radius is None else float(point_radius)
        return np.asarray(
            self.index(s).visible(
                pose, fov=fov, max_range=max_range, point_radius=radius, tolerance=tolerance
            ),
            dtype=np.int64,
        )

    def visible_points(
        self,
        pose: Sequence[float],
        fov: float = 2 * math.pi,
        max_range: float = 30.0,
        spacing: float = 0.05,
        *,
        exact: bool = False,
    ) -> tuple[FloatArray, FloatArray]:
        """``(points, normals)`` of :meth:`visible`."""
        idx = self.visible(pose, fov, max_range, spacing, exact=exact)
        p, n = self.sample(spacing)
        return p[idx], n[idx]

    # ------------------------------------------------------------------ output
    def save(self, path: str | Path, spacing: float | Sequence[float] | None = None) -> Path:
        """Save the prepared map (lines, grid, fallback points, samples for ``spacing``, metadata)
        to one ``.npz`` file that :meth:`load` reads back without refitting."""
        from .prepared import save_prepared

        spacings = (
            []
            if spacing is None
            else [spacing]
            if isinstance(spacing, int | float)
            else list(spacing)
        )
        return save_prepared(self, path, [_check_spacing(s) for s in spacings])

    def to_ros(
        self,
        yaml_path: str | Path,
        resolution: float,
        *,
        margin: float = 1.0,
        origin: Sequence[float] | None = None,
        image_format: str = "pgm",
    ) -> Path:
        """Rasterise the lines into a ROS map_server map (trinary YAML + PGM/PNG); returns the
        YAML path.

        Every cell a line passes through is occupied, all others free; the YAML says so
        (``icploc_surface_offset: 0.5``: walls run through the centres of their cells). By default the grid
        covers :attr:`bounds` plus ``margin`` and is aligned so cell centres sit on multiples
        of ``resolution`` (a wall at x = 2.0 runs through cell centres); ``origin`` (x, y[, yaw])
        overrides that.
        """
        from .raster import rasterize_lines
        from .ros import save_ros

        res = _check_spacing(resolution)
        if len(self.lines) == 0:
            raise MapError(self.source, "lines", "no lines to rasterise")
        xmin, ymin, xmax, ymax = self.bounds
        if origin is None:
            ox = math.floor((xmin - margin) / res) * res - res / 2
            oy = math.floor((ymin - margin) / res) * res - res / 2
            o = (ox, oy, 0.0)
        else:
            ov = [float(v) for v in origin]
            o = (ov[0], ov[1], ov[2] if len(ov) > 2 else 0.0)
        grid_map = Map(resolution=res, origin=o)
        cells = grid_map.world_to_cells(self.lines.reshape(-1, 2)).reshape(-1, 4)
        if origin is None:
            w = math.ceil((xmax + margin - o[0]) / res) + 1
            h = math.ceil((ymax + margin - o[1]) / res) + 1
        else:
            if cells.min() < -0.5:
                raise MapError(self.source, "origin", "lines extend below/left of the given origin")
            hi = cells.reshape(-1, 2).max(axis=0)
            w, h = (
                int(math.ceil(hi[0] + margin / res)) + 1,
                int(math.ceil(hi[1] + margin / res)) + 1,
            )
        if w * h > 400_000_000:
            raise MapError(self.source, "resolution", f"grid of {w}x{h} cells is too large")
        occ = rasterize_lines(cells, (h, w))
        yaml_path = Path(yaml_path)
        # a rasterised line runs through its cells: its surface is at their centres
        save_ros(yaml_path, occ, res, o, image_format=image_format, surface_offset=0.5)
        return yaml_path

    def to_geojson(self, path: str | Path) -> Path:
        """Write the lines in our GeoJSON format (see docs/map-formats.md)."""
        from .geojson import save_geojson

        save_geojson(path, self.lines, name=self.meta.get("name"))
        return Path(path)

    def plot(self, ax: Axes | None = None, **options: Any) -> Axes:
        """Draw grid, lines and samples with matplotlib (see :func:`icploc.maps.plot.plot_map`)."""
        from .plot import plot_map

        return plot_map(self, ax=ax, **options)

    def info(self, spacing: float | None = None) -> dict[str, Any]:
        """A summary (format, counts, bounds, fit statistics) as plain data."""
        d: dict[str, Any] = {
            "source": self.source,
            "format": self.meta.get("format"),
            "lines": int(len(self.lines)),
        }
        if len(self.lines):
            d["line_length_m"] = round(
                float(np.hypot(*(self.lines[:, 2:] - self.lines[:, :2]).T).sum()), 3
            )
        if self.grid is not None:
            d["grid_shape"] = list(self.grid.shape)
            d["resolution"] = self.resolution
            d["origin"] = list(self.origin)
            d["occupied_cells"] = int(self.grid.sum())
        if self.points is not None:
            d["points"] = int(len(self.points))
        if len(self.extra_points):
            d["boundary_points"] = int(len(self.extra_points))
        for k in ("fit", "sample_mode", "units"):
            if k in self.meta:
                d[k] = self.meta[k]
        try:
            d["bounds"] = [round(v, 4) for v in self.bounds]
        except MapError:
            pass
        if spacing is not None:
            d["samples"] = self.sample_counts(spacing)
            d["spacing"] = spacing
        return d

    def __repr__(self) -> str:
        parts = [f"lines={len(self.lines)}"]
        if self.grid is not None:
            parts.append(f"grid={self.grid.shape[1]}x{self.grid.shape[0]}@{self.resolution}m")
        if self.points is not None:
            parts.append(f"points={len(self.points)}")
        if len(self.extra_points):
            parts.append(f"boundary_points={len(self.extra_points)}")
        if self.source:
            parts.append(f"source={self.source!r}")
        return f"Map({', '.join(parts)})"


# -- the built-in map formats (icploc.maps.formats) ----------------------------------------


def _load_geojson(path: Path, cache: bool | None, options: dict[str, Any]) -> Map:
    from .geojson import load_geojson

    lines, meta = load_geojson(path)
    return Map(lines, source=str(path), meta={"format": "geojson", **meta})


def _save_geojson(m: Map, path: Path, options: dict[str, Any]) -> Path:
    return m.to_geojson(path)


def _load_dxf(path: Path, cache: bool | None, options: dict[str, Any]) -> Map:
    from .dxf import load_dxf

    lines, meta = load_dxf(path, **options)
    return Map(lines, source=str(path), meta={"format": "dxf", **meta})


def _load_points(path: Path, cache: bool | None, options: dict[str, Any]) -> Map:
    from .points import load_csv, load_npy

    pts, nrm = load_npy(path) if path.suffix.lower() == ".npy" else load_csv(path)
    return Map(points=pts, point_normals=nrm, source=str(path), meta={"format": "points"})


def _load_prepared(path: Path, cache: bool | None, options: dict[str, Any]) -> Map:
    from .prepared import load_prepared

    return load_prepared(path)


def _save_prepared(m: Map, path: Path, options: dict[str, Any]) -> Path:
    return m.save(path, options.get("spacing"))


def _save_ros(m: Map, path: Path, options: dict[str, Any]) -> Path:
    return m.to_ros(path, options.get("resolution", 0.05))


register(
    MapFormat(
        "ros",
        (".yaml", ".yml"),
        lambda p, cache, opts: Map._load_ros(p, cache, opts),
        _save_ros,
        "ROS map_server grid (YAML + PGM/PNG); saved by rasterising the lines",
    )
)
register(MapFormat("geojson", (".geojson", ".json"), _load_geojson, _save_geojson, "wall lines"))
register(MapFormat("dxf", (".dxf",), _load_dxf, None, "CAD drawing (lines, polylines, arcs)"))
register(MapFormat("points", (".npy", ".csv", ".txt"), _load_points, None, "map points"))
register(
    MapFormat("prepared", (".npz",), _load_prepared, _save_prepared, "a prepared map (Map.save)")
)

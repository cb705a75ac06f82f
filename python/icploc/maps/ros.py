"""ROS map_server maps: a YAML file naming a PGM/PNG image plus its metadata.

Semantics follow ROS 2 ``nav2_map_server`` (``map_io``), which match ROS 1 map_server for
``trinary`` and ``scale``:

* ``image`` is relative to the YAML file's directory (absolute paths are allowed).
* ``resolution`` is metres per pixel; ``origin`` is the pose ``[x, y, yaw]`` of the
  lower-left pixel's outer corner (yaw counter-clockwise, radians) and *is* applied here.
* The pixel value is the mean of the colour channels (trinary mode also averages in the
  opacity of an alpha channel, as map_server does); ``occ = (255 - v) / 255``, or ``v / 255``
  with ``negate``.
* ``trinary``: ``occ > occupied_thresh`` occupied (100), ``occ < free_thresh`` free (0), else
  unknown (-1). ``scale``: as trinary, but in-between values become 0..100 linearly and
  transparent pixels are unknown. ``raw``: the grey value is the occupancy in percent
  (0..100, anything else unknown); ``negate`` does not apply (as in ROS 2).

The resulting occupancy array uses the ``nav_msgs/OccupancyGrid`` layout: ``grid[iy, ix]``,
row 0 at the origin (the *bottom* of the image).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from icploc.flat_yaml import plain_mapping as plain_mapping  # here as before

from .errors import MapError

MODES = ("trinary", "scale", "raw")
REQUIRED = ("image", "resolution", "origin", "negate", "occupied_thresh", "free_thresh")

# Grey levels map_saver writes.
PGM_OCCUPIED = 0
PGM_FREE = 254
PGM_UNKNOWN = 205

#: largest image read (pixels): 10,000 x 10,000, e.g. 500 m square at 5 cm
MAX_PIXELS = 100_000_000

#: optional key (ignored by map_server) saying where wall surfaces lie inside the boundary
#: cells, in cells into the occupied side (0: on the occupied/free boundary; 0.5: on the
#: cell centres, as in maps built from laser hits). ``icploc map build`` writes 0.5.
SURFACE_OFFSET_KEY = "icploc_surface_offset"
#: where the walls of a map_server map without ``icploc_surface_offset`` lie, in cells from
#: the occupied/free boundary into the occupied side: such maps are made from laser hits
#: (gmapping, slam_toolbox, cartographer, ``icploc map build``), which mark the cell a beam
#: ends in, so the wall runs on average through the centres of its cells (0.5). A map whose
#: cells were rasterised from exact walls says ``icploc_surface_offset: 0`` to put the faces on
#: the boundary. On real 10 cm grids 0.5 halves the error against 0 (benches/eval_real.py).
DEFAULT_SURFACE_OFFSET = 0.5


@dataclass
class RosGrid:
    """A decoded ROS map: occupancy in OccupancyGrid layout and its metadata."""

    occupancy: NDArray[np.int8]  # (H, W): -1 unknown, 0..100
    occupied: NDArray[np.bool_]
    free: NDArray[np.bool_]
    resolution: float
    origin: tuple[float, float, float]
    meta: dict[str, Any] = field(default_factory=dict)


def _number(path: Path, doc: dict[str, Any], key: str) -> float:
    v = doc[key]
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise MapError(path, key, f"must be a number, got {v!r}")
    f = float(v)
    if not math.isfinite(f):
        raise MapError(path, key, f"must be finite, got {v!r}")
    return f


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Parse and validate a map_server YAML file; return the checked fields."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise MapError(path, None, f"cannot read file: {e.strerror or e}") from e
    doc = plain_mapping(text)
    if doc is None:  # anything beyond a flat file of plain keys and values: PyYAML reads it
        import yaml

        try:
            doc = yaml.safe_load(text)
        except yaml.YAMLError as e:
            raise MapError(path, None, f"not valid YAML: {e}") from e
    if not isinstance(doc, dict):
        raise MapError(path, None, "expected a YAML mapping of map_server fields")
    for key in REQUIRED:
        if key not in doc or doc[key] is None:
            raise MapError(path, key, "missing (required by map_server)")

    image = doc["image"]
    if not isinstance(image, str) or not image.strip():
        raise MapError(path, "image", f"must be a non-empty file name, got {image!r}")
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path
    if not image_path.is_file():
        raise MapError(path, "image", f"image file not found: {image_path}")

    resolution = _number(path, doc, "resolution")
    if resolution <= 0:
        raise MapError(path, "resolution", f"must be positive, got {resolution!r}")

    origin = doc["origin"]
    if not isinstance(origin, list | tuple) or len(origin) != 3:
        raise MapError(path, "origin", f"must be a list [x, y, yaw], got {origin!r}")
    ox: list[float] = []
    for i, v in enumerate(origin):
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
            raise MapError(path, f"origin[{i}]", f"must be a finite number, got {v!r}")
        ox.append(float(v))

    negate = doc["negate"]
    if isinstance(negate, bool):
        neg = negate
    elif isinstance(negate, int) and negate in (0, 1):
        neg = bool(negate)
    else:
        raise MapError(path, "negate", f"must be 0 or 1 (or true/false), got {negate!r}")

    occ = _number(path, doc, "occupied_thresh")
    free = _number(path, doc, "free_thresh")
    for key, v in (("occupied_thresh", occ), ("free_thresh", free)):
        if not 0.0 <= v <= 1.0:
            raise MapError(path, key, f"must lie in [0, 1], got {v!r}")
    if not free < occ:
        raise MapError(path, "free_thresh", f"must be below occupied_thresh ({free!r} >= {occ!r})")

    mode = doc.get("mode", "trinary")
    if not isinstance(mode, str) or mode.lower() not in MODES:
        raise MapError(path, "mode", f"must be one of {', '.join(MODES)}, got {mode!r}")

    offset = DEFAULT_SURFACE_OFFSET
    if doc.get(SURFACE_OFFSET_KEY) is not None:
        offset = _number(path, doc, SURFACE_OFFSET_KEY)
        if not 0.0 <= offset <= 0.5:
            raise MapError(path, SURFACE_OFFSET_KEY, f"must lie in [0, 0.5] cells, got {offset!r}")

    return {
        "image": image_path,
        "surface_offset": offset,
        "resolution": resolution,
        "origin": (ox[0], ox[1], ox[2]),
        "negate": neg,
        "occupied_thresh": occ,
        "free_thresh": free,
        "mode": mode.lower(),
    }


def _read_image(
    yaml_path: Path, image_path: Path
) -> tuple[NDArray[np.float64], NDArray[np.float64] | None, int]:
    """Grey levels 0..255 (mean of colour channels), opacity 0..1 (None without alpha) and
    the number of colour channels."""
    import warnings

    from PIL import Image, UnidentifiedImageError
    from PIL.Image import DecompressionBombError, DecompressionBombWarning

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DecompressionBombWarning)
            im_ctx = Image.open(image_path)
    except DecompressionBombError as e:
        raise MapError(
            yaml_path, "image", f"image {image_path} is too large (limit {MAX_PIXELS:,} pixels)"
        ) from e
    except (OSError, UnidentifiedImageError) as e:
        raise MapError(yaml_path, "image", f"cannot decode image {image_path}: {e}") from e
    w, h = im_ctx.size
    if w * h > MAX_PIXELS:
        im_ctx.close()
        raise MapError(
            yaml_path,
            "image",
            f"image {image_path} has {w} x {h} = {w * h:,} pixels (limit {MAX_PIXELS:,})",
        )
    try:
        with im_ctx as im:
            im.load()
            mode = im.mode
            if mode in ("I;16", "I;16B", "I;16L", "I"):
                arr = np.asarray(im, dtype=np.float64)
                top = 65535.0 if arr.max(initial=0) > 255 or mode.startswith("I;16") else 255.0
                return arr * (255.0 / top), None, 1
            if mode == "P":
                im2 = im.convert("RGBA" if "transparency" in im.info else "RGB")
            elif mode in ("1", "L", "LA", "RGB", "RGBA"):
                im2 = im
            else:
                im2 = im.convert("RGBA" if "A" in mode else "RGB")
            a = np.asarray(im2, dtype=np.float64)
    except (OSError, UnidentifiedImageError) as e:
        raise MapError(yaml_path, "image", f"cannot decode image {image_path}: {e}") from e
    if a.ndim == 2:
        if im2.mode == "1":
            a = a * 255.0
        return a, None, 1
    nch = a.shape[2]
    if nch in (2, 4):
        return a[..., : nch - 1].mean(axis=2), a[..., nch - 1] / 255.0, nch - 1
    return a.mean(axis=2), None, nch


def _classify(
    grey: NDArray[np.float64], alpha: NDArray[np.float64] | None, ncolour: int, f: dict[str, Any]
) -> tuple[NDArray[np.int8], NDArray[np.bool_], NDArray[np.bool_]]:
    """map_server's pixel rules: (occupancy -1/0..100, occupied, free) of grey levels."""
    mode, occ_t, free_t = f["mode"], f["occupied_thresh"], f["free_thresh"]
    if mode == "raw":
        v = np.rint(grey)
        occupancy = np.where((v >= 0) & (v <= 100), v, -1).astype(np.int8)
        pct = occupancy.astype(np.float64) / 100.0
        known = occupancy >= 0
        return occupancy, known & (pct > occ_t), known & (pct < free_t)
    if mode == "trinary" and alpha is not None:
        # map_server averages the opacity in with the colour channels in trinary mode
        grey = (grey * ncolour + alpha * 255.0) / (ncolour + 1)
    occ = grey / 255.0 if f["negate"] else (255.0 - grey) / 255.0
    occupied = occ > occ_t
    free = occ < free_t
    occupancy = np.full(grey.shape, -1, dtype=np.int8)
    occupancy[occupied] = 100
    occupancy[free] = 0
    if mode == "scale":
        mid = ~occupied & ~free
        if alpha is not None:
            mid &= alpha >= 1.0
        scaled = np.rint((occ - free_t) / (occ_t - free_t) * 100.0)
        occupancy[mid] = np.clip(scaled[mid], 0, 100).astype(np.int8)
    return occupancy, occupied, free


def load_ros(path: str | Path) -> RosGrid:
    """Load a map_server YAML + image into an occupancy grid (OccupancyGrid layout)."""
    path = Path(path)
    f = read_yaml(path)
    grey_u8 = _read_grey_u8(path, f["image"])
    if grey_u8 is not None:
        # 8-bit grey without alpha (PGM, grey PNG): classify the 256 levels once, then look
        # every pixel up (the same rules, one pass over bytes)
        if grey_u8.size == 0:
            raise MapError(path, "image", f"image {f['image']} is empty")
        lut_occ, lut_o, lut_f = _classify(np.arange(256, dtype=np.float64), None, 1, f)
        flipped = grey_u8[::-1]
        occupancy, occupied, free = lut_occ[flipped], lut_o[flipped], lut_f[flipped]
    else:
        grey, alpha, ncolour = _read_image(path, f["image"])
        if grey.size == 0:
            raise MapError(path, "image", f"image {f['image']} is empty")
        occupancy, occupied, free = _classify(grey, alpha, ncolour, f)
        # image row 0 is the top; OccupancyGrid row 0 is the bottom (the origin)
        occupancy, occupied, free = occupancy[::-1], occupied[::-1], free[::-1]
    meta = {k: (str(v) if isinstance(v, Path) else v) for k, v in f.items()}
    return RosGrid(
        occupancy=np.ascontiguousarray(occupancy),
        occupied=np.ascontiguousarray(occupied),
        free=np.ascontiguousarray(free),
        resolution=f["resolution"],
        origin=f["origin"],
        meta=meta,
    )


def _read_grey_u8(
    yaml_path: Path, image_path: Path, field: str | None = "image"
) -> NDArray[np.uint8] | None:
    """The pixels of a binary PGM (P5, maxval 255) as uint8, read directly; None for any
    other image (then PIL decodes it). Errors are :class:`MapError` of ``yaml_path``'s
    ``field`` (also :func:`icploc.mappatch.read_sigma_image`'s reader)."""
    try:
        with open(image_path, "rb") as fh:
            head = fh.read(512)
            if not head.startswith(b"P5"):
                return None
            fields: list[bytes] = []
            pos = 2
            while len(fields) < 3:
                while pos < len(head) and head[pos : pos + 1].isspace():
                    pos += 1
                if pos < len(head) and head[pos : pos + 1] == b"#":
                    nl = head.find(b"\n", pos)
                    if nl < 0:
                        return None
                    pos = nl + 1
                    continue
                end = pos
                while end < len(head) and head[end : end + 1].isdigit():
                    end += 1
                if end == pos:
                    return None
                fields.append(head[pos:end])
                pos = end
            w, h, maxval = (int(v) for v in fields)
            if maxval != 255 or w <= 0 or h <= 0:
                return None
            if w * h > MAX_PIXELS:
                raise MapError(
                    yaml_path,
                    field,
                    f"image {image_path} has {w} x {h} = {w * h:,} pixels (limit {MAX_PIXELS:,})",
                )
            fh.seek(pos + 1)  # one whitespace byte ends the header
            data = np.fromfile(fh, dtype=np.uint8, count=w * h)
    except OSError as e:
        raise MapError(yaml_path, field, f"cannot read image {image_path}: {e.strerror or e}") from e
    if data.size != w * h:
        raise MapError(
            yaml_path, field, f"cannot decode image {image_path}: truncated, {data.size} of {w * h} pixels"
        )
    return data.reshape(h, w)


def save_ros(
    yaml_path: str | Path,
    occupied: NDArray[np.bool_],
    resolution: float,
    origin: tuple[float, float, float],
    free: NDArray[np.bool_] | None = None,
    image_format: str = "pgm",
    surface_offset: float | None = None,
) -> Path:
    """Write a trinary map_server map (YAML + PGM/PNG beside it). Returns the image path.

    ``occupied``/``free`` are in OccupancyGrid layout (row 0 at the origin). Cells that are
    neither are written as unknown; ``free=None`` means every non-occupied cell is free.
    ``surface_offset`` (cells) is written as ``icploc_surface_offset`` when given.
    """
    yaml_path = Path(yaml_path)
    if image_format not in ("pgm", "png"):
        raise MapError(yaml_path, "image", f"image format must be pgm or png, got {image_format!r}")
    occupied = np.asarray(occupied, dtype=bool)
    if occupied.ndim != 2 or occupied.size == 0:
        raise MapError(
            yaml_path, "grid", f"occupancy must be a non-empty 2-D array, got {occupied.shape}"
        )
    if free is None:
        free = ~occupied
    h, w = (int(v) for v in occupied.shape)
    img = np.full((h, w), PGM_UNKNOWN, dtype=np.uint8)
    img[np.asarray(free, dtype=bool)] = PGM_FREE
    img[occupied] = PGM_OCCUPIED
    img = np.ascontiguousarray(img[::-1])
    image_path = yaml_path.with_suffix("." + image_format)
    if image_format == "pgm":
        with open(image_path, "wb") as fh:
            fh.write(f"P5\n# icploc map\n{w} {h}\n255\n".encode("ascii"))
            fh.write(img.tobytes())
    else:
        from PIL import Image

        Image.fromarray(img, mode="L").save(image_path)
    doc = {
        "image": image_path.name,
        "mode": "trinary",
        "resolution": float(resolution),
        "origin": [float(origin[0]), float(origin[1]), float(origin[2])],
        "negate": 0,
        "occupied_thresh": 0.65,
        "free_thresh": 0.196,
    }
    if surface_offset is not None:
        doc[SURFACE_OFFSET_KEY] = float(surface_offset)
    import yaml

    yaml_path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return image_path

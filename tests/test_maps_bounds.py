"""Unbounded map inputs end in a clear MapError, not in gigabytes or a raw traceback."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from icploc.maps import Map, MapError
from icploc.maps.map import MAX_SAMPLES
from icploc.maps.ros import MAX_PIXELS


def test_dxf_circle_of_radius_1e6_bounds_the_sampling(tmp_path: Path) -> None:
    ezdxf = pytest.importorskip("ezdxf")
    doc = ezdxf.new()
    doc.header["$INSUNITS"] = 6  # metres
    doc.modelspace().add_circle((0.0, 0.0), 1e6)
    path = tmp_path / "circle.dxf"
    doc.saveas(path)
    m = Map.load(path)
    with pytest.raises(MapError, match=r"field 'spacing'.*limit 20,000,000"):
        m.sample(0.05)


def test_tiny_spacing_is_refused_with_the_smallest_allowed() -> None:
    m = Map.from_lines(np.array([[0.0, 0.0, 100.0, 0.0]]))
    with pytest.raises(MapError, match=r"spacing.*at least 5e-06 m"):
        m.sample(1e-6)
    assert MAX_SAMPLES == 20_000_000


def test_huge_pgm_is_refused_by_its_pixel_count(tmp_path: Path) -> None:
    img = tmp_path / "huge.pgm"
    with open(img, "wb") as fh:  # the header says 20000 x 20000; no pixels are read
        fh.write(b"P5\n20000 20000\n255\n")
        fh.write(b"\xfe" * 1024)
    y = tmp_path / "huge.yaml"
    y.write_text(
        "image: huge.pgm\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    with pytest.raises(MapError, match=r"field .image.: .*20000 x 20000 = 400,000,000 pixels \(limit 100,000,000\)"):
        Map.load(y, cache=False)
    assert MAX_PIXELS == 100_000_000


def test_huge_png_is_refused_too(tmp_path: Path) -> None:
    pytest.importorskip("PIL")
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    ihdr = struct.pack(">IIBBBBB", 20000, 20000, 8, 0, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b"")
    (tmp_path / "huge.png").write_bytes(png)
    y = tmp_path / "huge.yaml"
    y.write_text(
        "image: huge.png\nresolution: 0.05\norigin: [0, 0, 0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )
    with pytest.raises(MapError, match=r"field .image.: .*too large \(limit 100,000,000 pixels\)"):
        Map.load(y, cache=False)


def test_deeply_nested_geojson_arrays_are_a_map_error(tmp_path: Path) -> None:
    p = tmp_path / "deep.geojson"
    p.write_text('{"type": "LineString", "coordinates": ' + "[" * 100_000 + "]" * 100_000 + "}")
    with pytest.raises(MapError, match="nested too deeply"):
        Map.load(p)


def test_deeply_nested_geometry_collections_are_a_map_error(tmp_path: Path) -> None:
    g: dict[str, object] = {"type": "LineString", "coordinates": [[0, 0], [1, 0]]}
    for _ in range(40):
        g = {"type": "GeometryCollection", "geometries": [g]}
    p = tmp_path / "nested.geojson"
    p.write_text(json.dumps(g))
    with pytest.raises(MapError, match="nested more than 32 deep"):
        Map.load(p)

"""GeoJSON, DXF and point maps; prepared .npz maps; plots and the ``icploc map`` CLI."""

from __future__ import annotations

import json
import math
from pathlib import Path

import ezdxf
import numpy as np
import pytest
from icploc.maps import Map, MapError

WALLS = np.array(
    [
        [0.0, 0.0, 8.0, 0.0],
        [8.0, 0.0, 8.0, 5.0],
        [8.0, 5.0, 0.0, 5.0],
        [0.0, 5.0, 0.0, 0.0],
        [2.0, 1.0, 5.5, 3.25],
    ]
)


def sorted_rows(a: np.ndarray) -> np.ndarray:
    """Segments as undirected rows, sorted, for order-independent comparison."""
    a = np.asarray(a).reshape(-1, 4)
    flip = (a[:, 0] > a[:, 2]) | ((a[:, 0] == a[:, 2]) & (a[:, 1] > a[:, 3]))
    a = np.where(flip[:, None], a[:, [2, 3, 0, 1]], a)
    return a[np.lexsort(a.T[::-1])]


# ----------------------------------------------------------------------------- GeoJSON
def test_geojson_round_trip(tmp_path: Path) -> None:
    p = Map.from_lines(WALLS).to_geojson(tmp_path / "w.geojson")
    m = Map.load(p)
    np.testing.assert_array_equal(m.lines, WALLS)
    assert m.meta["format"] == "geojson" and m.meta["units"] == "m"


def test_geojson_geometries_and_units(tmp_path: Path) -> None:
    doc = {
        "type": "FeatureCollection",
        "units": "cm",
        "features": [
            {
                "type": "Feature",
                "properties": {},
                "geometry": {
                    "type": "Polygon",
                    "coordinates": [[[0, 0], [800, 0], [800, 500], [0, 500], [0, 0]]],
                },
            },
            {
                "type": "Feature",
                "properties": {},
                "geometry": {"type": "LineString", "coordinates": [[200, 100, 3], [550, 325]]},
            },
            {"type": "Feature", "properties": {}, "geometry": None},
            {
                "type": "Feature",
                "properties": {},
                "geometry": {
                    "type": "GeometryCollection",
                    "geometries": [
                        {
                            "type": "MultiLineString",
                            "coordinates": [[[100, 100], [100, 100], [100, 200]]],
                        },
                        {
                            "type": "MultiPolygon",
                            "coordinates": [[[[300, 300], [310, 300], [310, 310], [300, 300]]]],
                        },
                    ],
                },
            },
        ],
    }
    p = tmp_path / "plan.geojson"
    p.write_text(json.dumps(doc))
    m = Map.load(p)
    # 4 polygon edges + 1 line + 1 (the zero-length repeat dropped) + 3 triangle edges
    assert len(m.lines) == 9
    np.testing.assert_allclose(sorted_rows(m.lines[:5]), sorted_rows(WALLS))
    np.testing.assert_allclose(m.lines[5], [1.0, 1.0, 1.0, 2.0])


def test_geojson_bare_geometry(tmp_path: Path) -> None:
    p = tmp_path / "g.json"
    p.write_text(json.dumps({"type": "LineString", "coordinates": [[0, 0], [1, 0], [1, 1]]}))
    np.testing.assert_array_equal(Map.load(p).lines, [[0, 0, 1, 0], [1, 0, 1, 1]])


GEOJSON_ERRORS = [
    ("{not json", None, "not valid JSON"),
    ([1, 2], "type", "GeoJSON object"),
    ({"type": "Topology"}, "geometry.type", "unsupported geometry"),
    ({"features": []}, "type", "missing or invalid"),
    ({"type": "FeatureCollection", "features": {}}, "features", "array"),
    ({"type": "FeatureCollection", "features": []}, "features", "no wall segments"),
    ({"type": "FeatureCollection", "units": "parsec", "features": []}, "units", "must be one of"),
    ({"type": "FeatureCollection", "features": [{"type": "Thing"}]}, "features[0].type", "Feature"),
    (
        {"type": "FeatureCollection", "features": [{"type": "Feature"}]},
        "features[0].geometry",
        "missing",
    ),
    (
        {"type": "Point", "coordinates": [0, 0]},
        "geometry.type",
        "unsupported geometry type 'Point'",
    ),
    ({"type": "LineString"}, "geometry.coordinates", "missing"),
    ({"type": "LineString", "coordinates": [[0, 0]]}, "geometry.coordinates", "at least 2"),
    ({"type": "LineString", "coordinates": [[0, 0], [1]]}, "geometry.coordinates[1]", "[x, y]"),
    (
        {"type": "LineString", "coordinates": [[0, 0], [1, "a"]]},
        "geometry.coordinates[1][1]",
        "finite number",
    ),
    (
        {"type": "LineString", "coordinates": [[0, 0], [1, float("nan")]]},
        "geometry.coordinates[1][1]",
        "finite",
    ),
    (
        {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [1, 1], [0, 1]]]},
        "geometry.coordinates[0]",
        "not closed",
    ),
    (
        {"type": "Polygon", "coordinates": [[[0, 0], [1, 0], [0, 0]]]},
        "geometry.coordinates[0]",
        "at least 4",
    ),
]


@pytest.mark.parametrize(("doc", "field", "message"), GEOJSON_ERRORS)
def test_geojson_validation_errors(
    tmp_path: Path, doc: object, field: str | None, message: str
) -> None:
    p = tmp_path / "bad.geojson"
    p.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    with pytest.raises(MapError) as ei:
        Map.load(p)
    assert str(p) in str(ei.value)
    assert ei.value.field == field
    assert message in str(ei.value)


# ----------------------------------------------------------------------------- DXF
def make_dxf(path: Path, insunits: int, scale: float) -> None:
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = insunits
    msp = doc.modelspace()
    w = WALLS * scale
    msp.add_lwpolyline(
        [tuple(w[0, :2]), tuple(w[1, :2]), tuple(w[2, :2]), tuple(w[3, :2])],
        close=True,
        dxfattribs={"layer": "WALLS"},
    )
    msp.add_line(tuple(w[4, :2]), tuple(w[4, 2:]), dxfattribs={"layer": "WALLS"})
    msp.add_polyline2d(
        [(1 * scale, 4 * scale), (3 * scale, 4 * scale)], dxfattribs={"layer": "FURNITURE"}
    )
    msp.add_circle((6 * scale, 2 * scale), 0.5 * scale, dxfattribs={"layer": "FURNITURE"})
    msp.add_text("not a wall")
    doc.saveas(path)


@pytest.mark.parametrize(
    ("insunits", "scale"), [(6, 1.0), (4, 1000.0), (5, 100.0), (2, 1 / 0.3048)]
)
def test_dxf_entities_and_units(tmp_path: Path, insunits: int, scale: float) -> None:
    p = tmp_path / "plan.dxf"
    make_dxf(p, insunits, scale)
    walls = Map.load(p, layers=["walls"])
    np.testing.assert_allclose(sorted_rows(walls.lines), sorted_rows(WALLS), atol=1e-9)
    everything = Map.load(p)
    lines = everything.lines
    # + the POLYLINE segment and the circle flattened to chords within 1 cm
    assert np.any(np.all(np.isclose(lines, [1.0, 4.0, 3.0, 4.0]), axis=1))
    circle = lines[np.hypot(lines[:, 0] - 6.0, lines[:, 1] - 2.0) < 0.6]
    assert len(circle) >= 8
    np.testing.assert_allclose(np.hypot(circle[:, 0] - 6.0, circle[:, 1] - 2.0), 0.5, atol=1e-3)
    mids = 0.5 * (circle[:, :2] + circle[:, 2:])
    assert np.all(0.5 - np.hypot(mids[:, 0] - 6.0, mids[:, 1] - 2.0) <= 0.01 + 1e-9)


def test_dxf_unitless_and_override(tmp_path: Path) -> None:
    p = tmp_path / "plan.dxf"
    make_dxf(p, 0, 1000.0)
    assert Map.load(p, layers=["WALLS"]).lines.max() == pytest.approx(8000.0)  # unitless: metres
    np.testing.assert_allclose(Map.load(p, units="mm", layers=["WALLS"]).lines.max(), 8.0)


def test_dxf_errors(tmp_path: Path) -> None:
    p = tmp_path / "plan.dxf"
    make_dxf(p, 6, 1.0)
    with pytest.raises(MapError) as ei:
        Map.load(p, layers=["nothing"])
    assert ei.value.field == "ENTITIES" and str(p) in str(ei.value)
    with pytest.raises(MapError) as ei:
        Map.load(p, units="furlong")
    assert ei.value.field == "units"
    bad = tmp_path / "bad.dxf"
    bad.write_text("this is not a drawing")
    with pytest.raises(MapError, match="not a readable DXF"):
        Map.load(bad)


# ----------------------------------------------------------------------------- points
def test_point_maps_npy_and_csv_round_trip(tmp_path: Path) -> None:
    from icploc.maps.points import save_csv
    from icploc.maps.sampling import sample_lines

    pts, nrm, _ = sample_lines(WALLS, 0.1)
    np.save(tmp_path / "p.npy", pts)
    np.save(tmp_path / "pn.npy", np.column_stack([pts, nrm]))
    save_csv(tmp_path / "p.csv", pts)
    save_csv(tmp_path / "pn.csv", pts, nrm)
    (tmp_path / "plain.csv").write_text("\n".join(f"{x} {y}" for x, y in pts) + "\n")
    for name in ("p.npy", "pn.npy", "p.csv", "pn.csv", "plain.csv"):
        m = Map.load(tmp_path / name)
        assert m.points is not None
        np.testing.assert_allclose(m.points, pts, rtol=1e-8)
        if name.startswith("pn"):
            assert m.point_normals is not None
            np.testing.assert_allclose(m.point_normals, nrm, atol=1e-8)
        p, n = m.sample(0.1)
        np.testing.assert_allclose(np.hypot(n[:, 0], n[:, 1]), 1.0)
        assert 0.8 * len(pts) <= len(p) <= len(pts)


def test_estimated_point_normals_are_perpendicular_to_walls() -> None:
    from icploc.maps.sampling import sample_lines

    pts, nrm, _ = sample_lines(WALLS[:4], 0.05)
    m = Map.from_points(pts)
    p, n = m.sample(0.05)
    interior = (np.abs(p[:, 0] - 0) > 0.3) & (np.abs(p[:, 0] - 8) > 0.3) | (
        (np.abs(p[:, 1] - 0) > 0.3) & (np.abs(p[:, 1] - 5) > 0.3)
    )
    on_h = (np.isclose(p[:, 1], 0) | np.isclose(p[:, 1], 5)) & interior
    np.testing.assert_allclose(np.abs(n[on_h, 1]), 1.0, atol=1e-6)


POINT_ERRORS = [
    ("a.csv", "x,y\n1,2\n3,oops\n", "row 3", "not a number"),
    ("b.csv", "a,b\n1,2\n", "header", "x and y"),
    ("c.csv", "1,2\n3\n", "row 2", "columns"),
    ("d.csv", "# only a comment\n", "rows", "no points"),
    ("e.csv", "1,2\nnan,3\n", "rows", "not finite"),
    ("f.csv", "1,2,0,0\n", "rows", "zero"),
]


@pytest.mark.parametrize(("name", "text", "field", "message"), POINT_ERRORS)
def test_point_csv_errors(tmp_path: Path, name: str, text: str, field: str, message: str) -> None:
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(MapError) as ei:
        Map.load(p)
    assert ei.value.field == field and message in str(ei.value) and str(p) in str(ei.value)


def test_point_npy_errors(tmp_path: Path) -> None:
    np.save(tmp_path / "a.npy", np.zeros((3, 3)))
    np.save(tmp_path / "b.npy", np.array(["a", "b"]))
    np.save(tmp_path / "c.npy", np.array([[0.0, np.inf]]))
    for name, field in (("a.npy", "array"), ("b.npy", "dtype"), ("c.npy", "array")):
        with pytest.raises(MapError) as ei:
            Map.load(tmp_path / name)
        assert ei.value.field == field
    (tmp_path / "d.npy").write_bytes(b"garbage")
    with pytest.raises(MapError, match="cannot read"):
        Map.load(tmp_path / "d.npy")


def test_from_constructors_validate() -> None:
    with pytest.raises(MapError, match="lines"):
        Map.from_lines([[0, 0, 1]])
    with pytest.raises(MapError, match="NaN"):
        Map.from_lines([[0, 0, 1, math.nan]])
    with pytest.raises(MapError, match="points"):
        Map.from_points(np.zeros((0, 2)))
    with pytest.raises(MapError, match="normals"):
        Map.from_points(np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(MapError, match="resolution"):
        Map.from_grid(np.zeros((3, 3), bool), -1.0)
    with pytest.raises(MapError, match="grid"):
        Map.from_grid(np.zeros(3, bool), 0.05)
    with pytest.raises(MapError, match="spacing"):
        Map.from_lines(WALLS).sample(0.0)


def test_from_grid_accepts_occupancy_values() -> None:
    g = np.zeros((30, 30), dtype=np.int8)
    g[10, 5:25] = 100
    g[20:, :] = -1
    m = Map.from_grid(g, 0.1, (0.0, 0.0))
    assert m.grid is not None and m.free is not None
    assert m.grid.sum() == 20 and not m.free[25, 0]
    # a one-cell wall: both faces (row 10 spans y 1.0 .. 1.1), normals to their free sides
    assert len(m.lines) == 2
    np.testing.assert_allclose(
        sorted_rows(m.lines), [[0.5, 1.0, 2.5, 1.0], [0.5, 1.1, 2.5, 1.1]], atol=1e-9
    )
    up = m.lines[m.lines[:, 1] > 1.05][0]
    assert up[2] > up[0]  # the upper face runs +x: its left normal faces +y


# ----------------------------------------------------------------------------- prepared
def test_prepared_round_trip(tmp_path: Path) -> None:
    y = Map.from_lines(WALLS).to_ros(tmp_path / "w.yaml", 0.05)
    m = Map.load(y)
    p = m.save(tmp_path / "w.npz", spacing=[0.05, 0.1])
    back = Map.load(p)
    np.testing.assert_array_equal(back.lines, m.lines)
    assert back.grid is not None and m.grid is not None and np.array_equal(back.grid, m.grid)
    assert back.free is not None and m.free is not None and np.array_equal(back.free, m.free)
    assert back.resolution == m.resolution and back.origin == m.origin
    assert back.occupancy is not None and m.occupancy is not None
    assert np.array_equal(back.occupancy, m.occupancy)
    for s in (0.05, 0.1):
        assert s in back._samples  # loaded, not recomputed
        for a, b in zip(back.sample(s), m.sample(s), strict=True):
            np.testing.assert_array_equal(a, b)
        assert back.sample_counts(s) == m.sample_counts(s)
    # a spacing that was not stored is computed from the lines
    np.testing.assert_array_equal(back.sample(0.2)[0], m.sample(0.2)[0])
    assert back.meta["fit"] == m.meta["fit"]


def test_prepared_points_map_round_trip(tmp_path: Path) -> None:
    pts = np.random.default_rng(1).random((50, 2))
    m = Map.from_points(pts)
    back = Map.load(m.save(tmp_path / "p.npz"))
    assert (
        back.points is not None and np.array_equal(back.points, pts) and back.point_normals is None
    )


def test_prepared_errors(tmp_path: Path) -> None:
    np.savez(tmp_path / "a.npz", lines=np.zeros((0, 4)))
    with pytest.raises(MapError) as ei:
        Map.load(tmp_path / "a.npz")
    assert ei.value.field == "meta"
    np.savez(tmp_path / "b.npz", meta=np.array(json.dumps({"format": "something"})))
    with pytest.raises(MapError) as ei:
        Map.load(tmp_path / "b.npz")
    assert ei.value.field == "meta.format"
    np.savez(
        tmp_path / "c.npz",
        meta=np.array(json.dumps({"format": "icploc-prepared-map", "version": 99})),
    )
    with pytest.raises(MapError) as ei:
        Map.load(tmp_path / "c.npz")
    assert ei.value.field == "meta.version"
    with pytest.raises(MapError, match=r"\.npz"):
        Map.from_lines(WALLS).save(tmp_path / "x.pkl")


# ----------------------------------------------------------------------------- plots, CLI
def test_plot_call_draws_everything(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = Map.load(Map.from_lines(WALLS).to_ros(tmp_path / "w.yaml", 0.1))
    fig, ax = plt.subplots()
    try:
        m.plot(ax, spacing=0.2)
        assert len(ax.images) == 1
        labels = [ln.get_label() for ln in ax.get_lines()]
        assert f"{len(m.lines)} lines" in labels
        assert any(lab.endswith("samples @ 0.2 m") for lab in labels)
    finally:
        plt.close(fig)


def test_cli_show_info_prepare_convert(tmp_path: Path) -> None:
    from icploc.maps.cli import map_app
    from typer.testing import CliRunner

    src = Map.from_lines(WALLS).to_geojson(tmp_path / "w.geojson")
    r = CliRunner()
    res = r.invoke(map_app, ["show", str(src), "--out", str(tmp_path / "map.png")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "map.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    res = r.invoke(map_app, ["info", str(src), "--json", "--spacing", "0.5"])
    assert res.exit_code == 0, res.output
    info = json.loads(res.output)
    assert info["lines"] == 5 and info["samples"]["total"] == info["samples"]["lines"] > 0
    res = r.invoke(
        map_app, ["convert", str(src), "--out", str(tmp_path / "w.yaml"), "--resolution", "0.05"]
    )
    assert res.exit_code == 0, res.output
    res = r.invoke(
        map_app,
        [
            "prepare",
            str(tmp_path / "w.yaml"),
            "--out",
            str(tmp_path / "w.npz"),
            "--spacing",
            "0.05",
        ],
    )
    assert res.exit_code == 0, res.output
    assert len(Map.load(tmp_path / "w.npz").lines) >= 5
    res = r.invoke(map_app, ["info", str(tmp_path / "missing.yaml")])
    assert res.exit_code == 1
    assert "not found" in res.output


def test_dxf_blocks_and_arcs(tmp_path: Path) -> None:
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 6
    blk = doc.blocks.new("DESK")
    blk.add_line((0, 0), (1, 0))
    msp = doc.modelspace()
    msp.add_blockref("DESK", (2, 3))
    msp.add_blockref("DESK", (5, 1), dxfattribs={"rotation": 90})
    msp.add_arc((0, 0), 2.0, 0, 90)
    doc.saveas(tmp_path / "b.dxf")
    lines = Map.load(tmp_path / "b.dxf").lines
    assert np.any(np.all(np.isclose(lines, [2, 3, 3, 3]), axis=1))
    assert np.any(np.all(np.isclose(lines, [5, 1, 5, 2], atol=1e-9), axis=1))
    r1, r2 = np.hypot(lines[:, 0], lines[:, 1]), np.hypot(lines[:, 2], lines[:, 3])
    arc = lines[(np.abs(r1 - 2.0) < 0.1) & (np.abs(r2 - 2.0) < 0.1)]
    assert len(arc) == len(lines) - 2
    assert len(arc) >= 4
    np.testing.assert_allclose(np.hypot(arc[:, 0], arc[:, 1]), 2.0, atol=1e-3)


def test_to_ros_errors(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="no lines"):
        Map.from_points(np.zeros((3, 2))).to_ros(tmp_path / "a.yaml", 0.05)
    with pytest.raises(MapError, match="origin"):
        Map.from_lines(WALLS).to_ros(tmp_path / "b.yaml", 0.05, origin=(1.0, 1.0, 0.0))
    with pytest.raises(MapError, match="spacing"):
        Map.from_lines(WALLS).to_ros(tmp_path / "c.yaml", 0.0)


def test_to_ros_png_with_explicit_origin(tmp_path: Path) -> None:
    y = Map.from_lines(WALLS).to_ros(
        tmp_path / "w.yaml", 0.1, origin=(-0.55, -0.55), image_format="png"
    )
    assert (tmp_path / "w.png").is_file()
    m = Map.load(y)
    assert m.origin == (-0.55, -0.55, 0.0)
    x0, y0, x1, y1 = m.bounds
    assert abs(x0) < 0.1 and abs(y0) < 0.1 and abs(x1 - 8.0) < 0.1 and abs(y1 - 5.0) < 0.1


def test_info_reports_counts() -> None:
    m = Map.from_lines(WALLS)
    info = m.info(spacing=0.5)
    length = float(np.hypot(WALLS[:, 2] - WALLS[:, 0], WALLS[:, 3] - WALLS[:, 1]).sum())
    assert info["lines"] == 5 and info["line_length_m"] == pytest.approx(length, abs=1e-3)
    assert info["samples"]["total"] == len(m.sample(0.5)[0])
    assert info["bounds"] == [0.0, 0.0, 8.0, 5.0]


@pytest.mark.parametrize("command", ["convert", "prepare", "show"])
def test_map_commands_refuse_an_output_that_is_their_input(command: str, tmp_path: Path) -> None:
    from icploc.maps.cli import map_app
    from typer.testing import CliRunner

    src = Map.from_lines([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0]]).to_ros(
        tmp_path / "m.yaml", 0.05
    )
    target = {"convert": src, "prepare": src.with_suffix(".pgm"), "show": src.with_suffix(".pgm")}
    before = {p: p.read_bytes() for p in (src, src.with_suffix(".pgm"))}
    r = CliRunner().invoke(map_app, [command, str(src), "--out", str(target[command])])
    assert r.exit_code == 1, r.output
    assert "is an input" in r.output
    assert {p: p.read_bytes() for p in before} == before

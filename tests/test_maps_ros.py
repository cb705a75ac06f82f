"""ROS map_server YAML + PGM/PNG: every field honoured, every bad value rejected."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from icploc.maps import Map, MapError
from icploc.maps.ros import load_ros, save_ros
from PIL import Image

GOOD = {
    "image": "m.pgm",
    "resolution": 0.05,
    "origin": [-1.0, 2.0, 0.0],
    "negate": 0,
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
}


def write_map(d: Path, img: np.ndarray, name: str = "m.pgm", **fields: object) -> Path:
    """Write an image (row 0 = top, as stored) and a YAML with GOOD overridden by ``fields``
    (a value of ... deletes the field)."""
    mode = {2: "L", 3: "RGB"}[img.ndim] if img.ndim != 3 or img.shape[2] != 4 else "RGBA"
    if img.ndim == 3 and img.shape[2] == 2:
        mode = "LA"
    Image.fromarray(img, mode=mode).save(d / name)
    doc = dict(GOOD, image=name)
    for k, v in fields.items():
        if v is ...:
            doc.pop(k, None)
        else:
            doc[k] = v
    p = d / "m.yaml"
    p.write_text(yaml.safe_dump(doc))
    return p


# A 3x4 image: top row black (occupied), middle row mid-grey 128, bottom row white (free).
GREY = np.array([[0, 0, 0, 0], [128, 128, 128, 128], [254, 254, 254, 254]], dtype=np.uint8)


def test_trinary_thresholds_and_row_order(tmp_path: Path) -> None:
    g = load_ros(write_map(tmp_path, GREY))
    # OccupancyGrid layout: row 0 is the image's bottom row
    assert g.occupancy[0].tolist() == [0, 0, 0, 0]
    assert g.occupancy[1].tolist() == [-1, -1, -1, -1]  # occ = 127/255 = 0.498: unknown
    assert g.occupancy[2].tolist() == [100, 100, 100, 100]
    assert g.occupied[2].all() and g.free[0].all() and not (g.occupied[1] | g.free[1]).any()
    assert g.resolution == 0.05 and g.origin == (-1.0, 2.0, 0.0)


def test_negate_inverts(tmp_path: Path) -> None:
    g = load_ros(write_map(tmp_path, GREY, negate=1))
    assert g.occupancy[0].tolist() == [100] * 4  # white is occupied when negated
    assert g.occupancy[2].tolist() == [0] * 4


def test_thresholds_are_used(tmp_path: Path) -> None:
    # occ of grey 128 is 0.498: occupied when occupied_thresh is 0.4
    g = load_ros(write_map(tmp_path, GREY, occupied_thresh=0.4, free_thresh=0.1))
    assert g.occupancy[1].tolist() == [100] * 4


def test_scale_mode(tmp_path: Path) -> None:
    g = load_ros(write_map(tmp_path, GREY, mode="scale"))
    expected = round((127 / 255 - 0.196) / (0.65 - 0.196) * 100)
    assert g.occupancy[1].tolist() == [expected] * 4
    assert g.occupancy[0].tolist() == [0] * 4 and g.occupancy[2].tolist() == [100] * 4


def test_scale_mode_transparent_is_unknown(tmp_path: Path) -> None:
    img = np.zeros((1, 3, 2), dtype=np.uint8)
    img[0, :, 0] = [128, 128, 0]
    img[0, :, 1] = [255, 0, 255]  # middle pixel transparent
    g = load_ros(write_map(tmp_path, img, name="m.png", mode="scale"))
    assert g.occupancy[0, 1] == -1 and g.occupancy[0, 0] >= 0 and g.occupancy[0, 2] == 100


def test_raw_mode(tmp_path: Path) -> None:
    img = np.array([[0, 37, 100, 101, 255]], dtype=np.uint8)
    g = load_ros(write_map(tmp_path, img, mode="raw", negate=1))  # negate does not apply to raw
    assert g.occupancy[0].tolist() == [0, 37, 100, -1, -1]
    assert g.occupied[0].tolist() == [False, False, True, False, False]
    assert g.free[0].tolist() == [True, False, False, False, False]


def test_rgb_png_is_averaged(tmp_path: Path) -> None:
    img = np.zeros((1, 2, 3), dtype=np.uint8)
    img[0, 0] = [255, 255, 255]
    img[0, 1] = [255, 0, 0]  # mean 85 -> occ 0.667 > 0.65: occupied
    g = load_ros(write_map(tmp_path, img, name="m.png"))
    assert g.occupancy[0].tolist() == [0, 100]


def test_image_path_relative_to_yaml_or_absolute(tmp_path: Path) -> None:
    sub = tmp_path / "maps"
    sub.mkdir()
    p = write_map(sub, GREY)
    cwd_independent = load_ros(p)
    absolute = write_map(sub, GREY, image=str((sub / "m.pgm").resolve()))
    assert np.array_equal(load_ros(absolute).occupancy, cwd_independent.occupancy)


def test_save_and_load_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    occ = rng.random((17, 23)) < 0.2
    free = ~occ & (rng.random((17, 23)) < 0.7)
    for fmt in ("pgm", "png"):
        img = save_ros(
            tmp_path / f"r{fmt}.yaml", occ, 0.1, (1.5, -2.0, 0.25), free=free, image_format=fmt
        )
        assert img.suffix == "." + fmt
        g = load_ros(tmp_path / f"r{fmt}.yaml")
        assert np.array_equal(g.occupied, occ) and np.array_equal(g.free, free)
        assert g.resolution == 0.1 and g.origin == (1.5, -2.0, 0.25)


def test_map_load_and_to_ros_round_trip(tmp_path: Path) -> None:
    walls = np.array([[0.0, 0.0, 5.0, 0.0], [5.0, 0.0, 5.0, 4.0], [1.0, 1.0, 3.5, 3.0]])
    y = Map.from_lines(walls).to_ros(tmp_path / "w.yaml", 0.05)
    doc = yaml.safe_load(y.read_text())
    assert doc["resolution"] == 0.05 and doc["mode"] == "trinary"
    # cell centres sit on multiples of the resolution: walls at x = 5.0 run through centres
    assert math.isclose((doc["origin"][0] + 0.025) / 0.05, round((doc["origin"][0] + 0.025) / 0.05))
    m = Map.load(y)
    assert m.grid is not None
    ix = np.rint(m.world_to_cells([[5.0, 2.0]])).astype(int)[0]
    assert m.grid[ix[1], ix[0]]
    np.testing.assert_allclose(m.cells_to_world(ix[None]), [[5.0, 2.0]], atol=1e-9)
    assert m.meta["format"] == "ros" and m.occupancy is not None


BAD_FIELDS = [
    ("image", ..., "missing"),
    ("image", "", "non-empty"),
    ("image", "nope.pgm", "not found"),
    ("resolution", ..., "missing"),
    ("resolution", float("nan"), "finite"),
    ("resolution", -0.05, "positive"),
    ("resolution", 0, "positive"),
    ("resolution", "fine", "number"),
    ("origin", ..., "missing"),
    ("origin", [0.0, 0.0], "[x, y, yaw]"),
    ("origin", "0 0 0", "[x, y, yaw]"),
    ("origin", [0.0, float("nan"), 0.0], "finite"),
    ("negate", ..., "missing"),
    ("negate", 2, "0 or 1"),
    ("occupied_thresh", ..., "missing"),
    ("occupied_thresh", float("nan"), "finite"),
    ("occupied_thresh", 1.5, "[0, 1]"),
    ("free_thresh", ..., "missing"),
    ("free_thresh", -0.1, "[0, 1]"),
    ("free_thresh", 0.7, "below occupied_thresh"),
    ("mode", "fancy", "trinary, scale, raw"),
    ("mode", 3, "trinary, scale, raw"),
]


@pytest.mark.parametrize(("field", "value", "message"), BAD_FIELDS)
def test_validation_errors_name_file_and_field(
    tmp_path: Path, field: str, value: object, message: str
) -> None:
    p = write_map(tmp_path, GREY, **{field: value})
    with pytest.raises(MapError) as ei:
        Map.load(p)
    err = ei.value
    assert isinstance(err, ValueError)
    assert str(p) in str(err)
    expected_field = (
        "origin[1]" if field == "origin" and isinstance(value, list) and len(value) == 3 else field
    )
    assert err.field == expected_field
    assert f"'{expected_field}'" in str(err)
    assert message in str(err)


def test_yaml_nan_literal_is_rejected(tmp_path: Path) -> None:
    p = write_map(tmp_path, GREY)
    p.write_text(p.read_text().replace("resolution: 0.05", "resolution: .nan"))
    with pytest.raises(MapError, match="resolution"):
        Map.load(p)


def test_not_a_mapping_and_bad_yaml_and_bad_image(tmp_path: Path) -> None:
    p = tmp_path / "m.yaml"
    p.write_text("- just\n- a list\n")
    with pytest.raises(MapError, match="mapping"):
        Map.load(p)
    p.write_text("image: [unclosed\n")
    with pytest.raises(MapError, match="not valid YAML"):
        Map.load(p)
    (tmp_path / "broken.pgm").write_bytes(b"P5\n10 10\n255\n\x00")
    p.write_text(yaml.safe_dump(dict(GOOD, image="broken.pgm")))
    with pytest.raises(MapError) as ei:
        Map.load(p)
    assert ei.value.field == "image" and "decode" in str(ei.value)


def test_unknown_suffix_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(MapError, match="unknown map format"):
        Map.load(tmp_path / "map.bmp")
    with pytest.raises(MapError, match="not found"):
        Map.load(tmp_path / "absent.yaml")

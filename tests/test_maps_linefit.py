"""Line fitting from occupancy grids: measured accuracy against known floor plans.

Requirement (issue 3): rasterise a known plan at 5 cm, fit, and every fitted line lies within
half a cell + 5 mm of its true wall and within 0.5 degrees of its direction, covering >= 95 %
of every wall longer than 0.5 m, diagonal walls included.

One caveat measured here rather than hidden: a raster only fixes a wall's direction to within
about atan(1 cell / length) (a wall that rises less than a cell over its length can rasterise
to a single straight row; with diagonal cells, up to atan(sqrt(2) cells / length)). Walls too short for 0.5 degrees to be decidable from the raster are
held to that raster bound instead; every wall of the floor plan of 1 m or more is held to 0.5.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from icploc.maps import Map, fit_lines, sample_lines
from icploc.maps.raster import rasterize_lines, supercover_cells

RES = 0.05
TOL = RES / 2 + 0.005  # half a cell + 5 mm

# A floor plan in metres: outer walls, rooms with door gaps, corridor, and diagonal walls at
# assorted angles (none of them multiples of 45 degrees except one).
PLAN = np.array(
    [
        [0.0, 0.0, 20.0, 0.0],
        [20.0, 0.0, 20.0, 12.0],
        [20.0, 12.0, 0.0, 12.0],
        [0.0, 12.0, 0.0, 0.0],
        [6.0, 0.0, 6.0, 5.0],  # room wall with a door gap 5.0 .. 6.2
        [6.0, 6.2, 6.0, 12.0],
        [6.0, 5.0, 11.0, 5.0],
        [12.0, 5.0, 20.0, 5.0],  # corridor wall, door gap 11 .. 12
        [2.03, 2.01, 4.57, 3.99],  # 37.7 deg, off-grid end points
        [14.0, 7.0, 18.0, 11.0],  # 45 deg
        [8.0, 7.0, 11.3, 8.1],  # 18.4 deg
        [9.5, 9.0, 10.1, 11.3],  # 75.4 deg
        [13.13, 1.07, 17.61, 3.22],  # 25.6 deg
        [1.0, 8.0, 1.55, 8.3],  # short: 0.63 m at 28.6 deg
        [3.0, 10.0, 3.8, 10.0],  # short axis-aligned 0.8 m
    ]
)


def point_segment_distance(p: np.ndarray, seg: np.ndarray) -> float:
    a, b = seg[:2], seg[2:]
    d = b - a
    t = float(np.clip((p - a) @ d / (d @ d), 0.0, 1.0))
    return float(np.hypot(*(a + t * d - p)))


def angle_deg(s1: np.ndarray, s2: np.ndarray) -> float:
    d1, d2 = s1[2:] - s1[:2], s2[2:] - s2[:2]
    c = abs(d1 @ d2) / (np.hypot(*d1) * np.hypot(*d2))
    return math.degrees(math.acos(min(1.0, c)))


def assess(walls: np.ndarray, fitted: np.ndarray, tol: float = TOL) -> list[dict[str, float]]:
    """Per true wall, over the fitted lines that lie along it (both end points within ``tol``
    of the wall's line, overlapping it, less than 10 degrees off): their worst perpendicular
    distance, worst angle, how far they run past the wall's ends, and the fraction of the
    wall's length their projections cover."""
    out = []
    for w in walls:
        a = w[:2]
        L = float(np.hypot(*(w[2:] - a)))
        u = (w[2:] - a) / L
        nrm = np.array([-u[1], u[0]])
        ivs, worst, ang, over = [], 0.0, 0.0, 0.0
        for s in fitted:
            perp = max(abs(float((s[:2] - a) @ nrm)), abs(float((s[2:] - a) @ nrm)))
            t1, t2 = sorted([float((s[:2] - a) @ u), float((s[2:] - a) @ u)])
            if perp > tol or t2 < 0 or t1 > L or angle_deg(s, w) > 10.0:
                continue
            ivs.append((max(t1, 0.0), min(t2, L)))
            worst = max(worst, perp)
            ang = max(ang, angle_deg(s, w))
            over = max(over, -t1, t2 - L)
        ivs.sort()
        cov, cur = 0.0, -math.inf
        for x, y in ivs:
            if y > cur:
                cov += y - max(x, cur)
                cur = y
        out.append(
            {
                "length": L,
                "coverage": cov / L,
                "distance": worst,
                "angle": ang,
                "overshoot": over,
                "n": len(ivs),
            }
        )
    return out


# A wall's end is only known to lie in the last cell it touches: that cell's centre projects up
# to sqrt(2)/2 cell past the end, and fitted lines extend half a cell past the last centre.
MAX_OVERSHOOT = (math.sqrt(0.5) + 0.5) * RES + 1e-9
# The faces of a one-cell-wide sloped wall run over the supercover's corner cells too: up to
# a fifth of a cell further (measured: 6.6 mm past MAX_OVERSHOOT at worst over 160 walls).
THIN_OVERSHOOT = MAX_OVERSHOOT + 0.2 * RES


def raster_angle_bound_deg(length: float) -> float:
    """How far a wall's direction can be from any line through the same cells: the cells at its
    two ends are each crossed somewhere within a cell diagonal."""
    return math.degrees(math.atan(math.sqrt(2.0) * RES / length))


@pytest.fixture(scope="module")
def plan_map(tmp_path_factory: pytest.TempPathFactory) -> Map:
    d = tmp_path_factory.mktemp("plan")
    yaml_path = Map.from_lines(PLAN).to_ros(d / "plan.yaml", RES)
    return Map.load(yaml_path)


def test_floor_plan_fit_accuracy(plan_map: Map) -> None:
    report = assess(PLAN, plan_map.lines)
    for w, r in zip(PLAN, report, strict=True):
        assert r["n"] >= 1, f"no fitted line within {TOL} m of wall {w}"
        assert r["distance"] <= TOL + 1e-9
        assert r["overshoot"] <= MAX_OVERSHOOT
        if r["length"] > 0.5:
            assert r["coverage"] >= 0.95, (w, r)
        limit = 0.5 if r["length"] >= 1.0 else max(0.5, raster_angle_bound_deg(r["length"]))
        assert r["angle"] <= limit, (w, r)


def test_floor_plan_has_no_spurious_lines(plan_map: Map) -> None:
    # every fitted line belongs to some wall (both end points within tolerance of the wall
    # segment, allowing the raster's end ambiguity)
    for s in plan_map.lines:
        d = min(
            max(point_segment_distance(s[:2], w), point_segment_distance(s[2:], w)) for w in PLAN
        )
        assert d <= MAX_OVERSHOOT, s
    # the fit explains all but the end caps of the thin walls: every leftover point lies
    # within a cell of a wall's end
    assert plan_map.meta["fit"]["explained_fraction"] >= 0.99
    ends = PLAN.reshape(-1, 2)
    for p in plan_map.extra_points:
        assert np.hypot(*(ends - p).T).min() <= 2.5 * RES, p
    # one line per face: two per thin wall, at most a few extra pieces where walls cross
    assert len(plan_map.lines) <= 2 * len(PLAN) + 4


def test_fitted_lines_face_free_space_for_thick_walls() -> None:
    # a 0.5 m thick wall (filled rectangle) between two free regions: two face lines,
    # each with its left normal pointing into free space, lying on the face cells
    occ = np.zeros((60, 100), dtype=bool)
    occ[25:35, 10:90] = True
    f = fit_lines(occ)
    long = f.lines[np.hypot(f.lines[:, 2] - f.lines[:, 0], f.lines[:, 3] - f.lines[:, 1]) > 50]
    assert len(long) == 2
    for s in long:
        assert abs(s[1] - s[3]) < 1e-6  # horizontal
        y = s[1]
        assert min(abs(y - 24.5), abs(y - 34.5)) < 1e-9  # on the faces (cell units)
        nrm_y = np.sign(s[2] - s[0])  # left normal of a +x line is +y
        assert (nrm_y > 0) == (y > 30)


@pytest.mark.parametrize("length", [0.5, 1.0, 2.0, 4.0])
def test_random_walls_within_raster_limits(length: float) -> None:
    """Single walls at random angles and sub-cell offsets, rasterised as in ``to_ros``; with
    the surface offset of rasterised lines (half a cell) both faces of the thin wall come
    back on its centre line, one line per face."""
    rng = np.random.default_rng(int(length * 100))
    n = length / RES
    for _ in range(40):
        th = rng.uniform(0.0, math.pi)
        c = rng.uniform(60.0, 61.0, 2)
        half = 0.5 * n * np.array([math.cos(th), math.sin(th)])
        wall_cells = np.concatenate([c - half, c + half])
        f = fit_lines(rasterize_lines(wall_cells[None], (122, 122)), surface_offset=0.5)
        r = assess(wall_cells[None] * RES, f.lines * RES, tol=TOL + 0.005)[0]
        # one line per face; a face of a sloped staircase may come in two pieces
        assert 1 <= r["n"] <= 4
        assert r["distance"] <= TOL + 0.005
        assert r["overshoot"] <= THIN_OVERSHOOT
        assert r["coverage"] >= 0.95
        assert r["angle"] <= max(0.5, raster_angle_bound_deg(length)), (th, r)
        # and no line elsewhere: both end points of every line within 1.5 cells of the wall
        for s in f.lines * RES:
            far = max(
                point_segment_distance(s[:2], wall_cells * RES),
                point_segment_distance(s[2:], wall_cells * RES),
            )
            assert far <= 1.5 * RES, s


def test_supercover_touches_every_cell_the_segment_crosses() -> None:
    rng = np.random.default_rng(7)
    for _ in range(50):
        p, q = rng.uniform(0, 20, 2), rng.uniform(0, 20, 2)
        cells = {tuple(c) for c in supercover_cells(p, q).tolist()}
        t = np.linspace(0, 1, 4001)[:, None]
        dense = np.floor(p + t * (q - p) + 0.5).astype(int)
        assert {tuple(c) for c in dense.tolist()} <= cells
        # and no cell farther than a half-diagonal from the segment
        for c in cells:
            assert (
                point_segment_distance(np.array(c, float), np.concatenate([p, q]))
                <= math.sqrt(0.5) + 1e-9
            )


def test_clutter_falls_back_to_boundary_points() -> None:
    # a room plus scattered blobs (furniture legs): the blobs are not lines; their surface
    # cells come back as fallback points with unit normals pointing away from the blob
    occ = np.zeros((80, 80), dtype=bool)
    occ[5, 5:75] = occ[74, 5:75] = True
    occ[5:75, 5] = occ[5:75, 74] = True
    blobs = [(30, 30), (50, 20), (40, 55)]
    for y, x in blobs:
        occ[y - 1 : y + 2, x - 1 : x + 2] = True
    m = Map.from_grid(occ, RES, (0.0, 0.0, 0.0), min_length=0.2)  # blob sides are 0.15 m
    assert 0.5 < m.meta["fit"]["explained_fraction"] < 1.0
    assert m.meta["sample_mode"] == "lines+points"
    assert len(m.extra_points) == 3 * 8  # the ring of each 3x3 blob
    nl = np.hypot(m.extra_normals[:, 0], m.extra_normals[:, 1])
    np.testing.assert_allclose(nl, 1.0)
    for p, nrm in zip(m.extra_points, m.extra_normals, strict=True):
        centre = min(
            (np.array([x, y]) + 0.5) * RES
            for y, x in blobs
            if np.hypot(*((np.array([x, y]) + 0.5) * RES - p)) < 0.1
        )
        assert nrm @ (p - centre) > 0  # faces away from the blob's centre, into free space
    pts, _ = m.sample(RES)
    assert m.sample_counts(RES)["boundary"] == 24
    assert len(pts) == m.sample_counts(RES)["total"]


def test_grid_without_lines_uses_all_boundary_points() -> None:
    occ = np.zeros((40, 40), dtype=bool)
    yy, xx = np.mgrid[:40, :40]
    occ[(xx - 20) ** 2 + (yy - 20) ** 2 <= 9] = True  # a round pillar: nothing straight
    m = Map.from_grid(occ, 0.1, (1.0, 2.0, 0.0), min_length=1.0)
    assert len(m.lines) == 0
    assert m.meta["sample_mode"] == "points"
    p, n = m.sample(0.1)
    assert len(p) > 0
    # normals point outwards from the pillar centre
    centre = np.array([1.0 + 2.05, 2.0 + 2.05])
    assert np.all(np.einsum("ij,ij->i", n, p - centre) > 0)


def test_rotated_origin_is_honoured(tmp_path: Path) -> None:
    walls = np.array([[0.0, 0.0, 4.0, 0.0], [4.0, 0.0, 4.0, 3.0]])
    m = Map.from_lines(walls)
    yaw = 0.3
    yaml_path = m.to_ros(tmp_path / "rot.yaml", RES, origin=(-1.0, -1.0, 0.0))
    text = yaml_path.read_text().replace("- 0.0\nnegate", f"- {yaw}\nnegate")
    yaml_path.write_text(text)
    g = Map.load(yaml_path)
    assert g.origin == (-1.0, -1.0, yaw)
    # the walls come back rotated by yaw about the origin
    c, s = math.cos(yaw), math.sin(yaw)
    o = np.array([-1.0, -1.0])
    rot = ((walls.reshape(-1, 2) - o) @ np.array([[c, s], [-s, c]]) + o).reshape(-1, 4)
    report = assess(rot, g.lines)
    for r in report:
        assert r["distance"] <= TOL + 1e-9 and r["coverage"] >= 0.95 and r["angle"] <= 0.5
        assert r["overshoot"] <= MAX_OVERSHOOT


WILLOW = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "maps" / "willow_garage"


@pytest.mark.shared_data
@pytest.mark.slow
@pytest.mark.skipif(not WILLOW.is_dir(), reason="../shared/data/maps/willow_garage is absent")
@pytest.mark.parametrize("name", ["willow-full-0.05.yaml", "willow-full-0.1.yaml"])
def test_willow_garage_loads_and_fits(name: str) -> None:
    m = Map.load(WILLOW / name)
    res = 0.05 if "0.05" in name else 0.1
    assert m.resolution == res
    from PIL import Image

    with Image.open(WILLOW / name.replace(".yaml", ".pgm")) as im:
        width, height = im.size
    assert m.grid is not None and m.grid.shape == (height, width)
    assert m.origin == (0.0, 0.0, 0.0)
    fit = m.meta["fit"]
    assert len(m.lines) > 200
    assert fit["explained_fraction"] > 0.5
    # every fitted line lies on occupied wall-surface cells: its samples are within a cell of one
    p, _, _ = sample_lines(m.lines, res)
    cells = np.rint(m.world_to_cells(p)).astype(int)
    occ = np.pad(m.grid, 1)
    near = np.zeros(len(cells), dtype=bool)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= occ[cells[:, 1] + 1 + dy, cells[:, 0] + 1 + dx]
    assert near.mean() > 0.98
    pts, nrm = m.sample(res)
    assert len(pts) > 1000
    np.testing.assert_allclose(np.hypot(nrm[:, 0], nrm[:, 1]), 1.0)
    xmin, ymin, xmax, ymax = m.bounds
    assert 0 <= xmin < xmax <= width * res + 1e-9 and 0 <= ymin < ymax <= height * res + 1e-9

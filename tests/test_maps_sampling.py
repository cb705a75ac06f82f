"""Uniform sampling (property tests), point thinning, visibility culling, MapIndex feeding."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from icploc.maps import Map, sample_lines
from icploc.maps.sampling import thin_points
from icploc.maps.visibility import in_fov, visible_exact

coord = st.floats(-100.0, 100.0, allow_nan=False, allow_infinity=False)
segments = arrays(np.float64, st.tuples(st.integers(1, 20), st.just(4)), elements=coord)
spacings = st.floats(0.01, 5.0, allow_nan=False)


@settings(max_examples=150, deadline=None)
@given(lines=segments, spacing=spacings)
def test_sampling_honours_spacing_and_normals(lines: np.ndarray, spacing: float) -> None:
    pts, nrm, src = sample_lines(lines, spacing)
    d = lines[:, 2:] - lines[:, :2]
    length = np.hypot(d[:, 0], d[:, 1])
    nonzero = length > 0
    # one point per ceil(L / spacing) piece of every non-degenerate segment, none for points
    expected = np.where(nonzero, np.maximum(1, np.ceil(length / spacing - 1e-9)), 0).astype(int)
    assert np.array_equal(np.bincount(src, minlength=len(lines)), expected)
    assert pts.shape == nrm.shape == (int(expected.sum()), 2)
    if len(pts) == 0:
        return
    u = d[src] / length[src, None]
    # normals: unit length and perpendicular to their own line
    np.testing.assert_allclose(np.hypot(nrm[:, 0], nrm[:, 1]), 1.0, rtol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", nrm, u), 0.0, atol=1e-12)
    # points lie on their segment
    rel = pts - lines[src, :2]
    t = np.einsum("ij,ij->i", rel, u)
    off = rel[:, 0] * u[:, 1] - rel[:, 1] * u[:, 0]
    scale = 1.0 + np.abs(lines).max()
    assert np.all(np.abs(off) <= 1e-9 * scale)
    assert np.all(t >= -1e-9 * scale) and np.all(t <= length[src] + 1e-9 * scale)
    # consecutive samples on a segment are equally spaced, at most ``spacing`` apart, and the
    # end samples are half a step in from the segment's ends
    for k in np.flatnonzero(nonzero):
        tk = t[src == k]
        step = length[k] / len(tk)
        assert step <= spacing * (1 + 1e-9)
        if len(tk) > 1:
            np.testing.assert_allclose(np.diff(tk), step, atol=1e-9 * scale)
            assert step >= spacing / 2 * (1 - 1e-9)
        np.testing.assert_allclose([tk[0], length[k] - tk[-1]], step / 2, atol=1e-9 * scale)


@settings(max_examples=60, deadline=None)
@given(lines=segments, spacing=spacings)
def test_map_sample_matches_lines_and_is_cached(lines: np.ndarray, spacing: float) -> None:
    keep = np.hypot(lines[:, 2] - lines[:, 0], lines[:, 3] - lines[:, 1]) > 0
    if not keep.any():
        return
    m = Map.from_lines(lines)
    p, n = m.sample(spacing)
    lp, ln, _ = sample_lines(lines, spacing)
    np.testing.assert_array_equal(p, lp)
    np.testing.assert_array_equal(n, ln)
    assert m.sample(spacing)[0] is p  # cached
    assert not p.flags.writeable
    assert m.sample_counts(spacing) == {"lines": len(lp), "total": len(lp)}


@settings(max_examples=80, deadline=None)
@given(
    pts=arrays(np.float64, st.tuples(st.integers(1, 300), st.just(2)), elements=st.floats(-20, 20)),
    spacing=st.floats(0.05, 3.0),
)
def test_thin_points_one_per_cell(pts: np.ndarray, spacing: float) -> None:
    keep = thin_points(pts, spacing)
    assert np.all(np.diff(keep) > 0)
    key = np.floor((pts - pts.min(axis=0)) / spacing + 1e-6).astype(np.int64)
    kept_cells = {tuple(k) for k in key[keep].tolist()}
    all_cells = {tuple(k) for k in key.tolist()}
    assert kept_cells == all_cells and len(kept_cells) == len(keep)


def test_grid_samples_have_unit_normals_facing_free_space() -> None:
    occ = np.zeros((60, 80), dtype=bool)
    occ[10:14, 10:70] = True  # a 4-cell-thick wall
    occ[40, 5:75] = True  # a thin wall
    m = Map.from_grid(occ, 0.05, (0.0, 0.0, 0.0))
    p, n = m.sample(0.05)
    np.testing.assert_allclose(np.hypot(n[:, 0], n[:, 1]), 1.0)
    # samples on the thick wall's faces: normals point away from the wall's inside
    y_mid = (12.0 + 0.5) * 0.05
    on_faces = (p[:, 0] > 1.0) & (p[:, 0] < 3.0) & (np.abs(p[:, 1] - y_mid) < 0.2)
    assert on_faces.sum() > 40
    assert np.all(np.sign(n[on_faces, 1]) == np.sign(p[on_faces, 1] - y_mid))


# ----------------------------------------------------------------------------- visibility
ROOM = np.array(
    [
        [0.0, 0.0, 10.0, 0.0],
        [10.0, 0.0, 10.0, 10.0],
        [10.0, 10.0, 0.0, 10.0],
        [0.0, 10.0, 0.0, 0.0],
        [5.0, 2.0, 5.0, 8.0],  # a free-standing wall in the middle
    ]
)


def test_in_fov() -> None:
    pts = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [5.0, 0.0]])
    assert in_fov(pts, (0.0, 0.0, 0.0), math.pi, 2.0).tolist() == [True, True, False, False]
    assert in_fov(pts, (0.0, 0.0, math.pi), math.radians(90), 10.0).tolist() == [
        False,
        False,
        True,
        False,
    ]
    assert in_fov(pts, (0.0, 0.0, 1.0), 2 * math.pi, 10.0).all()


def test_visible_exact_hides_points_behind_walls() -> None:
    m = Map.from_lines(ROOM)
    p, _ = m.sample(0.1)
    idx = m.visible((2.0, 5.0, 0.0), spacing=0.1, exact=True)
    vis = np.zeros(len(p), dtype=bool)
    vis[idx] = True
    # the whole near face of the middle wall is visible ...
    near_face = np.isclose(p[:, 0], 5.0) & (p[:, 1] > 2.0) & (p[:, 1] < 8.0)
    assert vis[near_face].all()
    # ... and the right wall behind it is hidden where the middle wall shadows it:
    # from (2, 5) the wall x=5, y in [2, 8] shadows x=10 for |y - 5| < 3 * 8 / 3 = 8 -> y in (-3, 13)
    right = np.isclose(p[:, 0], 10.0)
    assert right.sum() > 50 and not vis[right].any()
    # the left wall is fully visible
    left = np.isclose(p[:, 0], 0.0)
    assert vis[left].all()
    # field of view and range
    fwd = m.visible(
        (2.0, 5.0, math.pi), fov=math.radians(90), max_range=3.0, spacing=0.1, exact=True
    )
    d = p[fwd] - [2.0, 5.0]
    assert len(fwd) > 0 and np.all(np.hypot(d[:, 0], d[:, 1]) <= 3.0) and np.all(d[:, 0] < 0)


def test_visible_exact_corner_points_are_not_self_occluded() -> None:
    # points where two walls meet must not be hidden by the other wall
    m = Map.from_lines(ROOM[:4])
    p, _ = m.sample(0.25)
    idx = visible_exact(p, m.lines, (5.0, 5.0, 0.0))
    assert len(idx) == len(p)


def test_index_and_rust_visibility_agree_with_exact() -> None:
    pytest.importorskip("icploc._core")
    m = Map.from_lines(ROOM)
    p, n = m.sample(0.05)
    index = m.index(0.05)
    assert len(index) == len(p)
    assert m.index(0.05) is index
    dist, nearest = index.nearest(p)
    np.testing.assert_allclose(dist, 0.0, atol=1e-12)
    fast = set(
        m.visible((2.0, 5.0, 0.3), fov=math.radians(270), max_range=9.0, spacing=0.05).tolist()
    )
    exact = set(
        m.visible(
            (2.0, 5.0, 0.3), fov=math.radians(270), max_range=9.0, spacing=0.05, exact=True
        ).tolist()
    )
    assert len(exact) > 100
    jaccard = len(fast & exact) / len(fast | exact)
    assert jaccard > 0.95, (len(fast), len(exact), jaccard)

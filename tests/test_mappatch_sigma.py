"""The map patch's per-cell confidence (icploc.mappatch): the sigma image's reader and
levels, which beam ends a cell's sigma counts, the marginals' bound and the writer's
``confident_only`` / ``sigmas`` options."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from icploc.errors import IcplocError
from icploc.mappatch import grid_from_scans


def _wall_scan() -> np.ndarray:
    """Robot-frame beam ends on a wall 3 m ahead (x = 3), y -1..1 every 2 cm."""
    ys = np.arange(-1.0, 1.0001, 0.02)
    return np.column_stack([np.full_like(ys, 3.0), ys])


@pytest.mark.parametrize(
    "data",
    [
        b"P5\n3 2",
        b"P5\n# cut in a comment",
        b"P5\n3 2\n255",
        b"P5\n3",
        b"P5",
        b"",
        b"P2\n3 2\n255\n000000",
    ],
)
def test_a_cut_short_sigma_header_is_an_error_naming_the_file(tmp_path: Path, data: bytes) -> None:
    from icploc.mappatch import read_sigma_image

    p = tmp_path / "cut.sigma.pgm"
    p.write_bytes(data)
    with pytest.raises(IcplocError, match="cut.sigma.pgm"):
        read_sigma_image(p)


def test_a_sigma_image_short_of_pixels_or_of_another_maxval_is_an_error(tmp_path: Path) -> None:
    from icploc.mappatch import read_sigma_image

    short, deep = tmp_path / "short.sigma.pgm", tmp_path / "deep.sigma.pgm"
    short.write_bytes(b"P5\n3 2\n255\n" + bytes(5))
    deep.write_bytes(b"P5\n3 2\n65535\n" + bytes(12))
    with pytest.raises(IcplocError, match=r"short\.sigma\.pgm.*truncated, 5 of 6 pixels"):
        read_sigma_image(short)
    with pytest.raises(IcplocError, match=r"deep\.sigma\.pgm.*maxval 255"):
        read_sigma_image(deep)


def test_a_large_finite_sigma_is_written_below_the_none_level() -> None:
    from icploc.mappatch import PATCH_SIGMA_NONE, PATCH_SIGMA_UNIT, sigma_image

    big = [0.508, 0.6, 12.0, 1e300]
    img = sigma_image(np.array([big + [np.nan, np.inf]]))
    # the finite ones at the top finite level (read back as 0.508 m: at least that
    # unsure, never "none"); NaN and inf at the none level
    assert img.tolist() == [[PATCH_SIGMA_NONE - 1] * 4 + [PATCH_SIGMA_NONE] * 2]
    assert math.isclose((PATCH_SIGMA_NONE - 1) * PATCH_SIGMA_UNIT, 0.508)


def test_a_cells_sigma_leaves_out_the_beam_ends_without_a_covariance() -> None:
    from icploc.mappatch import cell_sigmas

    pts = _wall_scan()
    pose = (0.0, 0.0, 0.0)
    g = grid_from_scans([pts, pts], [pose, pose], resolution=0.05)
    assert g is not None
    ca = np.diag([1e-4, 0.0, 0.0])
    alone = cell_sigmas(g, [pts], [pose], [ca])
    mixed = cell_sigmas(g, [pts, pts], [pose, pose], [ca, None])
    occ = g.occupied
    assert bool(np.isfinite(alone[occ]).all())
    np.testing.assert_array_equal(mixed[occ], alone[occ])
    # inf only where no beam end has a covariance; NaN where no beam ended
    assert bool(np.isinf(cell_sigmas(g, [pts, pts], [pose, pose], [None, None])[occ]).all())
    assert bool(np.isnan(mixed[~occ & (g.hits == 0)]).all())


def test_a_cells_sigma_skips_a_scan_at_a_non_finite_pose() -> None:
    from icploc.mappatch import cell_sigmas

    pts = _wall_scan()
    pose = (0.0, 0.0, 0.0)
    g = grid_from_scans([pts, pts], [pose, (math.nan, 0.0, 0.0)], resolution=0.05)
    assert g is not None
    ca, cb = np.diag([1e-4, 0.0, 0.0]), np.diag([49e-4, 0.0, 0.0])
    got = cell_sigmas(g, [pts, pts], [pose, (math.nan, 0.0, 0.0)], [ca, cb])
    np.testing.assert_array_equal(got, cell_sigmas(g, [pts], [pose], [ca]))


def _chain(n: int):  # type: ignore[no-untyped-def]
    """A chain of ``n`` odometry edges (0.1 m steps) held at node 0 and at its end."""
    from icploc.mappatch import _Edge

    x = np.column_stack([np.arange(n + 1) * 0.1, np.zeros(n + 1), np.zeros(n + 1)])
    info = np.diag([1e4, 1e4, 1e5])
    edges = [_Edge(k, k + 1, (0.1, 0.0, 0.0), info, True) for k in range(n)]
    w = np.diag([1e3, 1e3, 1e4])
    priors = [(0, (0.0, 0.0, 0.0), w), (n, (n * 0.1, 0.0, 0.0), w)]
    return x, edges, priors


def test_the_marginals_of_a_subsample_stand_in_for_their_neighbours() -> None:
    from icploc.mappatch import _marginals

    x, edges, priors = _chain(600)
    full = _marginals(x, edges, priors, None, nodes=len(x))
    some = _marginals(x, edges, priors, None, nodes=60)
    # every 11th node is computed exactly (and the last); the rest interpolated
    picked = list(range(0, len(x), math.ceil(len(x) / 60))) + [len(x) - 1]
    np.testing.assert_allclose(some[picked], full[picked], rtol=1e-9, atol=1e-15)
    # along the chain the covariance varies slowly: each stand-in's sigma (x, y,
    # heading) within 2 % of the node's own, and never more than 1 % surer
    for i in range(3):
        own = np.sqrt(full[:, i, i])
        rel = (np.sqrt(some[:, i, i]) - own) / own
        assert float(np.abs(rel).max()) < 0.02
        assert float(rel.min()) > -0.01
    sx = np.sqrt(full[:, 1, 1])
    assert float(np.ptp(sx) / sx.max()) > 0.5  # the covariance does vary along it


def _stretch():  # type: ignore[no-untyped-def]
    """A stretch never back in the map: two scans of a wall 2 m ahead (drawn only with
    ``include_open``; no pose covariance, every wall cell unsure)."""
    from icploc.outside import Stretch

    y = np.arange(-1.0, 1.0001, 0.02)
    pts = np.column_stack([np.full_like(y, 2.0), y])
    st = Stretch(5, 0.0, (0.0, 0.0, 0.0))
    st.scans = [(5, pts, (0.0, 0.0, 0.0)), (6, pts - (0.1, 0.0), (0.1, 0.0, 0.0))]
    return st


def test_confident_only_leaves_the_unsure_wall_cells_unknown(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # the north half of the wall made sure (1 cm), the south half as computed (no
    # covariance: inf): with confident_only the patch keeps the north half's walls and
    # leaves the south half's unknown, neither wall nor free
    import yaml
    from icploc import mappatch
    from icploc.maps.ros import load_ros

    real = mappatch.patch_solution

    def half_sure(*args, **kwargs):  # type: ignore[no-untyped-def]
        g, sigma = real(*args, **kwargs)
        rows = np.arange(sigma.shape[0])
        north = (float(g.origin[1]) + (rows + 0.5) * g.resolution > 0.0)[:, None]
        return g, np.where(north & g.occupied, 0.01, sigma)

    monkeypatch.setattr(mappatch, "patch_solution", half_sure)
    every = mappatch.write_patch(tmp_path / "all.yaml", [_stretch()], include_open=True)
    sure = mappatch.write_patch(
        tmp_path / "sure.yaml", [_stretch()], include_open=True, confident_only=True
    )
    assert every is not None and sure is not None
    a, b = load_ros(tmp_path / "all.yaml"), load_ros(tmp_path / "sure.yaml")
    rows = np.arange(a.occupied.shape[0])
    north = (a.origin[1] + (rows + 0.5) * a.resolution > 0.0)[:, None] & np.ones_like(a.occupied)
    walls = a.occupied
    assert int((walls & north).sum()) >= 15 and int((walls & ~north).sum()) >= 15
    np.testing.assert_array_equal(b.occupied, walls & north)
    assert bool((b.occupancy[walls & ~north] == -1).all())
    np.testing.assert_array_equal(b.free, a.free & ~(walls & ~north))
    conf = yaml.safe_load((tmp_path / "sure.yaml").read_text())["icploc_patch_confidence"]
    assert [conf["uncertain_left_unknown"], conf["confident_wall_cells"]] == [
        True,
        int((walls & north).sum()),
    ]


def test_a_patch_without_sigmas_writes_no_sigma_image(tmp_path: Path) -> None:
    import yaml
    from icploc.mappatch import sigma_path, write_patch

    g = write_patch(tmp_path / "p.yaml", [_stretch()], include_open=True, sigmas=False)
    assert g is not None and bool(g.occupied.any())
    doc = yaml.safe_load((tmp_path / "p.yaml").read_text())
    assert [sigma_path(tmp_path / "p.yaml").exists(), "icploc_patch_confidence" in doc] == [
        False,
        False,
    ]
    assert doc["icploc_patch_stretches"][0]["in_patch"] is True
    with pytest.raises(ValueError, match="confident_only"):
        write_patch(
            tmp_path / "q.yaml", [_stretch()], include_open=True, sigmas=False, confident_only=True
        )

"""The mapped walls' priors in a stretch's pose graph (icploc.mappatch._wall_prior_solve):
a prior the solved graph disagrees with by a few sigma, yet within the outlier gate (a
wall matched beside itself), is down-weighted by its chi-square and the graph solved
again, so it no longer drags its part of the stretch (and the walls drawn from there)
off. The bound is per the prior's degrees of freedom (its
information's rank), so a right full-rank prior is not mistaken for a wrong one."""

from __future__ import annotations

import numpy as np
import pytest
from icploc.fusion import scan_covariance
from icploc.mappatch import (
    WALL_PRIOR_CHI2_PER_DOF,
    _Edge,
    _prior_chi2,
    _prior_dof,
    _solve_graph,
    _wall_prior_solve,
)


def _graph(n: int = 40):  # type: ignore[no-untyped-def]
    """A straight 4 m stretch along x (0.1 m steps, 1 cm / 3 mrad per step), the exit and
    the lock held at their true poses, and mapped walls' priors on the lateral position
    only (a wall along the way): four right ones (3 cm) and one at node 20 that says
    0.2 m to the left (1.5 cm)."""
    x = np.column_stack([np.arange(n + 1) * 0.1, np.zeros(n + 1), np.zeros(n + 1)])
    info = np.diag([1e4, 1e4, 1e5])
    edges = [_Edge(k, k + 1, (0.1, 0.0, 0.0), info, True) for k in range(n)]
    anchor = np.diag([1 / 0.03**2, 1 / 0.03**2, 1 / 0.01**2])
    priors = [(0, (0.0, 0.0, 0.0), anchor), (n, (n * 0.1, 0.0, 0.0), anchor)]

    def lateral(sigma: float) -> np.ndarray:
        return np.diag([0.0, 1 / sigma**2, 0.0])

    walls = [(k, (k * 0.1, 0.0, 0.0), lateral(0.03)) for k in (8, 14, 26, 32)]
    walls.append((20, (2.0, 0.2, 0.0), lateral(0.015)))
    return x, edges, priors, walls


def test_a_wrong_wall_prior_within_the_gate_no_longer_drags_the_stretch_off() -> None:
    x, edges, priors, walls = _graph()
    plain, kept_plain = _wall_prior_solve(x.copy(), edges, priors, walls, None, 16.0, per_dof=0.0)
    y, kept = _wall_prior_solve(x.copy(), edges, priors, walls, None, 16.0)
    # the wrong prior passes the gate: without the re-weighting it pulls node 20 (and the
    # walls its scan draws) more than 10 cm off; re-weighted, within 8 cm
    assert len(kept_plain) == len(kept) == len(walls)
    assert float(plain[20, 1]) > 0.1
    assert abs(float(y[20, 1])) < 0.08
    # the whole stretch closer to the truth, and the right priors agree with it
    assert float(np.abs(y[:, 1]).max()) < 0.6 * float(np.abs(plain[:, 1]).max())
    assert max(_prior_chi2(y, q) for q in walls[:4]) < WALL_PRIOR_CHI2_PER_DOF
    # the wrong prior's information was scaled down, the right ones' kept
    assert float(kept[4][2][1, 1]) < 0.5 * float(walls[4][2][1, 1])
    np.testing.assert_array_equal(kept[0][2], walls[0][2])


def test_wall_priors_the_graph_agrees_with_are_left_as_they_are() -> None:
    x, edges, priors, walls = _graph()
    right = walls[:4]
    y, kept = _wall_prior_solve(x.copy(), edges, priors, right, None, 16.0)
    for (k, z, w), (k2, z2, w2) in zip(right, kept, strict=True):
        assert (k, z) == (k2, z2)
        np.testing.assert_array_equal(w, w2)
    np.testing.assert_allclose(y, x, atol=1e-9)


def _firm_graph(n: int = 40):  # type: ignore[no-untyped-def]
    """A straight 4 m stretch along x held firmly (1 mm / 0.3 mrad a step, the exit and the
    lock to 1 cm / 2 mrad), so a prior's residual at the solution is most of its error."""
    x = np.column_stack([np.arange(n + 1) * 0.1, np.zeros(n + 1), np.zeros(n + 1)])
    info = np.diag([1e6, 1e6, 1e7])
    edges = [_Edge(k, k + 1, (0.1, 0.0, 0.0), info, True) for k in range(n)]
    anchor = np.diag([1 / 0.01**2, 1 / 0.01**2, 1 / 0.002**2])
    priors = [(0, (0.0, 0.0, 0.0), anchor), (n, (n * 0.1, 0.0, 0.0), anchor)]
    return x, edges, priors


def test_a_right_full_rank_prior_is_left_as_it_is_and_a_wrong_one_scaled() -> None:
    """Full 3 x 3 information (a corner's walls: as most production priors with rank 3):
    a right prior 1.3 sigma off on each axis (chi-square 5.07 of 3 dof, exceeded by one
    right prior in six) keeps its information; one 3.5 sigma beside its wall is scaled.
    A bound of 3 whatever the rank (the old rule) scaled the right one too."""
    x, edges, priors = _firm_graph()
    s, st = 0.03, 0.01
    full = np.diag([1 / s**2, 1 / s**2, 1 / st**2])
    right = (20, (2.0 + 1.3 * s, 1.3 * s, 1.3 * st), full)
    wrong = (30, (3.0, 3.5 * s, 0.0), full)
    assert _prior_dof(full) == 3
    at = _solve_graph(x.copy(), edges, [*priors, right, wrong])
    # the right prior's residual at the solution lies between the old bound and the new
    assert 3.0 < _prior_chi2(at, right) < 3 * WALL_PRIOR_CHI2_PER_DOF
    assert 3 * WALL_PRIOR_CHI2_PER_DOF < _prior_chi2(at, wrong) < 16.0
    y, kept = _wall_prior_solve(x.copy(), edges, priors, [right, wrong], None, 16.0)
    assert [k for k, _, _ in kept] == [20, 30]
    np.testing.assert_array_equal(kept[0][2], full)
    assert float(kept[1][2][1, 1]) < 0.7 * float(full[1, 1])
    # the wrong prior pulls node 30 less than it did unscaled
    assert abs(float(y[30, 1])) < 0.8 * abs(float(at[30, 1]))


def test_the_same_chi_square_scales_a_one_direction_prior() -> None:
    """The bound follows the prior's degrees of freedom: the residual a full-rank prior
    keeps its weight at, on a prior holding one direction, is scaled."""
    x, edges, priors = _firm_graph()
    s = 0.03
    lateral = (20, (2.0, 1.9 * s, 0.0), np.diag([0.0, 1 / s**2, 0.0]))
    assert _prior_dof(lateral[2]) == 1
    at = _solve_graph(x.copy(), edges, [*priors, lateral])
    c = _prior_chi2(at, lateral)
    assert WALL_PRIOR_CHI2_PER_DOF < c < 3 * WALL_PRIOR_CHI2_PER_DOF
    _, kept = _wall_prior_solve(x.copy(), edges, priors, [lateral], None, 16.0)
    assert float(kept[0][2][1, 1]) < float(lateral[2][1, 1])


@pytest.mark.parametrize(("weak", "dof"), [(3.0, 2), (50.0, 3)])
def test_a_prior_s_dof_is_the_rank_scan_covariance_leaves(weak: float, dof: int) -> None:
    """A match whose weakest direction is held by fewer beams than ``min_axis_beams`` (8,
    as :class:`icploc.mappatch.MappedWalls` asks) has that direction dropped: its
    information, inverted as the priors are, has rank 2; held by more, rank 3."""
    H = np.array([[weak, 0.0, 0.0], [0.0, 300.0, 20.0], [0.0, 20.0, 900.0]])
    R = scan_covariance(H, 320, 1e-4, 0.02, 5.0, 8.0)
    info = np.linalg.inv(np.asarray(R) + np.eye(3) * 1e-12)
    assert _prior_dof(0.5 * (info + info.T)) == dof

"""The mapped walls' priors in a stretch's pose graph (icploc.mappatch._wall_prior_solve):
a prior the solved graph disagrees with by a few sigma, yet within the outlier gate (a
wall matched beside itself), is down-weighted by its chi-square and the graph solved
again, so it no longer drags its part of the stretch (and the walls drawn from there)
off."""

from __future__ import annotations

import numpy as np
from icploc.mappatch import WALL_PRIOR_CHI2, _Edge, _prior_chi2, _wall_prior_solve


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
    plain, kept_plain = _wall_prior_solve(x.copy(), edges, priors, walls, None, 16.0, reweight=0.0)
    y, kept = _wall_prior_solve(x.copy(), edges, priors, walls, None, 16.0)
    # the wrong prior passes the gate: without the re-weighting it pulls node 20 (and the
    # walls its scan draws) more than 10 cm off; re-weighted, within 8 cm
    assert len(kept_plain) == len(kept) == len(walls)
    assert float(plain[20, 1]) > 0.1
    assert abs(float(y[20, 1])) < 0.08
    # the whole stretch closer to the truth, and the right priors agree with it
    assert float(np.abs(y[:, 1]).max()) < 0.6 * float(np.abs(plain[:, 1]).max())
    assert max(_prior_chi2(y, q) for q in walls[:4]) < WALL_PRIOR_CHI2
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

"""The replay's speed hooks in other modules answer exactly as the work they skip."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from icploc import fusion

_scale = st.sampled_from([1e-3, 1.0, 10.0, 100.0, 1000.0])


@st.composite
def _information(draw: st.DrawFn) -> np.ndarray:
    """An ICP information matrix: J'J of a few rows, sometimes nearly degenerate."""
    rows = draw(st.integers(1, 6))
    vals = draw(st.lists(st.floats(-1.0, 1.0), min_size=3 * rows, max_size=3 * rows))
    J = np.array(vals).reshape(rows, 3) * draw(_scale)
    H = J.T @ J
    if draw(st.booleans()):  # a corridor: the two position rows almost parallel
        H[1, 1] = H[0, 1] ** 2 / H[0, 0] * (1 + draw(st.floats(0, 1e-6))) if H[0, 0] > 0 else H[1, 1]
    return H


@settings(max_examples=400, deadline=None)
@given(H=_information(), bound=st.sampled_from([0.5, 8.0, 50.0]), inliers=st.integers(1, 500))
def test_scan_covariance_is_the_same_with_and_without_the_eigh_guard(
    H: np.ndarray, bound: float, inliers: int
) -> None:
    got = fusion.scan_covariance(H, inliers, 1e-4, 0.02, 40.0, bound)
    with pytest.MonkeyPatch.context() as m:
        m.setattr(fusion, "_may_be_below", lambda _h, _b: True)
        want = fusion.scan_covariance(H, inliers, 1e-4, 0.02, 40.0, bound)
    assert np.array_equal(got, want)

"""While a stretch outside the map is open (``icploc.outside``: coasted or re-entering), a
coasting fit from a turned heading seed must pass on the usual share: a weak one (under
it, taken for its tight hits) is not taken there. On freiburg-079's partial map (the
real-data partial benchmark, ``benches/eval_partial.py``) a weak fit from a turned seed
moved the dead reckoning of its one stretch, the stretch never re-locked and the revisits
within 0.5 m fell 100 -> 87 %; inside the map such fits are what corrects a heading the
odometry got wrong (``test_acc_coast``)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from icploc.localizer import Localizer

PRED = (1.0, 2.0, 0.3)
TURNED = (1.05, 2.0, 0.2)  # the fit a turned seed finds: 5 cm and 0.1 rad from the dead reckoning


def _room() -> np.ndarray:
    t = np.linspace(0.0, 4.0, 200)
    return np.vstack([np.column_stack([t, np.zeros_like(t)]), np.column_stack([t, np.full_like(t, 4.0)]),
                      np.column_stack([np.zeros_like(t), t]), np.column_stack([np.full_like(t, 4.0), t])])  # fmt: skip


def _coast(state: str | None, weak: bool) -> tuple[tuple[float, float, float], bool]:
    """``Localizer._coast`` where the fit from the dead reckoning fails and a turned seed's
    fit (``weak`` or not) is the only one: the pose it returns and whether it moved."""
    loc = Localizer(_room(), initial_pose=PRED)
    loc.outside = None if state is None else SimpleNamespace(state=state)
    cov = np.diag([0.1**2, 0.1**2, 0.1**2])

    def fit(pts: Any, pred: Any, pred_cov: Any, seed: Any, sig: float, at_pred: Any) -> Any:
        if seed == pred:  # the dead reckoning's own fit: nothing passes
            return None
        hit = SimpleNamespace(hit=0.4)
        return TURNED, cov * 0.5, hit, 0.55, TURNED, weak

    loc._coast_fit = fit  # type: ignore[method-assign]
    pts = np.column_stack([np.linspace(-1, 1, 100), np.full(100, 1.5)])
    pose, _cov, moved = loc._coast(pts, PRED, cov)
    return pose, moved


@pytest.mark.parametrize("state", ["outside", "reentering"])
def test_a_weak_turned_fit_is_not_taken_while_a_stretch_is_open(state: str) -> None:
    assert _coast(state, weak=True) == (PRED, False)


@pytest.mark.parametrize("state", [None, "inside"])
def test_inside_the_map_a_weak_turned_fit_corrects_the_dead_reckoning(state: str | None) -> None:
    assert _coast(state, weak=True) == (TURNED, True)


def test_a_turned_fit_on_the_usual_share_is_taken_while_a_stretch_is_open() -> None:
    assert _coast("reentering", weak=False) == (TURNED, True)

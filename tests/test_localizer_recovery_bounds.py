"""The global recovery's search window reads the map index's extent: checked once per index
(not on every lost scan), and a broken one is the package's map error, naming the field."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from icploc.config import LocalizerConfig
from icploc.errors import IcplocError
from icploc.maps import MapError
from icploc.recovery import RecoveryView
from icploc.relocalize import GlobalRelocalization

CFG = LocalizerConfig()


class _CountingIndex:
    """A stand-in for a MapIndex whose ``bounds`` counts its reads."""

    def __init__(self, bounds: Any) -> None:
        self._bounds = bounds
        self.reads = 0

    @property
    def bounds(self) -> Any:
        self.reads += 1
        return self._bounds


def _view(index: Any, k: int = 5) -> RecoveryView:
    return RecoveryView(
        pose=(10.0, 1.0, 0.3),
        covariance=np.diag([0.25, 0.25, 0.01]),
        motion=(0.0, 0.0, 0.0),
        stamp=0.1 * k,
        scans_processed=k,
        lost_scans=k + 1,
        index=index,
        icp_config=CFG.icp.to_icp_config(window_search=False),
        config=CFG,
        verify=lambda pts, p: (False, None, p),
    )


@pytest.mark.parametrize(
    "bounds", [(0.0, 0.0, 40.0), (0.0, 0.0, math.nan, 20.0), (40.0, 0.0, 0.0, 20.0), "abcd", 7]
)
def test_broken_bounds_are_a_map_error_naming_the_field(bounds: Any) -> None:
    gr = GlobalRelocalization(None, config=CFG)
    with pytest.raises(MapError, match=r"field 'bounds': map index bounds") as ei:
        gr.window(_view(_CountingIndex(bounds)))
    assert isinstance(ei.value, IcplocError)
    assert ei.value.field == "bounds"


def test_the_bounds_are_checked_once_per_index_not_per_scan() -> None:
    gr = GlobalRelocalization(None, config=CFG)
    index = _CountingIndex((0.0, 0.0, 40.0, 20.0))
    windows = [gr.window(_view(index, k)) for k in range(5, 25)]
    assert index.reads == 1
    assert windows[0] is not None and windows[0][0] == pytest.approx((7.5, 0.0, 12.5, 3.5))
    assert all(w == windows[0] for w in windows)
    # another index (a map swapped in) is read and checked afresh
    other = _CountingIndex((0.0, 0.0, 11.0, 20.0))
    got = gr.window(_view(other))
    assert other.reads == 1
    assert got is not None and got[0] == pytest.approx((7.5, 0.0, 11.0, 3.5))

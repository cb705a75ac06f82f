"""icploc.median.median is statistics.median (the replay path avoids importing statistics)."""

from __future__ import annotations

import statistics

import pytest
from hypothesis import given
from hypothesis import strategies as st
from icploc.median import median

finite = st.floats(allow_nan=False, allow_infinity=False, width=64, min_value=-1e300, max_value=1e300)


@given(st.lists(finite, min_size=1, max_size=40))
def test_median_is_the_statistics_median_bit_for_bit(values: list[float]) -> None:
    assert median(values) == statistics.median(values)


def test_median_of_nothing_is_an_error() -> None:
    with pytest.raises(ValueError, match="no values"):
        median([])

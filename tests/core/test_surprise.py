"""`dbcslam_core.surprise.SurpriseMonitor`: the surprise of a step against the median of the
recent observed steps."""

from __future__ import annotations

import math
import statistics

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dbcslam_core.errors import ModelError
from dbcslam_core.surprise import MIN_REFERENCE_STEPS, SurpriseMonitor


def test_no_surprise_until_the_reference_has_enough_steps() -> None:
    mon = SurpriseMonitor(window=5)
    assert [mon.update(x) for x in (10.0, 0.0, -50.0, 3.0, 8.0)] == [0.0] * 5
    assert mon.update(-20.0) == pytest.approx(3.0 + 20.0)  # median of 10, 0, -50, 3, 8
    assert len(mon) == 5  # the window keeps the last 5: 0, -50, 3, 8, -20
    assert mon.update(1.0) == pytest.approx(0.0 - 1.0)


def test_zero_likelihood_is_infinitely_surprising_and_not_recorded() -> None:
    mon = SurpriseMonitor()
    for _ in range(MIN_REFERENCE_STEPS):
        mon.update(12.0)
    assert mon.update(-math.inf) == math.inf
    assert len(mon) == MIN_REFERENCE_STEPS
    mon.clear()
    assert len(mon) == 0 and mon.update(-100.0) == 0.0


def test_window_below_the_reference_minimum_is_refused() -> None:
    with pytest.raises(ModelError, match=f">= {MIN_REFERENCE_STEPS} steps, got 4"):
        SurpriseMonitor(window=4)


@given(
    st.integers(min_value=MIN_REFERENCE_STEPS, max_value=30),
    st.lists(st.one_of(st.floats(-1e6, 1e6), st.just(-math.inf)), min_size=1, max_size=80),
)
def test_surprise_is_the_median_of_the_recent_finite_steps_minus_the_step(
    window: int, values: list[float]
) -> None:
    mon = SurpriseMonitor(window)
    finite: list[float] = []
    for x in values:
        ref = finite[-window:]
        expected = statistics.median(ref) - x if len(ref) >= MIN_REFERENCE_STEPS else 0.0
        got = mon.update(x)
        assert got == pytest.approx(expected, rel=1e-12, abs=1e-9) or got == expected == math.inf
        if math.isfinite(x):
            finite.append(x)
    assert len(mon) == min(window, len(finite))

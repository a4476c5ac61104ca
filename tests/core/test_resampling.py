"""Resamplers: counts, ancestry range, unbiasedness; ESS and log-weight normalisation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.errors import ModelError
from dbcslam_core.resampling import (
    RESAMPLERS,
    effective_sample_size,
    make_resampler,
    normalise_log_weights,
)

weights_st = st.lists(
    st.floats(min_value=0.0, max_value=1.0, allow_nan=False), min_size=1, max_size=40
).filter(lambda w: sum(w) > 1e-6)


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
@settings(max_examples=60, deadline=None)
@given(w=weights_st, seed=st.integers(0, 2**31 - 1))
def test_resampler_returns_valid_sorted_ancestors(name: str, w: list[float], seed: int) -> None:
    wa = np.asarray(w) / np.sum(w)
    idx = make_resampler(name)(wa, np.random.default_rng(seed))
    assert idx.shape == (wa.size,)
    assert np.all(np.diff(idx) >= 0)
    assert idx.min() >= 0 and idx.max() < wa.size
    # particles with zero weight are never selected
    assert np.all(wa[idx] > 0.0)


@pytest.mark.parametrize("name", ["systematic", "residual", "stratified"])
@settings(max_examples=60, deadline=None)
@given(w=weights_st, seed=st.integers(0, 2**31 - 1))
def test_low_variance_counts_bracket_expectation(name: str, w: list[float], seed: int) -> None:
    wa = np.asarray(w) / np.sum(w)
    n = wa.size
    counts = np.bincount(make_resampler(name)(wa, np.random.default_rng(seed)), minlength=n)
    assert counts.sum() == n
    if name in ("systematic", "residual"):
        assert np.all(counts >= np.floor(n * wa - 1e-9))
    if name == "systematic":
        assert np.all(counts <= np.ceil(n * wa + 1e-9))


@pytest.mark.parametrize("name", sorted(RESAMPLERS))
def test_resampler_is_unbiased(name: str) -> None:
    rng = np.random.default_rng(3)
    w = rng.random(12) ** 3
    w /= w.sum()
    r = make_resampler(name)
    reps = 4000
    total = np.zeros(w.size)
    for _ in range(reps):
        total += np.bincount(r(w, rng), minlength=w.size)
    mean = total / reps
    np.testing.assert_allclose(mean, w.size * w, atol=0.08)


def test_resampler_draws_requested_number() -> None:
    w = np.array([0.1, 0.2, 0.7])
    for name in RESAMPLERS:
        assert make_resampler(name)(w, np.random.default_rng(0), n=10).shape == (10,)


def test_unknown_resampler_and_bad_weights_raise() -> None:
    with pytest.raises(ModelError, match="valid names"):
        make_resampler("nope")
    with pytest.raises(ModelError, match="sum to 1"):
        make_resampler("systematic")(np.array([0.5, 0.7]), np.random.default_rng(0))
    with pytest.raises(ModelError):
        make_resampler("systematic")(np.array([0.5, np.nan]), np.random.default_rng(0))


def test_ess_and_normalisation() -> None:
    assert effective_sample_size(np.full(10, 0.1)) == pytest.approx(10.0)
    assert effective_sample_size(np.eye(1, 10)[0]) == pytest.approx(1.0)
    w, ls = normalise_log_weights(np.array([-1000.0, -1000.0 + np.log(3.0), -np.inf]))
    np.testing.assert_allclose(w, [0.25, 0.75, 0.0])
    assert ls == pytest.approx(-1000.0 + np.log(4.0))
    with pytest.raises(ModelError, match="no finite"):
        normalise_log_weights(np.array([-np.inf, -np.inf]))
    with pytest.raises(ModelError, match="NaN"):
        normalise_log_weights(np.array([0.0, np.nan]))

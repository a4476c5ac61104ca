"""Eq. (7) parameter models, the grid update (8)-(9) and the friction map."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.errors import ModelError
from dbcslam_core.parameters import (
    PARAMETER_MODELS,
    FrictionMap,
    grid_update,
    predict_parameters,
)

dist_st = st.lists(st.floats(0.0, 1.0, allow_nan=False), min_size=3, max_size=3).filter(
    lambda x: sum(x) > 1e-3
)


@pytest.mark.parametrize("model", PARAMETER_MODELS)
@settings(max_examples=80, deadline=None)
@given(f=dist_st, f0=dist_st, w=st.floats(0.0, 1.0))
def test_eq7_outputs_are_distributions(
    model: str, f: list[float], f0: list[float], w: float
) -> None:
    fa = np.asarray(f) / sum(f)
    f0a = np.asarray(f0) / sum(f0)
    out = predict_parameters(fa, f0a, w, model)
    assert out.shape == (3,)
    assert np.all(out >= 0.0)
    assert out.sum() == pytest.approx(1.0)


def test_eq7_limits_and_forms() -> None:
    f = np.array([0.9, 0.1])
    f0 = np.array([0.5, 0.5])
    for model in ("mixture", "geometric"):
        np.testing.assert_allclose(predict_parameters(f, f0, 0.0, model), f0)
        np.testing.assert_allclose(predict_parameters(f, f0, 1.0, model), f)
    np.testing.assert_allclose(predict_parameters(f, f0, 0.0, "reuse"), f)
    np.testing.assert_allclose(predict_parameters(f, f0, 0.3, "mixture"), 0.3 * f + 0.7 * f0)
    g = f**0.3 * f0**0.7
    np.testing.assert_allclose(predict_parameters(f, f0, 0.3, "geometric"), g / g.sum())
    # batched with per-row weights
    out = predict_parameters(np.tile(f, (2, 1)), f0, np.array([0.0, 1.0]), "mixture")
    np.testing.assert_allclose(out, [f0, f])
    with pytest.raises(ModelError, match="valid models"):
        predict_parameters(f, f0, 0.5, "diffusion")


def test_grid_update_is_bayes_rule() -> None:
    prior = np.array([0.2, 0.3, 0.5])
    lik = np.array([0.1, 0.4, 0.05])
    post, log_ev = grid_update(prior, np.log(lik))
    np.testing.assert_allclose(post, prior * lik / np.sum(prior * lik))
    assert log_ev == pytest.approx(np.log(np.sum(prior * lik)))
    # huge log-likelihoods do not overflow
    post2, _ = grid_update(prior, np.log(lik) - 5000.0)
    np.testing.assert_allclose(post2, post)
    # zero evidence keeps the predictive
    post3, ev3 = grid_update(prior, np.full(3, -np.inf))
    np.testing.assert_allclose(post3, prior)
    assert ev3 == -np.inf


def test_friction_map_cells_average_committed_beliefs() -> None:
    fmap = FrictionMap(((0.5, 0.5),), s_min=0.0, s_max=1.0, cell_size=0.1)
    assert fmap.n_cells == 10
    fmap.add(0, [0.05, 0.06, 0.55], [[1.0, 0.0], [0.0, 1.0], [0.2, 0.8]], [3.0, 1.0, 1.0])
    view = fmap.view()
    np.testing.assert_allclose(view.probs[0][0], [0.75, 0.25])
    np.testing.assert_allclose(view.probs[0][5], [0.2, 0.8])
    np.testing.assert_allclose(view.probs[0][3], [0.5, 0.5])  # untouched -> prior
    assert view.touched(0).tolist() == [i in (0, 5) for i in range(10)]
    np.testing.assert_allclose(view.centers[:2], [0.05, 0.15])
    # out-of-range coordinates are clipped to the border cells, zero weight ignored
    fmap.add(0, [5.0, -3.0], [[0.0, 1.0], [0.0, 1.0]], [1.0, 0.0])
    assert fmap.view().weight[0][9] == pytest.approx(1.0)
    assert fmap.view().weight[0][0] == pytest.approx(4.0)
    with pytest.raises(ModelError):
        fmap.add(1, [0.1], [[1.0, 0.0]], [1.0])
    with pytest.raises(ModelError):
        FrictionMap(((1.0,),), s_min=1.0, s_max=0.0)

"""Tests of dbcslam_core.metrics on hand-built arrays."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import ModelError
from dbcslam_core.metrics import (
    contact_accuracy,
    contact_mode_accuracy,
    final_true_friction_posterior,
    friction_map_accuracy,
    position_rmse,
    slid_cells,
    stick_slide_accuracy,
    wrap_angle,
    yaw_rmse,
)


def one_hot(modes: np.ndarray) -> np.ndarray:
    return np.eye(4)[modes]


def test_position_rmse_per_axis_and_euclidean() -> None:
    truth = np.zeros((4, 2))
    est = np.array([[3.0, 4.0], [3.0, 4.0], [-3.0, -4.0], [0.0, 5.0]])
    # Euclidean error is 5 at every step.
    assert position_rmse(est, truth, per_axis=False) == pytest.approx(5.0)
    assert position_rmse(est, truth) == pytest.approx(5.0 / np.sqrt(2.0))


def test_position_rmse_matches_noise_std() -> None:
    rng = np.random.default_rng(0)
    truth = rng.normal(size=(20000, 2))
    obs = truth + rng.normal(scale=0.01, size=truth.shape)
    assert position_rmse(obs, truth) == pytest.approx(0.01, rel=0.03)


def test_position_rmse_shape_errors() -> None:
    with pytest.raises(ModelError, match="shape"):
        position_rmse(np.zeros((3, 2)), np.zeros((4, 2)))
    with pytest.raises(ModelError, match="NaN"):
        position_rmse(np.full((3, 2), np.nan), np.zeros((3, 2)))


def test_yaw_rmse_wraps() -> None:
    truth = np.array([np.pi - 0.01, -np.pi + 0.01])
    est = np.array([-np.pi + 0.01, np.pi - 0.01])
    assert yaw_rmse(est, truth) == pytest.approx(0.02, abs=1e-12)


@settings(max_examples=50, deadline=None)
@given(st.floats(-50.0, 50.0), st.integers(-5, 5))
def test_wrap_angle_property(a: float, k: int) -> None:
    w = float(wrap_angle(a + 2.0 * np.pi * k))
    assert -np.pi <= w < np.pi
    assert np.cos(w) == pytest.approx(np.cos(a), abs=1e-9)
    assert np.sin(w) == pytest.approx(np.sin(a), abs=1e-9)


def test_contact_accuracy() -> None:
    truth = np.array([0, 1, 2, 3, 0])
    probs = one_hot(truth).astype(float)
    assert contact_accuracy(probs, truth) == 1.0
    probs[0] = [0.4, 0.6, 0.0, 0.0]  # says contact, truth separated -> wrong
    probs[1] = [0.3, 0.1, 0.3, 0.3]  # contact by 0.7 -> right
    assert contact_accuracy(probs, truth) == pytest.approx(4 / 5)
    # (T, C, 4) with C = 2 counts every entry.
    assert contact_accuracy(np.stack([probs, probs], 1), np.stack([truth, truth], 1)) == (
        pytest.approx(4 / 5)
    )


def test_stick_slide_accuracy_only_in_contact() -> None:
    truth = np.array([0, 1, 1, 2, 3])
    probs = np.array(
        [
            [0.0, 0.0, 1.0, 0.0],  # separated: not scored whatever it says
            [0.5, 0.3, 0.1, 0.1],  # stick 0.3 > slide 0.2 -> stick, right
            [0.0, 0.4, 0.3, 0.3],  # stick 0.4 < slide 0.6 -> slide, wrong
            [0.0, 0.1, 0.1, 0.8],  # slide (wrong direction does not matter) -> right
            [0.0, 0.9, 0.05, 0.05],  # stick, wrong
        ]
    )
    assert stick_slide_accuracy(probs, truth) == pytest.approx(2 / 4)


def test_stick_slide_accuracy_empty() -> None:
    truth = np.zeros(3, dtype=int)
    with pytest.raises(ModelError, match="empty"):
        stick_slide_accuracy(one_hot(truth), truth)
    assert stick_slide_accuracy(one_hot(truth), truth, empty=1.0) == 1.0


def test_contact_mode_accuracy_and_mask() -> None:
    truth = np.array([[0, 1], [2, 3], [3, 0]])
    probs = one_hot(truth)
    probs[2, 0] = one_hot(np.array(2))  # sliding direction wrong
    assert contact_mode_accuracy(probs, truth) == pytest.approx(5 / 6)
    mask = truth != Mode.SEPARATED
    assert contact_mode_accuracy(probs, truth, mask=mask) == pytest.approx(3 / 4)


def test_mode_input_validation() -> None:
    with pytest.raises(ModelError, match=r"0\.\.3"):
        contact_accuracy(one_hot(np.array([0, 1])), np.array([0, 4]))
    with pytest.raises(ModelError, match="shape"):
        contact_accuracy(np.zeros((3, 1, 3)), np.zeros((3, 1), dtype=int))


def test_slid_cells() -> None:
    edges = np.linspace(0.0, 1.0, 5)  # 4 cells of 0.25
    s = np.array([0.1, 0.3, 0.6, 0.9, 1.5])
    modes = np.array([2, 1, 3, 0, 2])  # slide, stick, slide, separated, slide outside
    np.testing.assert_array_equal(slid_cells(s, modes, edges), [True, False, True, False])
    np.testing.assert_array_equal(
        slid_cells(s, modes, edges, include_sticking=True), [True, True, True, False]
    )


def test_friction_map_accuracy() -> None:
    post = np.array([[0.9, 0.1], [0.2, 0.8], [0.6, 0.4], [np.nan, np.nan]])
    true_index = np.array([0, 1, 1, 0])
    cells = np.array([True, True, True, False])
    assert friction_map_accuracy(post, true_index, cells) == pytest.approx(2 / 3)
    # Never-touched cells count as wrong if selected.
    assert friction_map_accuracy(post, true_index, np.ones(4, bool)) == pytest.approx(2 / 4)


def test_final_true_friction_posterior() -> None:
    post = np.array([[1 / 3, 1 / 3, 1 / 3], [0.1, 0.7, 0.2]])
    assert final_true_friction_posterior(post, 1) == pytest.approx(0.7)
    two_pairs = np.stack([post, post[:, ::-1]], axis=1)
    assert final_true_friction_posterior(two_pairs, [1, 1]) == pytest.approx(0.7)
    assert final_true_friction_posterior(two_pairs, [1, 0]) == pytest.approx(0.2)
    with pytest.raises(ModelError, match="out of range"):
        final_true_friction_posterior(post, 3)

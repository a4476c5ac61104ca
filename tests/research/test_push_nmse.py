"""Full-push prediction (quasi-static) on the shipped MIT push files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dbcslam_research.push_nmse import displacement, load_cases, main, nmse, predict

DATA = Path(__file__).resolve().parents[1] / "data" / "mit-push"


@pytest.fixture(scope="module")
def cases():  # type: ignore[no-untyped-def]
    return load_cases(DATA, progress=False)


def test_displacement_is_in_the_initial_body_frame() -> None:
    d = displacement([1.0, 2.0, np.pi / 2], [1.0, 3.0, np.pi / 2 + 0.1])
    np.testing.assert_allclose(d, [1.0, 0.0, 0.1], atol=1e-12)


def test_nmse_is_zero_for_truth_and_one_for_the_mean() -> None:
    truth = np.random.default_rng(0).normal(size=(20, 3))
    assert nmse(truth, truth) == 0.0
    assert nmse(np.broadcast_to(truth.mean(axis=0), truth.shape), truth) == pytest.approx(1.0)


def test_quasi_static_predicts_real_pushes(cases) -> None:  # type: ignore[no-untyped-def]
    assert {c.shape for c in cases} == {"ellip1", "hex", "rect1"}
    for case in cases:
        pred = predict(case, 1.0, 0.2)
        moved = float(np.hypot(*case.truth[:2]))
        assert moved > 0.02  # these pushes move the object by centimetres
        assert np.hypot(*(pred[:2] - case.truth[:2])) < 0.2 * moved, case.name
        assert abs(pred[2] - case.truth[2]) < 0.15, case.name
        assert np.sign(pred[2]) == np.sign(case.truth[2]), case.name


def test_cli_writes_table_json_and_figure(tmp_path: Path) -> None:
    assert main([str(DATA), "--out", str(tmp_path)]) == 0
    for name in ("push_nmse.md", "push_nmse.json", "push_nmse.png"):
        assert (tmp_path / name).stat().st_size > 0
    assert main([str(tmp_path / "nowhere"), "--out", str(tmp_path)]) == 2

"""dbcslam_research.science: the benchmark's scoring rule and its merge of parts."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from dbcslam_core.extensions import ModelExtension
from dbcslam_research.science import edge_draw, merge, recovered


def _res(effect: str | None, params: dict[str, float], amb: tuple[str, ...] = ()) -> Any:
    win = None if effect is None else SimpleNamespace(effect=effect, params=params)
    return SimpleNamespace(winner=win, ambiguous=amb)


@pytest.mark.parametrize(
    ("res", "ok"),
    [
        (_res("viscous_damping", {"b": 2.2}), True),
        (_res("viscous_damping", {"b": 2.6}), False),  # 30 % off
        (_res("support_friction", {"mu": 0.2}), False),
        (_res(None, {}), False),
    ],
)
def test_recovered_within_25_percent(res: Any, ok: bool) -> None:
    assert recovered(res, ModelExtension.make("viscous_damping", b=2.0)) is ok


def test_recovered_pair_and_positions() -> None:
    ext = ModelExtension.make("mass_scale", factor=1.4)
    both = ("input_gain", "mass_scale")
    assert recovered(_res("input_gain", {"factor": 1 / 1.45}, both), ext)
    assert not recovered(_res("input_gain", {"factor": 1 / 1.45}), ext)  # pair not named
    bias = ModelExtension.make("sensor_bias", x=0.005, y=0.02, yaw=0.0)
    assert recovered(_res("sensor_bias", {"x": 0.0, "y": 0.025, "yaw": 0.0}), bias)
    assert not recovered(_res("sensor_bias", {"x": 0.0, "y": 0.045, "yaw": 0.0}), bias)


def test_draws_are_seeded_and_clean_draws_hide_nothing() -> None:
    a = edge_draw(3, clean=False, duration=0.5)
    b = edge_draw(3, clean=False, duration=0.5)
    assert a[2] == b[2] and a[2] is not None
    assert (a[0].obs == b[0].obs).all()
    assert edge_draw(3, clean=True, duration=0.5)[2] is None


def test_merge_keeps_one_row_per_draw(tmp_path: Path) -> None:
    row = {"index": 0, "clean": False, "hidden": "x", "verdict": "x", "fitted": "x",
           "outcome": "right", "seconds": 1.0}  # fmt: skip
    for name, rows in (("a", [row]), ("b", [row, {**row, "clean": True, "outcome": "none"}])):
        (tmp_path / name).mkdir()
        (tmp_path / name / "science.json").write_text(json.dumps(rows))
    merge(tmp_path / "m", [tmp_path / "a", tmp_path / "b"])
    assert len(json.loads((tmp_path / "m" / "science.json").read_text())) == 2
    assert "| 1 | 1 | 0 | 0 | 100% | 1 | 1 (100%)" in (tmp_path / "m" / "science.md").read_text()

"""`make bench` output: the plain-language reading is computed from the measured numbers."""

from __future__ import annotations

import math
from typing import Any

import pytest

from dbcslam_research.bench import reading_lines, render_markdown

META: dict[str, Any] = {
    "date_utc": "x",
    "machine": "m",
    "numpy": "2",
    "cpus": 2,
    "loadavg_1min_before_after": [0.0, 0.0],
    "warmup": 5,
    "repeat": 1,
    "steps": 40,
}


def _row(scenario: str, particles: int, dbc: float, lemke: float, pgs: float) -> dict[str, Any]:
    return {
        "scenario": scenario,
        "particles": particles,
        "dbcslam_ms": dbc,
        "dbcslam_rmse_mm": 1.0,
        "dbcslam_live_hypotheses": 5.0,
        "blackbox_pgs_ms": pgs,
        "blackbox_pgs_rmse_mm": 1.5,
        "blackbox_lemke_ms": lemke,
        "blackbox_lemke_rmse_mm": 1.5,
        "blackbox_lemke_as_ms": lemke / 2,
        "blackbox_lemke_as_rmse_mm": 1.5,
        "ratio_lemke_over_dbcslam": lemke / dbc if math.isfinite(lemke) else math.nan,
        "ratio_lemke_as_over_dbcslam": lemke / 2 / dbc if math.isfinite(lemke) else math.nan,
        "ratio_pgs_over_dbcslam": pgs / dbc,
    }


@pytest.mark.parametrize(
    ("ratios", "expected"),
    [
        ((8.0, 12.0, 14.0), "met at 300, 1000 particles"),
        ((11.0, 12.0, 14.0), "met at every measured particle count"),
        ((2.0, 3.0, 4.0), "met at no measured particle count"),
    ],
)
def test_reading_states_where_the_target_is_met(
    ratios: tuple[float, float, float], expected: str
) -> None:
    rows = [_row("gripper", p, 1.0, r, 0.3) for p, r in zip((100, 300, 1000), ratios, strict=True)]
    rows.append(_row("gripper", 3000, 1.0, math.nan, 0.3))  # Lemke not run there
    text = "\n".join(reading_lines({"scaling": rows}))
    assert expected in text
    assert f"{min(ratios):.1f}-{max(ratios):.1f}x faster than the per-particle Lemke" in text
    assert "takes 0.3x of DBC-SLAM's time" in text  # PGS faster: said, not hidden


def test_markdown_contains_reading() -> None:
    result = {
        "scaling": [_row("edge", 100, 2.0, 10.0, 0.3)],
        "accuracy": [],
        "meta": META,
    }
    md = render_markdown(result, "python -m dbcslam_research.bench")
    assert "**Reading the table.**" in md and "5.0x faster" in md


@pytest.mark.parametrize(("walls", "verdict"), [([3.9, 4.2, 3.8], "yes"), ([4.3, 4.1, 4.6], "no")])
def test_replay_table_says_whether_the_replay_kept_within_the_data(
    walls: list[float], verdict: str
) -> None:
    result: dict[str, Any] = {
        "scaling": [_row("gripper", 100, 2.0, 10.0, 0.3)],
        "accuracy": [],
        "replay": {
            "bag": "bags/gripper",
            "particles": 1000,
            "data_s": 4.0,
            "wall_s": walls,
            "wall_median_s": sorted(walls)[1],
            "wall_min_s": min(walls),
            "estimates": 400,
            "final_p_true": {"jaws": 1.0},
        },
        "meta": META,
    }
    md = render_markdown(result, "python -m dbcslam_research.bench")
    row = next(line for line in md.splitlines() if line.startswith("| `bags/gripper`"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[2] == "4.00"
    assert cells[4] == verdict
    assert cells[6] == "jaws 1.000"


def _profile_row(scenario: str, particles: int, compiled: float, step: float, pgs: float) -> Any:
    from dbcslam_research.step_profile import PHASES

    dbc = dict.fromkeys((name for name, _ in PHASES), 0.0)
    dbc.update({"_compiled_phases": compiled, "step": step, "other": step - compiled})
    return {
        "scenario": scenario,
        "particles": particles,
        "dbcslam": dbc,
        "blackbox_pgs": {"_simulate": 0.8 * pgs, "step": pgs, "other": 0.2 * pgs},
    }


def test_reading_says_where_the_time_goes_from_the_profile() -> None:
    profile = [
        _profile_row("edge", 100, 0.2, 0.5, 0.25),
        _profile_row("edge", 10000, 12.0, 16.0, 3.5),
    ]
    result = {"scaling": [_row("edge", 100, 0.5, 10.0, 0.25)], "accuracy": [], "meta": META}
    result["profile"] = profile
    text = "\n".join(reading_lines(result))
    assert "take 40%-75% of DBC-SLAM's step" in text
    assert "(12.00 of 16.00 ms at 10000 particles, where the PGS box's whole step takes" in text
    assert "takes 0.30 ms at 100 particles (the PGS box's whole step 0.25 ms)" in text
    md = render_markdown(result, "python -m dbcslam_research.bench")
    assert "## Where the time goes" in md and "| edge | 10000 | 16.000 |" in md

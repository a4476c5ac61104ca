"""`dbcslam_research.tracking_health`: the surprise of the filter's steps on pybullet runs
(items, report, command)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from dbcslam_core.surprise import SurpriseMonitor
from dbcslam_research.tracking_health import main, parse_items, render_markdown, surprises


def test_items_parse_and_bad_ones_name_what_is_valid() -> None:
    assert parse_items(["edge:1000", "gripper:40"]) == [("edge", 1000), ("gripper", 40)]
    for bad in ("edge", "edge:0", "table:10", "push:many"):
        with pytest.raises(ValueError, match=repr(bad)):
            parse_items([bad])


def test_surprises_are_the_monitor_s() -> None:
    lls = [5.0, 6.0, 4.0, 5.5, 5.0, -20.0, 5.0]
    mon = SurpriseMonitor()
    assert surprises(lls).tolist() == [mon.update(x) for x in lls]
    assert surprises(lls)[5] == pytest.approx(25.0)


def _row(kind: str, seed: int, peak: float, rmse: float, p_true: float | None) -> dict[str, Any]:
    return {
        "scenario": kind,
        "particles": 40,
        "seed": seed,
        "surprise_max": peak,
        "surprised_steps": int(peak > 10.0),
        "position_rmse_over_noise": rmse,
        "p_true_final": p_true,
    }


def test_report_lists_the_flagged_runs_and_the_wrong_coefficients() -> None:
    result = {
        "date": "2026-11-28 12:00 UTC",
        "wall_s": 3.0,
        "sim_set": {"jaw_mu": 0.1},
        "runs": [
            _row("gripper", 0, 120.0, 1.6, 0.0),
            _row("gripper", 1, 6.0, 0.5, 1.0),
            _row("gripper", 2, 7.0, 0.7, 0.2),
        ],
    }
    md = render_markdown(result, "cmd")
    assert "| gripper | 40 | 3 | 7.0 / 120.0 | 1 | 0: 1.60 | 0.70 | 1 / 1 |" in md


def test_command_writes_the_report(tmp_path: Path) -> None:
    pytest.importorskip("pybullet")
    assert (
        main(["edge:30", "--seeds", "1", "--workers", "1", "--out", str(tmp_path), "--quiet"]) == 0
    )
    report = json.loads((tmp_path / "tracking_health.json").read_text(encoding="utf-8"))
    (row,) = report["runs"]
    assert (row["scenario"], row["particles"], row["seed"]) == ("edge", 30, 0)
    assert row["surprise_max"] >= 0.0 and row["position_rmse_over_noise"] > 0.0
    assert "| edge | 30 | 1 |" in (tmp_path / "tracking_health.md").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["edge:x"], "PARTICLES must be an integer"),
        (["gripper:40", "--sim-set", "jaw_friction=0.1"], "not parameters of the gripper"),
        (["--seeds", "0"], "--seeds and --workers must be >= 1"),
    ],
)
def test_bad_arguments_exit_2(
    args: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        main([*args, "--quiet"])
    assert exc.value.code == 2
    assert says in capsys.readouterr().err

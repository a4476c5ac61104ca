"""`dbcslam_research.mitpush_gain`: tracking gain of an extended model from two eval runs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dbcslam_research.mitpush_gain import compare, main


def _eval(path: Path, yaw: dict[str, float]) -> Path:
    pushes = [
        {
            "name": n,
            "metrics": {
                "position_rmse_m": 0.001,
                "yaw_rmse_rad": y,
                "position_rmse_over_noise": 0.2,
                "yaw_rmse_over_noise": y / 0.05,
            },
        }
        for n, y in yaw.items()
    ]
    path.mkdir()
    (path / "mitpush.json").write_text(json.dumps({"pushes": pushes}))
    return path


def test_gain_is_the_ratio_of_rms_over_the_pushes(tmp_path: Path) -> None:
    nom = _eval(tmp_path / "n", {"a": 0.03, "b": 0.04, "c": 0.10})
    ext = _eval(tmp_path / "e", {"a": 0.03, "b": 0.04, "c": 0.02})
    (pair,) = compare([nom], [ext], {"held out": ["c"], "fitted": ["a", "b"]})
    held, fit = pair["groups"]["held out"], pair["groups"]["fitted"]
    assert held["yaw_gain"] == pytest.approx(5.0)
    assert fit["yaw_gain"] == pytest.approx(1.0) and fit["position_gain"] == pytest.approx(1.0)
    assert held["worse_than_noise"] == [1, 0]
    (only,) = compare([nom], [ext], None)
    assert only["groups"]["all"]["pushes"] == 3


def test_cli_reads_the_split_from_the_report_and_rejects_bad_input(tmp_path: Path) -> None:
    nom = _eval(tmp_path / "n", {"p1": 0.05, "p2": 0.02})
    ext = _eval(tmp_path / "e", {"p1": 0.025, "p2": 0.02})
    report = tmp_path / "r.json"
    report.write_text(json.dumps({"bags": {"fit": ["/x/p2"], "heldout": ["/x/p1"]}}))
    out = tmp_path / "out"
    args = ["--nominal", str(nom), "--extended", str(ext), "--out", str(out)]
    assert main([*args, "--discrepancy", str(report)]) == 0
    data = json.loads((out / "gain.json").read_text())
    assert data[0]["groups"]["held out"]["yaw_gain"] == pytest.approx(2.0)
    assert "| 0: held out | 1 |" in (out / "gain.md").read_text()
    assert main(["--nominal", str(nom), str(nom), "--extended", str(ext), "--out", str(out)]) == 2
    report.write_text(json.dumps({"bags": {"fit": [], "heldout": ["/x/p9"]}}))
    assert main([*args, "--discrepancy", str(report)]) == 2

"""`dbcslam_research.friction_calibration`: DBC-SLAM's final friction posterior against the
per-run verdict of the fixed-friction filters (counts, calibration gap, report, command)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from dbcslam_research.friction_calibration import (
    compare,
    default_out,
    load_verdicts,
    main,
    render_markdown,
)


def _verdict(run: int, p_true: float, true: int = 1) -> dict[str, Any]:
    return {"run": run, "true": true, "p_true": p_true}


def _final(run: int, post: list[float], particles: int = 40) -> dict[str, Any]:
    return {"run": run, "particles": particles, "posterior": post, "true": 1}


def test_compare_separates_decided_and_undecided_runs() -> None:
    verdicts = [_verdict(0, 0.99), _verdict(1, 0.95), _verdict(2, 0.6), _verdict(3, 0.3)]
    finals = [
        _final(0, [0.0, 1.0, 0.0]),  # decided, right
        _final(1, [1.0, 0.0, 0.0]),  # decided, confidently wrong
        _final(2, [0.0, 0.95, 0.05]),  # undecided, confident on the true one (lucky)
        _final(3, [0.2, 0.5, 0.3]),  # undecided, not confident
        _final(0, [0.0, 1.0, 0.0], particles=500),
    ]
    by_p = {c["particles"]: c for c in compare(verdicts, finals)}
    c = by_p[40]
    assert c["runs"] == 4
    assert c["ends_right"] == 2
    assert (c["decided"], c["right_where_decided"]) == (2, 1)
    assert (c["undecided"], c["confident_where_undecided"]) == (2, 1)
    assert c["confidently_wrong"] == 1
    assert c["calibration_gap"] == pytest.approx((0.01 + 0.95 + 0.35 + 0.2) / 4)
    assert [o["run"] for o in c["off_by_more_than_half"]] == [1]
    assert by_p[500]["runs"] == 1
    md = render_markdown(
        {
            "date": "x",
            "wall_s": 1.0,
            "evidence": "e.json",
            "verdict_particles": 4000,
            "sim_set": {"jaw_mu": 0.7},
            "overrides": {},
            "comparison": compare(verdicts, finals),
        },
        "cmd",
    )
    assert "| 40 | 4 | 2 | 1 of 2 | 1 of 2 | 1 | 0.38 | 1 (0.00 / 0.95) |" in md
    assert "simulator overrides: jaw_mu=0.7; filter overrides: none" in md


def test_compare_refuses_a_run_without_verdict() -> None:
    with pytest.raises(ValueError, match=r"runs \[7\] have no verdict"):
        compare([_verdict(0, 0.99)], [_final(7, [0.0, 1.0, 0.0])])


def test_compare_refuses_runs_with_another_true_coefficient() -> None:
    final = _final(0, [0.0, 1.0, 0.0])  # true index 1
    with pytest.raises(ValueError, match=r"runs \[0\]: the filter's true coefficient"):
        compare([_verdict(0, 0.99, true=2)], [final])


def test_default_out_keeps_variants_apart(tmp_path: Path) -> None:
    ev = tmp_path / "gripper_evidence.json"
    assert default_out(ev, {}) == tmp_path
    out = default_out(ev, {"bank_resampling": "hypothesis", "friction_bank": True})
    assert out == tmp_path / "calibration_bank_resampling=hypothesis_friction_bank=True"


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (None, "cannot read"),
        ("not json", "cannot read"),
        ('{"evidence": []}', "no per-run verdicts"),
    ],
)
def test_unusable_evidence_exits_2(
    tmp_path: Path, content: str | None, says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    path = tmp_path / "gripper_evidence.json"
    if content is not None:
        path.write_text(content, encoding="utf-8")
        with pytest.raises(ValueError, match=says):
            load_verdicts(path)
    with pytest.raises(SystemExit) as exc:
        main(["--evidence", str(path), "--quiet"])
    assert exc.value.code == 2
    assert says in capsys.readouterr().err


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--particles", "40", "500", "--set", "bank_switch=0.01"], "at 500 particles"),
        (["--set", "particles=80"], "the particle count is --particles"),
    ],
)
def test_filter_settings_are_checked_at_the_counts_that_run(
    tmp_path: Path, args: list[str], says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    evidence = {
        "sim_set": {},
        "verdict_particles": 1000,
        "cause": {"candidates": [0.1, 0.4, 0.7]},
        "verdicts": [{"run": 0, "true": 1, "p_true": 0.97}],
    }
    path = tmp_path / "gripper_evidence.json"
    path.write_text(json.dumps(evidence), encoding="utf-8")
    with pytest.raises(SystemExit) as exc:
        main(["--evidence", str(path), "--quiet", *args])
    assert exc.value.code == 2
    assert says in capsys.readouterr().err


def test_command_runs_the_evidence_runs_with_their_simulator_overrides(
    tmp_path: Path,
) -> None:
    pytest.importorskip("pybullet")
    evidence = {
        # start as JSON writes a tuple: a list (the simulator's default grasp)
        "sim_set": {"jaw_mu": 0.7, "duration": 0.6, "start": [0.0, 0.0, 0.35]},
        "verdict_particles": 1000,
        "cause": {"candidates": [0.1, 0.4, 0.7]},
        "verdicts": [{"run": 0, "true": 2, "p_true": 0.97}],
    }
    path = tmp_path / "gripper_evidence.json"
    path.write_text(json.dumps(evidence), encoding="utf-8")
    assert main(["--evidence", str(path), "--particles", "20", "--workers", "1", "--quiet"]) == 0
    report = json.loads((tmp_path / "friction_calibration.json").read_text(encoding="utf-8"))
    (final,) = report["finals"]
    assert final["true"] == 2  # the simulator ran with jaw_mu 0.7
    assert sum(final["posterior"]) == pytest.approx(1.0)
    assert report["comparison"][0]["runs"] == 1
    assert "| 20 | 1 |" in (tmp_path / "friction_calibration.md").read_text(encoding="utf-8")

"""Smoke test of `python -m dbcslam_research.experiments`: tiny run, files appear, table parses."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dbcslam_research.experiments import main


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("experiments")
    rc = main(["--out", str(out), "--seeds", "1", "--particles", "8", "--steps", "25", "--quiet"])
    assert rc == 0
    return out


def test_table_files_parse(out_dir: Path) -> None:
    data = json.loads((out_dir / "experiments.json").read_text())
    assert data["config"]["particles"] == 8
    assert {r["scenario"] for r in data["runs"]} == {"edge", "gripper"}
    methods = {r["method"] for r in data["runs"] if r["scenario"] == "edge"}
    assert methods == {"dbcslam", "fixed_mu_0.3", "fixed_mu_0.9"}
    labels = [t["target"] for t in data["targets"]]
    assert any("friction map" in lab for lab in labels)
    for t in data["targets"]:
        assert t["passed"] in (True, False, None)
    md = (out_dir / "experiments.md").read_text()
    rows = [
        ln for ln in md.splitlines() if ln.startswith("| edge |") or ln.startswith("| gripper |")
    ]
    assert len(rows) >= len(data["targets"])
    target_rows = rows[: len(data["targets"])]
    for row in target_rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[-1] in ("PASS", "FAIL", "report")


def test_figures_written(out_dir: Path) -> None:
    pngs = sorted(p.name for p in out_dir.glob("*.png"))
    for name in (
        "edge_trajectory.png",
        "edge_x_time.png",
        "edge_contact.png",
        "edge_sticking.png",
        "edge_friction.png",
        "gripper_com.png",
        "gripper_yaw.png",
        "gripper_friction.png",
        "gripper_hypotheses.png",
        "edge_overview.png",
        "gripper_overview.png",
    ):
        assert name in pngs
        assert (out_dir / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_arguments_exit_2(tmp_path: Path) -> None:
    assert main(["--out", str(tmp_path), "--scenarios", "nope", "--quiet"]) == 2
    assert not list(tmp_path.iterdir())


def test_bench_smoke(tmp_path: Path) -> None:
    from dbcslam_research.bench import main as bench_main

    argv = ["--out", str(tmp_path), "--particles", "4,6", "--steps", "6", "--warmup", "1"]
    argv += ["--lemke-max", "4", "--accuracy-particles", "0", "--scenarios", "edge", "--quiet"]
    argv += ["--profile-particles", "5"]
    assert bench_main(argv) == 0
    data = json.loads((tmp_path / "bench.json").read_text())
    rows = data["scaling"]
    assert [r["particles"] for r in rows] == [4, 6]
    assert rows[0]["blackbox_lemke_ms"] is not None
    assert rows[1]["blackbox_lemke_ms"] is None  # above --lemke-max: not run
    assert all(r["dbcslam_ms"] > 0 and r["dbcslam_1thread_ms"] > 0 for r in rows)
    md = (tmp_path / "bench.md").read_text()
    assert "| edge | 4 |" in md
    assert [(r["scenario"], r["particles"]) for r in data["profile"]] == [("edge", 5)]
    assert "## Where the time goes" in md and "| edge | 5 |" in md


def test_set_overrides_reach_the_filter(tmp_path: Path) -> None:
    argv = ["--out", str(tmp_path), "--seeds", "1", "--particles", "8", "--steps", "25"]
    argv += ["--scenarios", "edge", "--no-fixed", "--no-figures", "--quiet"]
    assert main([*argv, "--set", "max_hypotheses=1"]) == 0
    data = json.loads((tmp_path / "experiments.json").read_text())
    assert data["config"]["filter_overrides"] == {"edge": {"max_hypotheses": 1}}
    (run,) = data["runs"]
    assert run["metrics"]["live_hypotheses"] == pytest.approx(1.0)  # the cap took effect


@pytest.mark.parametrize(
    ("item", "expected"),
    [
        ("prune_threshold=0.01", {"prune_threshold": 0.01}),
        ("process_noise=(0.02, 0.02, 0.5)", {"process_noise": (0.02, 0.02, 0.5)}),
        ("resampler=residual", {"resampler": "residual"}),
        ("smoothed_joint_velocity=False", {"smoothed_joint_velocity": False}),
    ],
)
def test_parse_overrides(item: str, expected: dict[str, object]) -> None:
    from dbcslam_research.experiments import parse_overrides

    assert parse_overrides([item], ["edge", "gripper"]) == expected


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("prune=0.01", "KEY one of"),
        ("prune_threshold", "KEY one of"),
        ("particles=80", "the particle count is --particles"),
        ("resampler=nope", "nope"),
        ("friction_bank=True", "parameter_model"),
    ],
)
def test_parse_overrides_names_the_bad_item(item: str, message: str) -> None:
    from dbcslam_research.experiments import parse_overrides

    with pytest.raises(ValueError, match=message) as exc:
        parse_overrides([item], ["edge"])
    assert repr(item) in str(exc.value)


@pytest.mark.parametrize(
    ("particles", "refused_at"),
    [((40,), None), ((40, 100), None), ((40, 500), 500), ((500,), 500), ((), "default")],
)
def test_parse_overrides_checks_the_counts_that_run(
    particles: tuple[int, ...], refused_at: int | str | None
) -> None:
    """The gripper preset turns the friction bank on below 200 particles, so a bank option
    is valid at 40 and not at 500: it is checked at the counts the command runs (the
    preset's default 500 when none is given)."""
    from dbcslam_research.experiments import parse_overrides

    if refused_at is None:
        assert parse_overrides(["bank_switch=0.001"], ["gripper"], particles) == {
            "bank_switch": 0.001
        }
        return
    where = "preset: " if refused_at == "default" else f"preset at {refused_at} particles: "
    with pytest.raises(ValueError, match=where + "bank_switch acts only") as exc:
        parse_overrides(["bank_switch=0.001"], ["gripper"], particles)
    assert "'bank_switch=0.001'" in str(exc.value)


def test_shared_report_helpers(tmp_path: Path) -> None:
    import math

    import numpy as np

    from dbcslam_core.experiments import RunRecord, Target, TargetCheck
    from dbcslam_research.experiments import (
        fmt_value,
        json_safe,
        parse_scenarios,
        report_payload,
        report_sections,
        verdict,
        write_json,
    )

    assert [fmt_value(x) for x in (math.nan, 1234.5, 0.5, 2e-5)] == [
        "n/a",
        "1234",
        "0.500",
        "2e-05",
    ]
    checks = [
        TargetCheck(Target("edge", "pos", "position_rmse_ratio", "<=", 0.5), 0.3, True),
        TargetCheck(Target("edge", "hyp", "live_hypotheses", "report", math.nan), 4.0, None),
    ]
    assert [verdict(c) for c in checks] == ["PASS", "report"]
    recs = [
        RunRecord(
            "edge", s, "dbcslam", 9, {"position_rmse": 0.002 * (s + 1), "obs_position_rmse": 0.01}
        )
        for s in range(3)
    ]
    lines = report_sections(recs, checks)
    assert "| edge | pos | 0.300 | <= 0.500 | PASS |" in lines
    assert "| edge | hyp | 4.000 | - | report |" in lines
    assert "| method | pos RMSE [mm] | obs RMSE [mm] |" in lines
    assert "| dbcslam | 4.000 | 10.000 |" in lines  # medians over seeds
    assert "| edge | 2 | dbcslam | 6.000 |  |" in lines
    assert parse_scenarios(" gripper,edge ", ("edge", "gripper")) == ("gripper", "edge")
    for bad in ("", "edge,push"):
        with pytest.raises(ValueError, match="valid"):
            parse_scenarios(bad, ("edge", "gripper"))
    payload = report_payload("cmd", 1.5, {"seeds": (0, 1)}, checks, recs)
    assert payload["summary"]["edge"]["dbcslam"]["n_seeds"] == 3.0
    assert json_safe({1: (np.float64(2.0), math.inf)}) == {"1": [2.0, None]}
    data = json.loads(write_json(tmp_path / "r.json", payload).read_text())
    assert data["config"] == {"seeds": [0, 1]} and data["date_utc"].endswith("UTC")
    assert data["targets"][1]["passed"] is None


def test_figure_trace_attaches_better_fixed_baseline() -> None:
    from dataclasses import replace

    from dbcslam_core.experiments import run_task
    from dbcslam_research.experiments import figure_trace

    traces = {}
    for method in ("dbcslam", "fixed:0", "fixed:1"):
        rec, tr, _ = run_task("edge", 0, method, particles=5, n_steps=8)
        traces[("edge", 0, rec.method)] = tr
    far = traces[("edge", 0, "fixed_mu_0.9")]
    traces[("edge", 0, "fixed_mu_0.9")] = replace(far, est_q=far.est_q + 1.0)
    out = figure_trace(traces, "edge", 0)
    assert out.baseline_q is not None
    np_est = traces[("edge", 0, "fixed_mu_0.3")].est_q
    assert (out.baseline_q == np_est).all()
    assert "0.3" in out.baseline_label

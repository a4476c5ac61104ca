"""Tests of dbcslam_research.readme_results: the README results section generator."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from dbcslam_research.readme_results import (
    MARKER_BEGIN,
    MARKER_END,
    figure_caption,
    main,
    render_results,
    replace_between_markers,
    update_readme,
)

PNG = b"\x89PNG\r\n\x1a\n" + b"\0" * 16


def _targets(value: float) -> list[dict[str, object]]:
    return [
        {
            "scenario": "edge",
            "target": "position RMSE <= 0.5 x noise std",
            "metric": "position_rmse_ratio",
            "op": "<=",
            "threshold": 0.5,
            "value": value,
            "passed": value <= 0.5,
        },
        {
            "scenario": "gripper",
            "target": "live hypotheses",
            "metric": "live_hypotheses",
            "op": "report",
            "threshold": None,
            "value": 6.0,
            "passed": None,
        },
    ]


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A fake checkout: README with markers and a results dir with core results only."""
    res = tmp_path / "dbcslam_ros" / "research" / "results"
    res.mkdir(parents=True)
    payload = {
        "command": "python -m dbcslam_research.experiments --seeds 5",
        "date_utc": "2026-11-21 06:45 UTC",
        "elapsed_s": 120.0,
        "targets": _targets(0.26),
    }
    (res / "experiments.json").write_text(json.dumps(payload))
    (res / "experiments.md").write_text("# x\n")
    for name in ("edge_overview.png", "edge_friction.png", "gripper_yaw.png"):
        (res / name).write_bytes(PNG)
    (res / "bench.md").write_text(
        "# DBC-SLAM benchmark\n\nCommand: `python -m dbcslam_research.bench --repeat 2`\n\n"
        "## Per-step time\n\n| a | b |\n|---|---|\n| 1 | 2 |\n"
    )
    (res / "bench.json").write_text(json.dumps({"meta": {"date_utc": "2026-11-21 06:30 UTC"}}))
    readme = tmp_path / "README.md"
    readme.write_text(f"# Title\n\nintro\n\n{MARKER_BEGIN}\nold text\n{MARKER_END}\n\n## After\n")
    return tmp_path


def test_rewrites_only_between_markers(repo: Path) -> None:
    readme = repo / "README.md"
    res = repo / "dbcslam_ros" / "research" / "results"
    assert update_readme(readme, res) == "updated"
    text = readme.read_text()
    head, rest = text.split(MARKER_BEGIN)
    body, tail = rest.split(MARKER_END)
    assert head == "# Title\n\nintro\n\n"
    assert tail == "\n\n## After\n"
    assert "old text" not in body
    assert "`python -m dbcslam_research.experiments --seeds 5`" in body
    assert "2026-11-21 06:45 UTC" in body
    assert "| edge | position RMSE <= 0.5 x noise std | 0.260 | <= 0.500 | PASS |" in body
    assert "| gripper | live hypotheses | 6.000 | - | report |" in body
    # figures: relative paths; overview embedded, panels linked, each with a caption
    assert "](dbcslam_ros/research/results/edge_overview.png)" in body
    assert body.count("![") == 1
    assert "- [edge_friction.png](dbcslam_ros/research/results/edge_friction.png): Edge" in body
    assert "friction map along the edge" in body
    assert (
        "- [gripper_yaw.png](dbcslam_ros/research/results/gripper_yaw.png): Parallel-jaw" in body
    )
    # bench: title dropped, headings demoted, date from bench.json, no sim section
    assert "#### Per-step time" in body and "# DBC-SLAM benchmark" not in body
    assert "Date: 2026-11-21 06:30 UTC." in body
    assert "pybullet data" not in body
    # idempotent
    assert update_readme(readme, res) == "unchanged"
    assert readme.read_text() == text


def test_optional_sections_and_check(repo: Path) -> None:
    readme = repo / "README.md"
    res = repo / "dbcslam_ros" / "research" / "results"
    update_readme(readme, res)
    sim = res / "sim"
    sim.mkdir()
    (sim / "experiments_sim.json").write_text(
        json.dumps(
            {"command": "python -m dbcslam_research.experiments_sim", "targets": _targets(0.7)}
        )
    )
    (sim / "sim_push_offcentre_yaw.png").write_bytes(PNG)
    (res / "bench_live.md").write_text("# Live\n\nDate: today; rate 100 Hz\n")
    assert main(["--readme", str(readme), "--results", str(res), "--check"]) == 1
    assert "pybullet data" not in readme.read_text()
    assert main(["--readme", str(readme), "--results", str(res)]) == 0
    body = readme.read_text()
    assert "`python -m dbcslam_research.experiments_sim`" in body
    assert "(file time)" in body  # no date_utc in the sim JSON: file modification time
    assert "| edge | position RMSE <= 0.5 x noise std | 0.700 | <= 0.500 | FAIL |" in body
    assert (
        "](dbcslam_ros/research/results/sim/sim_push_offcentre_yaw.png): Planar push, off" in body
    )
    assert "Date: today; rate 100 Hz" in body
    assert main(["--readme", str(readme), "--results", str(res), "--check"]) == 0
    # a report that states its own date gets no extra Date line
    (res / "bench_live.md").write_text("# Live\n\nCommand: `x`; 2026-11-21 06:53 UTC\n")
    update_readme(readme, res)
    live = readme.read_text().split("### Live timing")[1]
    assert "Date:" not in live and "2026-11-21 06:53 UTC" in live


def test_no_markers_leaves_readme_alone(repo: Path, capsys: pytest.CaptureFixture[str]) -> None:
    readme = repo / "README.md"
    readme.write_text(f"# Title\n{MARKER_END}\n{MARKER_BEGIN}\n")  # wrong order
    before = readme.read_text()
    assert main(["--readme", str(readme), "--results", str(repo)]) == 0
    assert readme.read_text() == before
    assert "not found" in capsys.readouterr().out
    assert replace_between_markers("no markers", "x") is None


def test_missing_results_and_bad_files(repo: Path, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    text = render_results(empty, repo)
    assert "run `make experiments`" in text
    res = repo / "dbcslam_ros" / "research" / "results"
    (res / "experiments.json").write_text("{not json")
    assert main(["--readme", str(repo / "README.md"), "--results", str(res)]) == 2
    assert main(["--readme", str(tmp_path / "nope.md"), "--results", str(res)]) == 2


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        ("edge_overview.png", "Edge (table polishing) (synthetic data): x-y path, x over"),
        ("sim_push_offcentre_overview.png", "off-centre (pybullet data): object path, yaw"),
        ("other_overview.png", "other (synthetic data): all panels"),
        ("sim_edge_x_time.png", "Edge (table polishing) (pybullet data): x over time"),
        ("gripper_friction.png", "(true mu = 0.4)"),
        ("sim_push_friction.png", "Planar push (pybullet data): posterior of the pusher"),
        ("gripper_hypotheses.png", "live joint contact-mode hypotheses"),
        ("weird.png", "figure weird.png"),
    ],
)
def test_figure_caption(name: str, expected: str) -> None:
    cap = figure_caption(name)
    assert expected in cap
    assert "\n" not in cap and cap.endswith(".")

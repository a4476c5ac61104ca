"""Smoke test of `python -m dbcslam_research.experiments_sim`: tiny pybullet run, files appear,
table parses, bad arguments exit 2."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pybullet")

from dbcslam_research.experiments_sim import (
    SIM_TARGETS,
    ForceFedFilter,
    SimExperimentConfig,
    _segments_truth,
    _sim_spec,
    main,
    parse_sim_overrides,
    sim_trajectory,
)


@pytest.fixture(scope="module")
def out_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("experiments_sim")
    argv = ["--out", str(out), "--seeds", "1", "--particles", "8", "--duration", "0.5"]
    rc = main([*argv, "--workers", "1", "--quiet"])
    assert rc == 0
    return out


def test_table_files_parse(out_dir: Path) -> None:
    data = json.loads((out_dir / "experiments_sim.json").read_text())
    assert data["config"]["particles"] == 8
    assert data["config"]["duration"] == 0.5
    assert {r["scenario"] for r in data["runs"]} == {"edge", "gripper", "push", "push_offcentre"}
    methods = {(r["scenario"], r["method"]) for r in data["runs"]}
    assert ("edge", "fixed_mu_0.3") in methods
    assert ("edge", "fixed_mu_0.9") in methods
    assert ("push", "dbcslam_no_force") in methods
    assert len(data["targets"]) == len(SIM_TARGETS)
    for t in data["targets"]:
        assert t["passed"] in (True, False, None)
    for r in data["runs"]:
        rmse = r["metrics"]["position_rmse"]
        assert rmse is not None and 0.0 < rmse < 1.0
    md = (out_dir / "experiments_sim.md").read_text()
    heads = ("| edge |", "| gripper |", "| push |", "| push_offcentre |")
    rows = [ln for ln in md.splitlines() if ln.startswith(heads)]
    target_rows = rows[: len(data["targets"])]
    assert len(target_rows) == len(data["targets"])
    for row in target_rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[-1] in ("PASS", "FAIL", "report")


def test_figures_written(out_dir: Path) -> None:
    for scen in ("edge", "gripper", "push", "push_offcentre"):
        name = f"sim_{scen}_overview.png"
        assert (out_dir / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_arguments_exit_2(tmp_path: Path) -> None:
    assert main(["--out", str(tmp_path), "--scenarios", "nope", "--quiet"]) == 2
    assert main(["--out", str(tmp_path), "--particles", "0", "--quiet"]) == 2
    assert main(["--out", str(tmp_path), "--push-support-pair", "pusher", "--quiet"]) == 2


def test_segment_truth_marks_seam_cells_impure() -> None:
    class _Trace:
        map_edges = np.array([-0.1, 0.0, 0.1, 0.2, 0.25, 0.35, 0.4])
        candidates = (0.3, 0.9)

    segs = ((-5.0, 0.0, 0.3), (0.0, 0.3, 0.9), (0.3, 5.0, 0.3))
    idx, pure = _segments_truth(_Trace(), segs)  # type: ignore[arg-type]
    assert pure.tolist() == [True, True, True, True, False, True]
    assert idx.tolist()[:4] == [0, 1, 1, 1]
    assert idx[-1] == 0


def test_force_fed_filter_passes_force_of_step_k() -> None:
    seen: list[tuple[float, float, float | None]] = []

    class _Filt:
        def initialize(self, *args: object, **kwargs: object) -> None:
            pass

        def step(self, obs: object, inp: object, force: object) -> object:
            seen.append((force.fx, force.fy, force.std))  # type: ignore[attr-defined]
            return None

    force = np.array([[0.0, 0.0], [1.0, 2.0], [3.0, 4.0]])
    fed = ForceFedFilter(_Filt(), force, 0.05)  # type: ignore[arg-type]
    fed.initialize(None, None)
    fed.step(None, None)  # type: ignore[arg-type]
    fed.step(None, None)  # type: ignore[arg-type]
    assert seen == [(1.0, 2.0, 0.05), (3.0, 4.0, 0.05)]


def test_push_force_reading_matches_truth_in_contact() -> None:
    tr, params, force = sim_trajectory("push", 0, overrides={"support_pair": "surface"})
    assert force.shape == (tr.n_steps, 2)
    in_contact = tr.modes[:, 0] != 0
    assert in_contact.any() and (~in_contact).any()
    # quasi-static push: |F| ~ mu_surface m g
    expected = params.mu_surface * tr.scenario.body.mass * tr.scenario.gravity
    assert math.isclose(float(np.median(np.abs(force[in_contact, 1]))), expected, rel_tol=0.1)
    assert float(np.max(np.abs(force[~in_contact]))) < 6 * params.noise.force


def test_set_overrides_reach_every_filter_run(tmp_path: Path) -> None:
    argv = ["--out", str(tmp_path), "--seeds", "1", "--particles", "8", "--duration", "0.5"]
    argv += ["--scenarios", "edge,push", "--workers", "1", "--no-figures", "--quiet"]
    assert main([*argv, "--set", "max_hypotheses=1"]) == 0
    data = json.loads((tmp_path / "experiments_sim.json").read_text())
    assert data["config"]["filter_overrides"] == {"max_hypotheses": 1}
    methods = {r["method"] for r in data["runs"]}
    assert {"dbcslam", "fixed_mu_0.3", "dbcslam_no_force"} <= methods  # every kind of run
    for r in data["runs"]:  # the cap took effect in each
        assert r["metrics"]["live_hypotheses"] == pytest.approx(1.0), r["method"]
    assert '"max_hypotheses": 1' in (tmp_path / "experiments_sim.md").read_text()


def test_set_with_a_bad_key_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["--out", str(tmp_path), "--scenarios", "gripper", "--set", "nope=1", "--quiet"]
    assert main(argv) == 2
    assert "--set 'nope=1'" in capsys.readouterr().err


def test_sim_set_reaches_the_simulator(tmp_path: Path) -> None:
    argv = ["--out", str(tmp_path), "--seeds", "1", "--particles", "8", "--duration", "0.3"]
    argv += ["--scenarios", "gripper", "--workers", "1", "--no-figures", "--quiet"]
    assert main([*argv, "--sim-set", "jaw_mu=0.7"]) == 0
    data = json.loads((tmp_path / "experiments_sim.json").read_text())
    assert data["config"]["sim_overrides"]["gripper"] == {"jaw_mu": 0.7}
    given = data["config"]["sim_overrides"]
    cfg = SimExperimentConfig(scenarios=("gripper",), sim_overrides=given)
    sim, overrides = _sim_spec(cfg, "gripper")
    tr, _, _ = sim_trajectory(sim, 0, duration=0.1, overrides=overrides)
    assert tr.mu_pair.tolist() == [0.7]  # the truth the runs were scored against


@pytest.mark.parametrize(
    ("item", "says"),
    [
        ("jaw_muu=0.7", "valid: "),  # names the simulator's parameters
        ("jaw_mu", "expected KEY=VALUE"),
        ("jaw_mu=-1", "out of range"),
    ],
)
def test_sim_set_bad_item_exits_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], item: str, says: str
) -> None:
    argv = ["--out", str(tmp_path), "--scenarios", "gripper", "--sim-set", item, "--quiet"]
    assert main(argv) == 2
    assert says in capsys.readouterr().err
    assert not (tmp_path / "experiments_sim.json").exists()


def test_parse_sim_overrides_reads_literals() -> None:
    got = parse_sim_overrides(["jaw_mu=0.7", "jaw_speed = 0.02", "name=abc"])
    assert got == {"jaw_mu": 0.7, "jaw_speed": 0.02, "name": "abc"}

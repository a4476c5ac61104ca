"""Tests of dbcslam_core.experiments: scoring, summaries, targets and a tiny driver run."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from dbcslam_core.errors import ModelError
from dbcslam_core.experiments import (
    TARGETS,
    ExperimentConfig,
    RunRecord,
    RunTrace,
    edge_targets,
    evaluate_targets,
    experiment_tasks,
    make_trajectory,
    representative_seed,
    rmse_target,
    run_black_box,
    run_experiments,
    run_fixed_friction,
    run_parallel,
    run_task,
    score,
    summarize,
)


def perfect_trace(scenario: str, n_steps: int = 60) -> RunTrace:
    """A trace whose estimates equal the truth (built from the synthetic trajectory)."""
    tr = make_trajectory(scenario, 0, n_steps)
    q = tr.q[1:]
    modes = np.eye(4)[tr.modes[1:]]
    cands = tuple(tr.scenario.friction.candidates[0])
    ti = np.argmin(np.abs(tr.mu[1:, :1] - np.asarray(cands)), axis=-1)
    return RunTrace(
        scenario=scenario,
        seed=0,
        method="oracle",
        particles=1,
        t=tr.t[1:],
        true_q=q,
        obs_q=tr.obs[1:],
        est_q=q.copy(),
        est_modes=modes,
        true_modes=tr.modes[1:],
        true_s=q[:, :1].repeat(tr.scenario.n_contacts, axis=1),
        friction_post=np.eye(len(cands))[ti],
        true_mu=tr.mu[1:],
        candidates=cands,
        true_friction_index=1 if scenario == "gripper" else -1,
        live_hypotheses=np.ones(n_steps - 1),
        step_time=np.full(n_steps - 1, 1e-3),
        noise_position=tr.scenario.noise.position,
        noise_yaw=tr.scenario.noise.yaw,
    )


def test_score_perfect_edge() -> None:
    m = score(perfect_trace("edge"))
    assert m["position_rmse"] == 0.0
    assert m["contact_accuracy"] == 1.0
    assert m["contact_mode_accuracy"] == 1.0
    assert m["stick_slide_accuracy"] == 1.0
    assert m["true_friction_posterior_mean"] == 1.0
    assert m["obs_position_rmse"] > 0.0
    assert m["step_time_ms"] == pytest.approx(1.0)
    assert "friction_map_accuracy" not in m  # the oracle trace carries no map


def test_score_edge_friction_map() -> None:
    tr = perfect_trace("edge", 200)
    edges = np.linspace(0.0, 1.0, 51)
    centres = 0.5 * (edges[1:] + edges[:-1])
    rough = (centres >= 0.45) & (centres <= 0.85)
    post = np.stack([np.where(rough, 0.1, 0.9), np.where(rough, 0.9, 0.1)], -1)
    good = replace(tr, map_edges=edges, map_post=post)
    m = score(good)
    assert m["friction_map_accuracy"] == 1.0
    assert m["friction_map_cells"] > 0
    bad = replace(tr, map_edges=edges, map_post=post[:, ::-1])
    assert score(bad)["friction_map_accuracy"] == 0.0


def test_score_gripper_yaw_and_friction() -> None:
    tr = perfect_trace("gripper")
    shifted = tr.est_q.copy()
    shifted[:, 2] += 0.01
    m = score(replace(tr, est_q=shifted))
    assert m["yaw_rmse"] == pytest.approx(0.01)
    assert m["yaw_rmse_ratio"] == pytest.approx(0.01 / tr.noise_yaw)
    assert m["final_true_friction_posterior"] in (0.0, 1.0)


@pytest.mark.parametrize("winner", [0, 1, 2])
def test_score_names_the_coefficient_a_run_ends_on(winner: int) -> None:
    tr = perfect_trace("gripper")
    post = np.full_like(tr.friction_post, 0.1)
    post[-1, winner] = 0.8
    m = score(replace(tr, friction_post=post))
    assert m["final_friction_argmax"] == tr.candidates[winner]
    assert m["final_true_friction_posterior"] == pytest.approx(post[-1, tr.true_friction_index])


def rec(scen: str, seed: int, method: str, **metrics: float) -> RunRecord:
    return RunRecord(scen, seed, method, 10, dict(metrics))


def test_summarize_medians_ignore_nan() -> None:
    recs = [
        rec("edge", 0, "dbcslam", position_rmse=1.0, x=math.nan),
        rec("edge", 1, "dbcslam", position_rmse=3.0, x=2.0),
        rec("edge", 2, "dbcslam", position_rmse=2.0, x=4.0),
    ]
    s = summarize(recs)
    assert s["edge"]["dbcslam"]["position_rmse"] == 2.0
    assert s["edge"]["dbcslam"]["x"] == 3.0
    assert s["edge"]["dbcslam"]["n_seeds"] == 3


def test_evaluate_targets_pass_fail_and_fixed_ratios() -> None:
    good = {
        "position_rmse": 0.002,
        "position_rmse_ratio": 0.2,
        "contact_accuracy": 0.99,
        "stick_slide_accuracy": 0.5,
        "friction_map_accuracy": 0.95,
    }
    recs = []
    for s in range(3):
        recs.append(rec("edge", s, "dbcslam", **good))
        recs.append(rec("edge", s, "fixed_mu_0.3", position_rmse=0.1))
        recs.append(rec("edge", s, "fixed_mu_0.9", position_rmse=0.003))
    checks = {c.target.metric: c for c in evaluate_targets(recs)}
    assert all(c.target.scenario == "edge" for c in checks.values())  # no gripper records
    assert checks["position_rmse_ratio"].passed is True
    assert checks["stick_slide_accuracy"].passed is False
    assert checks["fixed_rmse_ratio_best"].value == pytest.approx(1.5)
    assert checks["fixed_rmse_ratio_best"].passed is False
    assert checks["fixed_rmse_ratio_worst"].value == pytest.approx(50.0)
    assert checks["fixed_rmse_ratio_worst"].passed is None


def test_missing_metric_fails() -> None:
    checks = evaluate_targets([rec("gripper", 0, "dbcslam", position_rmse=0.001)])
    by = {c.target.metric: c for c in checks}
    assert math.isnan(by["yaw_rmse_ratio"].value)
    assert by["yaw_rmse_ratio"].passed is False
    assert {t.scenario for t in TARGETS} == {"edge", "gripper"}


def test_config_validation() -> None:
    with pytest.raises(ModelError, match="unknown scenarios"):
        ExperimentConfig(scenarios=("push",))
    with pytest.raises(ModelError, match="n_steps"):
        ExperimentConfig(n_steps=1)


def test_run_experiments_tiny() -> None:
    msgs: list[str] = []
    cfg = ExperimentConfig(seeds=(0, 1), particles=8, n_steps=20)
    res = run_experiments(cfg, progress=msgs.append)
    methods = {(r.scenario, r.method) for r in res.records}
    assert methods == {
        ("edge", "dbcslam"),
        ("edge", "fixed_mu_0.3"),
        ("edge", "fixed_mu_0.9"),
        ("gripper", "dbcslam"),
    }
    assert len(res.records) == 8 == len(msgs)
    trace = res.traces[("gripper", 1, "dbcslam")]
    assert trace.est_q.shape == (19, 3)
    assert trace.est_modes.shape == (19, 6, 4)
    np.testing.assert_allclose(trace.est_modes.sum(-1), 1.0, atol=1e-6)
    assert trace.map_edges is not None
    assert res.representative_seed("edge") in (0, 1)


def test_run_black_box_record() -> None:
    tr = make_trajectory("edge", 0, 60)
    trace = run_black_box(tr, seed=0, particles=300, solver="pgs")
    assert trace.method == "blackbox_pgs"
    m = score(trace)
    assert m["live_hypotheses"] == 1.0
    assert m["position_rmse"] < tr.scenario.noise.position


def test_run_records_the_evidence_of_the_filter_model() -> None:
    """RunTrace.log_likelihood holds log p(o_k | o_<k) per step; summed it selects the true
    friction among fixed-friction filters on the core's synthetic gripper (model evidence)."""
    tr = make_trajectory("gripper", 0)
    true = int(np.argmin(np.abs(np.asarray(tr.scenario.friction.candidates[0]) - tr.mu_pair[0])))
    evidence = {}
    for c in range(len(tr.scenario.friction.candidates[0])):
        trace = run_fixed_friction(tr, c, seed=0, particles=60)
        assert trace.log_likelihood is not None
        assert trace.log_likelihood.shape == (tr.n_steps - 1,)
        assert np.all(np.isfinite(trace.log_likelihood))
        evidence[c] = float(np.sum(trace.log_likelihood))
    wrong = max(v for c, v in evidence.items() if c != true)
    assert evidence[true] > wrong + 3.0, evidence
    box = run_black_box(make_trajectory("edge", 0, 40), seed=0, particles=50, solver="pgs")
    assert box.log_likelihood is not None and np.all(np.isfinite(box.log_likelihood))


def _square(x: int) -> int:
    return x * x


def _fail(x: int) -> int:
    msg = f"job {x} failed"
    raise ValueError(msg)


@pytest.mark.parametrize("workers", [1, 2])
def test_run_parallel_results_in_job_order(workers: int) -> None:
    from functools import partial

    seen: list[int] = []
    jobs = [(k, partial(_square, k)) for k in (3, 1, 2)]
    out = run_parallel(jobs, workers=workers, on_done=lambda k, r: seen.append(k))
    assert list(out) == [3, 1, 2]
    assert out == {3: 9, 1: 1, 2: 4}
    assert sorted(seen) == [1, 2, 3]


def test_run_parallel_errors() -> None:
    from functools import partial

    with pytest.raises(ModelError, match="workers"):
        run_parallel([], workers=0)
    with pytest.raises(ValueError, match="job 5 failed"):
        run_parallel([(5, partial(_fail, 5))], workers=1)


def test_parallel_experiments_match_serial() -> None:
    cfg = ExperimentConfig(seeds=(0,), particles=6, n_steps=10, scenarios=("edge",))
    serial = run_experiments(cfg)
    parallel = run_experiments(replace(cfg, workers=2))
    assert [r.method for r in parallel.records] == ["dbcslam", "fixed_mu_0.3", "fixed_mu_0.9"]
    for a, b in zip(serial.records, parallel.records, strict=True):
        assert (a.scenario, a.seed, a.method) == (b.scenario, b.seed, b.method)
        assert a.metrics["position_rmse"] == b.metrics["position_rmse"]


def test_tasks_and_run_task() -> None:
    cfg = ExperimentConfig(seeds=(0, 1), scenarios=("gripper", "edge"))
    tasks = experiment_tasks(cfg)
    assert tasks[:2] == [("gripper", 0, "dbcslam"), ("gripper", 1, "dbcslam")]
    assert ("edge", 1, "fixed:1") in tasks and len(tasks) == 2 + 2 * 3
    assert len(experiment_tasks(replace(cfg, fixed_friction=False))) == 4
    rec, trace, wall = run_task("edge", 0, "fixed:0", particles=5, n_steps=8)
    assert rec.method == trace.method == "fixed_mu_0.3"
    assert trace.est_q.shape == (7, 2) and wall > 0
    with pytest.raises(ModelError, match="unknown method"):
        run_task("edge", 0, "fixed:x", particles=5, n_steps=8)


def test_target_builders() -> None:
    t = rmse_target("push", "yaw", 0.6, subject="object ")
    assert (t.label, t.metric, t.op, t.threshold) == (
        "object yaw RMSE <= 0.6 x noise std",
        "yaw_rmse_ratio",
        "<=",
        0.6,
    )
    with pytest.raises(ModelError, match="position"):
        rmse_target("edge", "speed", 1.0)
    edge = edge_targets(0.6)
    assert edge[0].threshold == 0.6 and edge[0].metric == "position_rmse_ratio"
    assert edge[1:] == TARGETS[1:5]
    assert TARGETS[0] == rmse_target("edge", "position", 0.5)


def test_representative_seed_lower_median() -> None:
    recs = [
        RunRecord("edge", s, "dbcslam", 1, {"position_rmse": v})
        for s, v in ((0, 3.0), (1, 1.0), (2, 2.0), (3, 4.0))
    ]
    recs.append(RunRecord("edge", 9, "fixed_mu_0.3", 1, {"position_rmse": 2.5}))
    assert representative_seed(recs, "edge") == 2
    assert representative_seed(recs, "edge", method="fixed_mu_0.3") == 9
    with pytest.raises(ModelError, match="gripper"):
        representative_seed(recs, "gripper")

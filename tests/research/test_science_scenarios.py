"""The discrepancy benchmark on the gripper and the push (`dbcslam_research.science
--scenario gripper|push`), seeded small versions: the draws are seeded and independent, the
hidden effect is drawn from the scenario's observable vocabulary at its documented size, the
push data do what the benchmark needs (strokes, stops, turns both ways), and an effect hidden
at random in a short gripper and push draw is found with its parameter (the benchmark itself:
>= 30 draws, 5-6 s runs, 150+ particles, `make science`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from dbcslam_core.contact_modes import Mode
from dbcslam_core.discrepancy import (
    DiscrepancyConfig,
    Hypothesis,
    ParamSpace,
    ScoreConfig,
    Scorer,
    analyse,
)
from dbcslam_core.discrepancy.fitting import fit_1d, fit_effect
from dbcslam_core.errors import ModelError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.scenario import gripper_scenario
from dbcslam_core.synthetic import (
    GRIPPER_HIDDEN_EFFECTS,
    PUSH_HIDDEN_EFFECTS,
    draw_gripper_effect,
    draw_push_effect,
    push_sweep_trajectory,
)
from dbcslam_research import science
from dbcslam_research.science import SCENARIOS, gripper_draw, merge, push_draw, recovered

DRAWS = {"gripper": gripper_draw, "push": push_draw}


@pytest.mark.parametrize("name", ["gripper", "push"])
def test_draws_are_seeded_independent_and_clean_draws_hide_nothing(name: str) -> None:
    draw = DRAWS[name]
    a = draw(4, clean=False, duration=1.0)
    b = draw(4, clean=False, duration=1.0)
    assert a[2] == b[2] and a[2] is not None
    assert np.array_equal(a[0].obs, b[0].obs)
    train, held, _ = a
    # the two runs of a draw: other noise and other inputs (gripper: force profile; push:
    # pusher strokes)
    assert not np.allclose(train.obs, held.obs)
    inputs = (train.u, held.u) if name == "gripper" else (train.env, held.env)
    assert not np.allclose(*inputs)
    assert draw(4, clean=True, duration=1.0)[2] is None
    assert a[0].scenario.kind == name


@pytest.mark.parametrize(
    ("draw", "vocab"),
    [(draw_gripper_effect, GRIPPER_HIDDEN_EFFECTS), (draw_push_effect, PUSH_HIDDEN_EFFECTS)],
)
def test_effect_draws_cover_the_vocabulary_at_documented_sizes(draw: Any, vocab: Any) -> None:
    rng = np.random.default_rng(0)
    seen = [draw(rng) for _ in range(200)]
    assert {e.effect for e in seen} == set(vocab)
    for e in seen:
        p = dict(e.params)
        if e.effect == "sensor_delay":
            assert 0.03 <= p["seconds"] <= 0.08
        elif e.effect == "viscous_damping":
            assert p["b"] > 0.0
        elif e.effect in ("mass_scale", "input_gain"):
            assert 1.25 <= max(p["factor"], 1.0 / p["factor"]) <= 1.6
        elif e.effect == "sensor_bias":
            assert abs(p["y"]) >= 0.0015  # >= 1.5 noise stds across the jaws / push
        elif e.effect == "support_concentration":
            assert 0.8 <= p["centre_fraction"] <= 0.9  # resolvable in 6 s push runs
    with pytest.raises(ModelError, match="valid"):
        draw(rng, "friction_patch")


def test_push_vocabulary_leaves_out_what_push_data_do_not_resolve() -> None:
    """support_pressure (no training gain at realistic size), mass_scale and input_gain
    (u = 0: the pusher's position drives the block) are not drawn on the push."""
    assert not {"support_pressure", "mass_scale", "input_gain"} & set(PUSH_HIDDEN_EFFECTS)
    with pytest.raises(ModelError, match="valid"):
        draw_push_effect(np.random.default_rng(0), "support_pressure")
    clean = push_sweep_trajectory(5, duration=2.0, mu_pusher=0.4, mu_surface=0.25)
    for name, factor in (("mass_scale", 1.5), ("input_gain", 1.5), ("mass_scale", 0.7)):
        ext = ModelExtension.make(name, factor=factor)
        tr = push_sweep_trajectory(
            5, duration=2.0, mu_pusher=0.4, mu_surface=0.25, extensions=(ext,)
        )
        assert np.allclose(tr.q, clean.q, rtol=0.0, atol=1e-12), name


def test_gripper_bias_is_sized_by_the_scenario_noise() -> None:
    sc = gripper_scenario()
    ext = draw_gripper_effect(np.random.default_rng(1), "sensor_bias", scenario=sc)
    p = dict(ext.params)
    assert 1.5 * sc.noise.position <= abs(p["y"]) <= 3.0 * sc.noise.position
    assert 1.5 * sc.noise.yaw <= abs(p["yaw"]) <= 3.0 * sc.noise.yaw
    assert abs(p["x"]) <= sc.noise.position


def test_push_sweep_pushes_in_strokes_and_turns_both_ways() -> None:
    tr = push_sweep_trajectory(3, duration=6.0)
    assert tr.q[-1, 1] > 0.3  # pushed along +y
    sep = tr.modes[:, 0] == int(Mode.SEPARATED)
    # stops: the block coasts off the pusher, the next stroke catches it up (several times)
    assert int(np.sum(np.diff(sep.astype(int)) == 1)) >= 3
    assert tr.q[:, 2].max() > 0.05 and tr.q[:, 2].min() < -0.05


def _res(effect: str | None, params: dict[str, float]) -> Any:
    win = None if effect is None else SimpleNamespace(effect=effect, params=params)
    return SimpleNamespace(winner=win, ambiguous=())


def test_recovered_uses_the_scenario_noise_for_positions() -> None:
    sc = gripper_scenario()  # 2 mm noise: positions within max(25 %, 4 mm)
    bias = ModelExtension.make("sensor_bias", x=0.001, y=0.005, yaw=0.04)
    ok = {"x": 0.0, "y": 0.0085, "yaw": 0.035}
    assert recovered(_res("sensor_bias", ok), bias, sc)
    assert not recovered(_res("sensor_bias", {**ok, "y": 0.0095}), bias, sc)
    assert not recovered(_res("sensor_bias", {**ok, "yaw": 0.025}), bias, sc)  # > 25 %
    assert recovered(_res("sensor_bias", {**ok, "y": 0.0095}), bias)  # edge default: 2 cm


def test_merge_keeps_one_row_per_scenario_and_draw(tmp_path: Path) -> None:
    row = {"index": 0, "clean": False, "hidden": "x", "verdict": "x", "fitted": "x",
           "outcome": "right", "seconds": 1.0}  # fmt: skip
    parts = {
        "edge": [row],  # an old edge part: no scenario key
        "g": [{**row, "scenario": "gripper", "outcome": "wrong"}],
        "p": [{**row, "scenario": "push"}, {**row, "scenario": "push", "clean": True}],
    }
    for name, rows in parts.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "science.json").write_text(json.dumps(rows))
    merge(tmp_path / "m", [tmp_path / n for n in parts])
    assert len(json.loads((tmp_path / "m" / "science.json").read_text())) == 4
    md = (tmp_path / "m" / "science.md").read_text()
    for name, counts in (
        ("edge", "| 1 | 1 | 0 | 0 | 100% | 0 |"),
        ("gripper", "| 1 | 0 | 1 | 0 | 0% | 0 |"),
        ("push", "| 1 | 1 | 0 | 0 | 100% | 1 | 0 (0%)"),
    ):
        assert f"| {SCENARIOS[name].label} {counts}" in md
    # without an oracle its three cells stay empty: every summary row has the header's cells
    head, _, *summary = md.split("\n\n")[0].splitlines()
    assert all(row.count("|") == head.count("|") for row in summary)


def test_oracle_marks_resolvable_draws_and_the_table_counts_them(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """--oracle adds, per effect draw, whether the true model passes the naming test (here a
    stand-in for the filter runs: gain 50 on draw 0, 5 on draw 1); the table then gives the
    right rate among resolvable draws and the unresolvable draws' `none` count."""
    from dbcslam_core.discrepancy import Resolvability

    rows = []
    for i, outcome in ((0, "right"), (1, "none")):
        _, _, ext = push_draw(i, clean=False, duration=1.0)
        assert ext is not None
        hidden = science._fmt(ext.effect, dict(ext.params))
        row = {"scenario": "push", "index": i, "clean": False, "hidden": hidden}
        rows.append({**row, "verdict": "x", "fitted": "", "outcome": outcome, "seconds": 1.0})
    rows.append({**rows[0], "clean": True, "hidden": "none", "outcome": "none"})
    (tmp_path / "science.json").write_text(json.dumps(rows))
    gains = {0: 50.0, 1: 5.0}
    seen: list[int] = []

    def fake(effect: str, params: dict[str, float], runs: Any, cfg: Any) -> Resolvability:
        seen.append(len(seen))
        g = gains[len(seen) - 1]
        return Resolvability(g, 20.0, g > 20.0)

    monkeypatch.setattr(science, "resolvability", fake)
    science.add_oracle(tmp_path, DiscrepancyConfig(pictures=False), "push", duration=1.0)
    got = json.loads((tmp_path / "science.json").read_text())
    assert [r.get("resolvable") for r in got] == [True, False, None]  # clean: no oracle
    md = (tmp_path / "science.md").read_text()
    assert "| 1 of 2 | 1 (100%) | 1 of 1 |" in md
    assert "+5 / 20 (not resolvable)" in md
    science.add_oracle(tmp_path, DiscrepancyConfig(pictures=False), "push", duration=1.0)
    assert len(seen) == 2  # draws that have it are not scored again
    # a table whose hidden effect the generator no longer draws is refused
    got[0]["hidden"], got[0]["resolvable"] = "sensor_delay seconds=1", None
    (tmp_path / "science.json").write_text(json.dumps(got))
    with pytest.raises(SystemExit, match="other generator"):
        science.add_oracle(tmp_path, DiscrepancyConfig(pictures=False), "push", duration=1.0)


# Seeded small versions of the benchmark: one draw per scenario (effect drawn at random from
# the scenario's vocabulary by the draw's seed: sensor_delay in both), 3 s runs, few particles,
# candidates the hidden effect and one other. ~15-25 filter runs of ~1 s CPU each. At these
# sizes the score of a mis-specified model is rough (the filter loses track at times): other
# draws fail here that pass in the benchmark (e.g. gripper draw 6, damping 0.78 N s/m, is
# fitted at 1.0 with 60 particles; gripper draw 4, a 44.3 ms delay, at 65 ms with 80
# particles and at 42.4 ms with the benchmark's 150).
SMALL: dict[str, tuple[int, int, tuple[str, ...]]] = {
    "gripper": (4, 150, ("viscous_damping",)),
    "push": (3, 60, ("support_pressure",)),
}


@pytest.mark.timeout(900)
@pytest.mark.parametrize("name", ["gripper", "push"])
def test_hidden_effect_of_a_seeded_draw_is_found(name: str) -> None:
    index, particles, others = SMALL[name]
    train, held, ext = DRAWS[name](index, clean=False, duration=3.0)
    assert ext is not None
    cfg = DiscrepancyConfig(
        particles=particles,
        pictures=False,
        effects=tuple(dict.fromkeys((ext.effect, *others))),
        filter_overrides=SCENARIOS[name].filter_overrides,
    )
    res = analyse([train], [held], cfg)
    assert recovered(res, ext, train.scenario), (ext, res.verdict, res.winner)


@pytest.mark.parametrize(("offset", "walked"), [(1e-9, 2), (0.0, 2), (0.5, 4)])
def test_a_parameter_without_effect_stops_the_walk(offset: float, walked: int) -> None:
    """Scores equal to the start value to rounding on both sides of the first round (e.g.
    input_gain on the push, u = 0; sensor bias x along the gripper's jaws): the walk stops
    after that round; a parameter that moves the score is walked on (two misses per side)."""
    sp = ParamSpace("factor", 0.4, 2.5, True, 1.0, (0.6, 0.8, 1.25, 1.6, 2.0))
    seen: list[float] = []

    def score(h: Hypothesis) -> float:
        f = h.param_dict["factor"]
        seen.append(f)
        return 100.0 - offset * abs(math.log(f)) / math.log(1.25)

    res = fit_1d(
        lambda x: Hypothesis.make("input_gain", {"factor": x}), sp, score, (1.0, 100.0), 30.0
    )
    assert len(seen) == walked
    assert res.x == 1.0 and not res.refined


@pytest.mark.timeout(900)
def test_gripper_y_and_yaw_bias_are_fitted_together() -> None:
    """Benchmark gripper draw 3 hides a bias of y 3.3 mm, yaw 0.040 rad. With the yaw bias
    still in the data the filter loses track at most y grid points (150 particles, yaw 0:
    y +4 mm -9162 nats, +7 mm +4328, nominal -8529), so one coordinate sweep (y, x, yaw)
    fitted y 7.0 mm and yaw 0.056; the second sweep from there (`fitting`) finds both
    within 25 %. One fit on the 5 s training run, ~27 filter runs at 150 particles (at 60
    particles the filter's score is too rough to tell the two fits apart)."""
    train, _, ext = gripper_draw(3, clean=False)
    assert ext is not None and ext.effect == "sensor_bias"
    with Scorer(ScoreConfig(particles=150, seed=0, workers=2)) as sc:
        nom = sc.score(Hypothesis(), [train]).loglik
        fit = fit_effect("sensor_bias", [train], sc, nom, 30.0)
    for k in ("y", "yaw"):
        true = ext.param(k)
        assert abs(fit.params[k] - true) <= 0.25 * abs(true), (k, fit.params, ext)

"""dbcslam_research.step_profile: per-phase wall time of a filter step (what `make bench`
prints under "Where the time goes"). Timing values are not asserted (benchmarks hold the
targets), only that the phases are the filter's real methods, add up to the step, and that
the instance is restored."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from dbcslam_core.experiments import make_trajectory, run_dbcslam, run_filter
from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig
from dbcslam_research.slices import slice_trajectory
from dbcslam_research.step_profile import PHASES, main, profile_steps, timed_phases


@pytest.fixture(scope="module")
def edge_slice() -> Any:
    return slice_trajectory(make_trajectory("edge", 0), 100, 112)


def test_every_phase_is_called_once_per_step_and_the_estimates_are_unchanged(
    edge_slice: Any,
) -> None:
    cfg = FilterConfig.preset("edge", particles=50, threads=1)
    filt = DbcSlamFilter(edge_slice.scenario, cfg, np.random.default_rng([0, 1]))
    calls: dict[str, int] = {}
    originals = {name: getattr(filt, name) for name, _ in PHASES}
    for name, fn in originals.items():

        def count(*a: Any, _n: str = name, _f: Any = fn, **k: Any) -> Any:
            calls[_n] = calls.get(_n, 0) + 1
            return _f(*a, **k)

        setattr(filt, name, count)
    totals: dict[str, float] = {}
    with timed_phases(filt, PHASES, totals, skip=2):
        timed = run_filter(filt, edge_slice, method="x", seed=0, particles=50)
    n_steps = edge_slice.n_steps - 1
    # the filter with these settings calls each phase once per step (resampling decides
    # inside _maybe_resample, the bank mixing phase is not timed)
    assert all(calls[name] == n_steps for name, _ in PHASES), calls
    assert totals["steps"] == n_steps - 2
    assert sum(totals[name] for name, _ in PHASES) <= totals["step"]
    ref = run_dbcslam(edge_slice, seed=0, particles=50, overrides={"threads": 1})
    np.testing.assert_array_equal(timed.est_q, ref.est_q)  # timing changes nothing


def test_the_instance_gets_its_methods_back_even_on_error(edge_slice: Any) -> None:
    cfg = FilterConfig.preset("edge", particles=10, threads=1)
    filt = DbcSlamFilter(edge_slice.scenario, cfg, np.random.default_rng(0))
    with pytest.raises(RuntimeError, match="boom"), timed_phases(filt, PHASES, {}):
        assert "step" in vars(filt)
        raise RuntimeError("boom")
    assert not {"step", *(name for name, _ in PHASES)} & set(vars(filt))


def test_a_missing_method_is_named(edge_slice: Any) -> None:
    filt = DbcSlamFilter(edge_slice.scenario, FilterConfig.preset("edge", particles=10))
    with (
        pytest.raises(AttributeError, match="no method '_nope'"),
        timed_phases(filt, [("_nope", "x")], {}),
    ):
        pass


def test_profile_rows_add_up() -> None:
    rows = profile_steps(["edge"], [30], steps=12, warmup=2)
    (row,) = rows
    d = row["dbcslam"]
    assert d["step"] > 0.0
    assert all(d[name] >= 0.0 for name, _ in PHASES)
    assert d["other"] == pytest.approx(d["step"] - sum(d[name] for name, _ in PHASES))
    assert 0.0 < row["blackbox_pgs"]["_simulate"] < row["blackbox_pgs"]["step"]


def test_cli_rejects_an_unknown_scenario(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["--scenarios", "table"])
    assert exc.value.code == 2
    assert "--scenarios must be a subset" in capsys.readouterr().err

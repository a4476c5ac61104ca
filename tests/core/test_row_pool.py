"""Threads over the rows of the compiled kernels (`row_pool`): the splits cover every row once
with balanced work, the pool returns results in order and survives a fork, and the filter's
estimates do not depend on the number of threads, bit for bit (every scenario kind, the
friction bank, support friction, force readings)."""

from __future__ import annotations

import itertools
import multiprocessing
import threading
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core import force_kernels, kernels, step_kernels
from dbcslam_core.errors import ModelError
from dbcslam_core.observation import ForceObservation, PoseObservation
from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig, FilterInput
from dbcslam_core.row_pool import RowPool, resolve_threads, row_chunks
from dbcslam_core.synthetic import Trajectory, edge_trajectory, gripper_trajectory, push_trajectory


@settings(max_examples=200, deadline=None)
@given(
    counts=st.lists(st.integers(0, 40), min_size=1, max_size=300),
    parts=st.integers(1, 8),
    min_work=st.integers(1, 500),
    weighted=st.booleans(),
)
def test_chunks_cover_every_row_once(
    counts: list[int], parts: int, min_work: int, weighted: bool
) -> None:
    """Contiguous, in order, no gaps or overlaps, at most `parts` ranges, each (when there is
    more than one) at least min_work units, and the heaviest range at most the average
    plus one row's work."""
    n_rows = len(counts)
    starts = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64) if weighted else None
    bounds = row_chunks(n_rows, parts, starts=starts, min_work=min_work)
    assert bounds[0][0] == 0 and bounds[-1][1] == n_rows
    assert all(a[1] == b[0] for a, b in itertools.pairwise(bounds))
    assert all(hi > lo for lo, hi in bounds)
    assert len(bounds) <= parts
    work = [(hi - lo) if starts is None else int(starts[hi] - starts[lo]) for lo, hi in bounds]
    if len(bounds) > 1:
        assert min(work) >= min(min_work, sum(work) // len(bounds)) - max([*counts, 1])
        assert max(work) <= sum(work) / len(bounds) + max([*counts, 1])


def test_chunks_of_an_empty_problem() -> None:
    assert row_chunks(0, 4) == [(0, 0)]
    assert row_chunks(5, 4, starts=np.zeros(6, dtype=np.int64)) == [(0, 5)]


@pytest.mark.parametrize("bad", [0, -1, 2.0, True, "2"])
def test_invalid_thread_counts_are_refused(bad: Any) -> None:
    with pytest.raises(ModelError, match="threads must be None"):
        resolve_threads(bad)
    with pytest.raises(ModelError, match="threads must be None"):
        FilterConfig(threads=bad)


def test_automatic_thread_count_is_bounded() -> None:
    assert 1 <= resolve_threads(None) <= 4
    assert resolve_threads(3) == 3


def test_map_runs_ranges_on_threads_in_order() -> None:
    pool = RowPool(3)
    seen: list[str] = []
    lock = threading.Lock()

    def fn(lo: int, hi: int) -> tuple[int, int]:
        with lock:
            seen.append(threading.current_thread().name)
        return lo, hi

    bounds = [(0, 3), (3, 5), (5, 9)]
    assert pool.map(fn, bounds) == bounds
    assert threading.current_thread().name in seen  # the caller takes the first range
    assert any(name.startswith("dbcslam-rows") for name in seen)
    pool.close()
    assert pool.map(fn, bounds) == bounds  # restarts after close
    pool.close()


def test_map_raises_the_error_of_any_range() -> None:
    pool = RowPool(2)

    def fn(lo: int, hi: int) -> int:
        if lo > 0:
            msg = f"range {lo}"
            raise ValueError(msg)
        return hi

    with pytest.raises(ValueError, match="range 4"):
        pool.map(fn, [(0, 4), (4, 8)])
    pool.close()


def _child_map(pool: RowPool, queue: Any) -> None:
    queue.put(pool.map(lambda lo, hi: hi - lo, [(0, 2), (2, 7)]))


@pytest.mark.skipif(
    "fork" not in multiprocessing.get_all_start_methods(), reason="needs the fork start method"
)
def test_pool_works_in_a_forked_child() -> None:
    """The parent's worker threads do not exist in a fork: the child starts its own."""
    pool = RowPool(2)
    assert pool.map(lambda lo, hi: hi - lo, [(0, 1), (1, 3)]) == [1, 2]  # threads started
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_child_map, args=(pool, queue))
    child.start()
    try:
        assert queue.get(timeout=60) == [2, 5]
    finally:
        child.join(timeout=60)
        if child.is_alive():
            child.kill()
    assert child.exitcode == 0
    pool.close()


# ----------------------------------------------------------------- the filter, any threads
@pytest.fixture(scope="module")
def trajectories() -> dict[str, Trajectory]:
    return {
        "edge": edge_trajectory(0),
        "gripper": gripper_trajectory(1, duration=1.6),
        "push": push_trajectory(0, side_position=0.8),
    }


def _run(traj: Trajectory, cfg: FilterConfig, steps: int, force: bool) -> list[np.ndarray]:
    filt = DbcSlamFilter(traj.scenario, cfg, np.random.default_rng(3))
    out = []
    for k in range(1, min(steps + 1, traj.n_steps)):
        obs = None if k % 9 == 0 else PoseObservation(*map(float, traj.obs[k]))
        fo = ForceObservation(0.3, -0.1) if force and k % 4 == 0 else None
        est = filt.step(obs, FilterInput(tuple(traj.u[k - 1]), tuple(traj.env_obs[k])), force=fo)
        out.append(
            np.concatenate(
                [
                    est.pose,
                    est.twist,
                    est.pose_cov.ravel(),
                    est.modes.ravel(),
                    est.friction.ravel(),
                    np.array([est.log_likelihood]),
                    filt.particles.log_w,
                    filt.particles.q.ravel(),
                ]
            )
        )
    return out


@pytest.mark.skipif(not step_kernels.AVAILABLE, reason="numba not installed")
@pytest.mark.parametrize(
    ("kind", "overrides", "force"),
    [
        ("edge", {}, False),
        ("gripper", {}, False),  # friction bank (the preset)
        ("gripper", {"friction_bank": False}, False),
        ("push", {}, True),  # support friction, force readings
    ],
)
def test_estimates_do_not_depend_on_threads(
    trajectories: dict[str, Trajectory],
    monkeypatch: pytest.MonkeyPatch,
    kind: str,
    overrides: dict[str, Any],
    force: bool,
) -> None:
    """With the minimum work per thread lowered to one row, every kernel really runs split
    over 2 and 3 threads; the particles and estimates equal the single-thread run bit for
    bit at every step."""
    monkeypatch.setattr(step_kernels, "_MIN_ENTRIES", 1)
    monkeypatch.setattr(step_kernels, "_MIN_ROWS", 1)
    monkeypatch.setattr(kernels, "_MIN_ENUMERATION_VISITS", 1)
    monkeypatch.setattr(force_kernels, "_MIN_ENTRIES", 1)
    calls: list[int] = []
    original = RowPool.map

    def counting_map(self: RowPool, fn: Any, bounds: Any) -> Any:
        calls.append(len(bounds))
        return original(self, fn, bounds)

    monkeypatch.setattr(RowPool, "map", counting_map)
    traj = trajectories[kind]
    steps = {"edge": 120, "gripper": 150, "push": 120}[kind]
    runs = {
        n: _run(
            traj, FilterConfig.preset(kind, particles=23, threads=n, **overrides), steps, force
        )
        for n in (1, 2, 3)
    }
    assert calls and max(calls) == 3  # the 3-thread run split the rows three ways
    for n in (2, 3):
        for k, (a, b) in enumerate(zip(runs[1], runs[n], strict=True)):
            np.testing.assert_array_equal(a, b, err_msg=f"{n} threads, step {k + 1}")


@pytest.mark.skipif(not step_kernels.AVAILABLE, reason="numba not installed")
@pytest.mark.parametrize("kind", ["edge", "gripper", "push"])
def test_generic_kernels_equal_the_specialised_ones(
    trajectories: dict[str, Trajectory], monkeypatch: pytest.MonkeyPatch, kind: str
) -> None:
    """The entry and proposal kernels compiled for the scenario's velocity dimension (2:
    edge, 3: gripper, push) and the generic ones (dimension read from the arrays) give the
    same filter, bit for bit: the constant only lets the compiler unroll."""
    traj = trajectories[kind]
    cfg = FilterConfig.preset(kind, particles=23, threads=1)
    special = _run(traj, cfg, 60, kind == "push")
    for table in ("_ENTRY_KERNELS", "_PROPOSE_KERNELS"):
        generic = dict(getattr(step_kernels, table))
        for nv in (2, 3):
            generic[nv] = generic[0]
        monkeypatch.setattr(step_kernels, table, generic)
    for k, (a, b) in enumerate(zip(special, _run(traj, cfg, 60, kind == "push"), strict=True)):
        np.testing.assert_array_equal(a, b, err_msg=f"step {k + 1}")

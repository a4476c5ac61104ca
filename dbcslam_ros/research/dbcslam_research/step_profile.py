"""Where a filter step spends its time: wall time per phase of `DbcSlamFilter.step`, next to
the black-box PGS filter's LCP simulation and the rest of its step, on one thread.

Each phase is a method of the filter; `timed_phases` wraps those methods on one filter
instance (its class is untouched) with ``time.perf_counter``. The wrappers add ~0.3 us per
call (~4 us per DBC-SLAM step, inside the phases' times); ``other`` is the step's own code
between the phases. Data: the slice of ``--steps`` samples with the most true contacts of
each scenario's synthetic trajectory (seed 0, as `bench`); the mean over the steps after
``--warmup``, after one untimed run of the same filter settings (compiled kernels loaded).

Example:
    python -m dbcslam_research.step_profile --scenarios edge --particles 100,1000,10000

prints the Markdown table (ms per step); `make bench` includes it in ``bench.md``
("Where the time goes").
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from dbcslam_core.baselines import BlackBoxNCPFilter
from dbcslam_core.experiments import (
    SCENARIOS,
    FilterLike,
    black_box_config,
    make_trajectory,
    run_filter,
)
from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig
from dbcslam_core.synthetic import Trajectory
from dbcslam_research.cli import doc_parser, ints_argument
from dbcslam_research.slices import contact_window, slice_trajectory

__all__ = ["BLACK_BOX_PHASES", "PHASES", "main", "profile_steps", "render_profile", "timed_phases"]

PHASES: tuple[tuple[str, str], ...] = (
    ("_read_inputs", "inputs"),
    ("_free_motion", "kinematics, free motion"),
    ("_predict_modes", "mode prediction"),
    ("_enumerate", "live hypotheses"),
    ("_compiled_phases", "dynamics, proposal, posterior (compiled)"),
    ("_update_beliefs", "eq. (7) belief"),
    ("_reweight", "weights"),
    ("_move", "move, map history"),
    ("_maybe_resample", "resampling"),
    ("_estimate", "estimate, friction map"),
)
"""(method of `DbcSlamFilter`, label) in the order `DbcSlamFilter.step` calls them."""

BLACK_BOX_PHASES: tuple[tuple[str, str], ...] = (("_simulate", "LCP simulation (PGS)"),)
"""(method of `BlackBoxNCPFilter`, label)."""


@contextmanager
def timed_phases(
    filt: object, phases: Sequence[tuple[str, str]], totals: dict[str, float], skip: int = 0
) -> Iterator[None]:
    """Within the block every call of ``filt.<method>`` of `phases`, and of ``filt.step``,
    adds its wall time (s) to ``totals[method]`` (``totals["step"]``), except during the
    first `skip` calls of ``step``; ``totals["steps"]`` counts the timed steps. The
    instance's methods are restored on exit, also on error.

    Raises AttributeError naming the method when `filt` has no such method."""
    names = ["step", *(name for name, _ in phases)]
    missing = [name for name in names if not callable(getattr(filt, name, None))]
    if missing:
        msg = f"{type(filt).__name__} has no method {missing[0]!r} to time"
        raise AttributeError(msg)
    calls = [0]

    def _wrap(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def timed(*args: Any, **kwargs: Any) -> Any:
            if name == "step":
                calls[0] += 1
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                if calls[0] > skip:
                    totals[name] = totals.get(name, 0.0) + time.perf_counter() - t0
                    if name == "step":
                        totals["steps"] = totals.get("steps", 0.0) + 1.0

        return timed

    for name in names:
        setattr(filt, name, _wrap(name, getattr(filt, name)))
    try:
        yield
    finally:
        for name in names:
            delattr(filt, name)  # the class's method shows through again


def _phase_ms(
    make: Callable[[], FilterLike],
    tr: Trajectory,
    phases: Sequence[tuple[str, str]],
    warmup: int,
) -> dict[str, float]:
    """ms per step of each phase, of the whole ``step`` and of ``other`` (the rest)."""
    run_filter(make(), tr, method="warm-up", seed=0, particles=0)
    filt = make()
    totals: dict[str, float] = {}
    with timed_phases(filt, phases, totals, skip=warmup):
        run_filter(filt, tr, method="profile", seed=0, particles=0)
    n = totals["steps"]
    out = {name: 1e3 * totals.get(name, 0.0) / n for name, _ in phases}
    out["step"] = 1e3 * totals["step"] / n
    out["other"] = out["step"] - sum(out[name] for name, _ in phases)
    return out


def _factory(
    cls: Callable[..., FilterLike], tr: Trajectory, cfg: Any, stream: int
) -> Callable[[], FilterLike]:
    """A maker of fresh filters cls(scenario, cfg, rng) on the random stream [0, stream] each
    time (that of `run_dbcslam`: 1, `run_black_box`: 3, seed 0: the bench's runs)."""
    return lambda: cls(tr.scenario, cfg, np.random.default_rng([0, stream]))


def profile_steps(
    scenarios: Sequence[str],
    particles: Sequence[int],
    *,
    steps: int = 40,
    warmup: int = 5,
    say: Callable[[str], None] = lambda _: None,
) -> list[dict[str, Any]]:
    """Per scenario and particle count: ms per step of each DBC-SLAM phase (scenario preset,
    one thread) and of the black-box PGS filter's LCP simulation (`bench`'s black box), on
    the slice of `steps` samples with the most true contacts, seed 0."""
    rows: list[dict[str, Any]] = []
    for scen in scenarios:
        full = make_trajectory(scen, 0)
        start = contact_window(full, steps)
        part = slice_trajectory(full, start, start + steps)
        for p in particles:
            dbc_cfg = FilterConfig.preset(scen, particles=p, threads=1)
            pgs_cfg = black_box_config(part.scenario, particles=p, solver="pgs")
            dbc = _factory(DbcSlamFilter, part, dbc_cfg, stream=1)
            pgs = _factory(BlackBoxNCPFilter, part, pgs_cfg, stream=3)
            ms_dbc = _phase_ms(dbc, part, PHASES, warmup)
            ms_pgs = _phase_ms(pgs, part, BLACK_BOX_PHASES, warmup)
            say(
                f"  {scen} P={p}: DBC-SLAM {ms_dbc['step']:.2f} ms per step, "
                f"black-box PGS {ms_pgs['step']:.2f} ms"
            )
            rows.append(
                {"scenario": scen, "particles": p, "dbcslam": ms_dbc, "blackbox_pgs": ms_pgs}
            )
    return rows


def render_profile(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The profile as Markdown lines: one row per (scenario, particles), ms per step."""
    head = [label for _, label in PHASES]
    lines = [
        "| scenario | particles | DBC-SLAM step | "
        + " | ".join(head)
        + " | other | black-box PGS step | its LCP simulation |",
        "|---|---|" + "---|" * (len(head) + 4),
    ]
    for r in rows:
        d, b = r["dbcslam"], r["blackbox_pgs"]
        cells = [f"{d[name]:.3f}" for name, _ in PHASES]
        lines.append(
            f"| {r['scenario']} | {r['particles']} | {d['step']:.3f} | "
            + " | ".join(cells)
            + f" | {d['other']:.3f} | {b['step']:.3f} | {b['_simulate']:.3f} |"
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit code (0 ok, 2 bad arguments)."""
    p = doc_parser("dbcslam_research.step_profile", __doc__)
    p.add_argument("--scenarios", default="edge,gripper", help="subset of edge,gripper,push")
    p.add_argument(
        "--particles", type=ints_argument, default=[100, 1000, 10000], help="particle counts"
    )
    p.add_argument("--steps", type=int, default=40, help="samples in the slice (40)")
    p.add_argument("--warmup", type=int, default=5, help="steps not timed (5)")
    args = p.parse_args(argv)
    scenarios = [s for s in args.scenarios.split(",") if s]
    if not scenarios or any(s not in SCENARIOS for s in scenarios):
        p.error(f"--scenarios must be a subset of {list(SCENARIOS)}, got {args.scenarios!r}")
    if args.warmup < 0 or args.steps < args.warmup + 2:
        p.error(f"need --warmup >= 0 and --steps >= --warmup + 2, got {args.steps}, {args.warmup}")
    rows = profile_steps(
        scenarios, args.particles, steps=args.steps, warmup=args.warmup, say=print
    )
    print("\n".join(render_profile(rows)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

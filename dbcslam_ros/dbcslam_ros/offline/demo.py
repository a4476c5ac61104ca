"""``dbcslam demo``: simulator, filter and recorder as three processes over DDS, then a summary.

:func:`run_demo` starts, in this order, each as its own process with the demo's environment
(so the same ``ROS_DOMAIN_ID`` and the runtime's loopback-only DDS settings):

1. ``dbcslam record -o BAG --contract``: subscribes to every contract topic at once;
2. ``dbcslam filter``: the filter node (``particles``, ``seed``, ``marker_particles`` as ROS
   parameters); the demo waits until the recorder has received the node's first
   ``/diagnostics`` (the node is up and matched) before it starts
3. ``dbcslam sim --scenario S``: the simulator, paced in real time; it exits by itself
   after ``--duration`` s of simulated time.

While the simulator runs, a progress line shows the simulated time (poses recorded / rate)
and the number of estimates, from the recorder's once-a-second counts. When the simulator
has exited the demo lets the filter drain (until no new estimate arrived for ``drain_s``),
stops the filter and then the recorder with SIGINT (SIGKILL after a timeout), evaluates the
bag (:func:`dbcslam_ros.offline.evaluate.evaluate_bag`), prints the summary table and writes
``metrics.json`` and the PNG plots (:func:`dbcslam_ros.offline.report.save_bag_figures`) into the
bag directory, next to its files.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from dbcslam_ros.contract import DIAGNOSTICS, OBJECT_POSE, POSE, SCENARIO
from dbcslam_ros.errors import DbcSlamRosError, UsageError
from dbcslam_ros.node.params import LIVE_PARTICLES

__all__ = ["DEFAULT_PARTICLES", "SCENARIOS", "DemoError", "DemoOptions", "DemoResult", "run_demo"]

SCENARIOS: tuple[str, ...] = ("edge", "gripper", "push")
#: Particles per scenario: the filter node's live defaults (few enough that it keeps up with
#: the simulator at 100 Hz on an idle 2-core machine; see filter_node.LIVE_PARTICLES).
DEFAULT_PARTICLES: dict[str, int] = LIVE_PARTICLES
#: Particles drawn in /dbcslam/markers: building and sending 100 costs the live node ~3 ms
#: per step (measured), time the filter needs to keep up.
DEMO_MARKER_PARTICLES = 20
_COUNTS = re.compile(r"^recorded (\d+) messages \((.*)\)$")


class DemoError(DbcSlamRosError):
    """A demo process failed to start or exited with an error (exit code 1 of the CLI)."""


@dataclass(frozen=True)
class DemoOptions:
    """Demo settings. ``duration``/``seed``/``rate`` None keep the simulator's defaults.

    Attributes:
        engine: simulator engine (``pybullet`` or ``core``).
        drain_s: s without a new estimate after the simulator ended before the filter stops.
        startup_timeout_s: bound on each process's start-up.
        progress: stream of the progress line and process messages (None: silent).
    """

    scenario: str = "gripper"
    out: Path | None = None
    duration: float | None = None
    seed: int | None = None
    particles: int | None = None
    engine: str = "pybullet"
    rate: float | None = None
    plots: bool = True
    markers: bool = True
    drain_s: float = 1.5
    startup_timeout_s: float = 30.0
    progress: IO[str] | None = None


@dataclass
class DemoResult:
    """Where the demo wrote its outputs and what it measured (wall times in s)."""

    bag: Path
    metrics: dict[str, Any]
    plots: list[Path]
    wall_s: float
    exit_codes: dict[str, int | None] = field(default_factory=dict)


class _Child:
    """A child process with its stderr collected by a thread (last lines kept)."""

    def __init__(self, name: str, argv: Sequence[str], env: dict[str, str]) -> None:
        self.name = name
        self.lines: list[str] = []
        self.counts: dict[str, int] = {}
        self.updated = threading.Event()
        self.proc = subprocess.Popen(
            list(argv),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            env=env,
            text=True,
            bufsize=1,
        )
        self._thread = threading.Thread(target=self._read, name=f"{name}-stderr", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            text = line.rstrip("\n")
            self.lines.append(text)
            del self.lines[:-200]
            match = _COUNTS.match(text)
            if match:
                counts: dict[str, int] = {}
                for item in match.group(2).split(", "):
                    topic, _, n = item.rpartition(" ")
                    if topic and n.isdigit():
                        counts[topic] = int(n)
                self.counts = counts
            self.updated.set()

    def saw(self, text: str) -> bool:
        return any(text in line for line in list(self.lines))

    def stop(self, timeout_s: float) -> int | None:
        """SIGINT, then SIGKILL after timeout_s; returns the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5.0)
        self._thread.join(timeout=2.0)
        return self.proc.returncode

    def tail(self, n: int = 8) -> str:
        return "\n".join(f"  {self.name}: {line}" for line in self.lines[-n:])


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "dbcslam_ros.cli", *args]


def default_bag_path(scenario: str) -> Path:
    """``bags/demo_<scenario>_<UTC time>`` under the current directory."""
    stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%S")
    return Path("bags") / f"demo_{scenario}_{stamp}"


def _check(opts: DemoOptions) -> None:
    if opts.scenario not in SCENARIOS:
        msg = f"--scenario {opts.scenario!r}: expected one of {list(SCENARIOS)}"
        raise UsageError(msg)
    if opts.duration is not None and not opts.duration > 0:
        msg = f"--duration {opts.duration}: expected a value > 0"
        raise UsageError(msg)
    if opts.particles is not None and opts.particles < 1:
        msg = f"--particles {opts.particles}: expected an integer >= 1"
        raise UsageError(msg)
    if opts.seed is not None and opts.seed < 0:
        msg = f"--seed {opts.seed}: expected an integer >= 0"
        raise UsageError(msg)
    if opts.engine == "core" and opts.scenario == "push":
        msg = "--engine core has no push trajectory; use --engine pybullet for push"
        raise UsageError(msg)


def _wait(child: _Child, what: str, until: Any, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not until():
        if child.proc.poll() is not None:
            msg = f"{child.name} exited (code {child.proc.returncode}) before {what}:\n"
            raise DemoError(msg + child.tail())
        if time.monotonic() > deadline:
            msg = f"{child.name}: no {what} within {timeout_s:.0f} s:\n{child.tail()}"
            raise DemoError(msg)
        child.updated.wait(0.1)
        child.updated.clear()


def run_demo(opts: DemoOptions) -> DemoResult:
    """Run the demo (see the module docstring); returns the bag, metrics and plots.

    Raises:
        UsageError: bad options or an existing output path.
        DemoError: a process failed to start or the run produced no estimates.
    """
    _check(opts)
    bag = _new_bag_dir(opts)
    particles = opts.particles or DEFAULT_PARTICLES[opts.scenario]
    seed = 0 if opts.seed is None else opts.seed
    env = dict(os.environ)
    env.setdefault("PYTHONUNBUFFERED", "1")
    started = time.monotonic()
    say = _sayer(opts.progress)
    children: list[_Child] = []
    codes: dict[str, int | None] = {}
    try:
        recorder = _start(children, "record", _cli("record", "-o", str(bag), "--contract"), env)
        _wait(
            recorder,
            "its subscriptions",
            lambda: recorder.saw("recording /object/pose"),
            opts.startup_timeout_s,
        )
        filt = _start(children, "filter", _filter_argv(opts, particles, seed), env)
        _wait_for_filter(recorder, filt, opts.startup_timeout_s)
        sim = _start(children, "sim", _sim_argv(opts, seed), env)
        say(
            f"demo: scenario {opts.scenario} ({opts.engine}), {particles} particles, "
            f"recording to {bag}"
        )
        codes["sim"] = _follow_sim(sim, recorder, opts)
        _drain(recorder, opts.drain_s)
        codes["filter"] = filt.stop(10.0)
        codes["record"] = recorder.stop(15.0)
        if recorder.counts.get(POSE, 0) == 0 and not _has_estimates(bag):
            msg = f"the filter published no estimates:\n{filt.tail()}"
            raise DemoError(msg)
    finally:
        for child in reversed(children):
            if child.proc.poll() is None:
                codes.setdefault(child.name, child.stop(5.0))
    return _summarise(bag, opts, codes, started, say)


def _new_bag_dir(opts: DemoOptions) -> Path:
    """The bag path to record to (its parent created); it must not exist yet."""
    bag = opts.out if opts.out is not None else default_bag_path(opts.scenario)
    if bag.exists():
        msg = f"{bag}: already exists; choose another --out"
        raise UsageError(msg)
    bag.parent.mkdir(parents=True, exist_ok=True)
    return bag


def _sayer(out: IO[str] | None) -> Callable[[str], None]:
    """A function that writes one line to ``out`` (nothing when None)."""

    def say(text: str) -> None:
        if out is not None:
            out.write(text + "\n")
            out.flush()

    return say


def _start(children: list[_Child], name: str, argv: Sequence[str], env: dict[str, str]) -> _Child:
    """Start a child process and add it to ``children`` (those the demo stops at the end)."""
    child = _Child(name, argv, env)
    children.append(child)
    return child


def _filter_argv(opts: DemoOptions, particles: int, seed: int) -> list[str]:
    """``dbcslam filter`` with the demo's particles, seed and markers as ROS parameters."""
    return _cli(
        "filter",
        "--ros-args",
        "-p",
        f"particles:={particles}",
        "-p",
        f"seed:={seed}",
        "-p",
        f"marker_particles:={DEMO_MARKER_PARTICLES if opts.markers else 0}",
        # markers at the node's default period (0.1 s), as `dbcslam replay` writes them
    )


def _wait_for_filter(recorder: _Child, filt: _Child, timeout_s: float) -> None:
    """Until the recorder has the filter's first /diagnostics (the node is up and matched)."""
    _wait(
        recorder,
        "the filter's first /diagnostics",
        lambda: recorder.counts.get(DIAGNOSTICS, 0) > 0 or filt.proc.poll() is not None,
        timeout_s,
    )
    if filt.proc.poll() is not None:
        msg = f"the filter exited (code {filt.proc.returncode}) at start-up:\n{filt.tail()}"
        raise DemoError(msg)


def _sim_argv(opts: DemoOptions, seed: int) -> list[str]:
    """``dbcslam sim`` for the demo's scenario, engine, seed and (if set) duration and rate."""
    sim_args = ["sim", "--scenario", opts.scenario, "--engine", opts.engine]
    sim_args += ["--seed", str(seed)]
    if opts.duration is not None:
        sim_args += ["--duration", repr(float(opts.duration))]
    if opts.rate is not None:
        sim_args += ["--rate", repr(float(opts.rate))]
    return _cli(*sim_args)


def _follow_sim(sim: _Child, recorder: _Child, opts: DemoOptions) -> int | None:
    """Show the progress line until the simulator exits; returns its exit code (0).

    Raises:
        DemoError: the simulator failed, or did not finish within 600 s.
    """
    out = opts.progress
    rate = opts.rate or 100.0
    sim_started = time.monotonic()
    while sim.proc.poll() is None:
        recorder.updated.wait(0.25)
        recorder.updated.clear()
        c = recorder.counts
        if out is not None:
            out.write(
                f"\rsim time {c.get('/object/pose', 0) / rate:6.2f} s, "
                f"{c.get('/dbcslam/pose', 0)} estimates, "
                f"wall {time.monotonic() - sim_started:5.1f} s"
            )
            out.flush()
        if time.monotonic() - sim_started > 600:
            msg = "the simulator did not finish within 600 s"
            raise DemoError(msg)
    if out is not None:
        out.write("\n")
    if sim.proc.returncode != 0:
        msg = f"the simulator failed (exit code {sim.proc.returncode}):\n{sim.tail()}"
        raise DemoError(msg)
    return sim.proc.returncode


def _drain(recorder: _Child, drain_s: float) -> None:
    """Wait (at most 30 s) until the estimate count stops growing for ``drain_s`` (>= 1.1 s:
    the recorder reports its counts once a second)."""
    last = -1
    quiet_since = time.monotonic()
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline:
        n = recorder.counts.get(POSE, 0)
        if n != last:
            last, quiet_since = n, time.monotonic()
        elif time.monotonic() - quiet_since >= max(drain_s, 1.1):
            break
        recorder.updated.wait(0.2)
        recorder.updated.clear()


def _has_estimates(bag: Path) -> bool:
    from dbcslam_ros.bag import open_bag

    with open_bag(bag, salvage=True) as reader:
        return reader.counts().get(POSE, 0) > 0


def _summarise(
    bag: Path,
    opts: DemoOptions,
    codes: dict[str, int | None],
    started: float,
    say: Callable[[str], None],
) -> DemoResult:
    from dbcslam_ros.offline.evaluate import (
        evaluate_bag,
        load_bag_arrays,
        metrics_table,
        write_metrics,
    )

    arrays = load_bag_arrays(bag, salvage=True)
    if arrays.counts.get(SCENARIO, 0) > 1:
        domain = os.environ.get("ROS_DOMAIN_ID", "0")
        say(
            f"warning: {arrays.counts['/scenario']} /scenario messages recorded: another "
            f"simulator publishes on ROS_DOMAIN_ID={domain}; use a domain of your own"
        )
    metrics = evaluate_bag(bag, arrays=arrays, require_truth=False)
    metrics["demo"] = {
        "scenario": opts.scenario,
        "engine": opts.engine,
        "exit_codes": codes,
        "poses": arrays.counts.get(OBJECT_POSE, 0),
    }
    plots: list[Path] = []
    if opts.plots:
        from dbcslam_ros.offline.report import save_bag_figures

        plots = save_bag_figures(arrays, bag)
    wall = time.monotonic() - started
    metrics["demo"]["wall_s"] = round(wall, 2)
    write_metrics(metrics, bag / "metrics.json")
    say(metrics_table(metrics))
    diag = metrics.get("diagnostics_last", {})
    if "backlog_dropped" in diag:
        say(
            f"live filter: {metrics['estimates']} estimates for "
            f"{metrics['demo']['poses']} poses; {diag['backlog_dropped']} poses dropped "
            "because the filter was still busy (`dbcslam replay` of the bag answers every pose)"
        )
    say(f"demo: bag, metrics.json and {len(plots)} plots in {bag} ({wall:.1f} s)")
    return DemoResult(bag, metrics, plots, wall, codes)

"""Live benchmark: the simulator node and the filter node as two processes, in real time.

Run: ``python -m dbcslam_research.bench_live [--scenarios edge gripper push] [--particles N ...]
[--duration S] [--engine pybullet|core] [--offline | --no-live] [--no-pusher-wrench]
[--out DIR] [--logs DIR]`` (one run per scenario and particle count; -1 = the filter node's
live default for the kind).

For each scenario it starts ``python -m dbcslam_ros.node.filter_node`` and ``python -m
sim_publisher.node`` (100 Hz, real-time pacing, default engine pybullet) on loopback in a
random ``ROS_DOMAIN_ID`` (or ``--domain-id``), listens in-process to ``/object/pose``,
``/truth/object/pose``, ``/dbcslam/pose`` and ``/diagnostics`` until the simulator exits,
and stops both processes by PID (also on failure or Ctrl-C). Reported per scenario:

* poses sent (truth poses heard), received and used (estimates published) by the filter;
* ms per model step (mean, p95; the filter node's ``/diagnostics``, over its last 1000 poses);
* latency pose receipt -> ``/dbcslam/pose`` publication inside the filter (mean, p95, max);
* backlog drops (poses replaced by a newer one before the filter got to them) and the model
  steps coasted over in catch-up;
* mean position error |estimate - truth| next to the noise |observation - truth| over the same
  stamps (mm), and their ratio;
* (JSON only) the filter's model steps and how many of them had a pusher force reading;
* with ``--offline`` (or only that, ``--no-live``): CPU time per model step
  (``time.process_time``: another process's load inflates it much less than wall time) of
  the same filter configuration on the same simulated run, fed through
  :class:`~dbcslam_ros.node.session.FilterSession` in one process without pacing, plus the CPU
  time to build and encode the output messages of a step, and the mean position error /
  noise of that offline run (every pose answered).

A run "keeps up" when at most 1 % of the received poses were dropped for backlog and the
latency p95 is below the sample period. Writes ``bench_live.md`` and ``bench_live.json`` into
``--out`` (default ``dbcslam_ros/research/results``) and prints the Markdown table. The machine's
load average at the start of each run is recorded: on a busy machine the live numbers say
little; the offline CPU time does.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import platform
import random
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dbcslam_ros.contract import DIAGNOSTICS, OBJECT_POSE, POSE, TRUTH_POSE

__all__ = ["LiveResult", "OfflineResult", "main", "offline_cpu", "run_live"]

DEFAULT_OUT = Path("dbcslam_ros/research/results")
SCENARIOS: tuple[str, ...] = ("edge", "gripper", "push")
#: Fraction of received poses dropped for backlog up to which a run still "keeps up".
KEEP_UP_DROP_FRACTION = 0.01
RATE_HZ = 100.0


@dataclass(frozen=True)
class OfflineResult:
    """CPU time per model step (ms) of the filter on a recorded run (no pacing, one process)."""

    cpu_ms_mean: float
    cpu_ms_p95: float
    wall_ms_mean: float
    output_cpu_ms_mean: float
    steps: int
    position_error_mm: float
    noise_mm: float


@dataclass(frozen=True)
class LiveResult:
    """One live run (see the module docstring for the meaning of each field)."""

    scenario: str
    engine: str
    particles: int
    load_before: float
    wall_s: float
    poses_sent: int
    poses_received: int
    poses_used: int
    backlog_dropped: int
    skipped_steps: int
    model_step_ms_mean: float
    model_step_ms_p95: float
    latency_ms_mean: float
    latency_ms_p95: float
    latency_ms_max: float
    position_error_mm: float
    noise_mm: float
    keeps_up: bool | None
    offline: OfflineResult | None = None
    filter_steps: int = 0
    force_steps: int = 0

    @property
    def error_over_noise(self) -> float:
        return self.position_error_mm / self.noise_mm if self.noise_mm > 0 else math.nan


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _stop(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> None:
    """SIGINT, then SIGTERM, then SIGKILL the process by its PID."""
    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
        if proc.poll() is not None:
            return
        try:
            os.kill(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout)
            return
        except subprocess.TimeoutExpired:
            continue


def _float(values: dict[str, str], key: str) -> float:
    try:
        return float(values[key])
    except (KeyError, ValueError):
        return math.nan


def run_live(
    scenario: str,
    *,
    particles: int = -1,
    duration: float = 0.0,
    engine: str = "pybullet",
    log_dir: Path | None = None,
    timeout_s: float = 120.0,
    pusher_wrench: bool = True,
    threads: int = 0,
) -> LiveResult:
    """Run the simulator node and the filter node for one scenario and measure (see module).

    Uses the caller's ``ROS_DOMAIN_ID`` (set it before: :func:`main` picks a random one);
    particles < 0 keeps the filter node's per-kind live default; duration <= 0 the simulator's
    default. log_dir: where the two processes' output goes (None: discarded); threads: the
    filter node's ``threads`` parameter (0: automatic).
    """
    from dbcslam_ros import runtime as rt

    node = rt.Node(f"bench_live_{scenario}")
    heard = _Heard()
    heard.subscribe(node)
    filter_cmd = _filter_command(particles, pusher_wrench=pusher_wrench, threads=threads)
    sim_cmd = _sim_command(scenario, engine, duration)
    load_before = os.getloadavg()[0]
    procs: list[subprocess.Popen[bytes]] = []
    started = time.monotonic()
    try:
        filter_log = _log(log_dir, scenario, "filter")
        procs.append(subprocess.Popen(filter_cmd, stdout=filter_log, stderr=subprocess.STDOUT))
        sim_log = _log(log_dir, scenario, "sim")
        sim = subprocess.Popen(sim_cmd, stdout=sim_log, stderr=subprocess.STDOUT)
        procs.append(sim)
        _listen_until_exit(node, sim, scenario, started, timeout_s)
        wall = time.monotonic() - started
        _listen_for_last_diagnostics(node, heard.diags)
    finally:
        for proc in reversed(procs):
            _stop(proc)
        node.destroy_node()
    return _live_result(heard, scenario, engine, particles, load_before=load_before, wall=wall)


@dataclass
class _Heard:
    """What the benchmark's listener heard: planar positions (m) by stamp (ns) of the truth,
    the observations and the estimates, and the filter's /diagnostics key/values in order."""

    truth: dict[int, tuple[float, float]] = field(default_factory=dict)
    obs: dict[int, tuple[float, float]] = field(default_factory=dict)
    est: dict[int, tuple[float, float]] = field(default_factory=dict)
    diags: list[dict[str, str]] = field(default_factory=list)

    def subscribe(self, node: Any) -> None:
        """Subscribe ``node`` to the four topics (observations best effort, as sent)."""
        from dbcslam_ros import runtime as rt

        cls = rt.message_class
        reliable = rt.qos_profile("default", depth=1000)
        pose_stamped = cls("geometry_msgs/msg/PoseStamped")
        node.create_subscription(pose_stamped, TRUTH_POSE, self._on_truth, reliable)
        node.create_subscription(
            pose_stamped, OBJECT_POSE, self._on_obs, rt.qos_profile("sensor_data", depth=1000)
        )
        node.create_subscription(
            cls("geometry_msgs/msg/PoseWithCovarianceStamped"), POSE, self._on_est, reliable
        )
        node.create_subscription(
            cls("diagnostic_msgs/msg/DiagnosticArray"), DIAGNOSTICS, self._on_diag, reliable
        )

    def _on_truth(self, m: Any) -> None:
        self.truth[_stamp(m)] = (m.pose.position.x, m.pose.position.y)

    def _on_obs(self, m: Any) -> None:
        self.obs[_stamp(m)] = (m.pose.position.x, m.pose.position.y)

    def _on_est(self, m: Any) -> None:
        self.est[_stamp(m)] = (m.pose.pose.position.x, m.pose.pose.position.y)

    def _on_diag(self, m: Any) -> None:
        for status in m.status:
            if status.name == "dbcslam_filter":
                self.diags.append({kv.key: kv.value for kv in status.values})


def _filter_command(particles: int, *, pusher_wrench: bool, threads: int = 0) -> list[str]:
    """The filter node with ``particles`` (< 0: its live default) and ``threads`` (0:
    automatic), diagnostics twice a second."""
    cmd = [sys.executable, "-m", "dbcslam_ros.node.filter_node", "--ros-args"]
    cmd += ["-p", f"particles:={particles}", "-p", "diagnostics_period:=0.5"]
    cmd += ["-p", f"threads:={threads}"]
    cmd += ["-p", f"use_pusher_wrench:={'true' if pusher_wrench else 'false'}"]
    return cmd


def _sim_command(scenario: str, engine: str, duration: float) -> list[str]:
    """The simulator node; it waits for the filter and the listener before it starts."""
    cmd = [sys.executable, "-m", "sim_publisher.node", "--ros-args", "-p", f"scenario:={scenario}"]
    cmd += ["-p", f"engine:={engine}", "-p", "wait_for_subscribers:=30.0"]
    cmd += ["-p", "min_subscribers:=2"]  # the filter and this listener
    if duration > 0.0:
        cmd += ["-p", f"duration:={duration}"]
    return cmd


def _log(log_dir: Path | None, scenario: str, name: str) -> Any:
    """Where a process's output goes: ``<log_dir>/<scenario>_<name>.log``, or nowhere."""
    if log_dir is None:
        return subprocess.DEVNULL
    log_dir.mkdir(parents=True, exist_ok=True)
    return (log_dir / f"{scenario}_{name}.log").open("wb")


def _listen_until_exit(
    node: Any, sim: subprocess.Popen[bytes], scenario: str, started: float, timeout_s: float
) -> None:
    """Spin ``node`` until the simulator exits (within ``timeout_s`` of ``started``, monotonic
    s) with code 0."""
    from dbcslam_ros import runtime as rt

    while sim.poll() is None:
        if time.monotonic() - started > timeout_s:
            msg = f"bench_live: {scenario} simulator still running after {timeout_s} s"
            raise RuntimeError(msg)
        rt.spin_once(node, timeout_sec=0.05)
    if sim.returncode != 0:
        msg = f"bench_live: simulator for {scenario} exited with code {sim.returncode}"
        raise RuntimeError(msg)


def _listen_for_last_diagnostics(node: Any, diags: list[dict[str, str]]) -> None:
    """Spin up to 3 s more, until two more /diagnostics arrived (they cover the last poses)."""
    from dbcslam_ros import runtime as rt

    n_diag = len(diags)
    end = time.monotonic() + 3.0
    while time.monotonic() < end and len(diags) < n_diag + 2:
        rt.spin_once(node, timeout_sec=0.05)


def _live_result(
    heard: _Heard,
    scenario: str,
    engine: str,
    particles: int,
    *,
    load_before: float,
    wall: float,
) -> LiveResult:
    """The run's figures: the filter's last /diagnostics, errors over the stamps heard."""
    if not heard.diags:
        msg = f"bench_live: no /diagnostics from the filter node for {scenario}"
        raise RuntimeError(msg)
    d = heard.diags[-1]
    truth, obs, est = heard.truth, heard.obs, heard.est
    common = [s for s in est if s in truth and s in obs]
    err = [math.dist(est[s], truth[s]) for s in common]
    noise = [math.dist(obs[s], truth[s]) for s in common]
    received = int(d.get("poses_received", "0"))
    dropped = int(d.get("backlog_dropped", "0"))
    lat_p95 = _float(d, "latency_ms_p95")
    return LiveResult(
        scenario=scenario,
        engine=engine,
        particles=int(d.get("particles", str(particles))),
        load_before=round(load_before, 2),
        wall_s=round(wall, 2),
        poses_sent=len(truth),
        poses_received=received,
        poses_used=int(d.get("estimates_published", "0")),
        backlog_dropped=dropped,
        skipped_steps=int(d.get("skipped_steps", "0")),
        model_step_ms_mean=_float(d, "model_step_time_ms_mean"),
        model_step_ms_p95=_float(d, "model_step_time_ms_p95"),
        latency_ms_mean=_float(d, "latency_ms_mean"),
        latency_ms_p95=lat_p95,
        latency_ms_max=_float(d, "latency_ms_max"),
        position_error_mm=round(1e3 * float(np.mean(err)), 3) if err else math.nan,
        noise_mm=round(1e3 * float(np.mean(noise)), 3) if noise else math.nan,
        filter_steps=int(d.get("filter_steps", "0")),
        force_steps=int(d.get("force_steps", "0")),
        keeps_up=bool(
            received > 0
            and dropped <= KEEP_UP_DROP_FRACTION * received
            and lat_p95 < 1e3 / RATE_HZ
        ),
    )


#: Simulated runs already generated by :func:`offline_cpu` (scenario, engine, duration).
_RUNS: dict[tuple[str, str, float], tuple[Any, list[Any]]] = {}


def offline_cpu(
    scenario: str,
    *,
    particles: int = -1,
    duration: float = 0.0,
    engine: str = "pybullet",
    pusher_wrench: bool = True,
) -> OfflineResult:
    """CPU time per model step of the live filter configuration on one simulated run.

    The run is the simulator node's (same engine, default seed); its inputs are fed to a
    :class:`FilterSession` configured like the filter node (presets + ``particles``; < 0: the
    node's live default for the kind), pose by pose without pacing; pusher_wrench: use the
    pusher F/T readings (push), like the node's ``use_pusher_wrench``.
    """
    from dbcslam_ros import runtime as rt
    from dbcslam_ros.convert import JointReading, PoseReading, WrenchReading, estimate_messages
    from dbcslam_ros.node.params import PARAMETERS, build_config
    from dbcslam_ros.node.session import FilterSession
    from sim_publisher.node import make_source

    key = (scenario, engine, duration)
    if key not in _RUNS:
        src = make_source(scenario, engine=engine, duration=duration)
        _RUNS[key] = (src, list(src.ticks))
    src, ticks = _RUNS[key]
    sc = src.scenario
    params = {name: default for name, (default, _) in PARAMETERS.items()}
    params["particles"] = particles
    session = FilterSession(sc, build_config(sc.kind, params), seed=0)
    order = [src.joint_names.index(j) for j in sc.joints]
    cpu: list[float] = []
    wall: list[float] = []
    out_cpu: list[float] = []
    err: list[float] = []
    noise: list[float] = []
    for tick in ticks:
        t_ns = round(tick.t * 1e9)
        session.add_joints(
            JointReading(t_ns, tuple(float(tick.observed_joints[i]) for i in order))
        )
        fx, fy, tau = (float(v) for v in tick.wrench)
        session.add_wrench(WrenchReading(t_ns, fx, fy, tau))
        if tick.pusher_wrench is not None and pusher_wrench:
            px, py, ptau = (float(v) for v in tick.pusher_wrench)
            session.add_pusher_wrench(WrenchReading(t_ns, px, py, ptau))
        x, y, yaw = (float(v) for v in tick.observed_pose)
        c0, w0 = time.process_time(), time.perf_counter()
        res = session.add_pose(PoseReading(t_ns, x, y, yaw))
        c1, w1 = time.process_time(), time.perf_counter()
        if res:
            cpu.append((c1 - c0) / res[0].model_steps)
            wall.append((w1 - w0) / res[0].model_steps)
            c0 = time.process_time()
            for msg in estimate_messages(res[0].estimate, sc, t_ns, "world").values():
                rt.encode(msg)
            out_cpu.append(time.process_time() - c0)
            pose = res[0].estimate.pose
            err.append(math.hypot(pose[0] - tick.pose[0], pose[1] - tick.pose[1]))
            noise.append(math.hypot(x - tick.pose[0], y - tick.pose[1]))
    skip = min(10, len(cpu) // 10)  # first steps: imports and caches
    c = np.asarray(cpu[skip:]) * 1e3
    return OfflineResult(
        cpu_ms_mean=round(float(c.mean()), 3),
        cpu_ms_p95=round(float(np.percentile(c, 95)), 3),
        wall_ms_mean=round(1e3 * float(np.mean(wall[skip:])), 3),
        output_cpu_ms_mean=round(1e3 * float(np.mean(out_cpu[skip:])), 3),
        steps=len(c),
        position_error_mm=round(1e3 * float(np.mean(err)), 3),
        noise_mm=round(1e3 * float(np.mean(noise)), 3),
    )


def table(results: Sequence[LiveResult]) -> str:
    """Markdown table of the runs."""
    head = (
        "| scenario | particles | load | poses sent / received / used | backlog drops "
        "(coasted steps) | ms/model step mean / p95 | latency ms mean / p95 / max "
        "| pos. error / noise (mm) | keeps up | offline CPU ms/step mean / p95 + outputs "
        "| offline pos. error / noise (mm) |\n"
        "|---|---|---|---|---|---|---|---|---|---|---|\n"
    )
    rows = []
    for r in results:
        o = r.offline
        if o is not None:
            off = (
                f"{o.cpu_ms_mean:.2f} / {o.cpu_ms_p95:.2f} + {o.output_cpu_ms_mean:.2f} "
                f"| {o.position_error_mm:.2f} / {o.noise_mm:.2f}"
            )
        else:
            off = "- | -"
        rows.append(
            f"| {r.scenario} ({r.engine}) | {r.particles} | {r.load_before:.1f} "
            f"| {r.poses_sent} / {r.poses_received} / {r.poses_used} "
            f"| {r.backlog_dropped} ({r.skipped_steps}) "
            f"| {r.model_step_ms_mean:.2f} / {r.model_step_ms_p95:.2f} "
            f"| {r.latency_ms_mean:.2f} / {r.latency_ms_p95:.2f} / {r.latency_ms_max:.1f} "
            f"| {r.position_error_mm:.2f} / {r.noise_mm:.2f} ({r.error_over_noise:.2f}x) "
            f"| {_yes_no(r.keeps_up)} | {off} |"
        )
    return head + "\n".join(rows) + "\n"


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="python -m dbcslam_research.bench_live",
        description="Live benchmark: simulator node + filter node in real time on loopback.",
    )
    p.add_argument("--scenarios", nargs="+", choices=SCENARIOS, default=list(SCENARIOS))
    p.add_argument(
        "--particles",
        type=int,
        nargs="+",
        default=[-1],
        help="filter particles, one run per value (default -1: the node's live default)",
    )
    p.add_argument("--duration", type=float, default=0.0, help="s (default: scenario's)")
    p.add_argument("--engine", choices=("pybullet", "core"), default="pybullet")
    p.add_argument("--offline", action="store_true", help="also measure offline CPU ms/step")
    p.add_argument(
        "--no-pusher-wrench", action="store_true", help="filter without /pusher/wrench (push)"
    )
    p.add_argument("--no-live", action="store_true", help="offline measurement only")
    p.add_argument(
        "--threads",
        type=int,
        default=0,
        help="the filter node's threads parameter (default 0: automatic, the usable CPUs)",
    )
    p.add_argument("--domain-id", type=int, default=None, help="default: random 150..230")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="directory for md/json")
    p.add_argument("--logs", type=Path, default=None, help="directory for process logs")
    args = p.parse_args(argv)
    for n in args.particles:
        if n == 0 or n < -1:
            p.error(f"--particles {n}: expected >= 1 (or -1 for the live default)")
    if args.engine == "core" and "push" in args.scenarios:
        p.error("--engine core has no push scenario; use --engine pybullet")
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; exit 0 on success, 1 when a run failed, 2 on bad arguments."""
    from dbcslam_ros.node.params import live_particles

    args = parse_args(argv)
    os.environ["ROS_DOMAIN_ID"] = str(
        args.domain_id if args.domain_id is not None else random.randint(150, 230)
    )
    results: list[LiveResult] = []
    failed = False
    if not args.no_live:
        from dbcslam_ros import runtime as rt

        rt.init(["bench_live"])
    try:
        for sc, particles in itertools.product(args.scenarios, args.particles):
            off = None
            if args.offline or args.no_live:
                off = offline_cpu(
                    sc,
                    particles=particles,
                    duration=args.duration,
                    engine=args.engine,
                    pusher_wrench=not args.no_pusher_wrench,
                )
            if args.no_live:
                n = particles if particles > 0 else live_particles(sc)
                results.append(_offline_only(sc, args.engine, n, off))
                continue
            try:
                res = run_live(
                    sc,
                    particles=particles,
                    duration=args.duration,
                    engine=args.engine,
                    log_dir=args.logs,
                    pusher_wrench=not args.no_pusher_wrench,
                    threads=args.threads,
                )
            except RuntimeError as err:
                print(str(err), file=sys.stderr)
                failed = True
                continue
            results.append(LiveResult(**{**_fields(res), "offline": off}))
    finally:
        if not args.no_live:
            rt.try_shutdown()
    text = table(results)
    print(text, end="")
    args.out.mkdir(parents=True, exist_ok=True)
    command = "python -m dbcslam_research.bench_live " + " ".join(
        sys.argv[1:] if argv is None else argv
    )
    (args.out / "bench_live.md").write_text(
        "# Live benchmark (simulator node + filter node, 100 Hz real time)\n\n"
        f"Command: `{command.strip()}`; {platform.node()}, {os.cpu_count()} CPUs, "
        f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}. `load` = 1-min load "
        "average before the run (other processes on the machine).\n\n" + text
    )
    payload = {
        "command": command.strip(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "runs": [{**asdict(r), "error_over_noise": round(r.error_over_noise, 3)} for r in results],
    }
    (args.out / "bench_live.json").write_text(json.dumps(_json_safe(payload), indent=2) + "\n")
    return 1 if failed else 0


def _yes_no(flag: bool | None) -> str:
    return "-" if flag is None else ("yes" if flag else "no")


def _json_safe(value: Any) -> Any:
    """NaN -> None (strict JSON), recursively."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_safe(v) for v in value]
    return value


def _fields(res: LiveResult) -> dict[str, Any]:
    return {name: getattr(res, name) for name in res.__dataclass_fields__}


def _offline_only(
    scenario: str, engine: str, particles: int, off: OfflineResult | None
) -> LiveResult:
    nan = math.nan
    return LiveResult(
        scenario=scenario,
        engine=engine,
        particles=particles,
        load_before=round(os.getloadavg()[0], 2),
        wall_s=nan,
        poses_sent=0,
        poses_received=0,
        poses_used=0,
        backlog_dropped=0,
        skipped_steps=0,
        model_step_ms_mean=nan,
        model_step_ms_p95=nan,
        latency_ms_mean=nan,
        latency_ms_p95=nan,
        latency_ms_max=nan,
        position_error_mm=nan,
        noise_mm=nan,
        keeps_up=None,
        offline=off,
    )


if __name__ == "__main__":
    sys.exit(main())

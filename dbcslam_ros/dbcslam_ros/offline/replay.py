"""Offline replay: run the filter node's processing over a recorded bag as fast as it can.

``dbcslam replay BAG -o OUTDIR`` (see :mod:`dbcslam_ros.cli.commands.replay`) calls
:func:`replay_bag`. Replay drives a :class:`~dbcslam_ros.node.session.FilterSession` directly,
with the live node's pieces and parameters (:mod:`dbcslam_ros.node.params`): every input
message of the bag goes, in log-time order, through the node's one input path
(:func:`~dbcslam_ros.node.inputs.feed_input`: validation, the session's stamp rules), each
``/object/pose`` is processed at once (gating and resets as live; no backlog, no dropped
poses, no wall-clock effects) and the messages of each estimate are the node's
(:class:`~dbcslam_ros.node.outputs.EstimateOutputs`).

Output bag (a rosbag2 MCAP directory, OUTDIR):

* every topic of the source bag except earlier estimates (``/dbcslam/*``, ``/diagnostics``),
  byte for byte at its original log time and with its recorded QoS (inputs, ``/scenario``,
  truth topics, ``/clock`` ...);
* the outputs of each filter step, ``/dbcslam/pose`` first, then ``/dbcslam/odometry``,
  ``/dbcslam/contact_modes``, ``/dbcslam/friction``, ``/dbcslam/friction_map``, and
  ``/dbcslam/markers`` once per ``marker_period`` of bag time (0.1 s, as live), all logged
  at the stamp of the observation they answer (log time = ``header.stamp`` of that step's
  ``/dbcslam/pose``), as the contract requires;
* ``/diagnostics`` every ``diagnostics_period`` seconds of bag time (stamp and log time: the
  latest estimate's stamp).

Next to the bag files: ``metrics.json`` (:func:`dbcslam_ros.offline.evaluate.evaluate_bag`; without
truth topics only the counts and timings) and PNG plots (:mod:`dbcslam_ros.offline.report`).

The module also writes contract bags from the core's synthetic trajectories
(:func:`write_trajectory_bag`), the same messages the simulator node's ``core`` engine
publishes, for tests and offline experiments without DDS.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

import numpy as np
import yaml

from dbcslam_core.errors import DbcSlamError
from dbcslam_core.scenario import Scenario
from dbcslam_ros.bag import BagWriter, contract_qos, find_bags, open_bag
from dbcslam_ros.contract import (
    DIAGNOSTICS,
    INPUT_TOPICS,
    JOINT_STATES,
    OBJECT_POSE,
    OBJECT_WRENCH,
    OUTPUT_TOPICS,
    POSE,
    SCENARIO,
    TRUTH_CONTACT_MODES,
    TRUTH_FRICTION,
    TRUTH_POSE,
    message_type,
)
from dbcslam_ros.errors import BagError, UsageError
from dbcslam_ros.node.session import FilterSession
from dbcslam_ros.offline.evaluate import BagMessages, bag_arrays

if TYPE_CHECKING:
    from dbcslam_ros.offline.evaluate import BagArrays

__all__ = [
    "INPUT_TOPICS",
    "ReplayOptions",
    "ReplayResult",
    "load_filter_params",
    "replay_bag",
    "replay_many",
    "write_trajectory_bag",
]

NS = 1_000_000_000

#: Particles of a replay when the parameters do not set them (the live node's default is
#: smaller, for real time).
REPLAY_PARTICLES = 500
#: Files replay writes next to the bag; an output directory holding only these (and bag
#: files) may be replaced with ``overwrite``.
_PRODUCT_SUFFIXES = (".mcap", ".png", ".json", ".tmp")


@dataclass(frozen=True)
class ReplayOptions:
    """How to replay.

    Attributes:
        params: filter node parameters (name -> value) overriding the node's defaults; see
            :data:`dbcslam_ros.node.params.PARAMETERS`.
        salvage: read a damaged bag up to the damage instead of failing.
        plots: write PNG plots next to the bag.
        progress: stream for the progress line (None: silent).
        overwrite: replace an existing replay output directory.
    """

    params: Mapping[str, Any] = field(default_factory=dict)
    salvage: bool = False
    plots: bool = True
    progress: IO[str] | None = None
    overwrite: bool = False


@dataclass(frozen=True)
class ReplayResult:
    """What one replay produced.

    Attributes:
        source: the replayed bag; out: the output bag directory.
        poses: /object/pose messages in the source; estimates: /dbcslam/pose written.
        wall_s: wall time of the filter loop (s); steps_per_s = estimates / wall_s.
        rejected: inputs rejected per reason (node counters).
        metrics: evaluate's metrics dict (also in out/metrics.json).
        plots: PNG files written.
    """

    source: Path
    out: Path
    poses: int
    estimates: int
    wall_s: float
    rejected: dict[str, int]
    metrics: dict[str, Any]
    plots: tuple[Path, ...]

    @property
    def steps_per_s(self) -> float:
        """Estimates per wall-clock second of the filter loop."""
        return self.estimates / self.wall_s if self.wall_s > 0 else math.inf


# -- parameters ------------------------------------------------------------------------------
def load_filter_params(path: str | Path) -> dict[str, Any]:
    """Filter node parameters from a ROS 2 parameters YAML file.

    Accepts ``dbcslam_filter: {ros__parameters: {...}}`` (any node name, or ``/**``) or a
    plain mapping of parameter names. Unknown names raise UsageError listing the valid ones.
    """
    from dbcslam_ros.node.params import PARAMETERS

    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as err:
        msg = f"{p}: cannot read the parameters file: {err}"
        raise UsageError(msg) from err
    if data is None:
        return {}
    if not isinstance(data, dict):
        msg = f"{p}: expected a mapping of parameters, got {type(data).__name__}"
        raise UsageError(msg)
    params: dict[str, Any] = {}
    nested = [v for v in data.values() if isinstance(v, dict) and "ros__parameters" in v]
    if nested:
        for section in nested:
            params.update(section["ros__parameters"] or {})
    else:
        params = dict(data)
    unknown = sorted(set(params) - set(PARAMETERS))
    if unknown:
        msg = f"{p}: unknown filter parameter(s) {unknown}; valid: {sorted(PARAMETERS)}"
        raise UsageError(msg)
    return params


# -- the offline logger -----------------------------------------------------------------------
class _Logger:
    """Counts warnings (reported in ``metrics.json``) instead of printing them."""

    def __init__(self) -> None:
        self.warnings: dict[str, int] = {}

    def info(self, _msg: str, **_kwargs: Any) -> None:
        return None

    def warning(self, msg: str, **_kwargs: Any) -> None:
        self.warnings[msg] = self.warnings.get(msg, 0) + 1

    def error(self, msg: str, **kwargs: Any) -> None:
        self.warning(msg, **kwargs)


# -- replay ----------------------------------------------------------------------------------
def _prepare_out(out: Path, overwrite: bool) -> None:
    if not out.exists():
        return
    if not out.is_dir():
        msg = f"{out}: exists and is not a directory"
        raise UsageError(msg)
    children = list(out.iterdir())
    if not children:
        out.rmdir()
        return
    if not overwrite:
        msg = f"{out}: already exists; not overwriting (pass --overwrite to replace it)"
        raise UsageError(msg)
    foreign = [
        c.name
        for c in children
        if c.is_dir() or not (c.name == "metadata.yaml" or c.name.endswith(_PRODUCT_SUFFIXES))
    ]
    if foreign:
        msg = f"{out}: holds files replay did not write ({foreign[:3]}); refusing to replace it"
        raise UsageError(msg)
    shutil.rmtree(out)


class _Progress:
    """A single progress line (carriage return), refreshed at most 4 times a second."""

    def __init__(self, stream: IO[str] | None, name: str, total: int) -> None:
        self.stream = stream
        self.name = name
        self.total = max(total, 1)
        self.started = time.perf_counter()
        self._last = 0.0

    def update(self, done: int, estimates: int, *, final: bool = False) -> None:
        if self.stream is None:
            return
        now = time.perf_counter()
        if not final and now - self._last < 0.25:
            return
        self._last = now
        elapsed = now - self.started
        rate = estimates / elapsed if elapsed > 0 else 0.0
        line = (
            f"\rreplay {self.name}: pose {done}/{self.total} ({100.0 * done / self.total:3.0f}%)"
            f", {estimates} estimates, {rate:.0f} steps/s"
        )
        self.stream.write(line + ("\n" if final else ""))
        self.stream.flush()


class _Replayer:
    """The filter node's processing of a bag, driving a :class:`FilterSession` directly:
    ``/scenario`` configures the session (a changed scenario reconfigures it), every other
    input goes through :func:`~dbcslam_ros.node.inputs.feed_input` (the live node's path) and
    each pose is processed at once; the estimate's messages
    (:class:`~dbcslam_ros.node.outputs.EstimateOutputs`) and ``/diagnostics`` every
    ``diagnostics_period`` s of bag time go to ``write(topic, msg, log_time_ns)``.

    Raises:
        UsageError: bad parameters or an unreadable ``scenario_file``.
    """

    def __init__(
        self, params: dict[str, Any], write: Callable[[str, Any, int], None], log: _Logger
    ) -> None:
        from dbcslam_ros.errors import ParameterError
        from dbcslam_ros.node.outputs import EstimateOutputs
        from dbcslam_ros.node.params import check_params, load_extensions

        self.params = params
        self.write = write
        self.log = log
        try:
            check_params(params)
            self.extensions = load_extensions(str(params["model_file"]))
        except ParameterError as err:
            raise UsageError(str(err)) from err
        frame = str(params["frame_id"])
        marker_period = float(params["marker_period"])
        self.outputs = EstimateOutputs(frame, int(params["marker_particles"]), marker_period, log)
        self.diag_period_ns = int(float(params["diagnostics_period"]) * NS)
        self.session: FilterSession | None = None
        self.scenario: Scenario | None = None
        self.poses = 0
        self.estimates = 0
        self.rejected_before_scenario = 0
        self._next_diag: int | None = None
        if str(params["scenario_file"]):
            self._configure_from_file(Path(str(params["scenario_file"])))

    def _configure_from_file(self, path: Path) -> None:
        try:
            self._configure(Scenario.from_yaml(path.read_text()))
        except (OSError, DbcSlamError) as err:
            msg = f"cannot load scenario_file {str(path)!r}: {err}"
            raise UsageError(msg) from err

    def _configure(self, scenario: Scenario) -> None:
        from dbcslam_ros.errors import ParameterError
        from dbcslam_ros.node.params import make_session

        try:
            self.session = make_session(scenario, self.params, self.extensions)
        except ParameterError as err:
            raise UsageError(str(err)) from err
        self.scenario = scenario

    def take(self, topic: str, msg: Any) -> None:
        """One input message of the bag, in log-time order."""
        from dbcslam_ros.node.inputs import feed_input

        if topic == SCENARIO:
            self._on_scenario(msg)
            return
        if topic == OBJECT_POSE:
            self.poses += 1
        if self.session is None:
            self.rejected_before_scenario += topic == OBJECT_POSE
            return
        use_force = bool(self.params["use_pusher_wrench"])
        text = feed_input(self.session, topic, msg, use_pusher_wrench=use_force)
        if text is not None:
            self.log.warning(text)
        if topic == OBJECT_POSE:
            self._process()

    def _on_scenario(self, msg: Any) -> None:
        if str(self.params["scenario_file"]):
            return
        try:
            scenario = Scenario.from_yaml(str(msg.data))
        except (DbcSlamError, ValueError, TypeError, KeyError) as err:
            self._reject_scenario(f"ignoring /scenario: {err}")
            return
        if self.scenario is not None and scenario == self.scenario:
            return
        try:
            self._configure(scenario)
        except UsageError as err:
            self._reject_scenario(f"cannot configure for /scenario: {err}")

    def _reject_scenario(self, text: str) -> None:
        if self.session is not None:
            self.session.reject("bad_scenario")
        else:
            self.rejected_before_scenario += 1
        self.log.warning(text)

    def _process(self) -> None:
        assert self.session is not None and self.scenario is not None
        taken = self.session.process_pending()
        if taken is None:  # the pose was rejected on arrival
            return
        outcome, _received = taken
        if outcome.rejected == "nan_estimate":
            self.outputs.not_published["nan_estimate"] += 1
        if outcome.message and outcome.level != "info":
            self.log.warning(outcome.message)
        for res in outcome.estimates:
            msgs = self.outputs.messages(res, self.scenario, self.session.last_joints())
            for topic, m in msgs:  # logged at the stamp of the observation they answer
                self.write(topic, m, res.stamp_ns)
            self.estimates += bool(msgs)
            self._diagnostics_due(res.stamp_ns)

    def _diagnostics_due(self, stamp_ns: int) -> None:
        if self._next_diag is None:
            self._next_diag = stamp_ns + self.diag_period_ns
        elif stamp_ns >= self._next_diag:
            self.write_diagnostics(stamp_ns)
            self._next_diag = stamp_ns + self.diag_period_ns

    def write_diagnostics(self, stamp_ns: int) -> None:
        """``/diagnostics`` at this stamp: the live node's keys that mean something offline
        (counts; the filter's statistics from :meth:`FilterSession.statistics`)."""
        from dbcslam_ros.node.outputs import diagnostics_message

        values = {
            "scenario": self.scenario.kind if self.scenario is not None else "",
            "poses_received": str(self.poses),
            "estimates_published": str(self.estimates),
            "rejected_before_scenario": str(self.rejected_before_scenario),
            "backlog_dropped": "0",
        }
        if self.session is not None:
            values.update(self.session.statistics())
        msg = diagnostics_message(values, stamp_ns, configured=self.session is not None)
        self.write(DIAGNOSTICS, msg, stamp_ns)

    def rejected(self) -> dict[str, int]:
        """Inputs rejected per reason (``before_scenario``: before any scenario)."""
        out = dict(self.session.rejected) if self.session is not None else {}
        if self.rejected_before_scenario:
            out["before_scenario"] = self.rejected_before_scenario
        return out


def _replay_params(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """The filter node's parameters for an offline replay: no real-time budget, so the full
    filter (:data:`REPLAY_PARTICLES`, not the node's live default), unless asked otherwise;
    everything else as the live node, ``/dbcslam/markers`` included (one per
    ``marker_period``, 0.1 s of bag time; ``marker_period: 0.0`` for one per estimate, which
    costs ~0.3 s per 400 estimates of building and encoding)."""
    from dbcslam_ros.errors import ParameterError
    from dbcslam_ros.node.params import coerce_params

    params = dict(overrides)
    params.setdefault("particles", REPLAY_PARTICLES)
    try:
        return coerce_params(params)
    except ParameterError as err:
        raise UsageError(str(err)) from err


def _check_source(src: Path, counts: Mapping[str, int], params: Mapping[str, Any]) -> int:
    """The number of poses to replay; BagError when the bag cannot be replayed."""
    n_poses = counts.get(OBJECT_POSE, 0)
    if n_poses == 0:
        have = ", ".join(sorted(t for t, n in counts.items() if n)) or "nothing"
        msg = f"{src}: no /object/pose messages to replay (the bag has {have})"
        raise BagError(msg)
    if counts.get(SCENARIO, 0) == 0 and not params.get("scenario_file"):
        msg = f"{src}: no /scenario in the bag; pass --scenario-file FILE"
        raise BagError(msg)
    return n_poses


def _open_output(
    dst: Path, src: Path, topics: Mapping[str, Any]
) -> tuple[BagWriter, dict[str, Any]]:
    """The output bag with its topics: the filter's outputs, then every source topic except
    earlier estimates; returns the writer and the copied source topics."""
    writer = BagWriter(dst, overwrite=True, custom_data={"dbcslam_replay_of": str(src)})
    writer.open()
    for topic in OUTPUT_TOPICS:
        writer.add_topic(topic, message_type(topic), (contract_qos(topic),))
    copied = {
        name: t
        for name, t in topics.items()
        if not name.startswith("/dbcslam/") and name != DIAGNOSTICS
    }
    for t in copied.values():
        writer.add_topic(t.name, t.msgtype, t.offered_qos or (contract_qos(t.name),))
    return writer, copied


def _run(
    reader: Any,
    output: tuple[BagWriter, Mapping[str, Any], BagMessages, BagMessages],
    replayer: _Replayer,
    progress: _Progress,
) -> float:
    """Copy every source message (output = (writer, copied topics, messages written,
    messages of the source's own estimates)) and hand the inputs to the replayer; wall time
    of the loop."""
    writer, copied, written, recorded = output
    done = 0
    started = time.perf_counter()
    for raw, obj in reader.decoded([*copied, POSE]):
        if raw.topic not in copied:  # an estimate of the source bag (not copied)
            recorded.add(raw.topic, raw.log_time_ns, obj)
            continue
        writer.write(raw.topic, raw.data, raw.log_time_ns, raw.publish_time_ns)
        written.record(raw.topic, raw.log_time_ns, obj)
        if raw.topic not in INPUT_TOPICS:
            continue
        replayer.take(raw.topic, obj)
        if raw.topic == OBJECT_POSE:
            done += 1
            progress.update(done, replayer.estimates)
    wall = time.perf_counter() - started
    if replayer.session is not None and replayer.session.last_estimate is not None:
        replayer.write_diagnostics(replayer.session.last_estimate.stamp_ns)
    progress.update(done, replayer.estimates, final=True)
    return wall


def replay_bag(
    bag: str | Path, out: str | Path, options: ReplayOptions | None = None
) -> ReplayResult:
    """Replay one bag into the output directory ``out`` (see the module docstring).

    Raises:
        BagError: the bag is damaged (without salvage), has no /object/pose, or no scenario
            (neither /scenario nor the ``scenario_file`` parameter).
        UsageError: bad parameters or an output directory that cannot be used.
    """
    from dbcslam_ros import runtime as rt

    opts = options or ReplayOptions()
    src, dst = Path(bag), Path(out)
    params = _replay_params(opts.params)
    logger = _Logger()
    written = BagMessages(path=dst)  # what goes into the output bag, for its metrics
    recorded = BagMessages(path=src)  # the source's own estimates, if any
    with open_bag(src, salvage=opts.salvage) as reader:
        counts = reader.counts()
        n_poses = _check_source(src, counts, params)
        _prepare_out(dst, opts.overwrite)
        writer, copied = _open_output(dst, src, reader.topics())

        def write(topic: str, msg: Any, t: int) -> None:
            writer.write(topic, rt.encode(msg), t)
            written.record(topic, t, msg)

        try:
            replayer = _Replayer(params, write, logger)
            progress = _Progress(opts.progress, src.name, n_poses)
            wall = _run(reader, (writer, copied, written, recorded), replayer, progress)
        finally:
            writer.close()
    rejected = replayer.rejected()
    warnings = sorted(logger.warnings.items(), key=lambda kv: -kv[1])
    if replayer.estimates == 0:
        why = "; ".join(f"{text} (x{n})" for text, n in warnings[:3]) or "no warnings"
        msg = (
            f"{src}: the filter produced no estimates from {n_poses} poses "
            f"(rejected inputs: {rejected or 'none'}; {why})"
        )
        raise BagError(msg)
    arrays, metrics, plots = _products(written, opts)
    metrics["replay"] = {
        "source": str(src),
        "poses": n_poses,
        "estimates": replayer.estimates,
        "wall_s": round(wall, 4),
        "steps_per_s": round(replayer.estimates / wall, 2) if wall > 0 else None,
        "rejected": rejected,
        "warnings": {text: n for text, n in warnings[:10]},
        "params": {k: v for k, v in sorted(params.items())},
    }
    if counts.get(POSE, 0):
        metrics["replay"]["recorded_estimates"] = _compare_recorded(recorded, arrays)
    (dst / "metrics.json").write_text(json.dumps(metrics, indent=2, sort_keys=False) + "\n")
    return ReplayResult(src, dst, n_poses, replayer.estimates, wall, rejected, metrics, plots)


def _compare_recorded(recorded: BagMessages, after: BagArrays) -> dict[str, Any]:
    """How the estimates recorded in the source bag (e.g. a live run) compare with the
    replayed ones (`after`, the arrays of the output bag) at the same stamps (m; differences
    of the planar position)."""
    before = bag_arrays(recorded)
    _, i, j = np.intersect1d(before.est_t, after.est_t, return_indices=True)
    diff = np.linalg.norm(before.est_pose[i, :2] - after.est_pose[j, :2], axis=1)
    return {
        "recorded": int(before.est_t.size),
        "replayed": int(after.est_t.size),
        "same_stamps": int(i.size),
        "position_diff_mean_m": round(float(diff.mean()), 6) if diff.size else None,
        "position_diff_max_m": round(float(diff.max()), 6) if diff.size else None,
    }


def _products(
    written: BagMessages, opts: ReplayOptions
) -> tuple[BagArrays, dict[str, Any], tuple[Path, ...]]:
    """The arrays, metrics (truth optional) and plots of a replayed bag, from the messages
    written to it (the same arrays as reading the bag back, without reading it: tested)."""
    from dbcslam_ros.offline.evaluate import evaluate_bag

    arrays = bag_arrays(written)
    metrics = evaluate_bag(written.path, require_truth=False, arrays=arrays)
    plots: tuple[Path, ...] = ()
    if opts.plots:
        from dbcslam_ros.offline.report import save_bag_figures

        plots = tuple(save_bag_figures(arrays, written.path))
    return arrays, metrics, plots


def replay_many(
    bag_arg: str | Path, out: str | Path, options: ReplayOptions | None = None
) -> list[ReplayResult]:
    """Replay one bag into ``out``, or every bag in a directory into ``out/<bag name>``."""
    bags = find_bags(bag_arg)
    outdir = Path(out)
    if len(bags) == 1 and Path(bag_arg) == bags[0]:
        return [replay_bag(bags[0], outdir, options)]
    return [replay_bag(b, outdir / b.name.removesuffix(".mcap"), options) for b in bags]


# -- bags from core trajectories -------------------------------------------------------------
def _trajectory_messages(traj: Any, t0_ns: int) -> Iterator[tuple[str, Any, int]]:
    """(topic, runtime message, stamp ns) per sample, in the simulator node's order."""
    from dbcslam_ros import runtime as rt
    from dbcslam_ros.convert import float64_multiarray, ns_to_stamp, pose_stamped, wrench_stamped

    sc = traj.scenario
    joint_cls = rt.message_class("sensor_msgs/msg/JointState")
    header_cls = rt.message_class("std_msgs/msg/Header")
    string_cls = rt.message_class("std_msgs/msg/String")
    contact_pair = np.asarray(sc.contact_pairs, dtype=np.int64)
    # per pair: the first contact of the pair (its coefficient varies along a patch), or -1
    # for a pair without contacts (the support pair of a push: its constant true value)
    first = [
        int(hits[0]) if (hits := np.flatnonzero(contact_pair == p)).size else -1
        for p in range(len(sc.friction.pairs))
    ]
    mu_pair = np.asarray(getattr(traj, "mu_pair", np.full(len(first), np.nan)), np.float64)
    eye = np.eye(4)
    yield SCENARIO, string_cls(data=str(sc.to_yaml())), t0_ns
    for k in range(traj.n_steps):
        stamp = t0_ns + round(float(traj.t[k]) * NS)
        q = np.zeros(3)
        q[: traj.q.shape[1]] = traj.q[k]
        obs = np.zeros(3)
        obs[: traj.obs.shape[1]] = traj.obs[k]
        u = np.zeros(3)
        u[: traj.u.shape[1]] = traj.u[k]
        if len(sc.joints):
            yield (
                JOINT_STATES,
                joint_cls(
                    header=header_cls(stamp=ns_to_stamp(stamp), frame_id="world"),
                    name=list(sc.joints),
                    position=[float(v) for v in traj.env_obs[k]],
                    velocity=[],
                    effort=[],
                ),
                stamp,
            )
        yield OBJECT_WRENCH, wrench_stamped(stamp, float(u[0]), float(u[1]), float(u[2])), stamp
        yield (
            OBJECT_POSE,
            pose_stamped(stamp, float(obs[0]), float(obs[1]), float(obs[2])),
            stamp,
        )
        yield (
            TRUTH_POSE,
            pose_stamped(stamp, float(q[0]), float(q[1]), float(q[2])),
            stamp,
        )
        modes = eye[np.asarray(traj.modes[k], dtype=np.int64)]
        yield TRUTH_CONTACT_MODES, float64_multiarray(modes, ("contacts", "modes")), stamp
        mu = traj.mu[min(k + 1, traj.n_steps - 1)]
        per_pair = np.asarray([mu[c] if c >= 0 else mu_pair[p] for p, c in enumerate(first)])
        yield TRUTH_FRICTION, float64_multiarray(per_pair, ("pairs",)), stamp


def write_trajectory_bag(traj: Any, path: str | Path, *, t0_ns: int = 0) -> Path:
    """Write a :class:`dbcslam_core.synthetic.Trajectory` as a contract bag (inputs + truth).

    Message order and stamps follow the simulator node's ``core`` engine (sample k stamped
    t0 + t_k; joints, wrench, pose, then truth); log time = stamp.
    """
    from dbcslam_ros import runtime as rt

    out = Path(path)
    with BagWriter(out) as writer:
        for topic, msg, stamp in _trajectory_messages(traj, t0_ns):
            writer.add_topic(topic, rt.type_name_of(msg), (contract_qos(topic),))
            writer.write(topic, rt.encode(msg), stamp)
    return out


def _main() -> int:  # pragma: no cover - manual helper
    import argparse

    parser = argparse.ArgumentParser(description="replay a bag (see `dbcslam replay`)")
    parser.add_argument("bag")
    parser.add_argument("-o", "--out", required=True)
    args = parser.parse_args()
    for res in replay_many(args.bag, args.out, ReplayOptions(progress=sys.stderr)):
        print(f"{res.out}: {res.estimates} estimates, {res.steps_per_s:.0f} steps/s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(_main())

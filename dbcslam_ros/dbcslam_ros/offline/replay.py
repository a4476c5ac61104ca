"""Offline replay: run the filter node's processing over a recorded bag as fast as it can.

``dbcslam replay BAG -o OUTDIR`` (see :mod:`dbcslam_ros.cli.commands.replay`) calls
:func:`replay_bag`. The filter is the live node's own code (:class:`~dbcslam_ros.node.filter_node.
FilterCore`, the object the live :class:`~dbcslam_ros.node.filter_node.FilterNode` wraps: the same
:class:`~dbcslam_ros.node.session.FilterSession`, input validation, gating and message building),
without any ROS node: every input message of the bag is handed to the core's callback for its
topic in log-time order, and each
``/object/pose`` is processed at once (no backlog, no dropped poses, no wall-clock effects).

Output bag (a rosbag2 MCAP directory, OUTDIR):

* every topic of the source bag except earlier estimates (``/dbcslam/*``, ``/diagnostics``),
  byte for byte at its original log time and with its recorded QoS (inputs, ``/scenario``,
  truth topics, ``/clock`` ...);
* the outputs of each filter step, ``/dbcslam/pose`` first, then ``/dbcslam/odometry``,
  ``/dbcslam/contact_modes``, ``/dbcslam/friction``, ``/dbcslam/friction_map``,
  ``/dbcslam/markers``, all logged at the stamp of the observation they answer (log time =
  ``header.stamp`` of that step's ``/dbcslam/pose``), as the contract requires;
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
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from dbcslam_ros.bag import BagWriter, contract_qos, find_bags, open_bag
from dbcslam_ros.contract import (
    DIAGNOSTICS,
    INPUT_TOPICS,
    JOINT_STATES,
    OBJECT_POSE,
    OBJECT_WRENCH,
    POSE,
    SCENARIO,
    TRUTH_CONTACT_MODES,
    TRUTH_FRICTION,
    TRUTH_POSE,
)
from dbcslam_ros.errors import BagError, UsageError

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
            :data:`dbcslam_ros.node.filter_node.PARAMETERS`.
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
    from dbcslam_ros.node.filter_node import PARAMETERS

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
    from dbcslam_ros.errors import ParameterError
    from dbcslam_ros.node.filter_node import OUTPUT_TYPES, FilterCore, coerce_params

    opts = options or ReplayOptions()
    src = Path(bag)
    dst = Path(out)
    params = dict(opts.params)
    # Offline there is no real-time budget: the full filter (not the node's live default
    # particle count) and one /dbcslam/markers message per estimate, unless asked otherwise.
    params.setdefault("particles", REPLAY_PARTICLES)
    params.setdefault("marker_period", 0.0)
    with open_bag(src, salvage=opts.salvage) as reader:
        topics = reader.topics()
        counts = reader.counts()
        n_poses = counts.get(OBJECT_POSE, 0)
        if n_poses == 0:
            have = ", ".join(sorted(t for t, n in counts.items() if n)) or "nothing"
            msg = f"{src}: no /object/pose messages to replay (the bag has {have})"
            raise BagError(msg)
        if counts.get(SCENARIO, 0) == 0 and not params.get("scenario_file"):
            msg = f"{src}: no /scenario in the bag; pass --scenario-file FILE"
            raise BagError(msg)
        _prepare_out(dst, opts.overwrite)
        writer = BagWriter(dst, overwrite=True, custom_data={"dbcslam_replay_of": str(src)})
        writer.open()
        estimates = 0
        current_stamp: list[int] = [0]

        def sink(topic: str, msg: Any) -> None:
            nonlocal estimates
            if topic == POSE:
                stamp = msg.header.stamp
                current_stamp[0] = int(stamp.sec) * NS + int(stamp.nanosec)
                estimates += 1
            writer.write(topic, rt.encode(msg), current_stamp[0])

        try:
            for topic, type_name in OUTPUT_TYPES.items():
                writer.add_topic(topic, type_name, (contract_qos(topic),))
            copied = {
                name: t
                for name, t in topics.items()
                if not name.startswith("/dbcslam/") and name != DIAGNOSTICS
            }
            for t in copied.values():
                writer.add_topic(t.name, t.msgtype, t.offered_qos or (contract_qos(t.name),))
            logger = _Logger()
            try:
                filt = FilterCore(coerce_params(params), sink, logger)
            except ParameterError as err:
                raise UsageError(str(err)) from err
            callbacks = filt.callbacks()
            diag_period_ns = int(float(filt.params["diagnostics_period"]) * NS)
            next_diag: int | None = None
            progress = _Progress(opts.progress, src.name, n_poses)
            done = 0
            started = time.perf_counter()
            for raw, obj in reader.decoded(copied):
                writer.write(raw.topic, raw.data, raw.log_time_ns, raw.publish_time_ns)
                callback = callbacks.get(raw.topic)
                if callback is None:
                    continue
                callback(obj)
                if raw.topic != OBJECT_POSE:
                    continue
                filt.process_pending()
                done += 1
                last = filt.last_estimate
                if last is not None:
                    if next_diag is None:
                        next_diag = last.stamp_ns + diag_period_ns
                    elif last.stamp_ns >= next_diag:
                        filt.publish_diagnostics()
                        next_diag = last.stamp_ns + diag_period_ns
                progress.update(done, estimates)
            wall = time.perf_counter() - started
            if filt.last_estimate is not None:
                filt.publish_diagnostics()
            progress.update(done, estimates, final=True)
        finally:
            writer.close()
    session = filt.session
    rejected = dict(session.rejected) if session is not None else {}
    if filt.rejected_before_scenario:
        rejected["before_scenario"] = filt.rejected_before_scenario
    warnings = sorted(logger.warnings.items(), key=lambda kv: -kv[1])
    if estimates == 0:
        why = "; ".join(f"{text} (x{n})" for text, n in warnings[:3]) or "no warnings"
        msg = (
            f"{src}: the filter produced no estimates from {n_poses} poses "
            f"(rejected inputs: {rejected or 'none'}; {why})"
        )
        raise BagError(msg)
    metrics, plots = _products(dst, opts)
    metrics["replay"] = {
        "source": str(src),
        "poses": n_poses,
        "estimates": estimates,
        "wall_s": round(wall, 4),
        "steps_per_s": round(estimates / wall, 2) if wall > 0 else None,
        "rejected": rejected,
        "warnings": {text: n for text, n in warnings[:10]},
        "params": {k: v for k, v in sorted(filt.params.items())},
    }
    if counts.get(POSE, 0):
        metrics["replay"]["recorded_estimates"] = _compare_recorded(src, dst, opts.salvage)
    (dst / "metrics.json").write_text(json.dumps(metrics, indent=2, sort_keys=False) + "\n")
    return ReplayResult(src, dst, n_poses, estimates, wall, rejected, metrics, plots)


def _compare_recorded(src: Path, out: Path, salvage: bool) -> dict[str, Any]:
    """How the estimates recorded in the source bag (e.g. a live run) compare with the
    replayed ones at the same stamps (m; differences of the planar position)."""
    from dbcslam_ros.offline.evaluate import load_bag_arrays

    before = load_bag_arrays(src, salvage=salvage)
    after = load_bag_arrays(out)
    _, i, j = np.intersect1d(before.est_t, after.est_t, return_indices=True)
    diff = np.linalg.norm(before.est_pose[i, :2] - after.est_pose[j, :2], axis=1)
    return {
        "recorded": int(before.est_t.size),
        "replayed": int(after.est_t.size),
        "same_stamps": int(i.size),
        "position_diff_mean_m": round(float(diff.mean()), 6) if diff.size else None,
        "position_diff_max_m": round(float(diff.max()), 6) if diff.size else None,
    }


def _products(out: Path, opts: ReplayOptions) -> tuple[dict[str, Any], tuple[Path, ...]]:
    """metrics (truth optional) and plots of a replayed bag."""
    from dbcslam_ros.offline.evaluate import evaluate_bag, load_bag_arrays

    arrays = load_bag_arrays(out)
    metrics = evaluate_bag(out, require_truth=False, arrays=arrays)
    plots: tuple[Path, ...] = ()
    if opts.plots:
        from dbcslam_ros.offline.report import save_bag_figures

        plots = tuple(save_bag_figures(arrays, out))
    return metrics, plots


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

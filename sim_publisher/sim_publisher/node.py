"""The simulator node ``sim_publisher``: publishes a simulated scenario on the contract topics.

Run: ``dbcslam sim --scenario gripper`` or ``ros2 run sim_publisher sim_node --ros-args -p
scenario:=gripper``.

Every sample time t_k = k / rate of the run it publishes, in this order (the filter steps on
the pose, so its inputs go first): ``/joint_states`` (noisy joint positions; empty for
``edge``), ``/object/wrench`` (the known applied wrench, mean over [t_k, t_k+1)),
``/pusher/wrench`` (push only: F/T sensor at the pusher), ``/object/pose`` (noisy observed
pose), then the truth: ``/truth/object/pose``, ``/truth/contact_modes`` (one-hot, dims
``contacts`` x ``modes``), ``/truth/friction`` (dim ``pairs``). ``/scenario`` is published
once, latched: only the a-priori model (candidates and prior of the friction, never the true
coefficients or their layout). QoS as in the contract: sensor data for the inputs, reliable
for the truth, reliable + transient local (depth 1) for ``/scenario``.

Time stamps: real-time pacing (default) stamps sample k with the wall time of its start plus
t_k; ``fast`` runs as fast as it can, stamps with the simulated time t_k and publishes
``/clock``. After the last sample the node waits (bounded) until reliable subscribers have
acknowledged everything, then exits with code 0.

Engines: ``pybullet`` (the physics simulation of :mod:`sim_publisher.simulate`) or ``core``
(the deterministic synthetic trajectories of :mod:`dbcslam_core.synthetic`: edge and gripper
only; fast and exactly consistent with the filter's model).
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node

from dbcslam_core.scenario import Scenario
from dbcslam_ros.contract import (
    JOINT_STATES,
    OBJECT_POSE,
    OBJECT_WRENCH,
    PUSHER_WRENCH,
    SCENARIO,
    TOPICS,
    TRUTH_CONTACT_MODES,
    TRUTH_FRICTION,
    TRUTH_POSE,
    TRUTH_TOPICS,
)

__all__ = ["ENGINES", "PARAMETERS", "SimNode", "Tick", "TickSource", "main", "make_source"]

FloatArray = NDArray[np.float64]
NS = 1_000_000_000
ENGINES: tuple[str, ...] = ("pybullet", "core")

# name: (default, description). Declared on the node with these types and descriptions.
PARAMETERS: dict[str, tuple[Any, str]] = {
    "scenario": ("edge", "scenario to simulate: edge | gripper | push"),
    "seed": (-1, "seed of the observation noise (-1: params file or default)"),
    "duration": (0.0, "simulated time in s (0: params file or scenario default)"),
    "rate": (0.0, "sample/publish rate in Hz (0: params file or default 100)"),
    "params_file": ("", "simulation parameters YAML (see sim_publisher.params)"),
    "fast": (False, "run as fast as possible, stamp with sim time and publish /clock"),
    "engine": ("pybullet", "pybullet (physics simulation) | core (synthetic trajectories)"),
    "wait_for_subscribers": (
        2.0,
        "s to wait for subscribers of /object/pose before the first sample (0: no wait)",
    ),
    "min_subscribers": (1, "number of /object/pose subscribers to wait for"),
    "frame_id": ("world", "frame of the published poses and wrenches"),
}


@dataclass(frozen=True)
class Tick:
    """One sample: what the node publishes at time t (s from the start of the run).

    pose / observed_pose: (x, y, yaw) true and noisy (m, m, rad); wrench: applied (fx, fy,
    tau) over [t, t + 1/rate) (N, N, N m); joints / observed_joints: (m) in the order of the
    source's joint names; pusher_wrench: noisy F/T reading at the pusher (push only, else
    None); modes: (C, 4) one-hot true modes; friction: (P,) true coefficient per pair.
    """

    t: float
    pose: FloatArray
    observed_pose: FloatArray
    wrench: FloatArray
    joints: FloatArray
    observed_joints: FloatArray
    pusher_wrench: FloatArray | None
    modes: FloatArray
    friction: FloatArray


@dataclass(frozen=True)
class TickSource:
    """A run to publish: the a-priori scenario, names, the sample period and the ticks."""

    scenario: Scenario
    scenario_yaml: str
    joint_names: tuple[str, ...]
    contacts: tuple[str, ...]
    pairs: tuple[str, ...]
    period: float
    n_ticks: int
    ticks: Iterator[Tick]


def _pybullet_source(scenario: str, params_file: str, overrides: dict[str, Any]) -> TickSource:
    from sim_publisher.simulate import make_simulation

    sim = make_simulation(scenario, params_file=params_file or None, **overrides)
    push = scenario == "push"

    def ticks() -> Iterator[Tick]:
        for rec in sim.records():
            yield Tick(
                t=rec.t,
                pose=rec.pose,
                observed_pose=rec.observed_pose,
                wrench=rec.wrench,
                joints=rec.joints,
                observed_joints=rec.observed_joints,
                pusher_wrench=rec.observed_pusher_wrench if push else None,
                modes=rec.modes,
                friction=rec.friction,
            )

    sc = sim.scenario()
    return TickSource(
        scenario=sc,
        scenario_yaml=sim.scenario_yaml(),
        joint_names=tuple(sim.joint_names),
        contacts=tuple(sim.contacts),
        pairs=tuple(sim.pairs),
        period=1.0 / float(sim.params.rate),
        n_ticks=int(sim.params.n_samples),
        ticks=ticks(),
    )


def _pad3(a: FloatArray) -> FloatArray:
    out = np.zeros(3)
    out[: a.shape[0]] = a
    return out


def _core_source(scenario: str, seed: int, duration: float, rate: float) -> TickSource:
    from dbcslam_core.synthetic import edge_trajectory, gripper_trajectory

    if scenario not in ("edge", "gripper"):
        msg = f"engine 'core' has no '{scenario}' trajectory; use edge or gripper"
        raise ValueError(msg)
    kwargs: dict[str, Any] = {"seed": max(0, seed)}
    if duration > 0.0:
        kwargs["duration"] = duration
    traj = (edge_trajectory if scenario == "edge" else gripper_trajectory)(**kwargs)
    sc = traj.scenario
    if rate > 0.0 and not math.isclose(rate * sc.dt, 1.0, rel_tol=1e-9):
        msg = f"engine 'core' samples at 1/dt = {1.0 / sc.dt:g} Hz; rate {rate:g} is not valid"
        raise ValueError(msg)
    n_modes = 4
    contact_pair = np.asarray(sc.contact_pairs, dtype=np.int64)
    first_contact = [
        int(np.flatnonzero(contact_pair == p)[0]) for p in range(len(sc.friction.pairs))
    ]

    def ticks() -> Iterator[Tick]:
        for k in range(traj.n_steps):
            # Truth friction at the next step's contact point (mu[k + 1] is evaluated at q[k]).
            mu_row = traj.mu[min(k + 1, traj.n_steps - 1)]
            yield Tick(
                t=float(traj.t[k]),
                pose=_pad3(traj.q[k]),
                observed_pose=_pad3(traj.obs[k]),
                wrench=_pad3(traj.u[k]),
                joints=np.asarray(traj.env[k], dtype=np.float64),
                observed_joints=np.asarray(traj.env_obs[k], dtype=np.float64),
                pusher_wrench=None,
                modes=np.eye(n_modes)[np.asarray(traj.modes[k], dtype=np.int64)],
                friction=np.asarray(mu_row[first_contact], dtype=np.float64),
            )

    return TickSource(
        scenario=sc,
        scenario_yaml=str(sc.to_yaml()),
        joint_names=tuple(sc.joints),
        contacts=tuple(sc.contacts),
        pairs=tuple(sc.friction.pairs),
        period=float(sc.dt),
        n_ticks=int(traj.n_steps),
        ticks=ticks(),
    )


def make_source(
    scenario: str,
    *,
    engine: str = "pybullet",
    seed: int = -1,
    duration: float = 0.0,
    rate: float = 0.0,
    params_file: str = "",
) -> TickSource:
    """The run a node publishes. seed < 0, duration <= 0, rate <= 0 keep the defaults (or the
    params file's values). Raises ValueError (core engine) or sim_publisher's ParamError."""
    if engine not in ENGINES:
        msg = f"unknown engine {engine!r}; valid engines are {list(ENGINES)}"
        raise ValueError(msg)
    if engine == "core":
        if params_file:
            msg = "engine 'core' takes no params_file (its trajectories are fixed)"
            raise ValueError(msg)
        return _core_source(scenario, seed, duration, rate)
    overrides: dict[str, Any] = {}
    if seed >= 0:
        overrides["seed"] = int(seed)
    if duration > 0.0:
        overrides["duration"] = float(duration)
    if rate > 0.0:
        overrides["rate"] = float(rate)
    return _pybullet_source(scenario, params_file, overrides)


class SimNode(Node):
    """The ``sim_publisher`` rclpy node: publishes a :class:`TickSource` on the contract
    topics (see the module docstring)."""

    def __init__(self, source: TickSource | None = None, **kwargs: Any) -> None:
        from dbcslam_ros import runtime as rt

        super().__init__("sim_publisher", **kwargs)
        self.rt = rt
        node = self
        self.log = self.get_logger()  # type: ignore[no-untyped-call]
        self.params: dict[str, Any] = {
            name: self.declare_parameter(
                name, default, ParameterDescriptor(description=text)
            ).value
            for name, (default, text) in PARAMETERS.items()
        }
        p = self.params
        self.source = source or make_source(
            str(p["scenario"]),
            engine=str(p["engine"]),
            seed=int(p["seed"]),
            duration=float(p["duration"]),
            rate=float(p["rate"]),
            params_file=str(p["params_file"]),
        )
        self.fast = bool(p["fast"])
        self.frame = str(p["frame_id"])
        cls = rt.message_class
        sensor = rt.qos_profile("sensor_data", depth=10)
        # Reliable truth: in fast mode the whole run may be queued before a reader catches up.
        reliable = rt.qos_profile(
            "default", depth=max(100, self.source.n_ticks + 1) if self.fast else 100
        )
        qos = {"sensor_data": sensor, "default": reliable, "latched": rt.qos_profile("latched")}
        topics = [SCENARIO, JOINT_STATES, OBJECT_WRENCH, OBJECT_POSE, *TRUTH_TOPICS]
        if self.source.scenario.kind == "push":
            topics.append(PUSHER_WRENCH)
        self.pubs: dict[str, Any] = {
            t: node.create_publisher(cls(TOPICS[t].type), t, qos[TOPICS[t].qos]) for t in topics
        }
        if self.fast:
            self.pubs["/clock"] = node.create_publisher(
                cls("rosgraph_msgs/msg/Clock"), "/clock", rt.qos_profile("clock")
            )
        self.published = 0

    # ----------------------------------------------------------------------------- run
    def publish_scenario(self) -> None:
        """Publish the latched a-priori model."""
        string = self.rt.message_class("std_msgs/msg/String")
        self.pubs[SCENARIO].publish(string(data=self.source.scenario_yaml))

    def wait_for_subscribers(self) -> None:
        """Wait (bounded by `wait_for_subscribers` s) until /object/pose has
        `min_subscribers` subscribers."""
        limit = float(self.params["wait_for_subscribers"])
        if limit <= 0.0:
            return
        wanted = max(1, int(self.params["min_subscribers"]))
        deadline = time.monotonic() + limit
        pub = self.pubs[OBJECT_POSE]
        while time.monotonic() < deadline and pub.get_subscription_count() < wanted:
            self.rt.spin_once(self, timeout_sec=0.02)  # raises on SIGINT/SIGTERM
        if pub.get_subscription_count() > 0:
            # Give the reader's side of the match a moment to complete as well.
            # (Fast DDS: the reader learns of the writer up to ~1 s after the writer of it)
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                self.rt.spin_once(self, timeout_sec=0.05)

    def run(self) -> None:
        """Publish every tick (paced in real time unless fast), then flush reliable topics."""
        from dbcslam_ros.convert import float64_multiarray, pose_stamped, wrench_stamped

        rt = self.rt
        self.publish_scenario()
        self.wait_for_subscribers()
        src = self.source
        self.log.info(
            f"publishing scenario '{src.scenario.kind}': {src.n_ticks} samples at "
            f"{1.0 / src.period:g} Hz ({'fast' if self.fast else 'real time'})"
        )
        joint_cls = rt.message_class("sensor_msgs/msg/JointState")
        header_cls = rt.message_class("std_msgs/msg/Header")
        clock_cls = rt.message_class("rosgraph_msgs/msg/Clock")
        from dbcslam_ros.convert import ns_to_stamp

        wall0 = time.time_ns()
        mono0 = time.monotonic()
        names = list(src.joint_names)
        for tick in src.ticks:
            if not rt.ok():  # SIGINT/SIGTERM
                raise rt.ExternalShutdownException
            t_ns = round(tick.t * NS)
            if self.fast:
                stamp_ns = t_ns
                self.pubs["/clock"].publish(clock_cls(clock=ns_to_stamp(stamp_ns)))
            else:
                stamp_ns = wall0 + t_ns
                delay = mono0 + tick.t - time.monotonic()
                if delay > 0.0:
                    time.sleep(delay)
            header = header_cls(stamp=ns_to_stamp(stamp_ns), frame_id=self.frame)
            self.pubs[JOINT_STATES].publish(
                joint_cls(
                    header=header,
                    name=names,
                    position=[float(v) for v in tick.observed_joints],
                    velocity=[],
                    effort=[],
                )
            )
            fx, fy, tau = (float(v) for v in tick.wrench)
            self.pubs[OBJECT_WRENCH].publish(
                wrench_stamped(stamp_ns, fx, fy, tau, frame_id=self.frame)
            )
            if tick.pusher_wrench is not None and PUSHER_WRENCH in self.pubs:
                px, py, ptau = (float(v) for v in tick.pusher_wrench)
                self.pubs[PUSHER_WRENCH].publish(
                    wrench_stamped(stamp_ns, px, py, ptau, frame_id=self.frame)
                )
            ox, oy, oyaw = (float(v) for v in tick.observed_pose)
            self.pubs[OBJECT_POSE].publish(
                pose_stamped(stamp_ns, ox, oy, oyaw, frame_id=self.frame)
            )
            tx, ty, tyaw = (float(v) for v in tick.pose)
            self.pubs[TRUTH_POSE].publish(
                pose_stamped(stamp_ns, tx, ty, tyaw, frame_id=self.frame)
            )
            self.pubs[TRUTH_CONTACT_MODES].publish(
                float64_multiarray(tick.modes, ("contacts", "modes"))
            )
            self.pubs[TRUTH_FRICTION].publish(float64_multiarray(tick.friction, ("pairs",)))
            self.published += 1
        self.flush()
        self.log.info(f"done: {self.published} samples published")

    def flush(self, timeout_sec: float = 3.0) -> None:
        """Wait (bounded) until reliable subscribers acknowledged all samples."""
        rt = self.rt
        for topic in (TRUTH_POSE, TRUTH_CONTACT_MODES, TRUTH_FRICTION):
            pub = self.pubs[topic]
            wait = getattr(pub, "wait_for_all_acked", None)
            if wait is not None:
                wait(rt.Duration(seconds=timeout_sec))
        # Best-effort readers get a short grace period to drain their queues.
        time.sleep(0.2)


def main(args: Sequence[str] | None = None) -> int:
    """Entry point of the simulator node; exit code 0 after the run, 2 on bad parameters."""
    from rclpy._rclpy_pybind11 import RCLError

    from dbcslam_ros import runtime as rt
    from dbcslam_ros.ros_context import init_ros
    from sim_publisher.errors import ParamError

    init_ros(list(args) if args is not None else sys.argv)
    node: SimNode | None = None
    code = 0
    try:
        node = SimNode()
        node.run()
    except (KeyboardInterrupt, rt.ExternalShutdownException):
        pass
    except RCLError:
        if rt.ok():  # not the signal-vs-wait-set race of a shutdown
            raise
    except (ValueError, ParamError) as err:
        rt.get_logger("sim_publisher").error(f"sim_publisher: bad parameters: {err}")
        code = 2
    finally:
        if node is not None:
            node.destroy_node()  # type: ignore[no-untyped-call]
        rt.try_shutdown()
    return code


if __name__ == "__main__":
    sys.exit(main())

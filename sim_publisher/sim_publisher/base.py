"""The simulation loop shared by all scenarios: physics stepping, sampling, noise.

A `Simulation` subclass builds its pybullet world (`_build`), applies the inputs of one
physics step (`_apply`) and measures the true state at a sample time (`_measure`). The base
class steps physics at `physics_dt`, samples at `rate` and adds the seeded Gaussian
observation noise. `records()` streams records (for a node publishing in real time),
`run()` collects them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from dbcslam_core.angles import wrap_angle
from dbcslam_core.scenario import Scenario

from .bullet import BulletClient
from .errors import BulletError, ParamError
from .params import SimParams
from .records import SimRecord, SimRun

__all__ = ["Simulation", "Truth", "interpolate_keyframes"]

FloatArray = NDArray[np.float64]


def interpolate_keyframes(frames: Sequence[Sequence[float]], t: float) -> FloatArray:
    """Piecewise-linear value of keyframes ((t, v1, v2, ...), ...) at time t, held outside."""
    arr = np.asarray(frames, dtype=np.float64)
    times = arr[:, 0]
    return np.array([np.interp(t, times, arr[:, k]) for k in range(1, arr.shape[1])])


@dataclass(frozen=True)
class Truth:
    """True quantities at one sample (see `SimRecord` for meanings and units)."""

    pose: FloatArray
    twist: FloatArray
    joints: FloatArray
    pusher_wrench: FloatArray
    modes: FloatArray
    friction: FloatArray
    normal_forces: FloatArray


class Simulation(ABC):
    """One scenario simulation. Subclasses set `name` and implement the three hooks."""

    name: ClassVar[str]
    params_type: ClassVar[type[SimParams]]
    point_body: ClassVar[bool] = False
    cone_friction: ClassVar[bool] = False
    """pybullet friction model: True = implicit cone (isotropic Coulomb, as the core model),
    False = pyramid (two independent directions; resists rotation of a sliding body)."""

    def __init__(self, params: SimParams) -> None:
        if not isinstance(params, self.params_type):
            msg = (
                f"{type(self).__name__} needs {self.params_type.__name__}, got "
                f"{type(params).__name__}"
            )
            raise ParamError(msg)
        self.params: Any = params

    # ------------------------------------------------------------------ what the robot knows
    @property
    @abstractmethod
    def contacts(self) -> tuple[str, ...]:
        """Potential contact names (order of the modes' dim 0)."""

    @property
    @abstractmethod
    def pairs(self) -> tuple[str, ...]:
        """Friction pair names (order of the true friction vector)."""

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Robot joint names (order of the joint vectors)."""
        return ()

    @abstractmethod
    def scenario(self) -> Scenario:
        """The a-priori scenario (geometry, mass, friction candidates, noise; no truth)."""

    def scenario_yaml(self) -> str:
        """The `/scenario` YAML text."""
        return str(self.scenario().to_yaml())

    # --------------------------------------------------------------------------- physics
    @abstractmethod
    def _gravity(self) -> tuple[float, float, float]:
        """World gravity vector of this scenario (m/s^2)."""

    @abstractmethod
    def _build(self, cid: int) -> None:
        """Create bodies and set the initial state."""

    def input_wrench(self, t: float) -> FloatArray:
        """Known applied wrench (fx, fy, tau) on the body during the physics step at t (s).

        N, N, N m, world frame, tau about the centre of mass. Zero unless overridden.
        """
        return np.zeros(3)

    def mean_input_wrench(self, t: float) -> FloatArray:
        """Mean applied wrench over the sample interval [t, t + 1/rate) (what is recorded).

        The exact impulse the physics delivers over the interval divided by its length, so a
        discrete model stepping from t uses it as its input u.
        """
        p: SimParams = self.params
        steps = p.steps_per_sample
        samples = np.stack([self.input_wrench(t + s * p.physics_dt) for s in range(steps)])
        return np.asarray(samples.mean(axis=0), dtype=np.float64)

    @abstractmethod
    def _apply(self, cid: int, t: float) -> None:
        """Set the inputs (forces, motor targets) for the physics step starting at t (s)."""

    @abstractmethod
    def _measure(self, cid: int, t: float) -> Truth:
        """True quantities after the last step, at sample time t (s)."""

    # ------------------------------------------------------------------------------ loop
    def records(self) -> Iterator[SimRecord]:
        """Generate the records of a run, one per sample time t = k / rate, k = 0 .. N."""
        p: SimParams = self.params
        rng = np.random.default_rng(p.seed)
        steps = p.steps_per_sample
        n_joints = len(self.joint_names)
        noise = p.noise
        with BulletClient(
            p.physics_dt, self._gravity(), p.solver_iterations, cone_friction=self.cone_friction
        ) as client:
            cid = client.id
            self._build(cid)
            prev_yaw: float | None = None
            lag = round(p.observation_delay * p.rate)
            history: list[FloatArray] = []
            bias = np.asarray(p.observation_bias, dtype=np.float64)
            for k in range(p.n_samples):
                if k > 0:
                    for s in range(steps):
                        self._apply(cid, ((k - 1) * steps + s) * p.physics_dt)
                        client.step()
                t = k / p.rate
                truth = self._measure(cid, t)
                pose = truth.pose.copy()
                if prev_yaw is not None:  # unwrap yaw against the previous sample
                    pose[2] = prev_yaw + float(wrap_angle(pose[2] - prev_yaw))
                prev_yaw = float(pose[2])
                if not (np.all(np.isfinite(pose)) and np.all(np.isfinite(truth.twist))):
                    msg = f"{self.name} simulation diverged at t = {t:.3f} s: pose {pose}"
                    raise BulletError(msg)
                e = rng.standard_normal(3 + n_joints + 2)
                history.append(pose.copy())
                seen = history[max(len(history) - 1 - lag, 0)]
                if lag:
                    del history[: max(len(history) - 1 - lag, 0)]
                obs = seen + bias + e[:3] * np.array([noise.position, noise.position, noise.yaw])
                if self.point_body:
                    obs[2] = 0.0
                obs_joints = truth.joints + noise.joint * e[3 : 3 + n_joints]
                obs_pw = truth.pusher_wrench.copy()
                obs_pw[:2] += noise.force * e[3 + n_joints :]
                yield SimRecord(
                    t=t,
                    pose=pose,
                    twist=truth.twist,
                    observed_pose=obs,
                    wrench=self.mean_input_wrench(t),
                    joints=truth.joints,
                    observed_joints=obs_joints,
                    pusher_wrench=truth.pusher_wrench,
                    observed_pusher_wrench=obs_pw,
                    modes=truth.modes,
                    friction=truth.friction,
                    normal_forces=truth.normal_forces,
                )

    def run(self) -> SimRun:
        """Simulate the whole duration and return all records with their metadata."""
        scenario = self.scenario()
        return SimRun(
            scenario_name=self.name,
            records=tuple(self.records()),
            contacts=self.contacts,
            pairs=self.pairs,
            joint_names=self.joint_names,
            scenario=scenario,
            scenario_yaml=scenario.to_yaml(),
            params=self.params,
        )

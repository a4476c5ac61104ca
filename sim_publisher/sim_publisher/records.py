"""Sample records of a simulation run (one per sample time) and the run container.

Frames: world frame of the scenario (x-y plane; `edge` vertical with gravity -y, `gripper`
and `push` horizontal with gravity -z). Poses are (x, y, yaw) of the body's centre of mass
(the point itself for the point mass), yaw unwrapped (continuous) in rad; twists are
(vx, vy, omega) in the world frame; wrenches (fx, fy, tau) in N, N, N m, world frame, tau
about the centre of mass (pusher wrench: about the pusher axis).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dbcslam_core.scenario import Scenario

__all__ = ["MODE_NAMES", "SimRecord", "SimRun"]

FloatArray = NDArray[np.float64]

MODE_NAMES: tuple[str, ...] = ("separated", "sticking", "sliding_pos", "sliding_neg")
"""Order of the one-hot mode axis (same as `/dbcslam/contact_modes` dim 1)."""


@dataclass(frozen=True, eq=False)
class SimRecord:
    """Everything sampled at time `t` (s, simulation time from 0).

    pose, twist: true (x, y, yaw) and (vx, vy, omega). observed_pose: pose plus Gaussian
    noise (a point mass reports yaw 0 without noise). wrench: the known applied wrench u
    (fx, fy, tau) on the body, averaged over [t, t + 1/rate): the input of a discrete model
    step from t to the next sample (zero in `push`, whose input is the pusher motion).
    joints / observed_joints: true and noisy joint
    positions in the order of `SimRun.joint_names` (m). pusher_wrench /
    observed_pusher_wrench: force the object exerts on the pusher (fx, fy, tau), true and
    with sensor noise (zeros outside `push`). modes: (C, 4) one-hot true mode per potential
    contact. friction: (P,) true friction coefficient per friction pair. normal_forces: (C,)
    true normal force per potential contact (N).
    """

    t: float
    pose: FloatArray
    twist: FloatArray
    observed_pose: FloatArray
    wrench: FloatArray
    joints: FloatArray
    observed_joints: FloatArray
    pusher_wrench: FloatArray
    observed_pusher_wrench: FloatArray
    modes: FloatArray
    friction: FloatArray
    normal_forces: FloatArray

    def same_as(self, other: SimRecord) -> bool:
        """Bitwise equality of all fields (reproducibility checks)."""
        if self.t != other.t:
            return False
        for name in ARRAY_FIELDS:
            if not np.array_equal(getattr(self, name), getattr(other, name)):
                return False
        return True


#: The per-sample array fields of SimRecord (everything but the time `t`).
ARRAY_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(SimRecord) if f.name != "t")


@dataclass(frozen=True, eq=False)
class SimRun:
    """A finished run: the records plus the names that give their arrays meaning.

    scenario_name: edge | gripper | push. contacts: potential contact names (dim 0 of
    `modes`); pairs: friction pair names (`friction`); joint_names: `joints`. scenario: the
    a-priori `dbcslam_core.scenario.Scenario`; scenario_yaml: its `/scenario` YAML text.
    params: the scenario's parameter dataclass.
    """

    scenario_name: str
    records: tuple[SimRecord, ...]
    contacts: tuple[str, ...]
    pairs: tuple[str, ...]
    joint_names: tuple[str, ...]
    scenario: Scenario
    scenario_yaml: str
    params: Any

    def stack(self) -> dict[str, FloatArray]:
        """All records as arrays with a leading time axis: 't' (N,), 'pose' (N, 3), ..."""
        out: dict[str, FloatArray] = {"t": np.array([r.t for r in self.records])}
        for name in ARRAY_FIELDS:
            out[name] = np.stack([getattr(r, name) for r in self.records])
        return out

    def mode_fractions(self) -> dict[str, dict[str, float]]:
        """Per contact, the fraction of samples spent in each mode."""
        modes = self.stack()["modes"]
        frac = modes.mean(axis=0)
        return {
            c: {m: float(frac[i, k]) for k, m in enumerate(MODE_NAMES)}
            for i, c in enumerate(self.contacts)
        }

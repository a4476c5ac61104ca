"""Measured runs: the data of the discrepancy analysis and how they are split.

`Run` = one measured run on the scenario's time grid (t_k = t_0 + k dt): observed pose
obs[T, nq] (x, y[, yaw]; nan = missing), applied wrench u[T, nq] over [t_k, t_k+1) (N, N m,
world frame), joint readings env[T, E] (m). Nothing else (never ground truth).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ..errors import ModelError
from ..scenario import Scenario

__all__ = ["Run", "default_effects", "nominal_friction", "split_runs"]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Run:
    """One measured run on the scenario time grid (see module docstring; SI units)."""

    name: str
    scenario: Scenario
    t: F64
    obs: F64
    u: F64
    env: F64

    def __post_init__(self) -> None:
        n = self.t.shape[0]
        nq = self.scenario.nq
        ne = len(self.scenario.joints)
        if self.obs.shape != (n, nq) or self.u.shape != (n, nq) or self.env.shape != (n, ne):
            msg = (
                f"run {self.name!r}: need obs/u [{n}, {nq}] and env [{n}, {ne}], got "
                f"{self.obs.shape}, {self.u.shape}, {self.env.shape}"
            )
            raise ModelError(msg)

    @property
    def n_observed(self) -> int:
        """Number of samples with a complete observation."""
        return int(np.sum(np.all(np.isfinite(self.obs), axis=-1)))

    def segment(self, start: int, stop: int, suffix: str) -> Run:
        """Samples [start, stop) as a run of their own (name + suffix)."""
        sl = slice(start, stop)
        return Run(
            f"{self.name}{suffix}",
            self.scenario,
            self.t[sl],
            self.obs[sl],
            self.u[sl],
            self.env[sl],
        )


def default_effects(scenario: Scenario) -> tuple[str, ...]:
    """Candidate effects that can act in this scenario kind (all go through the filter:
    `effects.EFFECT_SPACES`)."""
    base = ["friction_scale", "viscous_damping", "mass_scale", "input_gain", "sensor_delay"]
    base.append("sensor_bias")
    if scenario.kind == "edge":
        base += ["support_friction", "friction_patch"]
    if scenario.kind == "gripper":
        base += ["friction_patch"]
    if scenario.kind == "push":
        base += ["support_friction", "support_pressure", "support_concentration"]
    return tuple(base)


def nominal_friction(scenario: Scenario) -> F64:
    """Prior-mean friction coefficient per pair (used by the rollout pictures only; the
    scores integrate friction with the filter)."""
    f = scenario.friction
    out = [
        float(np.dot(c, p) / max(float(np.sum(p)), 1e-300))
        for c, p in zip(f.candidates, f.prior, strict=True)
    ]
    return np.asarray(out, dtype=np.float64)


def split_runs(
    runs: Sequence[Run], heldout: Sequence[Run], fraction: float = 0.4
) -> tuple[list[Run], list[Run], str]:
    """Training and held-out runs and a description of the split.

    With held-out runs given they are used as they are. Otherwise, with two or more runs,
    every second run (the 2nd, 4th, ...) is held out; with one run its last `fraction` of
    samples is held out (the filter starts afresh on that segment).
    """
    if not runs:
        msg = "need at least one run to fit on"
        raise ModelError(msg)
    if heldout:
        return list(runs), list(heldout), "held-out runs: " + ", ".join(r.name for r in heldout)
    if len(runs) >= 2:
        train = [r for i, r in enumerate(runs) if i % 2 == 0]
        held = [r for i, r in enumerate(runs) if i % 2 == 1]
        desc = "every second given run held out: " + ", ".join(r.name for r in held)
        return train, held, desc
    r = runs[0]
    n = r.t.shape[0]
    cut = math.floor(n * (1.0 - fraction))
    if cut < 20 or n - cut < 20:
        msg = f"run {r.name!r} has {n} samples: too short to hold part of it out (need >= 50)"
        raise ModelError(msg)
    desc = (
        f"the last {fraction:.0%} of {r.name} (t >= {r.t[cut] - r.t[0]:.2f} s) held out; "
        "the rest used for fitting"
    )
    return [r.segment(0, cut, "[fit]")], [r.segment(cut, n, "[held out]")], desc

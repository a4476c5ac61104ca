"""Shared synthetic edge data for the model-extension tests (core, CLI, filter session).

The core model's edge scenario with one friction candidate (the nominal coefficient is the
truth, so only a hidden extension separates model and data); importable from every test
directory (pytest puts this directory on sys.path for tests/conftest.py).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from dbcslam_core.dynamics import PlanarModel
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.scenario import NoiseSpec, Scenario, edge_scenario
from dbcslam_core.synthetic import Trajectory, edge_trajectory, observe, simulate

__all__ = ["MU", "hidden_effect_trajectory", "single_mu_edge_scenario"]

#: The edge's one friction coefficient (true and nominal).
MU = 0.5


def single_mu_edge_scenario(position_noise: float) -> Scenario:
    """Edge scenario with one friction candidate MU and pose noise `position_noise` (m)."""
    sc = edge_scenario()
    return dataclasses.replace(
        sc,
        noise=NoiseSpec(position_noise, 0.01, 0.0005),
        friction=dataclasses.replace(sc.friction, candidates=((MU,),), prior=((1.0,),)),
    )


def hidden_effect_trajectory(
    extensions: tuple[ModelExtension, ...],
    seed: int,
    *,
    duration: float,
    position_noise: float,
) -> Trajectory:
    """Edge run of `duration` (s) with `extensions` hidden in the physics and the sensor."""
    sc = single_mu_edge_scenario(position_noise)
    base = edge_trajectory(0, duration=duration)
    model = PlanarModel(sc, extensions, active_set=True)
    q, v, env, modes, ln, lt, mus = simulate(
        model, (0.0, sc.edge_y + 0.1), (1.2, 0.0), base.u, base.env, mu=MU
    )
    obs, env_obs = observe(sc, q, env, np.random.default_rng(seed), extensions)
    return Trajectory(
        sc, base.t, q, v, base.u, env, modes, ln, lt, mus, np.array([MU]), obs, env_obs
    )

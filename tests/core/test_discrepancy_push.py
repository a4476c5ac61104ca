"""dbcslam_core.discrepancy on synthetic pushes (core model): clean data -> none, a hidden
sensor bias -> sensor_bias.

Data: the rectangle of `push_trajectory` pushed at 5 cm/s off its axis (both pusher-object
friction and support friction known: one candidate each = the truth), observed with the
noise in the scenario. Clean pushes must give `none` also at the MIT noise level (5 mm,
0.05 rad), where the smoothed start states are poor: a plain open-loop comparison used to
name sensor_delay there (a delay, damping or more friction all stop a noisy start sooner).
A sensor bias is observable in pushing (the pose relative to the pusher contact); the
support friction is not (quasi-static pushing: the pusher sets the motion), so it is not
hidden here.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from dbcslam_core.discrepancy import DiscrepancyConfig, Run, analyse
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.scenario import push_scenario
from dbcslam_core.synthetic import PUSH_RECT, PUSH_RECT_MASS, push_trajectory

MU_PUSHER, MU_SURFACE = 0.4, 0.25
CFG = DiscrepancyConfig(stride=4)


def push_run(
    extensions: tuple[ModelExtension, ...] = (),
    *,
    seed: int = 0,
    noise: tuple[float, float] = (0.001, 0.01),
    angle: float = 0.3,
    side_position: float = 0.3,
) -> Run:
    sc = push_scenario(
        PUSH_RECT,
        mass=PUSH_RECT_MASS,
        support_pair="surface",
        position_noise=noise[0],
        yaw_noise=noise[1],
    )
    friction = dataclasses.replace(
        sc.friction, candidates=((MU_PUSHER,), (MU_SURFACE,)), prior=((1.0,), (1.0,))
    )
    sc = dataclasses.replace(sc, friction=friction)
    tr = push_trajectory(
        seed,
        scenario=sc,
        mu_pusher=MU_PUSHER,
        mu_surface=MU_SURFACE,
        extensions=extensions,
        travel=0.1,
        angle=angle,
        side_position=side_position,
    )
    return Run(f"push{seed}", sc, tr.t, tr.obs, tr.u, tr.env_obs)


@pytest.mark.parametrize("noise", [(0.001, 0.01), (0.005, 0.05)], ids=["1mm", "5mm"])
def test_clean_push_gives_none(noise: tuple[float, float]) -> None:
    rng = np.random.default_rng([2026, int(noise[0] * 1e4)])
    run = push_run(
        seed=int(rng.integers(1000)),
        noise=noise,
        angle=float(rng.uniform(-0.4, 0.4)),
        side_position=float(rng.uniform(0.25, 0.75)),
    )
    res = analyse([run], (), CFG)
    assert res.verdict == "none", res.evidence
    assert res.winner is None
    assert res.gain == 1.0


def test_hidden_sensor_bias_in_pushes() -> None:
    rng = np.random.default_rng([2026, 11, 21])
    sign = 1.0 if rng.random() < 0.5 else -1.0
    ext = ModelExtension.make(
        "sensor_bias",
        x=sign * float(rng.uniform(0.008, 0.012)),
        y=float(rng.uniform(-0.004, 0.004)),
        yaw=0.0,
    )
    run = push_run((ext,), seed=int(rng.integers(1000)))
    res = analyse([run], (), CFG)
    assert res.verdict == "sensor_bias", res.evidence
    assert res.winner is not None
    got = np.array([res.winner.params["x"], res.winner.params["y"]])
    true = np.array([ext.param("x"), ext.param("y")])
    assert np.linalg.norm(got - true) <= 0.25 * np.linalg.norm(true), (got, true)
    # yaw is weakly identified in one short push: consistent with its reported stderr
    assert abs(res.winner.params["yaw"]) <= 2.0 * res.winner.stderr["yaw"]
    assert res.gain >= 1.5, res.gain

"""Core push physics (support friction + disk pusher) against the pybullet push simulation.

One-step prediction: from each recorded pybullet state (q, v, pusher joints at both ends of
the step) the core model `PlanarModel.step` with the true frictions predicts the next pose;
errors are taken over the steps where pybullet reports pusher contact. Loose bounds: the
two simulators differ (pybullet: soft contacts, 1 ms steps, a 3-4 point contact manifold).

pybullet's default friction here is the pyramid approximation (two independent friction
directions per contact point), under which a sliding block resists rotation for free; the
off-centre checks therefore run pybullet with its implicit cone friction (isotropic Coulomb,
the model of the core and of real pushing).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from typing import Any

import numpy as np
import pybullet as pb
import pytest

from dbcslam_core.contact_modes import Mode
from dbcslam_core.dynamics import PlanarModel, State
from dbcslam_core.geometry import wrap_angle
from dbcslam_core.scenario import SurfaceSpec
from dbcslam_core.synthetic import Trajectory
from sim_publisher.simulate import simulate
from sim_publisher.trajectory import to_trajectory


@dataclasses.dataclass(frozen=True)
class OneStep:
    pos: np.ndarray  # (n,) m, contact steps only
    yaw: np.ndarray  # (n,) rad
    omega_model: np.ndarray
    omega_sim: np.ndarray
    modes_agree: float


@pytest.fixture(scope="module")
def cone_friction() -> Iterator[None]:
    original = pb.setPhysicsEngineParameter

    def patched(*args: Any, **kwargs: Any) -> Any:
        if "enableConeFriction" in kwargs:
            kwargs["enableConeFriction"] = 1
        return original(*args, **kwargs)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pb, "setPhysicsEngineParameter", patched)
        yield


def _run(**overrides: Any) -> tuple[Trajectory, float, float]:
    run = simulate("push", **overrides)
    return to_trajectory(run), float(run.params.mu_pusher), float(run.params.mu_surface)


def _one_step(tr: Trajectory, mu_p: float, mu_s: float, pressure: str) -> OneStep:
    sc = dataclasses.replace(tr.scenario, surface=SurfaceSpec(None, (), pressure))
    model = PlanarModel(sc)
    r = model.step(
        State(tr.q[:-1], tr.v[:-1]),
        tr.u[:-1],
        tr.env[:-1],
        tr.env[1:],
        mu=mu_p,
        mu_surface=mu_s,
    )
    contact = tr.modes[1:, 0] != Mode.SEPARATED
    dq = r.q - tr.q[1:]
    return OneStep(
        pos=np.linalg.norm(dq[contact, :2], axis=1),
        yaw=np.abs(wrap_angle(dq[contact, 2])),
        omega_model=r.v[contact, 2],
        omega_sim=tr.v[1:][contact, 2],
        modes_agree=float(np.mean(r.modes[contact, 0] == tr.modes[1:][contact, 0])),
    )


def test_centred_push_matches_pybullet() -> None:
    tr, mu_p, mu_s = _run(shape="rect1", side_position=0.5)
    res = _one_step(tr, mu_p, mu_s, "uniform")
    assert len(res.pos) > 50
    assert np.median(res.pos) < 5e-6  # m
    assert np.percentile(res.pos, 95) < 2e-5
    assert np.median(res.yaw) < 1e-4  # rad
    assert res.modes_agree > 0.95


@pytest.mark.usefixtures("cone_friction")
@pytest.mark.parametrize(
    "overrides",
    [
        {"shape": "rect1", "side_position": 0.8},
        {"shape": "rect1", "side_position": 0.3, "angle": 0.5},
    ],
)
def test_off_centre_push_matches_pybullet(overrides: dict[str, Any]) -> None:
    tr, mu_p, mu_s = _run(**overrides)
    res = _one_step(tr, mu_p, mu_s, "vertices")  # pybullet's manifold: the block's corners
    assert len(res.pos) > 50
    assert np.median(res.pos) < 4e-5  # m per 10 ms step, object speed ~50 mm/s
    assert np.median(res.yaw) < 1e-3  # rad per step
    turning = np.abs(res.omega_sim) > 0.05
    assert turning.sum() > 30
    assert np.mean(np.sign(res.omega_model[turning]) == np.sign(res.omega_sim[turning])) > 0.9
    rel = np.abs(res.omega_model[turning] - res.omega_sim[turning]) / np.abs(
        res.omega_sim[turning]
    )
    assert np.median(rel) < 0.5

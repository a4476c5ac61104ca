"""The compiled contact kinematics (`kinematics_kernels`) against the numpy reference
(`geometry.contact_kinematics`, `geometry.contact_coordinates`): bit for bit, for random
poses and joints of every scenario kind (the push pusher inside, outside, on an edge and on
a vertex of the outline), the filter's input shapes and the shapes that fall back."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core import geometry, kinematics_kernels, rbpf
from dbcslam_core.errors import ModelError
from dbcslam_core.geometry import ContactKinematics
from dbcslam_core.observation import PoseObservation
from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig, FilterInput
from dbcslam_core.scenario import Scenario, edge_scenario, gripper_scenario, push_scenario
from dbcslam_core.synthetic import (
    PUSH_RECT,
    PUSH_RECT_MASS,
    edge_trajectory,
    gripper_trajectory,
    push_trajectory,
)

pytestmark = pytest.mark.skipif(not kinematics_kernels.AVAILABLE, reason="numba not installed")

_FIELDS = ("phi", "Jn", "Jt", "vn_env", "vt_env", "point", "s", "normal")
_HEXAGON = [[0.04 * math.cos(a), 0.03 * math.sin(a)] for a in np.linspace(0, 2 * math.pi, 7)[:-1]]
_SCENARIOS: dict[str, Scenario] = {
    "edge": edge_scenario(),
    "gripper": gripper_scenario(),
    "push": push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS, support_pair="surface"),
    "push-hexagon": push_scenario(_HEXAGON, mass=0.5, pusher_radius=0.01),
}


def _assert_same(a: ContactKinematics, b: ContactKinematics) -> None:
    for name in _FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and x.dtype == y.dtype, name
        np.testing.assert_array_equal(x, y, err_msg=name)


def _assert_matches_numpy(sc: Scenario, q: Any, env: Any, env_vel: Any) -> None:
    """Both compiled functions (or their fallbacks) equal `geometry`'s, bit for bit."""
    _assert_same(
        kinematics_kernels.contact_kinematics(sc, q, env, env_vel),
        geometry.contact_kinematics(sc, q, env, env_vel),
    )
    np.testing.assert_array_equal(
        kinematics_kernels.contact_coordinates(sc, q, env),
        geometry.contact_coordinates(sc, q, env),
    )


def _pusher_centres(
    sc: Scenario, q: np.ndarray, where: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """World pusher centres (P, 2) of bodies at q (P, 3): where 0 outside (up to 3 x the
    outline's size), 1 inside (a shrunk outline point), 2 on a vertex, 3 on an edge."""
    v = np.asarray(sc.body.vertices, dtype=np.float64)
    n_p = q.shape[0]
    k = rng.integers(0, len(v), n_p)
    f = rng.uniform(0.0, 1.0, n_p)[:, None]
    on_edge = v[k] + f * (np.roll(v, -1, 0)[k] - v[k])
    size = float(np.max(np.abs(v)))
    body = np.select(
        [where[:, None] == 1, where[:, None] == 2, where[:, None] == 3],
        [rng.uniform(0.05, 0.95, (n_p, 1)) * on_edge, v[k], on_edge],
        rng.uniform(-3.0 * size, 3.0 * size, (n_p, 2)),
    )
    return q[:, :2] + geometry.rotate(q[:, 2], body)


def _inputs(
    sc: Scenario, seed: int, n_p: int, env_rows: int, spin: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random particles q (P, nq) and joints env, env_vel ((E,) or (env_rows, E))."""
    rng = np.random.default_rng(seed)
    q = rng.normal(0.0, 0.03, (n_p, sc.nq))
    if sc.nq == 3:
        q[:, 2] = rng.uniform(-spin, spin, n_p)
        if seed % 5 == 0:  # exact angles (cos / sin of 0, pi / 2)
            q[:, 2] = rng.choice([0.0, -0.0, math.pi / 2, -math.pi], n_p)
    n_env = len(sc.joints)
    shape = (n_env,) if env_rows == 0 else (env_rows, n_env)
    env = rng.normal(0.0, 0.04, shape)
    env_vel = rng.normal(0.0, 0.1, shape)
    if sc.kind == "push":
        rows = max(env_rows, 1)
        centres = _pusher_centres(sc, q[:rows], rng.integers(0, 4, rows), rng)
        env = centres.reshape(shape)
    if sc.kind == "gripper" and seed % 3 == 0:  # jaws exactly at rest
        env = np.zeros(shape)
    return q, env, env_vel


@settings(max_examples=60, deadline=None)
@given(
    kind=st.sampled_from(sorted(_SCENARIOS)),
    seed=st.integers(0, 100_000),
    n_p=st.sampled_from([1, 2, 7, 64]),
    env_rows=st.sampled_from([0, 1, -1]),  # (E,), (1, E), (P, E)
    spin=st.sampled_from([0.1, math.pi, 40.0]),
)
def test_compiled_kinematics_equal_numpy_bit_for_bit(
    kind: str, seed: int, n_p: int, env_rows: int, spin: float
) -> None:
    sc = _SCENARIOS[kind]
    q, env, env_vel = _inputs(sc, seed, n_p, n_p if env_rows < 0 else env_rows, spin)
    ref = geometry.contact_kinematics(sc, q, env, env_vel)
    _assert_same(kinematics_kernels.contact_kinematics(sc, q, env, env_vel), ref)
    _assert_same(kinematics_kernels.contact_kinematics(sc, q), geometry.contact_kinematics(sc, q))
    # the contact coordinates alone: with and without the joints
    np.testing.assert_array_equal(
        kinematics_kernels.contact_coordinates(sc, q, env),
        geometry.contact_coordinates(sc, q, env),
    )
    np.testing.assert_array_equal(
        kinematics_kernels.contact_coordinates(sc, q), geometry.contact_coordinates(sc, q)
    )
    # non-contiguous particle arrays (a bank's strided view)
    qs = np.repeat(q, 2, axis=0)[::2]
    _assert_same(
        kinematics_kernels.contact_kinematics(sc, qs, env, env_vel),
        geometry.contact_kinematics(sc, qs, env, env_vel),
    )


def test_pusher_cases_reach_every_branch() -> None:
    """The push inputs of the property test hold pushers inside (phi < -radius), outside,
    on a vertex and on an edge (|phi + radius| ~ 0: the outline's normal)."""
    sc = _SCENARIOS["push"]
    rng = np.random.default_rng(0)
    q = np.zeros((400, 3))
    q[:, 2] = rng.uniform(-math.pi, math.pi, 400)
    where = np.repeat(np.arange(4), 100)
    env = _pusher_centres(sc, q, where, rng)
    kin = kinematics_kernels.contact_kinematics(sc, q, env, np.zeros_like(env))
    _assert_same(kin, geometry.contact_kinematics(sc, q, env, np.zeros_like(env)))
    sd = kin.phi[:, 0] + sc.pusher_radius
    assert np.all(sd[where == 1] < 0.0) and np.mean(sd[where == 0] > 0.0) > 0.8
    assert np.all(np.abs(sd[where >= 2]) < 1e-12)
    # exactly on the outline (yaw 0 at the origin): the tiny-distance branch
    v = np.asarray(sc.body.vertices)
    q0 = np.zeros((len(v), 3))
    for centres in (v, 0.5 * (v + np.roll(v, -1, 0))):
        kin = kinematics_kernels.contact_kinematics(sc, q0, centres, np.zeros_like(centres))
        _assert_same(kin, geometry.contact_kinematics(sc, q0, centres, np.zeros_like(centres)))
        assert np.all(kin.phi[:, 0] == -sc.pusher_radius)
        assert np.allclose(np.linalg.norm(kin.normal[:, 0], axis=-1), 1.0)


@pytest.mark.parametrize("kind", sorted(_SCENARIOS))
def test_other_shapes_fall_back_to_numpy(kind: str) -> None:
    """One pose (nq,), a grid (A, B, nq) and q broadcast against env rows: the numpy
    function's values and shapes; wrong shapes raise the reference's errors."""
    sc = _SCENARIOS[kind]
    rng = np.random.default_rng(3)
    n_env = len(sc.joints)
    for q, env in (
        (rng.normal(0, 0.03, sc.nq), rng.normal(0, 0.03, n_env)),
        (rng.normal(0, 0.03, (2, 3, sc.nq)), rng.normal(0, 0.03, (3, n_env))),
        (rng.normal(0, 0.03, (1, sc.nq)), rng.normal(0, 0.03, (5, n_env))),
        (rng.normal(0, 0.03, (4, sc.nq)), rng.normal(0, 0.03, (2, 4, n_env))),
    ):
        _assert_matches_numpy(sc, q, env, env)
    with pytest.raises(ModelError, match="q must have shape"):
        kinematics_kernels.contact_kinematics(sc, np.zeros((3, sc.nq + 1)))
    with pytest.raises(ModelError, match="env must have shape"):
        kinematics_kernels.contact_kinematics(sc, np.zeros((3, sc.nq)), np.zeros(n_env + 1))
    with pytest.raises(ModelError, match="env must have shape"):
        kinematics_kernels.contact_coordinates(sc, np.zeros((3, sc.nq)), np.zeros(n_env + 1))


def test_warm_up_compiles_every_kinds_kernels() -> None:
    """After `rbpf.warm_up_kernels` the kinematics kernels hold their one specialisation,
    and the filter-shaped calls of every kind (one row or many, env (E,) or (P, E)) add
    none: a node never compiles them in a step."""
    rbpf.warm_up_kernels()
    kernels = (kinematics_kernels._kinematics_kernel, kinematics_kernels._coordinates_kernel)
    before = [len(k.signatures) for k in kernels]  # type: ignore[attr-defined]
    assert all(n >= 1 for n in before)
    for sc in _SCENARIOS.values():
        for n_p, env_rows in ((1, 0), (50, 0), (50, -1)):
            q, env, env_vel = _inputs(sc, 7, n_p, n_p if env_rows < 0 else env_rows, 1.0)
            kinematics_kernels.contact_kinematics(sc, q, env, env_vel)
            kinematics_kernels.contact_coordinates(sc, q, env)
            kinematics_kernels.contact_coordinates(sc, np.asfortranarray(q))
    assert [len(k.signatures) for k in kernels] == before  # type: ignore[attr-defined]


@pytest.mark.parametrize("kind", ["edge", "gripper", "push"])
def test_filter_steps_use_the_compiled_kinematics_bit_for_bit(
    kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every kinematics call of a filter run (initialisation, free motion of every step,
    contact coordinates of the moved particles; the gripper with its friction bank's rows)
    goes through the compiled path and equals the numpy reference bit for bit."""
    traj = {
        "edge": lambda: edge_trajectory(0),
        "gripper": lambda: gripper_trajectory(1, duration=2.0),
        "push": lambda: push_trajectory(0, side_position=0.8),
    }[kind]()
    calls = {"kinematics": 0, "coordinates": 0}
    compiled_kin = kinematics_kernels.contact_kinematics
    compiled_coords = kinematics_kernels.contact_coordinates

    def kinematics(sc: Scenario, q: np.ndarray, *args: np.ndarray | None) -> ContactKinematics:
        out = compiled_kin(sc, q, *args)
        _assert_same(out, geometry.contact_kinematics(sc, q, *args))
        calls["kinematics"] += 1
        return out

    def coordinates(sc: Scenario, q: np.ndarray, env: np.ndarray | None = None) -> np.ndarray:
        out = compiled_coords(sc, q, env)
        np.testing.assert_array_equal(out, geometry.contact_coordinates(sc, q, env))
        calls["coordinates"] += 1
        return out

    monkeypatch.setattr(kinematics_kernels, "contact_kinematics", kinematics)
    monkeypatch.setattr(kinematics_kernels, "contact_coordinates", coordinates)
    filt = DbcSlamFilter(
        traj.scenario, FilterConfig.preset(kind, particles=30), np.random.default_rng(5)
    )
    steps = {"edge": 80, "gripper": 150, "push": 100}[kind]
    p_separated = 1.0
    for k in range(1, steps + 1):
        est = filt.step(
            PoseObservation(*map(float, traj.obs[k])),
            FilterInput(tuple(traj.u[k - 1]), tuple(traj.env_obs[k])),
        )
        p_separated = min(p_separated, float(np.min(est.modes[:, 0])))
    # push: the coordinates of a disk contact are those of the full kinematics
    extra = steps if kind == "push" else 0
    assert calls == {"kinematics": steps + 1 + extra, "coordinates": steps}
    assert p_separated < 0.5  # the run reached contacts


def test_without_numba_the_numpy_functions_run(monkeypatch: pytest.MonkeyPatch) -> None:
    """`AVAILABLE` False (numba missing): the kernels are never called, the values are the
    numpy reference's."""

    def no_kernel(*_args: object) -> None:
        raise AssertionError

    monkeypatch.setattr(kinematics_kernels, "AVAILABLE", False)
    monkeypatch.setattr(kinematics_kernels, "_kinematics_kernel", no_kernel)
    monkeypatch.setattr(kinematics_kernels, "_coordinates_kernel", no_kernel)
    for kind in ("edge", "gripper", "push"):
        sc = _SCENARIOS[kind]
        q, env, env_vel = _inputs(sc, 11, 20, 0, 1.0)
        _assert_matches_numpy(sc, q, env, env_vel)

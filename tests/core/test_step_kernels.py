"""The compiled phases 4-6 of the filter step (`step_kernels`) against the numpy phases
(`_hypothesis_dynamics`, `_propose`, `_discrete_posterior`, the reference): from the same
filter state and the same random numbers, both give the same proposal and discrete
posterior to round-off, step after step, in every scenario kind (friction bank, support
friction, force readings, steps without a reading)."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core import contact_modes, step_kernels
from dbcslam_core.contact_modes import (
    ContactLayout,
    LiveHypotheses,
    enumerate_hypotheses,
    enumerate_live,
)
from dbcslam_core.observation import ForceObservation, PoseObservation
from dbcslam_core.rbpf import DbcSlamFilter, FilterConfig, FilterInput
from dbcslam_core.synthetic import (
    Trajectory,
    edge_trajectory,
    gripper_trajectory,
    push_trajectory,
)

pytestmark = pytest.mark.skipif(not step_kernels.AVAILABLE, reason="numba not installed")

_PROPOSAL = ("incr", "v_new", "q_new")
_POSTERIOR = ("fric_post", "fric_pair", "modes_post", "marg_post", "pair_in", "p_contact")


class _Checked(DbcSlamFilter):
    """A filter whose compiled phases are checked against the numpy phases at every step."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        DbcSlamFilter.__init__(self, *args, **kwargs)
        self.compared: list[int] = []

    def _compiled_phases(self, hyp: LiveHypotheses, pred: Any, free: Any, inp: Any) -> Any:
        state = copy.deepcopy(self.rng.bit_generator.state)
        prop, post = super()._compiled_phases(hyp, pred, free, inp)
        after = copy.deepcopy(self.rng.bit_generator.state)
        self.rng.bit_generator.state = state
        ent = self._live_entries(hyp.padded(), pred)
        dyn = self._hypothesis_dynamics(ent, free, inp)
        prop_np = self._propose(ent, dyn, inp)
        post_np = self._discrete_posterior(ent, dyn, prop_np)
        # the same random numbers were consumed
        assert self.rng.bit_generator.state == after
        for name in _PROPOSAL:
            np.testing.assert_allclose(
                getattr(prop, name), getattr(prop_np, name), rtol=1e-9, atol=1e-12, err_msg=name
            )
        for name in _POSTERIOR:
            np.testing.assert_allclose(
                getattr(post, name), getattr(post_np, name), rtol=1e-9, atol=1e-12, err_msg=name
            )
        self.compared.append(self._step)
        return prop, post


def _steps(
    traj: Trajectory, force: np.ndarray | None, skip_every: int
) -> Iterator[tuple[PoseObservation | None, FilterInput, ForceObservation | None]]:
    for k in range(1, traj.n_steps):
        o = traj.obs[k]
        obs = None if skip_every and k % skip_every == 0 else PoseObservation(*map(float, o))
        fo = None if force is None else ForceObservation(float(force[k, 0]), float(force[k, 1]))
        yield obs, FilterInput(tuple(traj.u[k - 1]), tuple(traj.env_obs[k])), fo


def _pusher_force(traj: Trajectory, rng: np.random.Generator) -> np.ndarray:
    """Pusher force readings (N) from the true impulses of contact 0, with 0.05 N noise."""
    from dbcslam_core.geometry import contact_kinematics

    kin = contact_kinematics(traj.scenario, traj.q[1:], traj.env[1:], None)
    n = kin.normal[:, 0, :]
    t = np.stack([n[:, 1], -n[:, 0]], axis=-1)
    f = -(n * traj.ln[1:, 0, None] + t * traj.lt[1:, 0, None]) / traj.scenario.dt
    f = np.vstack([np.zeros((1, 2)), f])
    return f + 0.05 * rng.standard_normal(f.shape)


@pytest.fixture(scope="module")
def trajectories() -> dict[str, Trajectory]:
    return {
        "edge": edge_trajectory(0),
        "gripper": gripper_trajectory(1, duration=2.0),
        "push": push_trajectory(0, side_position=0.8),
    }


def _run_checked(
    traj: Trajectory, cfg: FilterConfig, seed: int, *, force: bool, skip_every: int, steps: int
) -> _Checked:
    filt = _Checked(traj.scenario, cfg, np.random.default_rng(seed))
    forces = _pusher_force(traj, np.random.default_rng(seed)) if force else None
    for k, (obs, inp, fo) in enumerate(_steps(traj, forces, skip_every)):
        if k >= steps:
            break
        filt.step(obs, inp, force=fo)
    return filt


@pytest.mark.parametrize(
    ("kind", "overrides", "force"),
    [
        ("edge", {}, False),
        ("gripper", {}, False),  # friction bank (the preset)
        ("gripper", {"friction_bank": False}, False),
        ("push", {}, False),  # support friction: per-friction effective mass
        ("push", {}, True),  # pusher force readings
        ("push", {"friction_bank": True}, True),
    ],
)
def test_compiled_phases_equal_numpy_phases(
    trajectories: dict[str, Trajectory], kind: str, overrides: dict[str, Any], force: bool
) -> None:
    traj = trajectories[kind]
    cfg = FilterConfig.preset(kind, particles=40, **overrides)
    # the gripper's contacts start after ~1 s: run through them
    steps = {"edge": 150, "gripper": 199, "push": 150}[kind]
    filt = _run_checked(traj, cfg, 0, force=force, skip_every=7, steps=steps)
    assert len(filt.compared) == steps


@settings(max_examples=8, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    particles=st.sampled_from([1, 3, 17]),
    kind=st.sampled_from(["edge", "gripper", "push"]),
    skip_every=st.sampled_from([0, 2, 5]),
)
def test_compiled_phases_equal_numpy_phases_any_seed(
    trajectories: dict[str, Trajectory], seed: int, particles: int, kind: str, skip_every: int
) -> None:
    """Random filter seeds and particle counts (a single particle included), readings
    missing at random steps."""
    traj = trajectories[kind]
    cfg = FilterConfig.preset(kind, particles=particles)
    filt = _run_checked(traj, cfg, seed, force=kind == "push", skip_every=skip_every, steps=60)
    assert len(filt.compared) == 60


def test_numpy_backend_runs_the_numpy_phases(
    trajectories: dict[str, Trajectory], monkeypatch: pytest.MonkeyPatch
) -> None:
    """`contact_modes.DEFAULT_BACKEND = "numpy"` selects the reference phases; over a short
    run both backends give the same estimates to round-off."""
    traj = trajectories["gripper"]
    cfg = FilterConfig.preset("gripper", particles=20)

    def run() -> tuple[list[np.ndarray], int]:
        filt = _Checked(traj.scenario, cfg, np.random.default_rng(4))
        poses = []
        for k, (obs, inp, _) in enumerate(_steps(traj, None, 0)):
            if k >= 130:
                break
            poses.append(filt.step(obs, inp).pose)
        return poses, len(filt.compared)

    compiled, n_compiled = run()
    monkeypatch.setattr(contact_modes, "DEFAULT_BACKEND", "numpy")
    reference, n_reference = run()
    assert n_compiled == 130 and n_reference == 0
    np.testing.assert_allclose(np.array(compiled), np.array(reference), rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["edge", "gripper", "push"])
def test_compiled_map_view_equals_numpy_map_view(
    trajectories: dict[str, Trajectory], kind: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The friction-map snapshot with the uncommitted history (`map_pending`): the same
    sums in the same order as `_map_observations` + `FrictionMap.accumulate`, bit for bit,
    at every step (the ring buffer wraps after the lag)."""
    traj = trajectories[kind]
    filt = DbcSlamFilter(
        traj.scenario, FilterConfig.preset(kind, particles=30), np.random.default_rng(2)
    )
    checked = 0
    for k, (obs, inp, _) in enumerate(_steps(traj, None, 0)):
        if k >= 90:
            break
        filt.step(obs, inp)
        w = np.random.default_rng(k).dirichlet(np.ones(30))
        compiled = filt._friction_map_view(w)
        with monkeypatch.context() as m:
            m.setattr(contact_modes, "DEFAULT_BACKEND", "numpy")
            reference = filt._friction_map_view(w)
        pairs = zip(
            compiled.probs + compiled.weight, reference.probs + reference.weight, strict=True
        )
        for a, b in pairs:
            np.testing.assert_array_equal(a, b)
        checked += int(any(np.any(x > 0.0) for x in compiled.weight))
    assert checked > 10  # contacts reached the map


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    threshold=st.sampled_from([1e-3, 1e-2, 0.05]),
    max_h=st.sampled_from([4, 8, 32]),
    n_p=st.sampled_from([1, 3, 40]),
    ties=st.booleans(),
)
def test_live_enumeration_equals_padded_enumeration(
    seed: int, threshold: float, max_h: int, n_p: int, ties: bool
) -> None:
    """`enumerate_live` (compiled, no padded arrays) keeps the valid hypotheses of
    `enumerate_hypotheses` in their order, with their log priors; `padded` restores the
    padded layout (gripper contacts: geometric exclusions and gaps; exact ties included)."""
    from dbcslam_core.scenario import gripper_scenario

    sc = gripper_scenario()
    pcs = sc.potential_contacts
    layout = ContactLayout(
        feature_vertex=tuple(c.vertex for c in pcs),
        obstacle=tuple(c.obstacle for c in pcs),
        n_vertices=len(sc.body.vertices),
    )
    rng = np.random.default_rng(seed)
    mg = rng.dirichlet(np.full(4, 0.3), size=(n_p, len(pcs)))
    if ties:  # equal marginals: ties between tuples
        mg[:, 1:] = mg[:, :1]
    phi = rng.uniform(-1e-3, 3e-3, size=(n_p, len(pcs)))
    ref = enumerate_hypotheses(mg, threshold, max_h, layout=layout, phi=phi)
    live = enumerate_live(mg, threshold, max_h, layout=layout, phi=phi)
    np.testing.assert_array_equal(live.counts, ref.n_live)
    np.testing.assert_array_equal(live.modes, ref.modes[ref.valid])
    np.testing.assert_array_equal(live.log_prior, ref.log_prior[ref.valid])
    assert live.width == ref.modes.shape[1]
    pad = live.padded()
    np.testing.assert_array_equal(pad.valid, ref.valid)
    np.testing.assert_array_equal(pad.modes[pad.valid], ref.modes[ref.valid])
    np.testing.assert_array_equal(pad.log_prior, ref.log_prior)


@settings(max_examples=30, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n_f=st.sampled_from([1, 3]),
    scale=st.sampled_from([1e-4, 1e-3, 3e-2]),
)
def test_compiled_mode_prediction_equals_transition(seed: int, n_f: int, scale: float) -> None:
    """`predict_modes` = `soft_modes` + `mode_transition` with the far-gap reach (to
    round-off: the same operations, numba's tanh for numpy's)."""
    from dbcslam_core.transition import TransitionParams, mode_transition, soft_modes

    rng = np.random.default_rng(seed)
    tp = TransitionParams()
    n_r, n_c, dt = 25, 6, 0.01
    phi = rng.normal(0.0, scale, (n_r, n_c))
    an = rng.normal(0.0, 50.0 * scale, (n_r, n_c))
    at = rng.normal(0.0, 0.05, (n_r, n_c))
    prev = rng.dirichlet(np.full(4, 0.5), (n_r, n_f, n_c))
    soft = soft_modes(phi, an, at, dt, tp)
    ref = mode_transition(
        prev, soft[:, None], tp, phi=phi[:, None], gap_rate_free=an[:, None], dt=dt
    )
    out = step_kernels.predict_modes(
        prev,
        phi,
        an,
        at,
        dt=dt,
        params=(tp.gap_scale, tp.far_gap, tp.slip_scale, tp.slide_floor, tp.persistence),
    )
    np.testing.assert_allclose(out, ref, rtol=1e-12, atol=1e-15)


_SQUARE = [[-0.045, -0.045], [0.045, -0.045], [0.045, 0.045], [-0.045, 0.045]]


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**31),
    model=st.sampled_from(["dynamic", "quasi_static"]),
    pressure=st.sampled_from(["uniform", "rim", "tripod"]),
    effect=st.sampled_from([None, "viscous_damping", "support_pressure"]),
    per_row_mu=st.booleans(),
    slow=st.booleans(),
)
def test_compiled_support_terms_equal_the_model(
    seed: int, model: str, pressure: str, effect: str | None, per_row_mu: bool, slow: bool
) -> None:
    """`step_kernels.support_terms` (the push's implicit support friction, compiled) equals
    `PlanarModel.support_terms` to round-off: dynamic and quasi-static, any pressure
    distribution, an extension force and a pressure effect, coefficients per hypothesis or
    per row (friction bank), speeds below the regularisation velocity included."""
    from dbcslam_core.dynamics import PlanarModel
    from dbcslam_core.extensions import ModelExtension
    from dbcslam_core.scenario import push_scenario

    rng = np.random.default_rng(seed)
    sc = push_scenario(_SQUARE, mass=0.8, support_mu=0.3, pressure=pressure, model=model, dt=0.01)
    ext = {
        None: (),
        "viscous_damping": (ModelExtension.make("viscous_damping", b=1.5),),
        "support_pressure": (ModelExtension.make("support_pressure", rim_fraction=0.4),),
    }[effect]
    pm = PlanarModel(sc, ext)
    n = 37
    q = np.column_stack([rng.normal(0, 0.1, (n, 2)), rng.uniform(-4, 4, n)])
    v = rng.normal(0, 1e-3 if slow else 0.2, (n, 3))
    u = rng.normal(0, 2.0, 3)
    mus = rng.uniform(0.05, 0.6, (n, 3)) if per_row_mu else np.array([0.1, 0.25, 0.4])
    m_ref, v_ref = pm.support_terms(q, v, u, mus, velocity_eps=5e-3)
    m_c, v_c = step_kernels.support_terms(pm, q, v, u, mus, velocity_eps=5e-3)
    np.testing.assert_allclose(m_c, m_ref, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(v_c, v_ref, rtol=1e-9, atol=1e-13)


def test_compiled_support_terms_refuse_bad_input() -> None:
    from dbcslam_core.dynamics import PlanarModel
    from dbcslam_core.errors import ModelError
    from dbcslam_core.scenario import push_scenario

    qs = PlanarModel(push_scenario(_SQUARE, mass=0.8, support_mu=0.3, model="quasi_static"))
    q = np.zeros((2, 3))
    with pytest.raises(ModelError, match="coefficients > 0"):
        step_kernels.support_terms(qs, q, q, np.zeros(3), np.array([0.0, 0.2]))
    with pytest.raises(ModelError, match="velocity_eps"):
        step_kernels.support_terms(qs, q, q, np.zeros(3), np.array([0.2]), velocity_eps=0.0)

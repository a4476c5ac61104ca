"""The DBC-SLAM Rao-Blackwellized particle filter on short synthetic runs (fixed seeds)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dbcslam_core.contact_modes import Mode
from dbcslam_core.errors import ModelError
from dbcslam_core.observation import PoseObservation
from dbcslam_core.rbpf import DbcSlamFilter, Estimate, FilterConfig, FilterInput
from dbcslam_core.synthetic import (
    Trajectory,
    edge_mu_field,
    edge_trajectory,
    gripper_trajectory,
)


@pytest.fixture(scope="module")
def edge_traj() -> Trajectory:
    return edge_trajectory(0)


@pytest.fixture(scope="module")
def gripper_traj() -> Trajectory:
    return gripper_trajectory(1, duration=3.0)


def _run(
    traj: Trajectory, cfg: FilterConfig, seed: int = 0, drop: int = 0
) -> tuple[list[Estimate], DbcSlamFilter]:
    sc = traj.scenario
    f = DbcSlamFilter(sc, cfg, np.random.default_rng(seed))
    out = []
    for k in range(traj.n_steps - 1):
        o = traj.obs[k + 1]
        obs = (
            None
            if drop and k % drop == drop - 1
            else PoseObservation(float(o[0]), float(o[1]), float(o[2]) if sc.nq == 3 else None)
        )
        if k == 0:
            f.initialize(traj.obs[0], traj.obs[0] * 0 + sc.noise.position, joints=traj.env_obs[0])
        out.append(f.step(obs, FilterInput(tuple(traj.u[k]), tuple(traj.env_obs[k + 1]))))
    return out, f


def _pos_rmse(est: list[Estimate], traj: Trajectory) -> float:
    pose = np.array([e.pose[:2] for e in est])
    return float(np.sqrt(np.mean((pose - traj.q[1:, :2]) ** 2)))


@pytest.fixture(scope="module")
def edge_run(edge_traj: Trajectory) -> list[Estimate]:
    return _run(edge_traj, FilterConfig.preset("edge", particles=150))[0]


def test_edge_tracks_pose_modes_and_friction(
    edge_traj: Trajectory, edge_run: list[Estimate]
) -> None:
    est = edge_run
    noise = edge_traj.scenario.noise.position
    assert _pos_rmse(est, edge_traj) < 0.5 * noise
    modes = np.array([e.modes[0] for e in est])
    truth = edge_traj.modes[1:, 0]
    in_contact = truth != Mode.SEPARATED
    assert np.mean((modes[:, 0] < 0.5) == in_contact) > 0.95
    p_stick = modes[:, Mode.STICKING] / np.maximum(1.0 - modes[:, 0], 1e-12)
    stick = truth == Mode.STICKING
    assert np.mean((p_stick > 0.5)[in_contact] == stick[in_contact]) > 0.8
    # sticking in the rough region (mu 0.9) under a load above 0.3 m g rules out mu = 0.3
    k_rough = int(np.flatnonzero(edge_traj.q[1:, 0] > 0.6)[0])
    assert est[k_rough].friction[0, 1] > 0.8
    # out of contact (lifted off at the end) the belief relaxes to the prior
    assert truth[-1] == Mode.SEPARATED
    np.testing.assert_allclose(est[-1].friction[0], [0.5, 0.5], atol=1e-6)
    for e in est:
        np.testing.assert_allclose(e.modes.sum(axis=1), 1.0)
        np.testing.assert_allclose(e.friction.sum(axis=1), 1.0)
        assert e.pose_cov[2, 2] == 0.0 and e.pose[2] == 0.0  # point mass: no yaw
        assert 1.0 <= e.ess <= 150.0 + 1e-9
        assert 1.0 <= e.live_hypotheses <= 4.0


def test_edge_friction_map_marks_rough_region(
    edge_traj: Trajectory, edge_run: list[Estimate]
) -> None:
    fmap = edge_run[-1].friction_map
    touched = fmap.touched(0)
    truth = edge_traj.modes[1:, 0]
    slid = (truth == Mode.SLIDING_POS) | (truth == Mode.SLIDING_NEG)
    cells = np.unique(fmap.cell_of(edge_traj.q[1:][slid, 0]))
    assert cells.size > 20 and touched[cells].all()
    true_mu = edge_mu_field()(fmap.centers[cells])
    correct = np.where(true_mu > 0.5, fmap.probs[0][cells, 1], fmap.probs[0][cells, 0])
    assert np.mean(correct > 0.5) > 0.85
    assert not touched[fmap.centers < -0.1].any()


def test_fixed_friction_is_worse_on_edge(edge_traj: Trajectory, edge_run: list[Estimate]) -> None:
    fixed, _ = _run(edge_traj, FilterConfig.preset("edge", particles=150, frozen_friction=0))
    assert _pos_rmse(fixed, edge_traj) > 1.5 * _pos_rmse(edge_run, edge_traj)
    np.testing.assert_allclose(fixed[-1].friction[0], [1.0, 0.0])


def test_dropped_observations_and_determinism(edge_traj: Trajectory) -> None:
    cfg = FilterConfig.preset("edge", particles=60)
    n = 60
    short = replace(
        edge_traj,
        t=edge_traj.t[:n],
        q=edge_traj.q[:n],
        u=edge_traj.u[:n],
        env=edge_traj.env[:n],
        modes=edge_traj.modes[:n],
        obs=edge_traj.obs[:n],
        env_obs=edge_traj.env_obs[:n],
    )
    a, _ = _run(short, cfg, seed=5, drop=3)
    b, _ = _run(short, cfg, seed=5, drop=3)
    np.testing.assert_array_equal([e.pose for e in a], [e.pose for e in b])
    assert all(e.log_likelihood == 0.0 for e in a[2::3])
    assert _pos_rmse(a, short) < 2.0 * edge_traj.scenario.noise.position


def test_gripper_tracks_and_prunes(gripper_traj: Trajectory) -> None:
    est, _ = _run(gripper_traj, FilterConfig.preset("gripper", particles=120))
    sc = gripper_traj.scenario
    assert _pos_rmse(est, gripper_traj) < 0.5 * sc.noise.position
    yaw = np.array([e.pose[2] for e in est])
    dyaw = (yaw - gripper_traj.q[1:, 2] + np.pi) % (2 * np.pi) - np.pi
    assert np.sqrt(np.mean(dyaw**2)) < 0.75 * sc.noise.yaw
    live = np.mean([e.live_hypotheses for e in est])
    assert live < 32.0
    modes = np.array([e.modes.argmax(axis=1) for e in est])
    assert np.mean(modes == gripper_traj.modes[1:]) > 0.8
    assert est[-1].modes.shape == (6, 4) and est[-1].friction.shape == (1, 3)
    assert est[-1].friction[0, 1] > 0.9  # mu = 0.4 identified by the end of the grasp


def test_config_and_input_validation(edge_traj: Trajectory) -> None:
    with pytest.raises(ModelError, match="parameter_model"):
        FilterConfig(parameter_model="diffusion")
    with pytest.raises(ModelError, match="resampler"):
        FilterConfig(resampler="bogus")
    with pytest.raises(ModelError, match="preset"):
        FilterConfig.preset("moon")
    sc = edge_traj.scenario
    with pytest.raises(ModelError, match="frozen_friction"):
        DbcSlamFilter(sc, FilterConfig(frozen_friction=5), np.random.default_rng(0))
    f = DbcSlamFilter(sc, FilterConfig(particles=10), np.random.default_rng(0))
    with pytest.raises(ModelError, match="observation"):
        f.step(None, FilterInput((0.0, 0.0)))
    with pytest.raises(ModelError, match="joints"):
        f.step(PoseObservation(0.0, 0.1), FilterInput((0.0, 0.0), joints=(0.1,)))
    e = f.step(PoseObservation(0.0, 0.1), FilterInput((0.0, 0.0)))
    assert e.step == 1 and e.pose.shape == (3,) and e.twist_cov.shape == (3, 3)


def test_push_with_support_friction_runs_through_the_same_filter() -> None:
    from dbcslam_core.synthetic import push_trajectory

    traj = push_trajectory(0)
    n = 80
    short = replace(
        traj,
        t=traj.t[:n],
        q=traj.q[:n],
        u=traj.u[:n],
        env=traj.env[:n],
        modes=traj.modes[:n],
        obs=traj.obs[:n],
        env_obs=traj.env_obs[:n],
    )
    est, f = _run(short, FilterConfig.preset("push", particles=60))
    assert f._mu_surface is not None  # the support pair's candidates are hypotheses
    assert _pos_rmse(est, short) < traj.scenario.noise.position
    assert est[-1].friction.shape == (2, 3)
    np.testing.assert_allclose(est[-1].friction.sum(axis=1), 1.0)


def _push_force(traj: Trajectory, noise: float, rng: np.random.Generator) -> np.ndarray:
    """Force on the pusher (N, world) of step k -> k+1 at row k+1: -(n ln + t lt) / dt."""
    from dbcslam_core.geometry import contact_kinematics

    kin = contact_kinematics(traj.scenario, traj.q[:-1], traj.env[:-1])
    n = kin.normal[:, 0, :]
    t = np.stack([n[:, 1], -n[:, 0]], axis=-1)
    f = -(n * traj.ln[1:, 0, None] + t * traj.lt[1:, 0, None]) / traj.scenario.dt
    f = np.vstack([np.zeros((1, 2)), f])
    return f + noise * rng.standard_normal(f.shape)


@pytest.mark.parametrize("axes", ["normal", "both"])
def test_pusher_force_observation_detects_contact_and_support_friction(axes: str) -> None:
    from dbcslam_core.observation import ForceObservation
    from dbcslam_core.synthetic import push_trajectory

    traj = push_trajectory(0, side_position=0.8)
    force = _push_force(traj, 0.05, np.random.default_rng(5))
    sc = traj.scenario
    cfg = FilterConfig.preset("push", particles=80, force_axes=axes)

    def run(use_force: bool) -> tuple[float, np.ndarray]:
        f = DbcSlamFilter(sc, cfg, np.random.default_rng(3))
        f.initialize(traj.obs[0], [1e-3, 1e-3, 1e-2], joints=traj.env_obs[0])
        hits = []
        est = None
        for k in range(1, traj.n_steps):
            fo = ForceObservation(*force[k]) if use_force else None
            est = f.step(
                PoseObservation(*traj.obs[k]),
                FilterInput(tuple(traj.u[k - 1]), tuple(traj.env_obs[k])),
                force=fo,
            )
            hits.append((est.modes[0, Mode.SEPARATED] < 0.5) == (traj.modes[k, 0] != 0))
        assert est is not None
        return float(np.mean(hits)), est.friction

    acc_f, fric_f = run(True)
    acc_0, _ = run(False)
    assert acc_f >= 0.95 and acc_f > acc_0
    # support pair (index 1): true mu_s = 0.25 = candidate 1
    assert fric_f[1, 1] > 0.9


def test_force_observation_validation(edge_traj: Trajectory) -> None:
    from dbcslam_core.observation import ForceObservation

    f = DbcSlamFilter(edge_traj.scenario, FilterConfig.preset("edge", particles=10))
    inp = FilterInput(tuple(edge_traj.u[0]), tuple(edge_traj.env_obs[1]))
    obs = PoseObservation(*edge_traj.obs[1][:2])
    with pytest.raises(ModelError, match="no single disk"):
        f.step(obs, inp, force=ForceObservation(0.0, 0.0))
    with pytest.raises(ModelError, match="valid obstacles"):
        f.step(obs, inp, force=ForceObservation(0.0, 0.0, obstacle="nope"))
    with pytest.raises(ModelError, match="force_noise"):
        FilterConfig(force_noise=0.0)
    with pytest.raises(ModelError, match="force_axes"):
        FilterConfig(force_axes="tangent")
    # naming the edge obstacle works (a contact force reading on the edge)
    est = f.step(obs, inp, force=ForceObservation(0.0, 0.0, obstacle="edge"))
    assert est.step == 1


def test_gap_closure_softens_the_contact_velocity_jump(gripper_traj: Trajectory) -> None:
    """An in-contact hypothesis of a particle hovering off a jaw closes only gap_closure of the
    gap per step (no phi / dt velocity spike that the proposal would reject)."""
    from dbcslam_core.geometry import contact_kinematics

    sc = gripper_traj.scenario
    with pytest.raises(ModelError, match="gap_closure"):
        FilterConfig(gap_closure=0.0)
    env = np.asarray(gripper_traj.env[0])
    q = np.array([[0.0, 0.0, 0.0]])
    kin0 = contact_kinematics(sc, q, env)
    c = 0  # lift the body so that contact 0 hovers 0.3 mm off its jaw
    q[0, :2] += kin0.normal[0, c] * (0.3e-3 - kin0.phi[0, c])
    kin = contact_kinematics(sc, q, env, np.zeros_like(env))
    assert kin.phi[0, c] == pytest.approx(0.3e-3)
    modes = np.zeros((1, sc.n_contacts), dtype=np.int64)
    modes[0, c] = Mode.STICKING
    jumps = []
    for closure in (1.0, 0.05):
        cfg = FilterConfig.preset("gripper", particles=1, gap_closure=closure, gap_tolerance=None)
        f = DbcSlamFilter(sc, cfg)
        sol = f._solve_entries(
            modes, np.zeros((1, 3)), kin, np.array([0]), None, sensitivity=False
        )
        gap_rate_v = kin.Jn[0, c] @ sol.v_next[0, 0]  # normal velocity towards the jaw
        jumps.append(-gap_rate_v)
    assert jumps[0] == pytest.approx(0.3e-3 / sc.dt, rel=1e-6)
    assert jumps[1] == pytest.approx(0.05 * 0.3e-3 / sc.dt, rel=1e-6)


def test_warm_up_kernels_covers_every_kind_once() -> None:
    """After `warm_up_kernels` every built-in kind is warm: a second call and a filter's own
    warm-up spend nothing (what a node relies on to start before the first /scenario)."""
    from dbcslam_core import kernels, rbpf
    from dbcslam_core.scenario import gripper_scenario

    rbpf.warm_up_kernels()
    if kernels.AVAILABLE:
        assert {"edge", "gripper", "push"} <= rbpf._WARM
    assert rbpf.warm_up_kernels() == 0.0
    filt = DbcSlamFilter(
        gripper_scenario(), FilterConfig.preset("gripper", particles=4), np.random.default_rng(0)
    )
    assert filt.warm_up() == 0.0


def test_warm_up_kernels_rejects_an_unknown_kind() -> None:
    from dbcslam_core.rbpf import warm_up_kernels

    with pytest.raises(ModelError, match=r"'box'.*valid: \['edge', 'gripper', 'push'\]"):
        warm_up_kernels(("box",))

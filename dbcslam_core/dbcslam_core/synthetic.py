"""Deterministic ground-truth trajectories of the paper experiments, plus noisy observations.

The truth comes from `PlanarModel.step` with the Lemke solver (exact LCP solutions). Time
indexing: t[k] = k dt; input u[k] acts over [t_k, t_k + dt); the state k + 1 is
``step(state k, u[k], env[k], env[k + 1])`` and modes[k + 1], ln[k + 1], lt[k + 1], mu[k + 1]
are those of that step (row 0: modes from the initial gap, impulses 0; mu[k + 1] is the
friction at the contact point of the start of the step, q[k]). Observations
obs[k] = observed pose at t_k (position std `noise.position`, yaw std `noise.yaw`), env_obs[k]
= joint positions with std `noise.joint`.

* `edge_trajectory` (Fig. 3): point mass pressed by gravity (-y) onto the edge y = 0, rough
  region (mu 0.9) in the middle of smooth edge (mu 0.3): falls, lands, slides, sticks in the
  rough region, slides again as the pushing force grows, crosses into smooth and is lifted
  off near the right end.
* `gripper_trajectory` (Fig. 4): equilateral triangle between two closing jaws (friction 0.4)
  on a frictionless support, driven by a time-varying force and moment: vertex and edge
  contacts, stick-slip, ends grasped by both jaws.

`seed` changes the observation noise and mildly (a few percent) the force profile.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .contact_modes import Mode
from .dynamics import PlanarModel, State
from .errors import SolverError
from .extensions import ModelExtension, compose_observation
from .geometry import contact_kinematics, wrap_angle
from .scenario import Scenario, edge_scenario, gripper_scenario

__all__ = [
    "EDGE_ROUGH",
    "Trajectory",
    "edge_mu_field",
    "edge_trajectory",
    "gripper_trajectory",
    "observe",
    "simulate",
]

F64 = NDArray[np.float64]

EDGE_ROUGH: tuple[float, float] = (0.45, 0.85)
"""Rough region [x_min, x_max] (m) of the edge experiment."""


@dataclass(frozen=True)
class Trajectory:
    """A ground-truth trajectory with noisy observations (see module docstring for indexing).

    t[T] (s); q, v[T, nq]; u[T, nq] input wrench (N, N m); env[T, E] joint positions (m);
    modes[T, C] (`Mode` values); ln, lt[T, C] impulses (N s); mu[T, C] true friction per
    contact; mu_pair[P] true friction per pair where constant (nan where it varies);
    obs[T, nq] observed pose; env_obs[T, E] observed joints.
    """

    scenario: Scenario
    t: F64
    q: F64
    v: F64
    u: F64
    env: F64
    modes: NDArray[np.int64]
    ln: F64
    lt: F64
    mu: F64
    mu_pair: F64
    obs: F64
    env_obs: F64

    @property
    def n_steps(self) -> int:
        """Number of time samples T."""
        return int(self.t.shape[0])


def simulate(
    model: PlanarModel,
    q0: Sequence[float],
    v0: Sequence[float],
    u: F64,
    env: F64,
    *,
    mu: Callable[[F64], F64] | float,
    grip_force_limit: float | None = None,
) -> tuple[F64, F64, F64, NDArray[np.int64], F64, F64, F64]:
    """Roll `model` out from (q0, v0) under inputs u[T, nq] and commanded joints env[T, E].

    With `grip_force_limit` (N) the joints are compliant: a step whose LCP has no solution
    (position-controlled obstacles jamming the body) or needs a normal force above the limit
    is redone with the joints held still; afterwards the joints follow the command again
    (at most the commanded speed). Returns q, v [T, nq], the executed joints env [T, E],
    modes, ln, lt, mu [T, C] (row 0 from the initial gap).
    """
    n = u.shape[0]
    nq, nc = model.nq, model.nc
    dt = model.scenario.dt
    q = np.zeros((n, nq))
    v = np.zeros((n, nq))
    act = np.array(env, dtype=np.float64)
    modes = np.zeros((n, nc), dtype=np.int64)
    ln = np.zeros((n, nc))
    lt = np.zeros((n, nc))
    mus = np.zeros((n, nc))
    q[0], v[0] = q0, v0
    kin0 = contact_kinematics(model.scenario, q[0], act[0])
    modes[0] = np.where(kin0.phi > 1e-9, int(Mode.SEPARATED), int(Mode.STICKING))
    mus[0] = model.friction(kin0, mu=mu)
    for k in range(n - 1):
        state = State(q[k], v[k])
        if grip_force_limit is None:
            r = model.step(state, u[k], act[k], act[k + 1], mu=mu)
        else:
            vmax = np.max(np.abs(np.diff(env, axis=0)), axis=0) if n > 1 else 0.0
            act[k + 1] = act[k] + np.clip(env[k + 1] - act[k], -vmax, vmax)
            try:
                r = model.step(state, u[k], act[k], act[k + 1], mu=mu)
                ok = bool(np.all(r.ln <= grip_force_limit * dt))
            except SolverError:
                ok = False
            if not ok:
                act[k + 1] = act[k]
                r = model.step(state, u[k], act[k], act[k + 1], mu=mu)
        q[k + 1], v[k + 1] = r.q, r.v
        modes[k + 1], ln[k + 1], lt[k + 1], mus[k + 1] = r.modes, r.ln, r.lt, r.mu
    return q, v, act, modes, ln, lt, mus


def observe(
    scenario: Scenario,
    q: F64,
    env: F64,
    rng: np.random.Generator,
    extensions: Sequence[ModelExtension] = (),
) -> tuple[F64, F64]:
    """Noisy pose and joint observations (std from `scenario.noise`; extension transforms).

    A `sensor_delay` extension makes obs[k] the pose round(delay / dt) samples earlier
    (clamped at the first sample).
    """
    delay = sum(e.delay for e in extensions)
    lag = round(delay / scenario.dt)
    if lag > 0:
        q = q[np.maximum(np.arange(q.shape[0]) - lag, 0)]
    pose = compose_observation(extensions, q)
    std = np.full(q.shape[-1], scenario.noise.position)
    if q.shape[-1] == 3:
        std[2] = scenario.noise.yaw
    obs = pose + rng.normal(size=pose.shape) * std
    if obs.shape[-1] == 3:
        obs[:, 2] = wrap_angle(obs[:, 2])
    env_obs = env + rng.normal(size=env.shape) * scenario.noise.joint
    return obs, env_obs


def edge_mu_field(
    rough: tuple[float, float] = EDGE_ROUGH, mu_rough: float = 0.9, mu_smooth: float = 0.3
) -> Callable[[F64], F64]:
    """Friction as a function of the edge coordinate s = x: mu_rough inside `rough`."""

    def field(s: F64) -> F64:
        inside = (s >= rough[0]) & (s <= rough[1])
        return np.asarray(np.where(inside, mu_rough, mu_smooth), dtype=np.float64)

    return field


def _smoothstep(t: F64, t0: float, t1: float) -> F64:
    x = np.clip((t - t0) / (t1 - t0), 0.0, 1.0)
    return np.asarray(x * x * (3.0 - 2.0 * x), dtype=np.float64)


def edge_trajectory(
    seed: int = 0,
    *,
    duration: float = 4.0,
    scenario: Scenario | None = None,
    extensions: Sequence[ModelExtension] = (),
    rng: np.random.Generator | None = None,
) -> Trajectory:
    """Paper Fig. 3 trajectory (dt from the scenario, default edge preset, 1 cm noise).

    Rough region `EDGE_ROUGH` with mu 0.9, smooth mu 0.3 elsewhere. The mass starts 0.1 m
    above the edge moving right, lands, slides, sticks in the rough region while the pushing
    force is below 0.9 m g, slides on as the force grows and is lifted off near the right end.
    """
    sc = scenario if scenario is not None else edge_scenario()
    gen = rng if rng is not None else np.random.default_rng(seed)
    prof = np.random.default_rng([seed, 7])
    jitter = 1.0 + 0.03 * prof.uniform(-1.0, 1.0, size=4)
    model = PlanarModel(sc, extensions, active_set=True)
    dt = sc.dt
    n = round(duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    m = sc.body.mass
    g = sc.gravity
    # pushing force: moderate while sliding in / sticking, ramping above 0.9 m g, then lift off
    fx = (
        m
        * g
        * (
            0.2 * jitter[0]
            + (1.05 * jitter[1] - 0.2 * jitter[0]) * _smoothstep(t, 1.2, 2.6 * jitter[2])
            - 1.3 * _smoothstep(t, 3.0, 3.3)
        )
    )
    t_lift = 3.05 * jitter[2]
    fy = (
        m
        * g
        * (
            (1.0 + 0.5 * jitter[3]) * _smoothstep(t, t_lift, t_lift + 0.1)
            - 0.5 * jitter[3] * _smoothstep(t, t_lift + 0.15, t_lift + 0.35)
        )
    )
    u = np.stack([fx, fy], -1)
    env = np.zeros((n, 0))
    mu = edge_mu_field()
    q, v, env, modes, ln, lt, mus = simulate(
        model, (0.0, sc.edge_y + 0.1), (1.2, 0.0), u, env, mu=mu
    )
    obs, env_obs = observe(sc, q, env, gen, extensions)
    return Trajectory(sc, t, q, v, u, env, modes, ln, lt, mus, np.array([np.nan]), obs, env_obs)


def gripper_trajectory(
    seed: int = 0,
    *,
    duration: float = 3.0,
    scenario: Scenario | None = None,
    mu_jaw: float = 0.4,
    grip_force_limit: float = 20.0,
    extensions: Sequence[ModelExtension] = (),
    rng: np.random.Generator | None = None,
) -> Trajectory:
    """Paper Fig. 4 trajectory: triangle rattling between closing jaws, ends grasped.

    Jaws start 0.12 m apart and close (smoothly, over 75 % of `duration`) to the triangle's
    smallest width plus 0.4 %; they are compliant (`simulate` with `grip_force_limit`, N):
    a step that would jam the body or exceed the grip force holds the jaws still. Inputs
    (N, N m, world frame at the centre of mass): an intro phase pushes the triangle down onto
    the lower jaw while sliding +x and turning its lowest edge flat (vertex, then sliding edge
    contact); a rattle phase of periodic force and moment drives it between the jaws (vertex
    and edge contacts, stick-slip); the final phase fades the force out and applies a steady
    moment that wedges the triangle between both jaws (grasped, sticking).
    """
    sc = scenario if scenario is not None else gripper_scenario()
    gen = rng if rng is not None else np.random.default_rng(seed)
    prof = np.random.default_rng([seed, 11])
    jitter = 1.0 + 0.03 * prof.uniform(-1.0, 1.0, size=6)
    model = PlanarModel(sc, extensions, active_set=True)
    dt = sc.dt
    n = round(duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    verts = np.asarray(sc.body.vertices)
    # smallest width of the body between two parallel lines (edge flat on one jaw)
    widths = []
    for i in range(len(verts)):
        e = verts[(i + 1) % len(verts)] - verts[i]
        nrm = np.array([e[1], -e[0]]) / np.linalg.norm(e)
        proj = verts @ nrm
        widths.append(float(proj.max() - proj.min()))
    h = min(widths)
    final_open = h * 1.004
    open0 = 0.12
    close_t = 0.75 * duration
    opening = open0 + (final_open - open0) * _smoothstep(t, 0.0, close_t)
    centre = -0.004 * _smoothstep(t, 0.0, close_t)
    env = np.stack([centre - opening / 2.0, centre + opening / 2.0], -1)
    m = sc.body.mass
    a = float(np.max(np.linalg.norm(verts, axis=1)))
    # phase 1 (intro): down onto the lower jaw, sliding +x, turning the lowest edge flat
    intro = 1.0 - _smoothstep(t, 0.7, 0.9)
    # phase 3 (hold): the force fades out, a steady moment wedges the body between the jaws
    hold = _smoothstep(t, 0.72 * duration, 0.8 * duration)
    rattle = (1.0 - intro) * (1.0 - hold)
    tr = t - 0.8
    fx = m * (
        intro * 0.35 * jitter[0]
        + rattle * 0.186 * jitter[0] * np.cos(2.0 * math.pi * tr / (1.39 * jitter[1]))
    )
    fy = m * (
        intro * -0.6 * jitter[2]
        + rattle * (-0.75 * jitter[2] + 1.75 * np.sin(2.0 * math.pi * tr / (1.7 * jitter[3])) ** 2)
    )
    tau = (
        m
        * a
        * (
            intro * -0.15 * jitter[4]
            + rattle * (0.076 + 0.32 * jitter[4] * np.sin(2.0 * math.pi * tr / (0.95 * jitter[5])))
            + hold * 0.3
        )
    )
    u = np.stack([fx, fy, tau], -1)
    q0 = (0.0, 0.0, 0.376)
    v0 = (0.02, -0.05, 0.0)
    q, v, env, modes, ln, lt, mus = simulate(
        model, q0, v0, u, env, mu=mu_jaw, grip_force_limit=grip_force_limit
    )
    obs, env_obs = observe(sc, q, env, gen, extensions)
    return Trajectory(sc, t, q, v, u, env, modes, ln, lt, mus, np.array([mu_jaw]), obs, env_obs)

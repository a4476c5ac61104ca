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
* `push_trajectory` (MIT push set-up): a disk pusher moving on a straight line at constant
  speed pushes a polygon on a table with support friction (`PlanarModel.support_matrix`),
  then stops: separated approach, sticking / sliding pusher contact, quasi-static stop.

`seed` changes the observation noise and mildly (a few percent) the force profile.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .contact_modes import Mode
from .dynamics import PlanarModel, State
from .errors import ModelError, SolverError
from .extensions import ModelExtension, compose_observation
from .geometry import contact_kinematics, wrap_angle
from .scenario import Scenario, SurfaceSpec, edge_scenario, gripper_scenario, push_scenario

__all__ = [
    "EDGE_HIDDEN_EFFECTS",
    "EDGE_ROUGH",
    "GRIPPER_HIDDEN_EFFECTS",
    "PUSH_HIDDEN_EFFECTS",
    "PUSH_RECT",
    "PUSH_RECT_MASS",
    "Trajectory",
    "delayed",
    "draw_edge_effect",
    "draw_gripper_effect",
    "draw_push_effect",
    "edge_mu_field",
    "edge_sweep_trajectory",
    "edge_trajectory",
    "gripper_trajectory",
    "observe",
    "push_path",
    "push_sweep_trajectory",
    "push_trajectory",
    "simulate",
]

F64 = NDArray[np.float64]

EDGE_ROUGH: tuple[float, float] = (0.45, 0.85)
"""Rough region [x_min, x_max] (m) of the edge experiment."""

PUSH_RECT: tuple[tuple[float, float], ...] = (
    (-0.045, -0.045),
    (0.045, -0.045),
    (0.045, 0.045),
    (-0.045, 0.045),
)
"""Outline (m, about the centre of mass, CCW) of the MIT push `rect1` block (90 x 90 mm)."""
PUSH_RECT_MASS: float = 0.8374
"""kg (13 mm stainless steel)."""


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
    mu_surface: float | None = None,
) -> tuple[F64, F64, F64, NDArray[np.int64], F64, F64, F64]:
    """Roll `model` out from (q0, v0) under inputs u[T, nq] and commanded joints env[T, E].

    With `grip_force_limit` (N) the joints are compliant: a step whose LCP has no solution
    (position-controlled obstacles jamming the body) or needs a normal force above the limit
    is redone with the joints held still; afterwards the joints follow the command again
    (at most the commanded speed). Returns q, v [T, nq], the executed joints env [T, E],
    modes, ln, lt, mu [T, C] (row 0 from the initial gap). mu_surface: support friction
    coefficient (`PlanarModel.surface_mu`; needed when the scenario names a support pair).
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
            r = model.step(state, u[k], act[k], act[k + 1], mu=mu, mu_surface=mu_surface)
        else:
            vmax = np.max(np.abs(np.diff(env, axis=0)), axis=0) if n > 1 else 0.0
            act[k + 1] = act[k] + np.clip(env[k + 1] - act[k], -vmax, vmax)
            try:
                r = model.step(state, u[k], act[k], act[k + 1], mu=mu, mu_surface=mu_surface)
                ok = bool(np.all(r.ln <= grip_force_limit * dt))
            except SolverError:
                ok = False
            if not ok:
                act[k + 1] = act[k]
                r = model.step(state, u[k], act[k], act[k + 1], mu=mu, mu_surface=mu_surface)
        q[k + 1], v[k + 1] = r.q, r.v
        modes[k + 1], ln[k + 1], lt[k + 1], mus[k + 1] = r.modes, r.ln, r.lt, r.mu
    return q, v, act, modes, ln, lt, mus


def delayed(q: F64, lag: float) -> F64:
    """q (T, nq) sampled `lag` samples earlier (fractional: linear interpolation between
    samples; a yaw column, the third of three, is unwrapped first; before the first sample
    the first sample)."""
    last = q.shape[0] - 1
    src = np.array(q, dtype=np.float64)
    if src.shape[-1] == 3:
        src[:, 2] = np.unwrap(src[:, 2])
    t = np.clip(np.arange(q.shape[0], dtype=np.float64) - lag, 0.0, float(last))
    i0 = np.floor(t).astype(np.int64)
    i1 = np.minimum(i0 + 1, last)
    w = (t - i0)[:, None]
    return np.asarray((1.0 - w) * src[i0] + w * src[i1], dtype=np.float64)


def observe(
    scenario: Scenario,
    q: F64,
    env: F64,
    rng: np.random.Generator,
    extensions: Sequence[ModelExtension] = (),
) -> tuple[F64, F64]:
    """Noisy pose and joint observations (std from `scenario.noise`; extension transforms).

    A `sensor_delay` extension makes obs[k] the pose `delay` s earlier, linearly
    interpolated between the samples (yaw unwrapped first; clamped at the first sample): a
    continuous delay, not a whole number of samples (the filter's model of the effect
    interpolates too, `discrepancy.effects`).
    """
    delay = sum(e.delay for e in extensions)
    if delay > 0.0:
        q = delayed(q, delay / scenario.dt)
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


def edge_sweep_trajectory(
    seed: int = 0,
    *,
    duration: float = 10.0,
    scenario: Scenario | None = None,
    extensions: Sequence[ModelExtension] = (),
    rough: tuple[float, float] = EDGE_ROUGH,
) -> Trajectory:
    """A long edge run over spatially varying friction (discrepancy analysis data).

    Paper set-up: point mass (scenario default 1 kg, 1 cm pose noise) on the edge y = 0,
    rough region `rough` (mu 0.9) between smooth edge (mu 0.3). It is dropped from 5 cm and
    swept right across the rough region and back by a horizontal force from a PD law on a
    reference sweep x_ref(t) (seeded phase / amplitude jitter; the force is the recorded,
    known input u, computed from the true state: closed-loop data), which makes it stick in
    the rough region and slide on the smooth one; two upward force pulses (1.6 m g for
    0.12 s, seeded times) lift it off the edge (free flights). Hidden `extensions` act in the
    physics and the sensor (`observe`); the controller sees the true state.
    """
    sc = scenario if scenario is not None else edge_scenario()
    rng = np.random.default_rng([seed, 11])
    model = PlanarModel(sc, extensions, active_set=True)
    dt = sc.dt
    n = round(duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    m, g = sc.body.mass, sc.gravity
    period = duration * float(rng.uniform(0.9, 1.1))
    x_lo, x_hi = 0.1 + float(rng.uniform(-0.05, 0.05)), 1.2 + float(rng.uniform(-0.1, 0.1))
    x_ref = x_lo + (x_hi - x_lo) * 0.5 * (1.0 - np.cos(2.0 * np.pi * t / period))
    v_ref = np.gradient(x_ref, dt)
    wobble = 0.15 * m * g * np.sin(2.0 * np.pi * t / float(rng.uniform(0.8, 1.4)))
    lifts = (float(rng.uniform(0.2, 0.35)) * duration, float(rng.uniform(0.6, 0.8)) * duration)
    fy = np.zeros(n)
    for tl in lifts:
        fy += (
            1.6
            * m
            * g
            * _smoothstep(t, tl, tl + 0.02)
            * (1.0 - _smoothstep(t, tl + 0.12, tl + 0.14))
        )
    mu = edge_mu_field(rough)
    q = np.zeros((n, 2))
    v = np.zeros((n, 2))
    u = np.zeros((n, 2))
    modes = np.zeros((n, 1), dtype=np.int64)
    ln = np.zeros((n, 1))
    lt = np.zeros((n, 1))
    mus = np.zeros((n, 1))
    q[0] = (x_lo, sc.edge_y + 0.05)
    kin0 = contact_kinematics(sc, q[0], np.zeros(0))
    modes[0] = np.where(kin0.phi > 1e-9, int(Mode.SEPARATED), int(Mode.STICKING))
    mus[0] = model.friction(kin0, mu=mu)
    for k in range(n - 1):
        fx = m * (40.0 * (x_ref[k] - q[k, 0]) + 10.0 * (v_ref[k] - v[k, 0])) + wobble[k]
        u[k] = (float(np.clip(fx, -1.5 * m * g, 1.5 * m * g)), fy[k])
        r = model.step(State(q[k], v[k]), u[k], np.zeros(0), np.zeros(0), mu=mu)
        q[k + 1], v[k + 1] = r.q, r.v
        modes[k + 1], ln[k + 1], lt[k + 1], mus[k + 1] = r.modes, r.ln, r.lt, r.mu
    env = np.zeros((n, 0))
    obs, env_obs = observe(sc, q, env, np.random.default_rng([seed, 12]), extensions)
    return Trajectory(sc, t, q, v, u, env, modes, ln, lt, mus, np.array([np.nan]), obs, env_obs)


EDGE_HIDDEN_EFFECTS: tuple[str, ...] = (
    "friction_scale",
    "viscous_damping",
    "mass_scale",
    "input_gain",
    "sensor_delay",
    "sensor_bias",
    "support_friction",
)
"""Effects of the contract vocabulary observable in `edge_sweep_trajectory` data (the
filter path scores them; friction_patch is what the filter's own friction map estimates)."""


def draw_edge_effect(rng: np.random.Generator, effect: str | None = None) -> ModelExtension:
    """A hidden effect of realistic size for the edge (effect uniform over
    `EDGE_HIDDEN_EFFECTS` unless given).

    factors (friction_scale, mass_scale, input_gain): 1.25-1.6 or its inverse (+-25-60 %);
    viscous_damping: 1.5-4 N s/m per kg (0.3-0.8 m g at 2 m/s); sensor_delay: 30-80 ms;
    sensor_bias: y +-1.5-3 cm (1.5-3 noise stds), x within +-1 cm (along the edge a bias
    is nearly unobservable); support_friction: mu 0.1-0.3.
    """
    name = effect if effect is not None else str(rng.choice(EDGE_HIDDEN_EFFECTS))
    if name in ("friction_scale", "mass_scale", "input_gain"):
        f = float(rng.uniform(1.25, 1.6))
        return ModelExtension.make(name, factor=f if rng.random() < 0.5 else 1.0 / f)
    if name == "viscous_damping":
        return ModelExtension.make(name, b=float(rng.uniform(1.5, 4.0)))
    if name == "sensor_delay":
        return ModelExtension.make(name, seconds=float(rng.uniform(0.03, 0.08)))
    if name == "sensor_bias":
        y = float(rng.uniform(0.015, 0.03)) * (1.0 if rng.random() < 0.5 else -1.0)
        return ModelExtension.make(name, x=float(rng.uniform(-0.01, 0.01)), y=y, yaw=0.0)
    if name == "support_friction":
        return ModelExtension.make(name, mu=float(rng.uniform(0.1, 0.3)))
    msg = f"no edge draw for effect {name!r}; valid: {list(EDGE_HIDDEN_EFFECTS)}"
    raise ModelError(msg)


def gripper_trajectory(
    seed: int = 0,
    *,
    duration: float = 3.0,
    scenario: Scenario | None = None,
    mu_jaw: float = 0.4,
    grip_force_limit: float = 20.0,
    extensions: Sequence[ModelExtension] = (),
    rng: np.random.Generator | None = None,
    variation: float = 0.03,
) -> Trajectory:
    """Paper Fig. 4 trajectory: triangle rattling between closing jaws, ends grasped.

    Jaws start 0.12 m apart and close (smoothly, over 75 % of `duration`) to the triangle's
    smallest width plus 0.4 %; they are compliant (`simulate` with `grip_force_limit`, N):
    a step that would jam the body or exceed the grip force holds the jaws still. Inputs
    (N, N m, world frame at the centre of mass): an intro phase pushes the triangle down onto
    the lower jaw while sliding +x and turning its lowest edge flat (vertex, then sliding edge
    contact); a rattle phase of periodic force and moment drives it between the jaws (vertex
    and edge contacts, stick-slip); the final phase fades the force out and applies a steady
    moment that wedges the triangle between both jaws (grasped, sticking). `variation`: the
    seeded relative jitter of the force / moment amplitudes and periods (+-3 % by default).
    """
    sc = scenario if scenario is not None else gripper_scenario()
    gen = rng if rng is not None else np.random.default_rng(seed)
    prof = np.random.default_rng([seed, 11])
    jitter = 1.0 + variation * prof.uniform(-1.0, 1.0, size=6)
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


def push_path(
    vertices: Sequence[Sequence[float]],
    *,
    side: int,
    side_position: float,
    angle: float,
    pusher_radius: float,
    approach: float,
) -> tuple[F64, F64]:
    """Start point (m) and unit direction of a straight push (the sim_publisher convention).

    vertices (n, 2) counter-clockwise outline (world frame); side i runs from vertex i to
    vertex i + 1; the contact point lies at `side_position` in [0, 1] along it; the push
    direction is the side's inward normal rotated by `angle` (rad, counter-clockwise); the
    pusher centre touches at the contact point plus `pusher_radius` along the outward normal
    and starts `approach` (m) before it along the direction.
    """
    v = np.asarray(vertices, dtype=np.float64)
    n = len(v)
    if not 0 <= side < n:
        msg = f"push side {side} is out of range; valid: 0 .. {n - 1} for this outline"
        raise ModelError(msg)
    if not 0.0 <= side_position <= 1.0:
        msg = f"push side_position must lie in [0, 1], got {side_position}"
        raise ModelError(msg)
    a, b = v[side], v[(side + 1) % n]
    e = b - a
    outward = np.array([e[1], -e[0]]) / float(np.linalg.norm(e))
    c, s_ = math.cos(angle), math.sin(angle)
    direction = np.array([-c * outward[0] + s_ * outward[1], -s_ * outward[0] - c * outward[1]])
    touch = a + side_position * e + pusher_radius * outward
    return touch - approach * direction, direction


def push_trajectory(
    seed: int = 0,
    *,
    scenario: Scenario | None = None,
    vertices: Sequence[Sequence[float]] = PUSH_RECT,
    mass: float = PUSH_RECT_MASS,
    inertia: float | None = None,
    speed: float = 0.05,
    side: int = 0,
    side_position: float = 0.5,
    angle: float = 0.0,
    approach: float = 0.01,
    travel: float = 0.05,
    duration: float | None = None,
    mu_pusher: float = 0.4,
    mu_surface: float = 0.25,
    pressure: str | None = None,
    extensions: Sequence[ModelExtension] = (),
    rng: np.random.Generator | None = None,
) -> Trajectory:
    """A straight push at constant speed (the MIT push set-up), truth by `PlanarModel.step`.

    scenario: a push `Scenario` (default: `push_scenario(vertices, mass=, inertia=,
    support_pair="surface", pressure=)`, candidates (0.1, 0.25, 0.4)); `pressure` overrides
    its ``surface.pressure``. The object starts at rest at the origin (yaw 0); the pusher
    (joints pusher_x, pusher_y) starts `approach` (m) before touching side `side` at
    `side_position`, moves along the side's inward normal rotated by `angle` (rad) at
    `speed` (m/s) for approach + travel, then holds still (duration default: that plus
    0.3 s). True friction: `mu_pusher` (pusher pair), `mu_surface` (support: the scenario's
    surface pair if any, else used directly). u = 0 (no other wrench). `seed` changes the
    observation noise only.
    """
    sc = scenario
    if sc is None:
        sc = push_scenario(
            vertices, mass=mass, inertia=inertia, support_pair="surface", pressure=pressure
        )
    elif pressure is not None:
        sc = dataclasses.replace(
            sc, surface=SurfaceSpec(sc.surface.pair, sc.surface.params, pressure)
        )
    if sc.kind != "push":
        msg = f"push_trajectory needs a 'push' scenario, got {sc.kind!r}"
        raise ModelError(msg)
    if not speed > 0.0:
        msg = f"push speed must be > 0 m/s, got {speed}"
        raise ModelError(msg)
    gen = rng if rng is not None else np.random.default_rng(seed)
    model = PlanarModel(sc, extensions, active_set=True)
    dt = sc.dt
    move = (approach + travel) / speed
    dur = move + 0.3 if duration is None else duration
    n = round(dur / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    start, direction = push_path(
        sc.body.vertices,
        side=side,
        side_position=side_position,
        angle=angle,
        pusher_radius=sc.pusher_radius,
        approach=approach,
    )
    dist = speed * np.minimum(t, move)
    env = start[None, :] + dist[:, None] * direction[None, :]
    u = np.zeros((n, 3))
    q, v, env, modes, ln, lt, mus = simulate(
        model, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), u, env, mu=mu_pusher, mu_surface=mu_surface
    )
    mu_pair = np.full(len(sc.friction.pairs), np.nan)
    for pc in sc.potential_contacts:
        mu_pair[pc.pair] = mu_pusher
    if model.surface_pair is not None:
        mu_pair[model.surface_pair] = mu_surface
    obs, env_obs = observe(sc, q, env, gen, extensions)
    return Trajectory(sc, t, q, v, u, env, modes, ln, lt, mus, mu_pair, obs, env_obs)


def push_sweep_trajectory(
    seed: int = 0,
    *,
    duration: float = 6.0,
    scenario: Scenario | None = None,
    mu_pusher: float = 0.25,
    mu_surface: float = 0.25,
    extensions: Sequence[ModelExtension] = (),
) -> Trajectory:
    """A long push over the table with stops (discrepancy analysis data), truth by
    `PlanarModel.step`.

    Scenario default: the MIT `rect1` block (`PUSH_RECT`, `PUSH_RECT_MASS`), estimated
    support pair ``surface`` (candidates 0.1 / 0.25 / 0.4), 1 mm / 0.01 rad pose noise. The
    block starts at rest at the origin; the disk pusher starts 5 mm behind side 0 and drives
    it along +y in strokes: each stroke at a seeded speed of 0.05-0.15 m/s for 0.5-0.9 s
    (ramps of 0.1 s), then a stop of 0.25-0.45 s in which the block coasts off the pusher
    and stops on the support friction; the next stroke catches it up. The pusher's lateral
    position follows the block's centre plus a seeded sinusoidal offset of 0.5-1.5 cm
    (closed loop on the true state: the pusher stays on the side while the off-centre
    contact turns the block one way and back, at most ~0.8 rad/s; a first version with
    0.1-0.25 m/s strokes and 1-2.5 cm offsets spun the block at up to 3.5 rad/s with pusher
    and support friction 0.1, and the filter lost track of the clean run: -3400 nats against
    ~+7800). True friction: `mu_pusher` (pusher pair),
    `mu_surface` (support). u = 0. Hidden `extensions` act in the physics and the sensor.
    """
    sc = scenario
    if sc is None:
        sc = push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS, support_pair="surface")
    if sc.kind != "push":
        msg = f"push_sweep_trajectory needs a 'push' scenario, got {sc.kind!r}"
        raise ModelError(msg)
    rng = np.random.default_rng([seed, 21])
    model = PlanarModel(sc, extensions, active_set=True)
    dt = sc.dt
    n = round(duration / dt) + 1
    t = np.arange(n, dtype=np.float64) * dt
    speed = np.zeros(n)
    t0 = 0.0
    while t0 < duration:
        v, on = float(rng.uniform(0.05, 0.15)), float(rng.uniform(0.5, 0.9))
        ramp_up = _smoothstep(t, t0, t0 + 0.1)
        speed += v * ramp_up * (1.0 - _smoothstep(t, t0 + on, t0 + on + 0.1))
        t0 += on + 0.1 + float(rng.uniform(0.25, 0.45))
    amp = float(rng.uniform(0.005, 0.015)) * (1.0 if rng.random() < 0.5 else -1.0)
    period = float(rng.uniform(2.0, 3.5))
    offset = amp * np.sin(2.0 * np.pi * t / period)
    verts = np.asarray(sc.body.vertices, dtype=np.float64)
    y_back = float(verts[:, 1].min()) - sc.pusher_radius - 0.005
    q = np.zeros((n, 3))
    v_ = np.zeros((n, 3))
    env = np.zeros((n, 2))
    modes = np.zeros((n, sc.n_contacts), dtype=np.int64)
    ln = np.zeros((n, sc.n_contacts))
    lt = np.zeros((n, sc.n_contacts))
    mus = np.zeros((n, sc.n_contacts))
    u = np.zeros((n, 3))
    env[0] = (0.0, y_back)
    kin0 = contact_kinematics(sc, q[0], env[0])
    modes[0] = np.where(kin0.phi > 1e-9, int(Mode.SEPARATED), int(Mode.STICKING))
    mus[0] = mu_pusher
    for k in range(n - 1):
        # lateral: follow the block's centre plus the offset, at most 0.1 m/s
        dx = float(np.clip(q[k, 0] + offset[k] - env[k, 0], -0.1 * dt, 0.1 * dt))
        env[k + 1] = (env[k, 0] + dx, env[k, 1] + speed[k] * dt)
        r = model.step(
            State(q[k], v_[k]), u[k], env[k], env[k + 1], mu=mu_pusher, mu_surface=mu_surface
        )
        q[k + 1], v_[k + 1] = r.q, r.v
        modes[k + 1], ln[k + 1], lt[k + 1], mus[k + 1] = r.modes, r.ln, r.lt, r.mu
    mu_pair = np.full(len(sc.friction.pairs), np.nan)
    for pc in sc.potential_contacts:
        mu_pair[pc.pair] = mu_pusher
    if model.surface_pair is not None:
        mu_pair[model.surface_pair] = mu_surface
    obs, env_obs = observe(sc, q, env, np.random.default_rng([seed, 22]), extensions)
    return Trajectory(sc, t, q, v_, u, env, modes, ln, lt, mus, mu_pair, obs, env_obs)


GRIPPER_HIDDEN_EFFECTS: tuple[str, ...] = (
    "viscous_damping",
    "mass_scale",
    "input_gain",
    "sensor_delay",
    "sensor_bias",
)
"""Effects of the contract vocabulary observable in gripper data (`gripper_trajectory`
with `variation`; horizontal plane, frictionless support, jaws as the only contacts).

In: viscous_damping (the triangle moves freely between the jaws for most of the run, at
0.1-0.3 m/s under forces of ~1 m/s^2 x m: a drag of 1.5-4 N s/m per kg is a 10-60 %
change of the net force); mass_scale / input_gain (the known wrench drives the free motion;
k and 1 / k predict the same motion: no gravity, contact impulses scale with the mass, so
the pair is one class, `discrepancy.analysis.EQUIVALENT`); sensor_delay (the jaws, a known
input, move and hit the triangle: a lag shows at every impact); sensor_bias (y and yaw: the
jaws are the lines y = const and a flat edge on a jaw fixes the yaw; x, along the jaws, is
not observable and is drawn within one noise std). Out: friction_scale (the filter
estimates the one jaw coefficient over its candidates 0.1 / 0.4 / 0.7; a factor on it is a
different value of that estimated coefficient, k x 0.4 = 0.5-0.64 lies between candidates
and is absorbed); friction_patch (no filter path, `discrepancy.effects`); the support
effects (the gripper's support is frictionless: no support friction to change)."""

PUSH_HIDDEN_EFFECTS: tuple[str, ...] = (
    "sensor_delay",
    "sensor_bias",
    "support_concentration",
)
"""Effects of the contract vocabulary observable in push data (`push_sweep_trajectory`:
position-controlled pusher, no applied wrench, support friction estimated by the filter).

In: sensor_delay (the pusher, a known input, starts and stops the block); sensor_bias (y,
the push direction: the block's back side rests on the known pusher; x and yaw are drawn
within one noise std: a point contact on a flat side fixes neither); support_concentration
(the pressure distribution sets the frictional moment, c = m_max / f_max, which sets how
far the off-centre pusher turns the block) at centre_fraction 0.8-0.9: the training gain of
the true value over the nominal model (6 s runs, 150 particles, pusher / support mu 0.4 /
0.25, 0.4 / 0.4, 0.1 / 0.1) was +211 / +4 / +2 nats at 0.5, +897 / +54 / +10 at 0.75,
+1270 / +93 / +72 at 0.9: below ~0.8 it is not resolvable on most draws (the analysis
screens at 30 nats). Out: support_pressure (rim-heavy, c +10-50 %): the true rim_fraction
gained -105 / +5.5 / +20 nats over the nominal model at 0.5 and +0.2 / +14 / +24 at 0.8 on
the same three draws, and benchmark draws at 0.34 and 0.40 gained nothing anywhere on the
grid (rim 0.25: -1.4, 0.5: -12 nats): the block's yaw spans at most ~0.5 rad in these 6 s
runs and a rim-heavy distribution is not resolved; viscous_damping (at 0.05-0.15 m/s the
pusher's position sets the motion; the block coasts off the pusher only with support mu
0.1, by 2-10 mm, and a drag of 3.7 N s/m per kg shortens that by 1-4 mm; on translation
only, it otherwise acts like a change of the limit surface, i.e. of the pressure effects;
a first version of the data with 0.1-0.25 m/s strokes hid b = 3.1 N s/m and the fit found
no gain at b = 0.59 or 1.26);
mass_scale and input_gain (u = 0 and the support force scales with the mass: the pusher's
position, not a force, drives the block; neither changes the motion: data generated with
mass_scale 1.5 or 1 / 1.5 differ from the clean run by < 3e-15 m, with input_gain 1.5 not
at all, and on a clean run the filter scores of mass_scale 1.5 and input_gain 1.5 equal
the nominal model's to 1e-3 nats); friction_scale and support_friction (the filter
estimates the pusher and the support coefficients over their candidates 0.1 / 0.25 / 0.4;
a factor or a new support value is a different value of these estimated coefficients);
friction_patch (no filter path)."""


def _factor(rng: np.random.Generator) -> float:
    f = float(rng.uniform(1.25, 1.6))
    return f if rng.random() < 0.5 else 1.0 / f


def _sign(rng: np.random.Generator) -> float:
    return 1.0 if rng.random() < 0.5 else -1.0


def draw_gripper_effect(
    rng: np.random.Generator, effect: str | None = None, *, scenario: Scenario | None = None
) -> ModelExtension:
    """A hidden effect of realistic size for the gripper (uniform over
    `GRIPPER_HIDDEN_EFFECTS` unless given; scenario default `gripper_scenario()`).

    viscous_damping: 1.5-4 N s/m per kg; mass_scale, input_gain: 1.25-1.6 or its inverse;
    sensor_delay: 30-80 ms; sensor_bias: y +-1.5-3 position noise stds (3-6 mm), yaw
    +-1.5-3 yaw noise stds (0.03-0.06 rad), x within +-1 std (along the jaws).
    """
    sc = scenario if scenario is not None else gripper_scenario()
    name = effect if effect is not None else str(rng.choice(GRIPPER_HIDDEN_EFFECTS))
    if name in ("mass_scale", "input_gain"):
        return ModelExtension.make(name, factor=_factor(rng))
    if name == "viscous_damping":
        return ModelExtension.make(name, b=sc.body.mass * float(rng.uniform(1.5, 4.0)))
    if name == "sensor_delay":
        return ModelExtension.make(name, seconds=float(rng.uniform(0.03, 0.08)))
    if name == "sensor_bias":
        sp, sy = sc.noise.position, sc.noise.yaw
        y = sp * float(rng.uniform(1.5, 3.0)) * _sign(rng)
        yaw = sy * float(rng.uniform(1.5, 3.0)) * _sign(rng)
        return ModelExtension.make(name, x=sp * float(rng.uniform(-1.0, 1.0)), y=y, yaw=yaw)
    msg = f"no gripper draw for effect {name!r}; valid: {list(GRIPPER_HIDDEN_EFFECTS)}"
    raise ModelError(msg)


def draw_push_effect(
    rng: np.random.Generator, effect: str | None = None, *, scenario: Scenario | None = None
) -> ModelExtension:
    """A hidden effect of realistic size for the push (uniform over `PUSH_HIDDEN_EFFECTS`
    unless given; scenario default: that of `push_sweep_trajectory`).

    sensor_delay: 30-80 ms; sensor_bias: y +-1.5-3 position noise stds (1.5-3 mm), x within
    +-1 std, yaw within +-1 yaw std; support_concentration: centre_fraction 0.8-0.9 (what
    these runs resolve: `PUSH_HIDDEN_EFFECTS`).
    """
    sc = scenario
    if sc is None:
        sc = push_scenario(PUSH_RECT, mass=PUSH_RECT_MASS, support_pair="surface")
    name = effect if effect is not None else str(rng.choice(PUSH_HIDDEN_EFFECTS))
    if name == "sensor_delay":
        return ModelExtension.make(name, seconds=float(rng.uniform(0.03, 0.08)))
    if name == "sensor_bias":
        sp, sy = sc.noise.position, sc.noise.yaw
        y = sp * float(rng.uniform(1.5, 3.0)) * _sign(rng)
        x = sp * float(rng.uniform(-1.0, 1.0))
        return ModelExtension.make(name, x=x, y=y, yaw=sy * float(rng.uniform(-1.0, 1.0)))
    if name == "support_concentration":
        return ModelExtension.make(name, centre_fraction=float(rng.uniform(0.8, 0.9)))
    msg = f"no push draw for effect {name!r}; valid: {list(PUSH_HIDDEN_EFFECTS)}"
    raise ModelError(msg)

"""Simulation parameters: one frozen dataclass per scenario, and the params YAML loader.

Units are SI (m, kg, s, N, rad). Planar quantities live in the x-y plane of frame `world`:
for `edge` the plane is vertical (gravity -y), for `gripper` and `push` it is a horizontal
table seen from above (gravity -z).

Params YAML (`dbcslam sim --params FILE`): a mapping whose top level may hold the common keys
(`duration`, `rate`, `physics_dt`, `seed`, `noise`, ...) and one section per scenario
(`edge:`, `gripper:`, `push:`) holding that scenario's keys (which may also override the
common ones)::

    seed: 3
    noise: {position: 0.005}
    edge: {duration: 8.0, segments: [[-5, 0, 0.3], [0, 0.3, 0.9], [0.3, 5, 0.3]]}
    push: {shape: hex, speed: 0.02}

Keys missing from the file keep their defaults; unknown keys are errors (`ParamError`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dbcslam_core.polygon import polygon_area, polygon_centroid

from .errors import ParamError

__all__ = [
    "SCENARIO_NAMES",
    "EdgeParams",
    "GripperParams",
    "NoiseParams",
    "PushParams",
    "ScenarioParams",
    "SimParams",
    "equilateral_triangle",
    "load_params",
    "params_class",
    "params_to_dict",
]

SCENARIO_NAMES: tuple[str, ...] = ("edge", "gripper", "push")


def _fail(msg: str) -> ParamError:
    return ParamError(msg)


def _check_range(name: str, value: float, lo: float, hi: float, *, lo_open: bool = False) -> None:
    ok = math.isfinite(value) and (value > lo if lo_open else value >= lo) and value <= hi
    if not ok:
        bracket = "(" if lo_open else "["
        raise _fail(f"parameter '{name}' = {value!r} is out of range; valid: {bracket}{lo}, {hi}]")


def equilateral_triangle(side: float) -> tuple[tuple[float, float], ...]:
    """Vertices (m, counter-clockwise, about the centroid) of an equilateral triangle.

    One edge is parallel to x at the bottom (vertex 0 lower left, 1 lower right, 2 top).
    """
    h = side * math.sqrt(3.0) / 2.0
    return ((-side / 2.0, -h / 3.0), (side / 2.0, -h / 3.0), (0.0, 2.0 * h / 3.0))


@dataclass(frozen=True)
class NoiseParams:
    """Std of the zero-mean Gaussian observation noise.

    position: m (x and y of the observed pose), yaw: rad (observed yaw; a point mass reports
    yaw 0 without noise), joint: m (observed joint positions), force: N (pusher F/T sensor,
    push only).
    """

    position: float = 0.01
    yaw: float = 0.02
    joint: float = 0.0005
    force: float = 0.05

    def __post_init__(self) -> None:
        _check_range("noise.position", self.position, 0.0, 1.0)
        _check_range("noise.yaw", self.yaw, 0.0, math.pi)
        _check_range("noise.joint", self.joint, 0.0, 1.0)
        _check_range("noise.force", self.force, 0.0, 1.0e3)


@dataclass(frozen=True)
class SimParams:
    """Parameters common to every scenario.

    duration: s, simulated time (samples at t = k / rate for k = 0 .. round(duration * rate)).
    rate: Hz, sample (publish) rate; the model step of the `/scenario` YAML is 1 / rate.
    physics_dt: s, pybullet time step; 1 / rate must be an integer multiple of it.
    seed: seed of the numpy Generator drawing the observation noise (same seed, same records).
    noise: observation noise std (see `NoiseParams`).
    gravity: m/s^2, magnitude of gravity.
    solver_iterations: pybullet constraint solver iterations per step.
    contact_force_threshold: N, a contact with total normal force above it is "in contact".
    slip_threshold: m/s, |tangential relative velocity| above it is sliding, else sticking.
    Hidden model effects (never written to the `/scenario`; for `dbcslam discrepancy` tests):
    observation_delay: s, the observed pose is the true pose this long ago (whole samples);
    observation_bias: (x m, y m, yaw rad) added to the observed pose; damping: N s/m, viscous
    force -damping v on the body's translation (edge scenario).
    """

    duration: float = 5.0
    rate: float = 100.0
    physics_dt: float = 0.001
    seed: int = 0
    noise: NoiseParams = field(default_factory=NoiseParams)
    gravity: float = 9.81
    solver_iterations: int = 100
    contact_force_threshold: float = 1.0e-3
    slip_threshold: float = 1.0e-3
    observation_delay: float = 0.0
    observation_bias: tuple[float, float, float] = (0.0, 0.0, 0.0)
    damping: float = 0.0

    def __post_init__(self) -> None:
        _check_range("duration", self.duration, 0.0, 3600.0, lo_open=True)
        _check_range("observation_delay", self.observation_delay, 0.0, 10.0)
        if len(self.observation_bias) != 3 or not all(
            math.isfinite(b) for b in self.observation_bias
        ):
            raise _fail(
                f"parameter 'observation_bias' = {self.observation_bias!r} must be 3 finite "
                "numbers (x m, y m, yaw rad)"
            )
        _check_range("damping", self.damping, 0.0, 1.0e3)
        _check_range("rate", self.rate, 0.0, 1000.0, lo_open=True)
        _check_range("physics_dt", self.physics_dt, 1.0e-5, 0.01)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise _fail(f"parameter 'seed' = {self.seed!r} must be an integer >= 0")
        if not isinstance(self.noise, NoiseParams):
            raise _fail(f"parameter 'noise' must be a NoiseParams, got {self.noise!r}")
        _check_range("gravity", self.gravity, 0.0, 100.0)
        if not isinstance(self.solver_iterations, int) or not (
            1 <= self.solver_iterations <= 10000
        ):
            raise _fail(
                f"parameter 'solver_iterations' = {self.solver_iterations!r} must be an "
                "integer in [1, 10000]"
            )
        _check_range("contact_force_threshold", self.contact_force_threshold, 0.0, 1.0e3)
        _check_range("slip_threshold", self.slip_threshold, 0.0, 1.0, lo_open=True)
        period = 1.0 / self.rate
        ratio = period / self.physics_dt
        if abs(ratio - round(ratio)) > 1e-6 * ratio or round(ratio) < 1:
            raise _fail(
                f"parameter 'physics_dt' = {self.physics_dt!r} s must divide the sample period "
                f"1/rate = {period!r} s into an integer number of steps (e.g. "
                f"{period / max(1, round(ratio)):.6g})"
            )

    @property
    def steps_per_sample(self) -> int:
        """Physics steps between two samples."""
        return round(1.0 / (self.rate * self.physics_dt))

    @property
    def n_samples(self) -> int:
        """Number of records of a run (the initial state included)."""
        return round(self.duration * self.rate) + 1


def _check_keyframes(name: str, frames: tuple[tuple[float, ...], ...], width: int) -> None:
    if not frames:
        raise _fail(f"parameter '{name}' needs at least one keyframe (t, ...)")
    last = -math.inf
    for i, row in enumerate(frames):
        if len(row) != width:
            raise _fail(
                f"parameter '{name}[{i}]' = {list(row)} must have {width} numbers "
                f"(t then the {width - 1} values)"
            )
        if not all(math.isfinite(v) for v in row):
            raise _fail(f"parameter '{name}[{i}]' = {list(row)} must be finite")
        if row[0] <= last:
            raise _fail(f"parameter '{name}' times must increase strictly; row {i} has t={row[0]}")
        last = row[0]
    if frames[0][0] != 0.0:
        raise _fail(f"parameter '{name}' must start at t = 0, got t = {frames[0][0]}")


@dataclass(frozen=True)
class EdgeParams(SimParams):
    """Point mass on an edge (paper Fig. 3): vertical x-y plane, gravity -y.

    The point is the centre of a sphere of radius `radius` (m) whose surface touches the edge
    when the point is at y = edge_y; only x and y move (no rotation).
    mass: kg. segments: ((x_min, x_max, mu), ...) contiguous, sorted, covering the travel (m),
    the true friction layout (hidden from the robot). start, start_velocity: m, m/s.
    force: ((t, fx, fy), ...) keyframes of the applied force (s, N, N), world frame, linear
    interpolation, held after the last keyframe. friction_candidates/prior: the robot's
    a-priori friction model written to the `/scenario` YAML.
    """

    duration: float = 5.5
    noise: NoiseParams = field(default_factory=lambda: NoiseParams(0.01, 0.02, 0.0005, 0.0))
    mass: float = 1.0
    radius: float = 0.01
    edge_y: float = 0.0
    segments: tuple[tuple[float, float, float], ...] = (
        (-5.0, 0.0, 0.3),
        (0.0, 0.3, 0.9),
        (0.3, 5.0, 0.3),
    )
    start: tuple[float, float] = (-0.45, 0.03)
    start_velocity: tuple[float, float] = (0.0, 0.0)
    force: tuple[tuple[float, float, float], ...] = (
        (0.0, 3.6, 0.0),
        (1.6, 3.6, 0.0),
        (3.3, 9.6, 0.0),
        (3.95, 9.6, 0.0),
        (4.05, 2.0, 0.0),
        (4.3, 2.0, 0.0),
        (4.7, 0.5, 10.3),
        (5.1, 0.0, 10.1),
    )
    friction_candidates: tuple[float, ...] = (0.3, 0.9)
    friction_prior: tuple[float, ...] = (0.5, 0.5)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range("mass", self.mass, 0.0, 1.0e3, lo_open=True)
        _check_range("radius", self.radius, 1.0e-4, 0.1)
        _check_range("edge_y", self.edge_y, -100.0, 100.0)
        if not self.segments:
            raise _fail("parameter 'segments' needs at least one (x_min, x_max, mu) segment")
        for i, seg in enumerate(self.segments):
            if len(seg) != 3:
                raise _fail(f"parameter 'segments[{i}]' = {list(seg)} must be (x_min, x_max, mu)")
            x0, x1, mu = seg
            if not (math.isfinite(x0) and math.isfinite(x1) and x1 > x0):
                raise _fail(f"parameter 'segments[{i}]' = {list(seg)} needs x_min < x_max")
            _check_range(f"segments[{i}].mu", mu, 0.0, 2.0)
            if i > 0 and abs(self.segments[i - 1][1] - x0) > 1e-12:
                raise _fail(
                    f"parameter 'segments' must be contiguous: segment {i} starts at {x0}, "
                    f"segment {i - 1} ends at {self.segments[i - 1][1]}"
                )
        lo, hi = self.segments[0][0], self.segments[-1][1]
        if not lo < self.start[0] < hi:
            raise _fail(
                f"parameter 'start' x = {self.start[0]} must lie on the edge, in ({lo}, {hi})"
            )
        if self.start[1] < self.edge_y:
            raise _fail(
                f"parameter 'start' y = {self.start[1]} must be >= edge_y = {self.edge_y} "
                "(the body lives above the edge)"
            )
        _check_keyframes("force", self.force, 3)
        _check_candidates(self.friction_candidates, self.friction_prior)

    def mu_at(self, x: float) -> float:
        """True friction coefficient of the segment under abscissa x (m), clamped at the ends."""
        for x0, x1, mu in self.segments:
            if x0 <= x < x1:
                return mu
        return self.segments[0][2] if x < self.segments[0][0] else self.segments[-1][2]


def _check_candidates(cands: tuple[float, ...], prior: tuple[float, ...]) -> None:
    if not cands:
        raise _fail("parameter 'friction_candidates' must not be empty")
    for c in cands:
        _check_range("friction_candidates[]", c, 0.0, 2.0)
    if len(prior) != len(cands):
        raise _fail(
            f"parameter 'friction_prior' = {list(prior)} needs one entry per candidate "
            f"{list(cands)}"
        )
    if any(p < 0.0 for p in prior) or not math.isclose(sum(prior), 1.0, abs_tol=1e-6):
        raise _fail(f"parameter 'friction_prior' = {list(prior)} must be >= 0 and sum to 1")


@dataclass(frozen=True)
class GripperParams(SimParams):
    """Triangle between two parallel jaws (paper Fig. 4): horizontal table, gravity -z.

    vertices: body-frame outline (m), counter-clockwise, centroid at the origin (uniform
    density: centre of mass = centroid); inertia: kg m^2 about the centroid (None: uniform
    plate). thickness: m, prism height. start: (x, y, yaw) in m, m, rad; start_twist in m/s,
    m/s, rad/s. The support is frictionless. Jaws: faces normal to y, lower face at
    y = `lower_jaw`, upper face at y = `upper_jaw`; each jaw is position controlled towards
    a target moving from `*_start` to `*_target` at `jaw_speed` (m/s), with at most
    `jaw_force` (N), so the jaws stall on the object and squeeze it with that force.
    jaw_mu: true jaw friction. wrench: ((t, fx, fy, tau), ...) keyframes (s, N, N, N m) of the
    applied wrench at the centroid, world frame.
    """

    duration: float = 4.0
    noise: NoiseParams = field(default_factory=lambda: NoiseParams(0.002, 0.02, 0.0005, 0.0))
    solver_iterations: int = 300
    mass: float = 0.2
    vertices: tuple[tuple[float, float], ...] = equilateral_triangle(0.06)
    inertia: float | None = None
    thickness: float = 0.02
    start: tuple[float, float, float] = (0.0, 0.0, 0.35)
    start_twist: tuple[float, float, float] = (0.0, 0.0, 0.0)
    jaw_mu: float = 0.4
    lower_start: float = -0.06
    upper_start: float = 0.06
    lower_target: float = 0.0
    upper_target: float = 0.0
    jaw_speed: float = 0.012
    jaw_force: float = 8.0
    wrench: tuple[tuple[float, float, float, float], ...] = (
        (0.0, 0.03, -0.06, 1.0e-5),
        (0.7, 0.03, -0.06, 1.0e-5),
        (0.9, -0.02, 0.1, -2.0e-5),
        (1.6, -0.02, 0.1, -2.0e-5),
        (1.9, -0.06, 0.1, 0.0),
        (2.1, 0.04, -0.08, 1.0e-5),
        (2.4, -0.05, -0.08, 0.0),
        (2.7, 0.05, -0.05, 0.0),
        (3.2, 0.0, 0.0, 0.0),
    )
    friction_candidates: tuple[float, ...] = (0.1, 0.4, 0.7)
    friction_prior: tuple[float, ...] = (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        _check_range("mass", self.mass, 0.0, 1.0e3, lo_open=True)
        if len(self.vertices) < 3:
            raise _fail(f"parameter 'vertices' needs >= 3 points, got {list(self.vertices)}")
        area = polygon_area(self.vertices)
        if area <= 0.0:
            raise _fail(
                f"parameter 'vertices' must be counter-clockwise with positive area, got area "
                f"{area:.3g} m^2 for {list(self.vertices)}"
            )
        cx, cy = polygon_centroid(self.vertices)
        size = max(math.hypot(x, y) for x, y in self.vertices)
        if math.hypot(cx, cy) > 1e-9 + 1e-6 * size:
            raise _fail(
                f"parameter 'vertices' must have the centroid at the origin (the centre of "
                f"mass); centroid is ({cx:.6g}, {cy:.6g})"
            )
        if self.inertia is not None:
            _check_range("inertia", self.inertia, 0.0, 1.0e3, lo_open=True)
        _check_range("thickness", self.thickness, 1.0e-4, 1.0)
        _check_range("jaw_mu", self.jaw_mu, 0.0, 2.0)
        _check_range("jaw_speed", self.jaw_speed, 0.0, 10.0)
        _check_range("jaw_force", self.jaw_force, 0.0, 1.0e4, lo_open=True)
        if not self.lower_start < self.upper_start:
            raise _fail(
                f"parameters 'lower_start' = {self.lower_start} and 'upper_start' = "
                f"{self.upper_start} need lower_start < upper_start"
            )
        lo = min(self.start[1] + vy for vy in self._world_vertex_y())
        hi = max(self.start[1] + vy for vy in self._world_vertex_y())
        if not (self.lower_start < lo and hi < self.upper_start):
            raise _fail(
                f"the start pose {list(self.start)} puts the body (y in [{lo:.4g}, {hi:.4g}]) "
                f"outside the open jaws (lower_start {self.lower_start}, upper_start "
                f"{self.upper_start})"
            )
        _check_keyframes("wrench", self.wrench, 4)
        _check_candidates(self.friction_candidates, self.friction_prior)

    def _world_vertex_y(self) -> list[float]:
        c, s = math.cos(self.start[2]), math.sin(self.start[2])
        return [s * x + c * y for x, y in self.vertices]

    @property
    def body_inertia(self) -> float:
        """Polar moment of inertia about the centroid, kg m^2 (uniform plate if not given)."""
        if self.inertia is not None:
            return self.inertia
        return polygon_inertia(self.vertices, self.mass)


def polygon_inertia(verts: tuple[tuple[float, float], ...], mass: float) -> float:
    """Polar moment of inertia (kg m^2) of a uniform polygon plate about the origin."""
    n = len(verts)
    num = 0.0
    area2 = 0.0
    for i in range(n):
        x0, y0 = verts[i]
        x1, y1 = verts[(i + 1) % n]
        cr = x0 * y1 - x1 * y0
        area2 += cr
        num += cr * (x0 * x0 + x0 * x1 + x1 * x1 + y0 * y0 + y0 * y1 + y1 * y1)
    return mass * num / (6.0 * area2)


@dataclass(frozen=True)
class PushParams(SimParams):
    """Cylindrical pusher pushing a polygon prism on a support (MIT MCube push set-up).

    shape: a name of `shapes.SHAPES` (outline from the package's shape files) or the path
    of an (n, 2) `.npy` outline (m, object frame, clockwise or counter-clockwise).
    mass (kg) / inertia (kg m^2 about the centroid): None takes the dataset table (else
    uniform stainless steel, 7950 kg/m^3). thickness: m. pusher_radius: m.
    The push mirrors the dataset's file name fields: side index `side` of the outline (in the
    counter-clockwise order about the centroid), contact position `side_position` in [0, 1]
    along it, push direction `angle` (rad) relative to the side's inward normal; the pusher
    starts `approach` (m) before touching and moves at constant `speed` (m/s) for `approach +
    travel` (m), then stops. mu_surface: object-support friction, mu_pusher: pusher-object
    friction (both true values, hidden; each is one of `friction_candidates`). support_pair:
    name of the second friction pair (object-support friction) in the `/scenario` YAML,
    default `surface`; null leaves the support out of the a-priori model, and the filter then
    treats the table as frictionless.
    """

    duration: float = 2.5
    noise: NoiseParams = field(default_factory=lambda: NoiseParams(0.001, 0.01, 0.0005, 0.05))
    shape: str = "rect1"
    mass: float | None = None
    inertia: float | None = None
    thickness: float = 0.013
    pusher_radius: float = 0.00475
    side: int = 0
    side_position: float = 0.5
    angle: float = 0.0
    speed: float = 0.05
    approach: float = 0.04
    travel: float = 0.05
    mu_surface: float = 0.3
    mu_pusher: float = 0.2
    support_pair: str | None = "surface"
    friction_candidates: tuple[float, ...] = (0.1, 0.2, 0.3)
    friction_prior: tuple[float, ...] = (1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.shape:
            raise _fail("parameter 'shape' must name a shape or an .npy outline file")
        if self.mass is not None:
            _check_range("mass", self.mass, 0.0, 1.0e3, lo_open=True)
        if self.inertia is not None:
            _check_range("inertia", self.inertia, 0.0, 1.0e3, lo_open=True)
        _check_range("thickness", self.thickness, 1.0e-3, 0.5)
        _check_range("pusher_radius", self.pusher_radius, 1.0e-4, 0.1)
        if isinstance(self.side, bool) or not isinstance(self.side, int) or self.side < 0:
            raise _fail(f"parameter 'side' = {self.side!r} must be an integer >= 0")
        _check_range("side_position", self.side_position, 0.0, 1.0)
        _check_range("angle", self.angle, -1.5, 1.5)
        _check_range("speed", self.speed, 0.0, 2.0, lo_open=True)
        _check_range("approach", self.approach, 0.0, 1.0)
        _check_range("travel", self.travel, 0.0, 1.0)
        _check_range("mu_surface", self.mu_surface, 0.0, 2.0)
        _check_range("mu_pusher", self.mu_pusher, 0.0, 2.0)
        if self.support_pair is not None and (
            not self.support_pair or self.support_pair == "pusher"
        ):
            raise _fail(
                f"parameter 'support_pair' = {self.support_pair!r} must be null or a non-empty "
                "name other than 'pusher'"
            )
        _check_candidates(self.friction_candidates, self.friction_prior)


ScenarioParams = EdgeParams | GripperParams | PushParams

_CLASSES: dict[str, type[EdgeParams] | type[GripperParams] | type[PushParams]] = {
    "edge": EdgeParams,
    "gripper": GripperParams,
    "push": PushParams,
}


def params_class(
    scenario: str,
) -> type[EdgeParams] | type[GripperParams] | type[PushParams]:
    """The parameter dataclass of a scenario name."""
    try:
        return _CLASSES[scenario]
    except KeyError as err:
        msg = f"unknown scenario {scenario!r}; valid scenarios are {list(SCENARIO_NAMES)}"
        raise ParamError(msg) from err


# ------------------------------------------------------------------------------ YAML coercion
def _num(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise _fail(f"parameter '{name}' must be a number, got {v!r}")
    return float(v)


def _int(name: str, v: Any) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise _fail(f"parameter '{name}' must be an integer, got {v!r}")
    return v


def _text(name: str, v: Any) -> str:
    if not isinstance(v, str):
        raise _fail(f"parameter '{name}' must be a string, got {v!r}")
    return v


def _vec(name: str, v: Any, n: int | None) -> tuple[float, ...]:
    if not isinstance(v, list | tuple):
        raise _fail(f"parameter '{name}' must be a list of numbers, got {v!r}")
    if n is not None and len(v) != n:
        raise _fail(f"parameter '{name}' must have {n} numbers, got {v!r}")
    return tuple(_num(f"{name}[{i}]", x) for i, x in enumerate(v))


def _rows(name: str, v: Any, n: int) -> tuple[tuple[float, ...], ...]:
    if not isinstance(v, list | tuple):
        raise _fail(f"parameter '{name}' must be a list of [{n} numbers] rows, got {v!r}")
    return tuple(_vec(f"{name}[{i}]", row, n) for i, row in enumerate(v))


def _noise(name: str, v: Any, default: NoiseParams) -> NoiseParams:
    if isinstance(v, NoiseParams):
        return v
    if not isinstance(v, Mapping):
        raise _fail(f"parameter '{name}' must be a mapping of std values, got {v!r}")
    valid = [f.name for f in dataclasses.fields(NoiseParams)]
    extra = sorted(set(v) - set(valid))
    if extra:
        raise _fail(f"unknown key(s) {extra} in '{name}'; valid keys are {valid}")
    return dataclasses.replace(default, **{k: _num(f"{name}.{k}", x) for k, x in v.items()})


_COERCE: dict[str, Callable[[str, Any], Any]] = {
    "float": _num,
    "int": _int,
    "str": _text,
    "float | None": lambda n, v: None if v is None else _num(n, v),
    "str | None": lambda n, v: None if v is None else _text(n, v),
    "tuple[float, float]": lambda n, v: _vec(n, v, 2),
    "tuple[float, float, float]": lambda n, v: _vec(n, v, 3),
    "tuple[float, ...]": lambda n, v: _vec(n, v, None),
    "tuple[tuple[float, float], ...]": lambda n, v: _rows(n, v, 2),
    "tuple[tuple[float, float, float], ...]": lambda n, v: _rows(n, v, 3),
    "tuple[tuple[float, float, float, float], ...]": lambda n, v: _rows(n, v, 4),
}


def _coerce_all(
    cls: type[EdgeParams] | type[GripperParams] | type[PushParams], raw: Mapping[str, Any]
) -> dict[str, Any]:
    fields = {f.name: f for f in dataclasses.fields(cls)}
    extra = sorted(set(raw) - set(fields))
    if extra:
        raise _fail(
            f"unknown parameter(s) {extra} for scenario params {cls.__name__}; valid keys are "
            f"{sorted(fields)}"
        )
    out: dict[str, Any] = {}
    for key, value in raw.items():
        f = fields[key]
        if key == "noise":
            default = f.default_factory() if callable(f.default_factory) else NoiseParams()
            out[key] = _noise(key, value, default)
            continue
        conv = _COERCE.get(str(f.type))
        if conv is None:  # pragma: no cover - guards against a new field type
            raise _fail(f"parameter '{key}' has an unsupported type {f.type}")
        out[key] = conv(key, value)
    return out


def load_params(
    scenario: str,
    source: str | Path | Mapping[str, Any] | None = None,
    **overrides: Any,
) -> ScenarioParams:
    """Parameters of `scenario` from a params YAML file, a parsed mapping, or defaults.

    `overrides` (already typed values, e.g. seed=3, duration=2.0) win over the file. Raises
    `ParamError` naming the file and the offending key on any problem.
    """
    cls = params_class(scenario)
    where = "<mapping>"
    data: Any
    if source is None:
        data = {}
    elif isinstance(source, Mapping):
        data = source
    else:
        path = Path(source)
        where = str(path)
        try:
            data = yaml.safe_load(path.read_text(encoding="utf-8"))
        except OSError as err:
            msg = f"cannot read params file {where}: {err}"
            raise ParamError(msg) from err
        except yaml.YAMLError as err:
            msg = f"params file {where} is not valid YAML: {err}"
            raise ParamError(msg) from err
        if data is None:
            data = {}
    if not isinstance(data, Mapping):
        raise _fail(f"params {where} must be a mapping at the top level, got {type(data)}")
    common = {k: v for k, v in data.items() if k not in SCENARIO_NAMES}
    section = data.get(scenario) or {}
    if not isinstance(section, Mapping):
        raise _fail(f"params {where}: section '{scenario}' must be a mapping, got {section!r}")
    merged: dict[str, Any] = dict(common)
    for k, v in section.items():
        if k == "noise" and isinstance(v, Mapping) and isinstance(merged.get(k), Mapping):
            merged[k] = {**merged[k], **v}
        else:
            merged[k] = v
    try:
        kwargs = _coerce_all(cls, merged)
        kwargs.update(overrides)
        return cls(**kwargs)
    except ParamError as err:
        msg = f"params {where} (scenario {scenario}): {err}"
        raise ParamError(msg) from err
    except TypeError as err:
        msg = f"params {where} (scenario {scenario}): {err}"
        raise ParamError(msg) from err


def _plain(value: Any) -> Any:
    if isinstance(value, tuple | list):
        return [_plain(v) for v in value]
    if isinstance(value, NoiseParams):
        return {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    return value


def params_to_dict(params: ScenarioParams) -> dict[str, Any]:
    """The params as a section mapping ``{scenario: {key: value}}`` (YAML-ready, lists).

    `load_params(scenario, params_to_dict(p))` gives back `p`.
    """
    name = next(k for k, c in _CLASSES.items() if type(params) is c)
    body = {f.name: _plain(getattr(params, f.name)) for f in dataclasses.fields(params)}
    return {name: body}

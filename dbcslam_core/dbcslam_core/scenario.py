"""The a-priori scenario model: frozen dataclasses mirroring the `/scenario` YAML 1:1.

Units SI, frames REP-103 (planar, frame `world`, yaw about +z counter-clockwise). The YAML
layout is the one of the interface contract::

    scenario: edge            # edge | gripper | push
    dt: 0.01                  # s
    gravity: 9.81             # m/s^2
    body: {mass: 1.0, inertia: 0.0, shape: point}   # kg, kg m^2, point | polygon
                              # (polygon without inertia: uniform density about the origin)
    vertices: []              # polygon only: [[x, y], ...] body frame about the CoM, m
    contacts: [edge]          # potential contacts, order of /dbcslam/contact_modes dim 0
    friction: {pairs: [edge], candidates: [0.3, 0.9], prior: [0.5, 0.5]}
    noise: {position: 0.01, yaw: 0.02, joint: 0.0005}  # std: m, rad, m
    edge: {y: 0.0}            # edge scenario: the line y = edge.y, body in y >= edge.y

Scenario keys added here (defaults shown):

* gripper: ``jaws: {lower_joint: lower_jaw, upper_joint: upper_jaw}``. Two position
  controlled half-spaces moving along y: obstacle ``lower`` with normal +y at y = joint
  ``lower_jaw`` and obstacle ``upper`` with normal -y at y = joint ``upper_jaw``. Jaws are
  infinitely long; the support plane is frictionless.
* push: ``pusher: {radius: 0.01, joint_x: pusher_x, joint_y: pusher_y}`` (a disk pusher)
  and ``surface: {pair: null, pressure: uniform, mu: 0.0, velocity_eps: 1.0e-4}`` (support
  friction, all keys optional: `pair` names the friction pair of the body-support contact,
  estimated like any pair; without a pair the coefficient is the known `mu` (default 0,
  frictionless); `pressure` is the pressure distribution
  ``uniform | rim | vertices | centre | tripod``
  (`geometry.support_points`); `velocity_eps` (m/s) regularises the Coulomb support friction
  (`PlanarModel.support_matrix`); `model` is the push model ``dynamic`` (default: rigid body
  with inertia, implicit Coulomb support friction, the object coasts when released) or
  ``quasi_static`` (no inertia: ellipsoidal limit surface of the pressure distribution, the
  object moves only while pushed; `PlanarModel`, `dbcslam_core.quasi_static`); other numeric
  keys are kept verbatim).

``friction.candidates`` / ``friction.prior`` are either one list shared by all pairs or one
list per pair. Each obstacle belongs to a friction pair: the pair with the obstacle's name,
else the pair named by the optional ``friction.obstacles: {obstacle: pair}`` map, else the
only pair when there is exactly one.

Potential contacts (names): point mass vs half-space ``{obstacle}`` (e.g. ``edge``);
polygon vertex i vs half-space ``v{i}_{obstacle}`` (e.g. ``v0_lower``); polygon outline vs
disk ``{obstacle}`` (``pusher``). ``contacts`` may list any non-empty subset of these in any
order; that order is dim 0 of ``/dbcslam/contact_modes``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Literal, cast

import yaml

from .errors import ScenarioError
from .polygon import polygon_inertia

__all__ = [
    "DEFAULT_VELOCITY_EPS",
    "MAX_SCENARIO_BYTES",
    "PRESSURE_MODELS",
    "PUSH_MODELS",
    "SCENARIO_KINDS",
    "Body",
    "Disk",
    "FrictionSpec",
    "HalfSpace",
    "NoiseSpec",
    "Obstacle",
    "PotentialContact",
    "Scenario",
    "SurfaceSpec",
    "edge_scenario",
    "equilateral_triangle",
    "gripper_scenario",
    "push_scenario",
]

#: Longest `/scenario` YAML text accepted (characters); real scenarios are a few kB (polygon
#: outlines of ~100 vertices included).
MAX_SCENARIO_BYTES = 256 * 1024


class _NoAliasSafeLoader(yaml.SafeLoader):
    """yaml.SafeLoader that refuses anchors and aliases (no alias expansion attacks)."""

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()  # type: ignore[no-untyped-call]
            raise yaml.composer.ComposerError(
                None, None, "YAML aliases are not accepted in a scenario", event.start_mark
            )
        return super().compose_node(parent, index)


SCENARIO_KINDS: tuple[str, ...] = ("edge", "gripper", "push")
ScenarioKind = Literal["edge", "gripper", "push"]
Shape = Literal["point", "polygon"]
Feature = Literal["origin", "vertex", "outline"]

_TOP_KEYS = {
    "scenario",
    "dt",
    "gravity",
    "body",
    "vertices",
    "contacts",
    "friction",
    "noise",
    "edge",
    "jaws",
    "pusher",
    "surface",
}
_SCENARIO_KEYS: dict[str, tuple[str, ...]] = {
    "edge": ("edge",),
    "gripper": ("jaws",),
    "push": ("pusher", "surface"),
}


# --------------------------------------------------------------------------- validation helpers
def _fail(msg: str) -> ScenarioError:
    return ScenarioError(msg)


def _mapping(value: Any, key: str) -> Mapping[str, Any]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise _fail(f"scenario key '{key}' must be a mapping, got {value!r}")
    for k in value:
        if not isinstance(k, str):
            raise _fail(f"scenario key '{key}' has a non-string key {k!r}")
    return value


def _check_keys(m: Mapping[str, Any], allowed: Sequence[str], where: str) -> None:
    extra = sorted(set(m) - set(allowed))
    if extra:
        raise _fail(f"unknown key(s) {extra} in '{where}'; valid keys are {sorted(allowed)}")


def _float(value: Any, key: str, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _fail(f"scenario key '{key}' must be a number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise _fail(f"scenario key '{key}' must be finite, got {value!r}")
    if positive and x <= 0.0:
        raise _fail(f"scenario key '{key}' must be > 0, got {value!r}")
    if nonneg and x < 0.0:
        raise _fail(f"scenario key '{key}' must be >= 0, got {value!r}")
    return x


def _str(value: Any, key: str) -> str:
    if not isinstance(value, str) or not value:
        raise _fail(f"scenario key '{key}' must be a non-empty string, got {value!r}")
    return value


def _str_list(value: Any, key: str) -> tuple[str, ...]:
    if not isinstance(value, list | tuple) or not value:
        raise _fail(f"scenario key '{key}' must be a non-empty list of names, got {value!r}")
    names = tuple(_str(v, f"{key}[{i}]") for i, v in enumerate(value))
    if len(set(names)) != len(names):
        raise _fail(f"scenario key '{key}' has duplicate names: {list(names)}")
    return names


def _float_list(value: Any, key: str) -> tuple[float, ...]:
    if not isinstance(value, list | tuple) or not value:
        raise _fail(f"scenario key '{key}' must be a non-empty list of numbers, got {value!r}")
    return tuple(_float(v, f"{key}[{i}]") for i, v in enumerate(value))


def _cross(ax: float, ay: float, bx: float, by: float) -> float:
    return ax * by - ay * bx


def _signed_area(verts: Sequence[tuple[float, float]]) -> float:
    n = len(verts)
    return 0.5 * sum(
        _cross(verts[i][0], verts[i][1], verts[(i + 1) % n][0], verts[(i + 1) % n][1])
        for i in range(n)
    )


def _uniform_inertia(verts: Sequence[tuple[float, float]], mass: float) -> float:
    """Polar moment (kg m^2) about the origin of a uniform polygon of `mass`."""
    n = len(verts)
    area2 = 0.0
    acc = 0.0
    for i in range(n):
        (x0, y0), (x1, y1) = verts[i], verts[(i + 1) % n]
        cr = _cross(x0, y0, x1, y1)
        area2 += cr
        acc += cr * (x0 * x0 + x0 * x1 + x1 * x1 + y0 * y0 + y0 * y1 + y1 * y1)
    if area2 == 0.0:
        raise _fail(f"scenario key 'vertices' is degenerate (zero area): {list(verts)}")
    return mass * acc / (6.0 * area2)


def _normalise_polygon(verts: tuple[tuple[float, float], ...]) -> tuple[tuple[float, float], ...]:
    """Check a convex simple polygon; return it in counter-clockwise order."""
    n = len(verts)
    if n < 3:
        raise _fail(f"scenario key 'vertices' needs >= 3 vertices for a polygon, got {n}")
    area = _signed_area(verts)
    scale = max(math.hypot(x, y) for x, y in verts)
    if abs(area) <= 1e-12 * max(scale * scale, 1e-300):
        raise _fail(f"scenario key 'vertices' is degenerate (zero area): {list(verts)}")
    if area < 0.0:
        verts = tuple(reversed(verts))
    for i in range(n):
        a, b, c = verts[i], verts[(i + 1) % n], verts[(i + 2) % n]
        turn = _cross(b[0] - a[0], b[1] - a[1], c[0] - b[0], c[1] - b[1])
        if turn <= 1e-12 * scale * scale:
            raise _fail(
                f"scenario key 'vertices' must be a strictly convex polygon without repeated or "
                f"collinear vertices; turn at vertex {(i + 1) % n} is {turn:.3g}: {list(verts)}"
            )
    # a convex, consistently turning polygon could still wind twice: total turning must be 2 pi
    total = 0.0
    for i in range(n):
        a, b, c = verts[i], verts[(i + 1) % n], verts[(i + 2) % n]
        total += math.atan2(
            _cross(b[0] - a[0], b[1] - a[1], c[0] - b[0], c[1] - b[1]),
            (b[0] - a[0]) * (c[0] - b[0]) + (b[1] - a[1]) * (c[1] - b[1]),
        )
    if abs(total - 2.0 * math.pi) > 1e-6:
        raise _fail(f"scenario key 'vertices' is self-intersecting: {list(verts)}")
    return verts


# ----------------------------------------------------------------------------- dataclasses
@dataclass(frozen=True)
class Body:
    """The tracked rigid body.

    mass in kg, inertia about the centre of mass in kg m^2 (0 for a point mass); vertices in
    the body frame about the centre of mass (m), counter-clockwise, empty for a point mass.
    """

    mass: float
    inertia: float = 0.0
    shape: Shape = "point"
    vertices: tuple[tuple[float, float], ...] = ()

    def __post_init__(self) -> None:
        _float(self.mass, "body.mass", positive=True)
        if self.shape not in ("point", "polygon"):
            raise _fail(
                f"scenario key 'body.shape' must be 'point' or 'polygon', got {self.shape!r}"
            )
        if self.shape == "point":
            _float(self.inertia, "body.inertia", nonneg=True)
            if self.vertices:
                raise _fail(
                    "scenario key 'vertices' must be empty for body.shape 'point', got "
                    f"{list(self.vertices)}"
                )
        else:
            _float(self.inertia, "body.inertia", positive=True)
            verts = tuple(
                (_float(v[0], f"vertices[{i}][0]"), _float(v[1], f"vertices[{i}][1]"))
                for i, v in enumerate(self.vertices)
            )
            object.__setattr__(self, "vertices", _normalise_polygon(verts))

    @property
    def nq(self) -> int:
        """Number of generalised coordinates: 2 (x, y) or 3 (x, y, yaw)."""
        return 2 if self.shape == "point" else 3


@dataclass(frozen=True)
class FrictionSpec:
    """Friction pairs, the discrete candidate coefficients per pair and their prior."""

    pairs: tuple[str, ...]
    candidates: tuple[tuple[float, ...], ...]
    prior: tuple[tuple[float, ...], ...]
    obstacles: tuple[tuple[str, str], ...] = ()
    """Optional explicit obstacle -> pair map (sorted items)."""

    def __post_init__(self) -> None:
        if len(self.candidates) != len(self.pairs) or len(self.prior) != len(self.pairs):
            raise _fail(
                f"friction.candidates/prior need one list per pair ({len(self.pairs)} pairs "
                f"{list(self.pairs)}), got {len(self.candidates)} and {len(self.prior)}"
            )
        for p, cands, pri in zip(self.pairs, self.candidates, self.prior, strict=True):
            if not cands:
                raise _fail(f"friction.candidates for pair '{p}' is empty")
            for c in cands:
                if not (math.isfinite(c) and c >= 0.0):
                    raise _fail(
                        f"friction.candidates for pair '{p}' must be finite and >= 0, got {c}"
                    )
            if len(set(cands)) != len(cands):
                raise _fail(f"friction.candidates for pair '{p}' has duplicates: {list(cands)}")
            if len(pri) != len(cands):
                raise _fail(
                    f"friction.prior for pair '{p}' needs {len(cands)} entries (one per "
                    f"candidate {list(cands)}), got {list(pri)}"
                )
            if any(x < 0.0 for x in pri) or not math.isclose(sum(pri), 1.0, abs_tol=1e-6):
                raise _fail(
                    f"friction.prior for pair '{p}' must be >= 0 and sum to 1, got {list(pri)}"
                )

    def pair_index(self, name: str) -> int:
        """Index of friction pair `name`."""
        try:
            return self.pairs.index(name)
        except ValueError as err:
            msg = f"unknown friction pair {name!r}; valid pairs are {list(self.pairs)}"
            raise ScenarioError(msg) from err


@dataclass(frozen=True)
class NoiseSpec:
    """Observation noise standard deviations: position (m), yaw (rad), joint (m)."""

    position: float = 0.01
    yaw: float = 0.02
    joint: float = 0.0005

    def __post_init__(self) -> None:
        for key in ("position", "yaw", "joint"):
            _float(getattr(self, key), f"noise.{key}", nonneg=True)


@dataclass(frozen=True)
class HalfSpace:
    """Obstacle {p : n . p >= d}, d = offset + sign * env[joint] (static when joint is None).

    normal: unit normal into the free side; tangent t = (n_y, -n_x).
    """

    name: str
    normal: tuple[float, float]
    offset: float
    joint: str | None = None
    sign: float = 1.0

    @property
    def tangent(self) -> tuple[float, float]:
        """Contact tangent t = (n_y, -n_x)."""
        return (self.normal[1], -self.normal[0])


@dataclass(frozen=True)
class Disk:
    """Disk obstacle (pusher) of radius `radius` (m), centre (env[joint_x], env[joint_y])."""

    name: str
    radius: float
    joint_x: str = "pusher_x"
    joint_y: str = "pusher_y"


Obstacle = HalfSpace | Disk


PRESSURE_MODELS: tuple[str, ...] = ("uniform", "rim", "vertices", "centre", "tripod")
"""Support pressure distributions (`surface.pressure`, see `geometry.support_points`)."""

DEFAULT_VELOCITY_EPS: float = 1e-4
"""Default regularisation speed (m/s) of the support friction (`surface.velocity_eps`)."""

PUSH_MODELS: tuple[str, ...] = ("dynamic", "quasi_static")
"""Push models (`surface.model`): rigid body with inertia and Coulomb support friction, or
quasi-static pusher-slider on an ellipsoidal limit surface (see `PlanarModel`)."""


@dataclass(frozen=True)
class SurfaceSpec:
    """Support surface under a horizontal scenario (the push scenario's table).

    pair: friction pair of the body-support contact (its coefficient is estimated like any
    pair; None = known coefficient `mu`). params: numeric keys, sorted (name, value) pairs;
    interpreted: ``mu`` (support coefficient when `pair` is None, default 0 = frictionless),
    ``velocity_eps`` (m/s, > 0, regularisation speed of the implicit Coulomb support friction,
    default `DEFAULT_VELOCITY_EPS`); other numeric keys are kept verbatim. pressure: the
    pressure distribution of the body on the support, one of `PRESSURE_MODELS` (None = not
    given = ``uniform``; kept as None so that YAML without the key round-trips unchanged).
    model: the push model, one of `PUSH_MODELS` (None = not given = ``dynamic``).
    """

    pair: str | None = None
    params: tuple[tuple[str, float], ...] = ()
    pressure: str | None = None
    model: str | None = None

    def __post_init__(self) -> None:
        if self.model is not None and self.model not in PUSH_MODELS:
            raise _fail(
                f"scenario key 'surface.model' must be one of {list(PUSH_MODELS)}, got "
                f"{self.model!r}"
            )
        if self.pressure is not None and self.pressure not in PRESSURE_MODELS:
            raise _fail(
                f"scenario key 'surface.pressure' must be one of {list(PRESSURE_MODELS)}, got "
                f"{self.pressure!r}"
            )
        p = dict(self.params)
        if "mu" in p:
            _float(p["mu"], "surface.mu", nonneg=True)
        if "velocity_eps" in p:
            _float(p["velocity_eps"], "surface.velocity_eps", positive=True)

    @property
    def pressure_model(self) -> str:
        """The pressure distribution name (``uniform`` when not given)."""
        return self.pressure if self.pressure is not None else "uniform"

    @property
    def push_model(self) -> str:
        """The push model name (``dynamic`` when not given)."""
        return self.model if self.model is not None else "dynamic"

    @property
    def quasi_static(self) -> bool:
        """Whether the push model is ``quasi_static``."""
        return self.push_model == "quasi_static"

    @property
    def mu(self) -> float:
        """Known support friction coefficient (used when `pair` is None; default 0)."""
        return float(dict(self.params).get("mu", 0.0))

    @property
    def velocity_eps(self) -> float:
        """Regularisation speed (m/s) of the support friction."""
        return float(dict(self.params).get("velocity_eps", DEFAULT_VELOCITY_EPS))


@dataclass(frozen=True)
class PotentialContact:
    """One potential contact: body feature x obstacle, with its friction pair index.

    feature: 'origin' (point mass), 'vertex' (polygon vertex `vertex`), 'outline' (polygon
    outline vs a disk). obstacle: index into `Scenario.obstacles`.
    """

    name: str
    feature: Feature
    vertex: int
    obstacle: int
    pair: int


@dataclass(frozen=True)
class Scenario:
    """The `/scenario` YAML as a frozen value (see module docstring for the layout)."""

    kind: ScenarioKind
    dt: float
    gravity: float
    body: Body
    contacts: tuple[str, ...]
    friction: FrictionSpec
    noise: NoiseSpec = field(default_factory=NoiseSpec)
    edge_y: float = 0.0
    lower_joint: str = "lower_jaw"
    upper_joint: str = "upper_jaw"
    pusher_radius: float = 0.01
    pusher_joint_x: str = "pusher_x"
    pusher_joint_y: str = "pusher_y"
    surface: SurfaceSpec = field(default_factory=SurfaceSpec)

    def __post_init__(self) -> None:
        if self.kind not in SCENARIO_KINDS:
            raise _fail(
                f"scenario key 'scenario' must be one of {list(SCENARIO_KINDS)}, got {self.kind!r}"
            )
        _float(self.dt, "dt", positive=True)
        _float(self.gravity, "gravity", nonneg=True)
        _float(self.edge_y, "edge.y")
        _float(self.pusher_radius, "pusher.radius", positive=True)
        if self.kind == "edge" and self.body.shape != "point":
            raise _fail(
                f"scenario 'edge' needs body.shape 'point' (a point mass), got {self.body.shape!r}"
            )
        if self.kind in ("gripper", "push") and self.body.shape != "polygon":
            raise _fail(
                f"scenario '{self.kind}' needs body.shape 'polygon', got {self.body.shape!r}"
            )
        if len(set(self.joints)) != len(self.joints):
            raise _fail(f"joint names must differ, got {list(self.joints)}")
        if self.surface.pair is not None:
            self.friction.pair_index(self.surface.pair)
        for obst, pair in self.friction.obstacles:
            if obst not in {o.name for o in self.obstacles}:
                raise _fail(
                    f"friction.obstacles names unknown obstacle {obst!r}; valid obstacles are "
                    f"{[o.name for o in self.obstacles]}"
                )
            self.friction.pair_index(pair)
        if not self.contacts:
            raise _fail("scenario key 'contacts' must list at least one potential contact")
        if len(set(self.contacts)) != len(self.contacts):
            raise _fail(f"scenario key 'contacts' has duplicates: {list(self.contacts)}")
        valid = [c.name for c in self._all_potential_contacts()]
        for c in self.contacts:
            if c not in valid:
                raise _fail(
                    f"scenario key 'contacts' names unknown contact {c!r}; valid contacts for "
                    f"this scenario are {valid}"
                )

    # ------------------------------------------------------------------ derived quantities
    @property
    def nq(self) -> int:
        """Number of generalised coordinates (2 point mass, 3 polygon); nv == nq."""
        return self.body.nq

    @property
    def joints(self) -> tuple[str, ...]:
        """Joint names of the `env` vector, in order (positions from /joint_states)."""
        if self.kind == "gripper":
            return (self.lower_joint, self.upper_joint)
        if self.kind == "push":
            return (self.pusher_joint_x, self.pusher_joint_y)
        return ()

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        """The obstacles of the scenario (half-spaces, disks)."""
        if self.kind == "edge":
            return (HalfSpace("edge", (0.0, 1.0), self.edge_y),)
        if self.kind == "gripper":
            return (
                HalfSpace("lower", (0.0, 1.0), 0.0, self.lower_joint, 1.0),
                HalfSpace("upper", (0.0, -1.0), 0.0, self.upper_joint, -1.0),
            )
        return (Disk("pusher", self.pusher_radius, self.pusher_joint_x, self.pusher_joint_y),)

    def obstacle_pair(self, obstacle: str) -> int:
        """Friction pair index of obstacle `obstacle` (see module docstring for the rule)."""
        explicit = dict(self.friction.obstacles)
        if obstacle in explicit:
            return self.friction.pair_index(explicit[obstacle])
        if obstacle in self.friction.pairs:
            return self.friction.pairs.index(obstacle)
        if len(self.friction.pairs) == 1:
            return 0
        raise _fail(
            f"obstacle {obstacle!r} has no friction pair: name a pair {obstacle!r} or map it in "
            f"friction.obstacles; pairs are {list(self.friction.pairs)}"
        )

    def _all_potential_contacts(self) -> list[PotentialContact]:
        out: list[PotentialContact] = []
        for k, obst in enumerate(self.obstacles):
            pair = self.obstacle_pair(obst.name)
            if isinstance(obst, Disk):
                out.append(PotentialContact(obst.name, "outline", -1, k, pair))
            elif self.body.shape == "point":
                out.append(PotentialContact(obst.name, "origin", -1, k, pair))
            else:
                for i in range(len(self.body.vertices)):
                    out.append(PotentialContact(f"v{i}_{obst.name}", "vertex", i, k, pair))
        return out

    @cached_property
    def potential_contacts(self) -> tuple[PotentialContact, ...]:
        """Potential contacts in the order of `contacts` (dim 0 of /dbcslam/contact_modes)."""
        by_name = {c.name: c for c in self._all_potential_contacts()}
        return tuple(by_name[n] for n in self.contacts)

    @property
    def n_contacts(self) -> int:
        """Number of potential contacts C."""
        return len(self.contacts)

    @property
    def contact_pairs(self) -> tuple[int, ...]:
        """Friction pair index of each contact."""
        return tuple(c.pair for c in self.potential_contacts)

    @staticmethod
    def default_contacts(kind: ScenarioKind, n_vertices: int = 0) -> tuple[str, ...]:
        """All potential contact names of a scenario kind, in the default order."""
        if kind == "edge":
            return ("edge",)
        if kind == "gripper":
            return tuple(f"v{i}_{o}" for o in ("lower", "upper") for i in range(n_vertices))
        return ("pusher",)

    # ------------------------------------------------------------------------------ codecs
    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Scenario:
        """Build and validate a scenario from the parsed `/scenario` YAML mapping."""
        data = _mapping(data, "<root>")
        _check_keys(data, sorted(_TOP_KEYS), "<root>")
        for key in ("scenario", "dt", "body", "contacts", "friction"):
            if key not in data:
                raise _fail(f"scenario is missing required key '{key}'")
        kind = _parse_kind(data)
        noise_m = _mapping(data.get("noise"), "noise")
        _check_keys(noise_m, ["position", "yaw", "joint"], "noise")
        noise = NoiseSpec(**{k: _float(v, f"noise.{k}", nonneg=True) for k, v in noise_m.items()})
        return cls(
            kind=kind,
            dt=_float(data["dt"], "dt", positive=True),
            gravity=_float(data.get("gravity", 9.81), "gravity", nonneg=True),
            body=_parse_body(data),
            contacts=_str_list(data["contacts"], "contacts"),
            friction=_parse_friction(data["friction"]),
            noise=noise,
            **_parse_kind_keys(kind, data),
        )

    @classmethod
    def from_yaml(cls, text: str) -> Scenario:
        """Parse and validate the `/scenario` YAML text.

        Hostile input is refused before it costs memory or time: text longer than
        `MAX_SCENARIO_BYTES`, and YAML anchors/aliases (a scenario never needs them; nested
        aliases are the "billion laughs" expansion), raise ScenarioError.
        """
        if len(text) > MAX_SCENARIO_BYTES:
            msg = (
                f"scenario YAML is {len(text)} characters long; at most "
                f"{MAX_SCENARIO_BYTES} are accepted (a scenario is a few kB)"
            )
            raise ScenarioError(msg)
        try:
            data = yaml.load(text, Loader=_NoAliasSafeLoader)  # a SafeLoader subclass
        except RecursionError as err:  # thousands of nested brackets
            msg = "scenario YAML is nested too deeply to be a scenario"
            raise ScenarioError(msg) from err
        except yaml.YAMLError as err:
            msg = f"scenario YAML does not parse: {err}"
            raise ScenarioError(msg) from err
        if not isinstance(data, Mapping):
            raise _fail(f"scenario YAML must be a mapping at the top level, got {data!r}")
        return cls.from_dict(data)

    def to_dict(self) -> dict[str, Any]:
        """The `/scenario` mapping (plain Python types, YAML-ready)."""
        fr = self.friction
        shared = all(c == fr.candidates[0] for c in fr.candidates) and all(
            p == fr.prior[0] for p in fr.prior
        )
        friction: dict[str, Any] = {
            "pairs": list(fr.pairs),
            "candidates": list(fr.candidates[0]) if shared else [list(c) for c in fr.candidates],
            "prior": list(fr.prior[0]) if shared else [list(p) for p in fr.prior],
        }
        if fr.obstacles:
            friction["obstacles"] = dict(fr.obstacles)
        out: dict[str, Any] = {
            "scenario": self.kind,
            "dt": self.dt,
            "gravity": self.gravity,
            "body": {
                "mass": self.body.mass,
                "inertia": self.body.inertia,
                "shape": self.body.shape,
            },
            "vertices": [list(v) for v in self.body.vertices],
            "contacts": list(self.contacts),
            "friction": friction,
            "noise": {
                "position": self.noise.position,
                "yaw": self.noise.yaw,
                "joint": self.noise.joint,
            },
        }
        if self.kind == "edge":
            out["edge"] = {"y": self.edge_y}
        elif self.kind == "gripper":
            out["jaws"] = {"lower_joint": self.lower_joint, "upper_joint": self.upper_joint}
        else:
            out["pusher"] = {
                "radius": self.pusher_radius,
                "joint_x": self.pusher_joint_x,
                "joint_y": self.pusher_joint_y,
            }
            surface: dict[str, Any] = {"pair": self.surface.pair}
            if self.surface.pressure is not None:
                surface["pressure"] = self.surface.pressure
            if self.surface.model is not None:
                surface["model"] = self.surface.model
            surface.update(dict(self.surface.params))
            out["surface"] = surface
        return out

    def to_yaml(self) -> str:
        """The `/scenario` YAML text (round-trips through `from_yaml`)."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None)


def _per_pair(value: Any, pairs: tuple[str, ...], key: str) -> tuple[tuple[float, ...], ...]:
    if (
        isinstance(value, list | tuple)
        and value
        and all(isinstance(v, list | tuple) for v in value)
    ):
        if len(value) != len(pairs):
            raise _fail(
                f"scenario key '{key}' has {len(value)} lists but there are {len(pairs)} pairs "
                f"{list(pairs)}; give one list per pair or one shared list"
            )
        return tuple(_float_list(v, f"{key}[{i}]") for i, v in enumerate(value))
    shared = _float_list(value, key)
    return tuple(shared for _ in pairs)


# ---------------------------------------------------------------------------------- presets
def edge_scenario(
    *,
    dt: float = 0.01,
    mass: float = 1.0,
    candidates: Sequence[float] = (0.3, 0.9),
    position_noise: float = 0.01,
    edge_y: float = 0.0,
) -> Scenario:
    """Paper Fig. 3: point mass on the edge y = edge_y (vertical plane, gravity -y)."""
    cands = tuple(float(c) for c in candidates)
    return Scenario(
        kind="edge",
        dt=dt,
        gravity=9.81,
        body=Body(mass=mass),
        contacts=("edge",),
        friction=FrictionSpec(("edge",), (cands,), (tuple(1.0 / len(cands) for _ in cands),)),
        noise=NoiseSpec(position=position_noise, yaw=0.02, joint=0.0005),
        edge_y=edge_y,
    )


def equilateral_triangle(side: float) -> tuple[tuple[float, float], ...]:
    """Vertices (CCW, about the centroid) of an equilateral triangle, one edge along -y."""
    h = side * math.sqrt(3.0) / 2.0
    return ((-side / 2.0, -h / 3.0), (side / 2.0, -h / 3.0), (0.0, 2.0 * h / 3.0))


def gripper_scenario(
    *,
    dt: float = 0.01,
    side: float = 0.06,
    mass: float = 0.2,
    candidates: Sequence[float] = (0.1, 0.4, 0.7),
    position_noise: float = 0.002,
    yaw_noise: float = 0.02,
) -> Scenario:
    """Paper Fig. 4: equilateral triangle between two parallel jaws (one friction pair)."""
    verts = equilateral_triangle(side)
    inertia = mass * side * side / 12.0  # uniform equilateral triangle about its centroid
    cands = tuple(float(c) for c in candidates)
    return Scenario(
        kind="gripper",
        dt=dt,
        gravity=9.81,
        body=Body(mass=mass, inertia=inertia, shape="polygon", vertices=verts),
        contacts=Scenario.default_contacts("gripper", len(verts)),
        friction=FrictionSpec(("jaws",), (cands,), (tuple(1.0 / len(cands) for _ in cands),)),
        noise=NoiseSpec(position=position_noise, yaw=yaw_noise, joint=0.0005),
    )


def push_scenario(
    vertices: Sequence[Sequence[float]],
    *,
    mass: float,
    inertia: float | None = None,
    dt: float = 0.01,
    pusher_radius: float = 0.00475,
    candidates: Sequence[float] = (0.1, 0.25, 0.4),
    position_noise: float = 0.001,
    yaw_noise: float = 0.01,
    support_pair: str | None = None,
    support_mu: float | None = None,
    pressure: str | None = None,
    velocity_eps: float | None = None,
    model: str | None = None,
) -> Scenario:
    """A pushed polygon (outline about its centre of mass) and a disk pusher.

    inertia defaults to the uniform-density polar moment of the outline about the origin.
    support_pair: name of the support friction pair (estimated; second pair after
    ``pusher``); support_mu: known support coefficient (``surface.mu``, used without a pair);
    pressure: ``surface.pressure``; velocity_eps: ``surface.velocity_eps`` (m/s); model:
    ``surface.model`` (`PUSH_MODELS`).
    """
    verts = tuple((float(v[0]), float(v[1])) for v in vertices)
    if inertia is None:
        inertia = polygon_inertia(verts, mass)
    pairs: tuple[str, ...] = ("pusher",) if support_pair is None else ("pusher", support_pair)
    cands = tuple(float(c) for c in candidates)
    return Scenario(
        kind="push",
        dt=dt,
        gravity=9.81,
        body=Body(mass=mass, inertia=inertia, shape="polygon", vertices=verts),
        contacts=("pusher",),
        friction=FrictionSpec(
            pairs,
            tuple(cands for _ in pairs),
            tuple(tuple(1.0 / len(cands) for _ in cands) for _ in pairs),
        ),
        noise=NoiseSpec(position=position_noise, yaw=yaw_noise, joint=0.0005),
        pusher_radius=pusher_radius,
        surface=SurfaceSpec(
            support_pair,
            tuple(
                sorted(
                    (k, float(v))
                    for k, v in (("mu", support_mu), ("velocity_eps", velocity_eps))
                    if v is not None
                )
            ),
            pressure,
            model,
        ),
    )


def _parse_kind(data: Mapping[str, Any]) -> ScenarioKind:
    """The scenario kind; keys of other kinds are refused."""
    kind = data["scenario"]
    if kind not in SCENARIO_KINDS:
        raise _fail(f"scenario key 'scenario' must be one of {list(SCENARIO_KINDS)}, got {kind!r}")
    for other, keys in _SCENARIO_KEYS.items():
        if other != kind:
            for k in keys:
                if k in data and k not in _SCENARIO_KEYS[kind]:
                    raise _fail(
                        f"key '{k}' belongs to scenario '{other}', not '{kind}'; valid "
                        f"scenario keys for '{kind}' are {list(_SCENARIO_KEYS[kind])}"
                    )
    return cast("ScenarioKind", kind)


def _parse_body(data: Mapping[str, Any]) -> Body:
    """`body` (mass kg, inertia kg m^2, shape) and `vertices` (m, body frame)."""
    body_m = _mapping(data["body"], "body")
    _check_keys(body_m, ["mass", "inertia", "shape"], "body")
    if "mass" not in body_m:
        raise _fail("scenario is missing required key 'body.mass'")
    shape = body_m.get("shape", "point")
    if shape not in ("point", "polygon"):
        raise _fail(f"scenario key 'body.shape' must be 'point' or 'polygon', got {shape!r}")
    raw_verts = data.get("vertices") or []
    if not isinstance(raw_verts, list | tuple):
        raise _fail(f"scenario key 'vertices' must be a list of [x, y], got {raw_verts!r}")
    verts: list[tuple[float, float]] = []
    for i, v in enumerate(raw_verts):
        if not isinstance(v, list | tuple) or len(v) != 2:
            raise _fail(f"scenario key 'vertices[{i}]' must be [x, y], got {v!r}")
        verts.append((_float(v[0], f"vertices[{i}][0]"), _float(v[1], f"vertices[{i}][1]")))
    mass = _float(body_m["mass"], "body.mass", positive=True)
    if "inertia" in body_m or shape == "point" or len(verts) < 3:
        inertia = _float(body_m.get("inertia", 0.0), "body.inertia", nonneg=True)
    else:  # polygon without inertia: uniform density about the body origin
        inertia = abs(_uniform_inertia(verts, mass))
    return Body(mass=mass, inertia=inertia, shape=shape, vertices=tuple(verts))


def _parse_friction(raw: Any) -> FrictionSpec:
    """`friction`: pairs, candidates (one list or one per pair), prior, obstacles."""
    fr = _mapping(raw, "friction")
    _check_keys(fr, ["pairs", "candidates", "prior", "obstacles"], "friction")
    for key in ("pairs", "candidates"):
        if key not in fr:
            raise _fail(f"scenario is missing required key 'friction.{key}'")
    pairs = _str_list(fr["pairs"], "friction.pairs")
    cands = _per_pair(fr["candidates"], pairs, "friction.candidates")
    if "prior" in fr and fr["prior"] is not None:
        prior = _per_pair(fr["prior"], pairs, "friction.prior")
    else:
        prior = tuple(tuple(1.0 / len(cs) for _ in cs) for cs in cands)
    obst_map = _mapping(fr.get("obstacles"), "friction.obstacles")
    return FrictionSpec(
        pairs,
        cands,
        prior,
        tuple(sorted((k, _str(v, f"friction.obstacles.{k}")) for k, v in obst_map.items())),
    )


def _parse_kind_keys(kind: str, data: Mapping[str, Any]) -> dict[str, Any]:
    """The keys of one scenario kind: edge `edge.y`; gripper `jaws`; push `pusher` and
    `surface`."""
    kwargs: dict[str, Any] = {}
    if kind == "edge":
        edge_m = _mapping(data.get("edge"), "edge")
        _check_keys(edge_m, ["y"], "edge")
        kwargs["edge_y"] = _float(edge_m.get("y", 0.0), "edge.y")
    elif kind == "gripper":
        jaws_m = _mapping(data.get("jaws"), "jaws")
        _check_keys(jaws_m, ["lower_joint", "upper_joint"], "jaws")
        kwargs["lower_joint"] = _str(jaws_m.get("lower_joint", "lower_jaw"), "jaws.lower_joint")
        kwargs["upper_joint"] = _str(jaws_m.get("upper_joint", "upper_jaw"), "jaws.upper_joint")
    else:
        pm = _mapping(data.get("pusher"), "pusher")
        _check_keys(pm, ["radius", "joint_x", "joint_y"], "pusher")
        kwargs["pusher_radius"] = _float(pm.get("radius", 0.01), "pusher.radius", positive=True)
        kwargs["pusher_joint_x"] = _str(pm.get("joint_x", "pusher_x"), "pusher.joint_x")
        kwargs["pusher_joint_y"] = _str(pm.get("joint_y", "pusher_y"), "pusher.joint_y")
        kwargs["surface"] = _parse_surface(_mapping(data.get("surface"), "surface"))
    return kwargs


def _parse_surface(sm: Mapping[str, Any]) -> SurfaceSpec:
    """`surface` of a push: friction pair, pressure distribution, motion model, numbers."""
    named: dict[str, str | None] = {}
    for key in ("pair", "pressure", "model"):
        value = sm.get(key)
        named[key] = None if value is None else _str(value, f"surface.{key}")
    params = tuple(
        sorted(
            (k, _float(v, f"surface.{k}"))
            for k, v in sm.items()
            if k not in ("pair", "pressure", "model")
        )
    )
    return SurfaceSpec(named["pair"], params, named["pressure"], named["model"])

"""Model extensions: the seam through which the nominal contact model is augmented.

Effect vocabulary (interface contract, `dbcslam discrepancy`), parameters in SI units:

* ``friction_scale``: ``factor`` - every friction coefficient multiplied by factor
* ``friction_patch``: ``x_min``, ``x_max`` (m), ``mu`` - contacts whose obstacle tangent
  coordinate s lies in [x_min, x_max] have coefficient mu (for the edge s = x)
* ``viscous_damping``: ``b`` (N s/m) - force -b v on the body's translation
* ``mass_scale``: ``factor`` - the body's mass and inertia times factor
* ``input_gain``: ``factor`` - the applied wrench actually delivered, times factor
* ``sensor_delay``: ``seconds`` - observations lag the true state (applied by the consumer:
  the synthetic generator / the filter; exposed as `ModelExtension.delay`)
* ``sensor_bias``: ``x``, ``y`` (m), ``yaw`` (rad) - added to the observed pose
* ``support_friction``: ``mu`` - Coulomb friction between the body and its supporting plane:
  the support-point model of `PlanarModel.support_matrix` (normal load m g spread over the
  pressure distribution's points, implicit regularised Coulomb, translation and rotation)
  with this coefficient, replacing the scenario's own support coefficient (``surface.pair`` /
  ``surface.mu``). On the edge scenario (vertical plane) it is a modelling device: a
  Coulomb drag of m g mu on the point mass.
* ``support_pressure``: ``rim_fraction`` in [0, 1] - the support pressure distribution is
  (1 - rim_fraction) x uniform over the outline area + rim_fraction x along the outline
  (replaces ``surface.pressure``; `geometry.support_points`); push-specific
* ``support_concentration``: ``centre_fraction`` in [0, 0.99] - that fraction of the normal
  load rests at the centre of mass, the rest is spread as the scenario's pressure
  distribution (a plate that is not perfectly flat bears more of its weight near the middle);
  it shrinks the frictional moment: the limit-surface ratio c = m_max / f_max becomes
  (1 - centre_fraction) c of the distribution (`PlanarModel.limit_surface_c`); push-specific
* ``none`` - no effect

`PlanarModel` takes a tuple of extensions; the empty tuple is the nominal model. Several
extensions compose (factors multiply, forces add, fields and observations chain in order).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import ModelError

__all__ = [
    "EFFECTS",
    "ModelExtension",
    "compose_input_gain",
    "compose_mass_factor",
    "compose_mu_field",
    "compose_observation",
    "extra_force",
    "support_centre_fraction",
    "support_friction_mu",
    "support_rim_fraction",
]

F64 = NDArray[np.float64]

EFFECTS: dict[str, tuple[str, ...]] = {
    "friction_scale": ("factor",),
    "friction_patch": ("x_min", "x_max", "mu"),
    "viscous_damping": ("b",),
    "mass_scale": ("factor",),
    "input_gain": ("factor",),
    "sensor_delay": ("seconds",),
    "sensor_bias": ("x", "y", "yaw"),
    "support_friction": ("mu",),
    "support_pressure": ("rim_fraction",),
    "support_concentration": ("centre_fraction",),
    "none": (),
}
"""Effect name -> parameter names (all required, floats)."""


@dataclass(frozen=True)
class ModelExtension:
    """One model effect with its parameters (frozen; params as sorted (name, value) pairs)."""

    effect: str
    params: tuple[tuple[str, float], ...] = ()

    def __post_init__(self) -> None:
        if self.effect not in EFFECTS:
            msg = f"unknown model effect {self.effect!r}; valid effects are {sorted(EFFECTS)}"
            raise ModelError(msg)
        given = dict(self.params)
        need = EFFECTS[self.effect]
        if sorted(given) != sorted(need):
            msg = f"effect {self.effect!r} takes parameters {list(need)}, got {sorted(given)}"
            raise ModelError(msg)
        for k, v in given.items():
            if not np.isfinite(v):
                msg = f"parameter {k!r} of effect {self.effect!r} must be finite, got {v}"
                raise ModelError(msg)
        p = given
        if self.effect in ("friction_scale", "mass_scale", "input_gain") and p["factor"] <= 0:
            msg = f"effect {self.effect!r}: factor must be > 0, got {p['factor']}"
            raise ModelError(msg)
        if self.effect == "friction_patch" and not (p["x_min"] < p["x_max"] and p["mu"] >= 0):
            msg = f"effect 'friction_patch' needs x_min < x_max and mu >= 0, got {p}"
            raise ModelError(msg)
        if self.effect == "support_pressure" and not 0.0 <= p["rim_fraction"] <= 1.0:
            msg = f"effect 'support_pressure': rim_fraction must lie in [0, 1], got {p}"
            raise ModelError(msg)
        if self.effect == "support_concentration" and not 0.0 <= p["centre_fraction"] <= 0.99:
            msg = f"effect 'support_concentration': centre_fraction must lie in [0, 0.99], got {p}"
            raise ModelError(msg)
        for key in ("b", "seconds", "mu"):
            if key in p and p[key] < 0 and self.effect != "friction_patch":
                msg = f"effect {self.effect!r}: {key} must be >= 0, got {p[key]}"
                raise ModelError(msg)
        object.__setattr__(self, "params", tuple(sorted((k, float(v)) for k, v in p.items())))

    @classmethod
    def make(cls, effect: str, **params: float) -> ModelExtension:
        """`ModelExtension.make("viscous_damping", b=0.5)`."""
        return cls(effect, tuple(sorted(params.items())))

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> ModelExtension:
        """From `{"effect": name, "params": {...}}` (the discrepancy report layout)."""
        try:
            effect = str(data["effect"])
            params = dict(data.get("params") or {})
        except (KeyError, TypeError, ValueError) as err:
            msg = f"extension needs {{'effect': name, 'params': {{...}}}}, got {data!r}"
            raise ModelError(msg) from err
        try:
            return cls(effect, tuple(sorted((str(k), float(v)) for k, v in params.items())))
        except (TypeError, ValueError) as err:
            if isinstance(err, ModelError):
                raise
            msg = f"extension parameters must be numbers, got {params!r}"
            raise ModelError(msg) from err

    def to_dict(self) -> dict[str, Any]:
        """`{"effect": name, "params": {...}}`."""
        return {"effect": self.effect, "params": dict(self.params)}

    def param(self, name: str) -> float:
        """Value of parameter `name`."""
        return dict(self.params)[name]

    # ------------------------------------------------------------------------------ hooks
    @property
    def mass_factor(self) -> float:
        """Multiplier on mass and inertia."""
        return self.param("factor") if self.effect == "mass_scale" else 1.0

    @property
    def input_gain(self) -> float:
        """Multiplier on the applied wrench."""
        return self.param("factor") if self.effect == "input_gain" else 1.0

    @property
    def delay(self) -> float:
        """Observation delay (s)."""
        return self.param("seconds") if self.effect == "sensor_delay" else 0.0

    def extra_force(self, q: ArrayLike, v: ArrayLike) -> F64:
        """Extra generalised force (N, N m) at state (q, v), shape of v."""
        va = np.asarray(v, dtype=np.float64)
        out = np.zeros_like(va)
        if self.effect == "viscous_damping":
            out[..., 0:2] = -self.param("b") * va[..., 0:2]
        return out

    def mu_field(self, s: ArrayLike, mu: ArrayLike) -> F64:
        """Friction coefficient per contact given the tangent coordinate s (m)."""
        sa = np.asarray(s, dtype=np.float64)
        m = np.asarray(mu, dtype=np.float64)
        if self.effect == "friction_scale":
            return np.asarray(m * self.param("factor"), dtype=np.float64)
        if self.effect == "friction_patch":
            inside = (sa >= self.param("x_min")) & (sa <= self.param("x_max"))
            return np.asarray(np.where(inside, self.param("mu"), m), dtype=np.float64)
        return np.asarray(np.broadcast_to(m, np.broadcast_shapes(m.shape, sa.shape)), float)

    def observation(self, pose: ArrayLike) -> F64:
        """Observed pose (x, y[, yaw]) from the true pose (sensor_bias)."""
        p = np.array(pose, dtype=np.float64)
        if self.effect == "sensor_bias":
            p[..., 0] += self.param("x")
            p[..., 1] += self.param("y")
            if p.shape[-1] > 2:
                p[..., 2] += self.param("yaw")
        return p


def compose_mass_factor(exts: Sequence[ModelExtension]) -> float:
    """Product of the mass factors."""
    return float(np.prod([e.mass_factor for e in exts])) if exts else 1.0


def compose_input_gain(exts: Sequence[ModelExtension]) -> float:
    """Product of the input gains."""
    return float(np.prod([e.input_gain for e in exts])) if exts else 1.0


def extra_force(exts: Sequence[ModelExtension], q: ArrayLike, v: ArrayLike) -> F64:
    """Sum of the extensions' extra generalised forces."""
    out = np.zeros_like(np.asarray(v, dtype=np.float64))
    for e in exts:
        out = out + e.extra_force(q, v)
    return out


def compose_mu_field(exts: Sequence[ModelExtension], s: ArrayLike, mu: ArrayLike) -> F64:
    """Apply the friction fields in order (patches first then scales, as listed)."""
    m = np.asarray(mu, dtype=np.float64)
    for e in exts:
        m = e.mu_field(s, m)
    return m


def compose_observation(exts: Sequence[ModelExtension], pose: ArrayLike) -> F64:
    """Apply the observation transforms in order."""
    p = np.array(pose, dtype=np.float64)
    for e in exts:
        p = e.observation(p)
    return p


def support_friction_mu(exts: Sequence[ModelExtension]) -> float | None:
    """Support-plane friction coefficient of a ``support_friction`` extension (None when
    absent; the last one wins)."""
    mu: float | None = None
    for e in exts:
        if e.effect == "support_friction":
            mu = e.param("mu")
    return mu


def support_rim_fraction(exts: Sequence[ModelExtension]) -> float | None:
    """rim_fraction of a ``support_pressure`` extension (None when absent; the last wins)."""
    f: float | None = None
    for e in exts:
        if e.effect == "support_pressure":
            f = e.param("rim_fraction")
    return f


def support_centre_fraction(exts: Sequence[ModelExtension]) -> float:
    """centre_fraction of a ``support_concentration`` extension (0 when absent; the last
    wins)."""
    f = 0.0
    for e in exts:
        if e.effect == "support_concentration":
            f = e.param("centre_fraction")
    return f

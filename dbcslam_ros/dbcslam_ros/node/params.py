"""The filter node's parameters and what they build: defaults and descriptions
(:data:`PARAMETERS`), typed overrides (:func:`coerce_params`), their checks
(:func:`check_params`), the core's :class:`~dbcslam_core.rbpf.FilterConfig` of a scenario kind
(:func:`build_config`), model-extension files (:func:`load_extensions`) and the
:class:`~dbcslam_ros.node.session.FilterSession` they configure (:func:`make_session`).

No rclpy here: the live node declares these parameters, offline tools (replay, the MIT
evaluation, the live benchmark) pass them as a mapping.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from dbcslam_core.errors import DbcSlamError
from dbcslam_core.extensions import ModelExtension
from dbcslam_core.rbpf import FilterConfig
from dbcslam_core.scenario import Scenario
from dbcslam_ros.errors import ParameterError
from dbcslam_ros.node.session import FilterSession

__all__ = [
    "LIVE_PARTICLES",
    "LIVE_PARTICLES_OTHER",
    "PARAMETERS",
    "build_config",
    "check_params",
    "coerce_params",
    "live_particles",
    "load_extensions",
    "make_session",
]

# name: (default, description). Declared with these types and descriptions.
PARAMETERS: dict[str, tuple[Any, str]] = {
    "particles": (
        -1,
        "number of particles of the Rao-Blackwellized filter (-1: live default per scenario "
        "kind, LIVE_PARTICLES)",
    ),
    "ess_threshold": (0.5, "resample when ESS < ess_threshold * particles (0..1)"),
    "prune_threshold": (-1.0, "prune mode hypotheses below this probability (<0: preset)"),
    "parameter_model": ("", "eq. (7) form: reuse | mixture | geometric ('' = preset)"),
    "contact_weight": (-1.0, "eq. (7) weight w on the posterior while in contact (<0: preset)"),
    "gating_threshold": (
        8.0,
        "reject a pose whose Mahalanobis distance to the prediction exceeds this (0: off)",
    ),
    "seed": (0, "seed of the filter's random generator"),
    "scenario_file": ("", "YAML scenario file used instead of the /scenario topic"),
    "model_file": ("", "model-extension YAML (from `dbcslam discrepancy`) to load"),
    "frame_id": ("world", "frame of the published estimates"),
    "marker_particles": (100, "particles drawn in /dbcslam/markers (0: no markers)"),
    "marker_period": (
        0.1,
        "s of stamp time between /dbcslam/markers messages (0: one per estimate)",
    ),
    "diagnostics_period": (1.0, "seconds between /diagnostics messages"),
    "catch_up_steps": (
        2,
        "max model steps run for one pose after poses were dropped for backlog (>= 1)",
    ),
    "use_pusher_wrench": (
        True,
        "use /pusher/wrench (F/T force on the pusher) as a force observation (push scenarios)",
    ),
    "force_noise": (-1.0, "N; std per axis of the pusher force observation (<0: preset)"),
    "threads": (
        0,
        "threads of the filter's compiled kernels (0: automatic, the usable CPUs up to 4; "
        "1: the node's thread only); the estimates do not depend on it",
    ),
    "max_gap": (1.0, "s; a longer gap between poses re-initialises the filter"),
    "reset_after": (0.5, "s; a jump back in time larger than this resets the filter"),
}

#: Default particle count per scenario kind (parameter ``particles`` = -1): chosen so that on
#: an idle 2-core machine the filter keeps up with the simulator at 100 Hz (latency p95 under
#: 10 ms, < 1 % of the poses dropped; gripper 500: p95 7.9 ms at load 1.1, the tightest of
#: the three); measured with ``python -m dbcslam_research.bench_live`` (README).
LIVE_PARTICLES: dict[str, int] = {"edge": 1000, "gripper": 500, "push": 500}
#: Live default for a kind not in LIVE_PARTICLES.
LIVE_PARTICLES_OTHER = 100


def live_particles(kind: str) -> int:
    """The filter node's default particle count for a scenario kind (LIVE_PARTICLES)."""
    return LIVE_PARTICLES.get(kind, LIVE_PARTICLES_OTHER)


def load_extensions(path: str) -> tuple[ModelExtension, ...]:
    """Model extensions from a YAML model file (``extensions: [{effect, params}, ...]`` or a
    single ``{effect, params}`` mapping); empty path -> nominal model."""
    if not path:
        return ()
    import yaml

    try:
        data = yaml.safe_load(Path(path).read_text())
        items = data.get("extensions", [data]) if isinstance(data, dict) else data
        return tuple(
            ModelExtension.from_dict(item) for item in items if item.get("effect") != "none"
        )
    except (OSError, yaml.YAMLError, DbcSlamError, ValueError, TypeError, AttributeError) as err:
        msg = (
            f"model_file {path!r} is not a model-extension YAML "
            f"({{effect, params}} or extensions: [...]): {err}"
        )
        raise ParameterError(msg) from err


def build_config(kind: str, params: Mapping[str, Any]) -> FilterConfig:
    """FilterConfig for a scenario kind from the preset plus explicit parameter overrides
    (``particles`` < 1: :func:`live_particles` of the kind)."""
    particles = int(params["particles"])
    overrides: dict[str, Any] = {
        "particles": particles if particles >= 1 else live_particles(kind),
        "ess_threshold": float(params["ess_threshold"]),
    }
    if float(params["prune_threshold"]) >= 0.0:
        overrides["prune_threshold"] = float(params["prune_threshold"])
    if str(params["parameter_model"]):
        overrides["parameter_model"] = str(params["parameter_model"])
    if float(params["contact_weight"]) >= 0.0:
        overrides["contact_weight"] = float(params["contact_weight"])
    if float(params.get("force_noise", -1.0)) > 0.0:
        overrides["force_noise"] = float(params["force_noise"])
    if int(params.get("threads", 0)) >= 1:
        overrides["threads"] = int(params["threads"])
    return FilterConfig.preset(kind, **overrides)


def coerce_params(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """All filter parameters: :data:`PARAMETERS` defaults with ``overrides`` converted to the
    declared types (``"true"``/``"false"`` for booleans), as offline tools pass them.

    Raises:
        ParameterError: unknown name, or a value that does not convert.
    """
    unknown = sorted(set(overrides) - set(PARAMETERS))
    if unknown:
        msg = f"unknown filter parameter(s) {unknown}: expected some of {sorted(PARAMETERS)}"
        raise ParameterError(msg)
    params = {name: default for name, (default, _text) in PARAMETERS.items()}
    for name, value in overrides.items():
        default = PARAMETERS[name][0]
        try:
            if isinstance(default, bool):
                params[name] = value if isinstance(value, bool) else str(value).lower() == "true"
            elif isinstance(default, int):
                params[name] = int(value)
            elif isinstance(default, float):
                params[name] = float(value)
            else:
                params[name] = str(value)
        except (TypeError, ValueError) as err:
            msg = f"filter parameter {name} = {value!r}: expected a {type(default).__name__}"
            raise ParameterError(msg) from err
    return params


def check_params(params: Mapping[str, Any]) -> None:
    """Raise ParameterError naming the first parameter out of its valid range."""
    p = params
    checks = (
        ("particles", int(p["particles"]) >= 1 or int(p["particles"]) == -1, ">= 1 or -1"),
        ("marker_period", float(p["marker_period"]) >= 0.0, ">= 0"),
        ("threads", int(p["threads"]) >= 0, ">= 0 (0: automatic)"),
        ("catch_up_steps", int(p["catch_up_steps"]) >= 1, ">= 1"),
        ("diagnostics_period", float(p["diagnostics_period"]) > 0.0, "> 0"),
        ("max_gap", float(p["max_gap"]) > 0.0, "> 0"),
        ("reset_after", float(p["reset_after"]) >= 0.0, ">= 0"),
        ("gating_threshold", float(p["gating_threshold"]) >= 0.0, ">= 0"),
    )
    for name, good, valid in checks:
        if not good:
            msg = f"parameter {name} = {p[name]!r} is invalid; expected {valid}"
            raise ParameterError(msg)


def make_session(
    scenario: Scenario, params: Mapping[str, Any], extensions: tuple[ModelExtension, ...]
) -> FilterSession:
    """The session the filter node runs for ``scenario`` with these (coerced) parameters.

    Raises:
        ParameterError: the parameters do not make a filter configuration for this kind.
    """
    try:
        config = build_config(scenario.kind, params)
    except DbcSlamError as err:
        msg = f"bad filter parameters for scenario '{scenario.kind}': {err}"
        raise ParameterError(msg) from err
    return FilterSession(
        scenario,
        config,
        seed=int(params["seed"]),
        extensions=extensions,
        reset_after_s=float(params["reset_after"]),
        max_gap_s=float(params["max_gap"]),
        gating_threshold=float(params["gating_threshold"]),
        catch_up_steps=int(params["catch_up_steps"]),
    )

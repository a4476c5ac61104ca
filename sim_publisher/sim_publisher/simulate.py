"""Entry points: scenario name -> simulation class, and one-call simulation.

Example: ``run = simulate("edge", seed=3)`` (defaults plus overrides) or
``run = simulate("push", params_file="params.yaml")`` (as `dbcslam sim --params FILE`);
then ``run.stack()`` gives the arrays and ``run.scenario_yaml`` the `/scenario` text.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .base import Simulation
from .edge import EdgeSimulation
from .errors import ParamError
from .gripper import GripperSimulation
from .params import SCENARIO_NAMES, ScenarioParams, load_params
from .push import PushSimulation
from .records import SimRun

__all__ = ["SIMULATIONS", "make_simulation", "simulate"]

SIMULATIONS: dict[str, type[Simulation]] = {
    "edge": EdgeSimulation,
    "gripper": GripperSimulation,
    "push": PushSimulation,
}


def make_simulation(
    scenario: str,
    params: ScenarioParams | None = None,
    *,
    params_file: str | Path | Mapping[str, Any] | None = None,
    **overrides: Any,
) -> Simulation:
    """Build the simulation of `scenario` from a params object, or a params file + overrides.

    Give either `params` or `params_file`/`overrides`, not both.
    """
    try:
        cls = SIMULATIONS[scenario]
    except KeyError as err:
        msg = f"unknown scenario {scenario!r}; valid scenarios are {list(SCENARIO_NAMES)}"
        raise ParamError(msg) from err
    if params is not None:
        if params_file is not None or overrides:
            msg = "give either a params object or params_file/overrides, not both"
            raise ParamError(msg)
        return cls(params)
    return cls(load_params(scenario, params_file, **overrides))


def simulate(
    scenario: str,
    params: ScenarioParams | None = None,
    *,
    params_file: str | Path | Mapping[str, Any] | None = None,
    **overrides: Any,
) -> SimRun:
    """Run the whole simulation of `scenario` and return its records and metadata."""
    return make_simulation(scenario, params, params_file=params_file, **overrides).run()

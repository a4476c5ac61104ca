"""pybullet simulations of the DBC-SLAM scenarios (edge, gripper, push) and their ROS node.

Names are imported lazily so that `import sim_publisher` does not load pybullet. The one-call
runner is `sim_publisher.simulate.simulate(name, ...)` (not re-exported here: the submodule of
the same name would shadow it).
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "SCENARIO_NAMES",
    "SIMULATIONS",
    "BulletError",
    "EdgeParams",
    "EdgeSimulation",
    "GripperParams",
    "GripperSimulation",
    "NoiseParams",
    "ParamError",
    "PushParams",
    "PushSimulation",
    "SimError",
    "SimParams",
    "SimRecord",
    "SimRun",
    "Simulation",
    "load_params",
    "make_simulation",
    "params_to_dict",
    "to_trajectory",
]

_WHERE = {
    "SimError": "errors",
    "ParamError": "errors",
    "BulletError": "errors",
    "SimParams": "params",
    "EdgeParams": "params",
    "GripperParams": "params",
    "PushParams": "params",
    "NoiseParams": "params",
    "load_params": "params",
    "params_to_dict": "params",
    "SCENARIO_NAMES": "params",
    "SimRecord": "records",
    "SimRun": "records",
    "Simulation": "base",
    "EdgeSimulation": "edge",
    "GripperSimulation": "gripper",
    "PushSimulation": "push",
    "SIMULATIONS": "simulate",
    "make_simulation": "simulate",
    "to_trajectory": "trajectory",
}


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        msg = f"module 'sim_publisher' has no attribute {name!r}"
        raise AttributeError(msg)
    return getattr(importlib.import_module(f"sim_publisher.{module}"), name)

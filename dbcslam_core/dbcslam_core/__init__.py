"""dbcslam_core: the DBC-SLAM estimator (pure numpy/scipy; no ROS, no pybullet).

Contact dynamics as a complementarity problem (`dynamics`, `lcp`), discrete contact modes and
their reduced dynamics (`contact_modes`, `transition`), the Rao-Blackwellized particle filter
(`rbpf`) with eq. (7) parameter models and the friction map (`parameters`), baselines, model
extensions (the effect vocabulary of the contract) and the paper's synthetic experiments.
SI units; planar REP-103 conventions (x-y plane of `world`, yaw counter-clockwise about +z).
"""

from __future__ import annotations

from dbcslam_core.baselines import BlackBoxNCPFilter, NCPFilterConfig, fixed_friction_filter
from dbcslam_core.contact_modes import MODE_NAMES, N_MODES, Mode, solve_reduced
from dbcslam_core.dynamics import PlanarModel, State, StepResult, modes_from_lcp
from dbcslam_core.errors import DbcSlamError, ModelError, ScenarioError, SolverError
from dbcslam_core.extensions import EFFECTS, ModelExtension
from dbcslam_core.geometry import ContactKinematics, contact_kinematics
from dbcslam_core.lcp import SOLVERS, LCPSolver, LemkeSolver, PGSSolver, make_solver
from dbcslam_core.observation import PoseObservation
from dbcslam_core.parameters import PARAMETER_MODELS, FrictionMap, FrictionMapView
from dbcslam_core.rbpf import DbcSlamFilter, Estimate, FilterConfig, FilterInput
from dbcslam_core.resampling import RESAMPLERS, Resampler, make_resampler
from dbcslam_core.scenario import (
    Scenario,
    edge_scenario,
    gripper_scenario,
    push_scenario,
)
from dbcslam_core.synthetic import (
    Trajectory,
    edge_trajectory,
    gripper_trajectory,
    push_trajectory,
)

__all__ = [
    "EFFECTS",
    "MODE_NAMES",
    "N_MODES",
    "PARAMETER_MODELS",
    "RESAMPLERS",
    "SOLVERS",
    "BlackBoxNCPFilter",
    "ContactKinematics",
    "DbcSlamError",
    "DbcSlamFilter",
    "Estimate",
    "FilterConfig",
    "FilterInput",
    "FrictionMap",
    "FrictionMapView",
    "LCPSolver",
    "LemkeSolver",
    "Mode",
    "ModelError",
    "ModelExtension",
    "NCPFilterConfig",
    "PGSSolver",
    "PlanarModel",
    "PoseObservation",
    "Resampler",
    "Scenario",
    "ScenarioError",
    "SolverError",
    "State",
    "StepResult",
    "Trajectory",
    "contact_kinematics",
    "edge_scenario",
    "edge_trajectory",
    "fixed_friction_filter",
    "gripper_scenario",
    "gripper_trajectory",
    "make_resampler",
    "make_solver",
    "modes_from_lcp",
    "push_scenario",
    "push_trajectory",
    "solve_reduced",
]

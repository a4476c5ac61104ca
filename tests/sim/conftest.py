"""Shared fixtures of the simulator tests: one default run per scenario, reused by modules."""

from __future__ import annotations

import pytest

from sim_publisher.edge import EdgeSimulation
from sim_publisher.gripper import GripperSimulation
from sim_publisher.params import EdgeParams, GripperParams, PushParams
from sim_publisher.push import PushSimulation
from sim_publisher.records import SimRun


@pytest.fixture(scope="session")
def edge_sim() -> EdgeSimulation:
    return EdgeSimulation(EdgeParams(seed=1))


@pytest.fixture(scope="session")
def edge_run(edge_sim: EdgeSimulation) -> SimRun:
    return edge_sim.run()


@pytest.fixture(scope="session")
def gripper_sim() -> GripperSimulation:
    return GripperSimulation(GripperParams(seed=2))


@pytest.fixture(scope="session")
def gripper_run(gripper_sim: GripperSimulation) -> SimRun:
    return gripper_sim.run()


@pytest.fixture(scope="session")
def push_sim() -> PushSimulation:
    return PushSimulation(PushParams(seed=3))


@pytest.fixture(scope="session")
def push_run(push_sim: PushSimulation) -> SimRun:
    return push_sim.run()

"""Launch the simulator node alone.

    ros2 launch sim_publisher sim.launch.py scenario:=gripper
    ros2 launch sim_publisher sim.launch.py scenario:=edge engine:=core fast:=true

Arguments: scenario (edge | gripper | push), engine (pybullet | core), seed (-1: default),
duration (s, 0: scenario default), params_file (simulation parameters YAML), fast (true:
no real-time pacing, publishes /clock). The launch ends when the simulation ends.
"""

from __future__ import annotations

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

ARGUMENTS = {
    "scenario": ("gripper", "scenario to simulate: edge | gripper | push"),
    "engine": ("pybullet", "pybullet (physics) | core (synthetic trajectories)"),
    "seed": ("-1", "observation noise seed (-1: params file or default)"),
    "duration": ("0.0", "simulated time in s (0: scenario default)"),
    "params_file": ("", "simulation parameters YAML"),
    "fast": ("false", "run as fast as possible and publish /clock"),
}


def sim_node() -> Node:
    """The sim_publisher node configured from the launch arguments."""
    return Node(
        package="sim_publisher",
        executable="sim_node",
        name="sim_publisher",
        output="screen",
        parameters=[
            {
                "scenario": LaunchConfiguration("scenario"),
                "engine": LaunchConfiguration("engine"),
                "seed": ParameterValue(LaunchConfiguration("seed"), value_type=int),
                "duration": ParameterValue(LaunchConfiguration("duration"), value_type=float),
                "params_file": LaunchConfiguration("params_file"),
                "fast": ParameterValue(LaunchConfiguration("fast"), value_type=bool),
            }
        ],
    )


def generate_launch_description() -> LaunchDescription:
    """Simulator node; shuts the launch down when the simulation is over."""
    sim = sim_node()
    return LaunchDescription(
        [
            *(
                DeclareLaunchArgument(name, default_value=default, description=text)
                for name, (default, text) in ARGUMENTS.items()
            ),
            sim,
            RegisterEventHandler(
                OnProcessExit(
                    target_action=sim,
                    on_exit=[EmitEvent(event=Shutdown(reason="simulation finished"))],
                )
            ),
        ]
    )

"""Launch the demo: simulator node + DBC-SLAM filter node (+ optional bag recorder).

    ros2 launch dbcslam_ros demo.launch.py scenario:=gripper
    ros2 launch dbcslam_ros demo.launch.py scenario:=edge record:=true bag:=/tmp/edge_bag
    ros2 launch dbcslam_ros demo.launch.py scenario:=push particles:=300 filter_params:=f.yaml

Arguments: scenario (edge | gripper | push), engine (pybullet | core), seed, duration (s),
sim_params (simulation parameters YAML), fast (true: no real-time pacing, /clock),
particles, filter_params (ROS parameters file of the filter node, optional), record
(true: `dbcslam record` of every topic), bag (output directory of the recording).
The launch ends when the simulation ends (the filter and the recorder are stopped then).
"""

from __future__ import annotations

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.conditions import IfCondition, UnlessCondition
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration, PythonExpression
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

ARGUMENTS = {
    "scenario": ("gripper", "scenario to simulate: edge | gripper | push"),
    "engine": ("pybullet", "simulator engine: pybullet | core"),
    "seed": ("-1", "observation noise seed (-1: default)"),
    "duration": ("0.0", "simulated time in s (0: scenario default)"),
    "sim_params": ("", "simulation parameters YAML"),
    "fast": ("false", "simulate as fast as possible and publish /clock"),
    "particles": ("-1", "particles of the filter (-1: live default per scenario kind)"),
    "filter_params": ("", "ROS parameters YAML of the filter node (optional)"),
    "record": ("false", "record every topic with `dbcslam record`"),
    "bag": ("dbcslam_demo_bag", "output directory of the recording"),
}


def generate_launch_description() -> LaunchDescription:
    """Simulator, filter and (record:=true) recorder; shut down when the simulation ends."""
    cfg = LaunchConfiguration
    sim = Node(
        package="sim_publisher",
        executable="sim_node",
        name="sim_publisher",
        output="screen",
        parameters=[
            {
                "scenario": cfg("scenario"),
                "engine": cfg("engine"),
                "seed": ParameterValue(cfg("seed"), value_type=int),
                "duration": ParameterValue(cfg("duration"), value_type=float),
                "params_file": cfg("sim_params"),
                "fast": ParameterValue(cfg("fast"), value_type=bool),
            }
        ],
    )
    has_filter_params = PythonExpression(["'", cfg("filter_params"), "' != ''"])
    filter_args = {"particles": ParameterValue(cfg("particles"), value_type=int)}
    # Two variants: with and without a parameters file (launch_ros cannot take an empty one).
    filter_plain = Node(
        package="dbcslam_ros",
        executable="filter_node",
        name="dbcslam_filter",
        output="screen",
        parameters=[filter_args],
        condition=UnlessCondition(has_filter_params),
    )
    filter_with_file = Node(
        package="dbcslam_ros",
        executable="filter_node",
        name="dbcslam_filter",
        output="screen",
        parameters=[filter_args, cfg("filter_params")],
        condition=IfCondition(has_filter_params),
    )
    recorder = Node(
        package="dbcslam_ros",
        executable="dbcslam",
        arguments=["record", "-o", cfg("bag")],
        output="screen",
        condition=IfCondition(cfg("record")),
    )
    return LaunchDescription(
        [
            *(
                DeclareLaunchArgument(name, default_value=default, description=text)
                for name, (default, text) in ARGUMENTS.items()
            ),
            recorder,
            filter_plain,
            filter_with_file,
            sim,
            RegisterEventHandler(
                OnProcessExit(
                    target_action=sim,
                    on_exit=[EmitEvent(event=Shutdown(reason="simulation finished"))],
                )
            ),
        ]
    )

"""Parameters on real rclpy: declaration, -p overrides, params files (incl. /** wildcard),
remapping, as the nodes use them."""

from __future__ import annotations

import pytest
from rclpy.exceptions import (
    InvalidParameterTypeException,
    ParameterAlreadyDeclaredException,
    ParameterNotDeclaredException,
)

from dbcslam_ros import runtime as rt

PARAMS_YAML = """
/**:
  ros__parameters:
    shared: 1.5
    particles: 10
filter:
  ros__parameters:
    particles: 250
    resampler: systematic
    noise:
      position: 0.02
other:
  ros__parameters:
    particles: 3
"""


def test_defaults_and_descriptor(rt_context) -> None:
    node = rt_context("filter")
    p = node.declare_parameter(
        "particles", 500, rt.ParameterDescriptor(description="number of particles")
    )
    assert (p.name, p.value) == ("particles", 500)
    assert node.get_parameter("particles").value == 500
    assert node.describe_parameter("particles").description == "number of particles"
    assert node.get_parameter("use_sim_time").value is False
    with pytest.raises(ParameterAlreadyDeclaredException):
        node.declare_parameter("particles", 1)
    with pytest.raises(ParameterNotDeclaredException):
        node.get_parameter("nope")


def test_params_file_then_command_line(rt_context, tmp_path) -> None:
    path = tmp_path / "params.yaml"
    path.write_text(PARAMS_YAML)
    node = rt_context("filter", ("--ros-args", "--params-file", str(path), "-p", "shared:=2.5"))
    assert node.declare_parameter("particles", 500).value == 250  # node entry beats /**
    # -p is a /** rule given after the file's /**, so it wins there; a node entry of the file
    # still beats every /** rule (rcl's precedence)
    assert node.declare_parameter("shared", 0.0).value == 2.5
    assert node.declare_parameter("resampler", "x").value == "systematic"
    assert node.declare_parameter("noise.position", 0.01).value == 0.02  # nested -> dotted
    assert node.declare_parameter("untouched", "d").value == "d"


def test_command_line_types_and_coercion(rt_context) -> None:
    node = rt_context(
        "n",
        (
            "--ros-args",
            "-p", "rate:=5.0",
            "-p", "names:=[a, b]",
            "-p", "flag:=true",
            "-p", "count:=2.5",
        ),
    )  # fmt: skip
    assert node.declare_parameter("rate", 1.0).value == 5.0
    assert isinstance(node.get_parameter("rate").value, float)
    assert node.declare_parameter("names", ["x"]).value == ["a", "b"]
    assert node.declare_parameter("flag", False).value is True
    with pytest.raises(InvalidParameterTypeException):
        node.declare_parameter("count", 1)


def test_set_parameters_checks_types(rt_context) -> None:
    node = rt_context("n")
    node.declare_parameter("gain", 1.0)
    ok, bad = node.set_parameters(
        [rt.Parameter("gain", value=2.0), rt.Parameter("gain", value="x")]
    )
    assert ok.successful and not bad.successful
    assert node.get_parameter("gain").value == 2.0


def test_name_and_namespace_remap(rt_context) -> None:
    node = rt_context("orig", ("--ros-args", "-r", "__node:=renamed", "-r", "__ns:=/robot",
                               "-r", "chatter:=/talk"))  # fmt: skip
    assert node.get_name() == "renamed"
    assert node.get_namespace() == "/robot"
    assert node.get_fully_qualified_name() == "/robot/renamed"
    assert node.resolve_topic_name("pose") == "/robot/pose"
    assert node.resolve_topic_name("/abs") == "/abs"
    assert node.resolve_topic_name("~/state") == "/robot/renamed/state"
    assert node.resolve_topic_name("chatter") == "/talk"


def test_remove_ros_args() -> None:
    assert rt.remove_ros_args(["prog", "a", "--ros-args", "-p", "x:=1", "--", "b"]) == [
        "prog",
        "a",
        "b",
    ]


def test_bad_ros_args_fail_init() -> None:
    from rclpy._rclpy_pybind11 import RCLError

    with pytest.raises((RCLError, RuntimeError)):
        rt.init(["x", "--ros-args", "-p", "novalue"])
    rt.try_shutdown()


def test_node_cli_args_win_over_process_args(rt_context) -> None:
    node = rt_context(
        "base",
        ("--ros-args", "-p", "gain:=1.0"),
        cli_args=["--ros-args", "-p", "gain:=2.0", "-r", "__node:=local"],
    )
    assert node.get_name() == "local"
    assert node.declare_parameter("gain", 0.0).value == 2.0

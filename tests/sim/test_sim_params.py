"""Parameter dataclasses and the params YAML loader: defaults, overrides, clear errors."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from sim_publisher.errors import ParamError, SimError
from sim_publisher.params import (
    EdgeParams,
    GripperParams,
    NoiseParams,
    PushParams,
    equilateral_triangle,
    load_params,
    params_class,
    params_to_dict,
)
from sim_publisher.push import PushSimulation
from sim_publisher.shapes import SHAPES, load_outline


def test_param_error_is_a_sim_error_and_a_value_error() -> None:
    assert issubclass(ParamError, SimError) and issubclass(ParamError, ValueError)


@pytest.mark.parametrize("cls", [EdgeParams, GripperParams, PushParams])
def test_defaults_are_valid_and_sampling_is_consistent(cls: Any) -> None:
    p = cls()
    assert p.steps_per_sample * p.physics_dt == pytest.approx(1.0 / p.rate)
    assert p.n_samples == round(p.duration * p.rate) + 1


@pytest.mark.parametrize(
    ("cls", "kwargs", "match"),
    [
        (EdgeParams, {"rate": 0.0}, "rate"),
        (EdgeParams, {"duration": -1.0}, "duration"),
        (EdgeParams, {"physics_dt": 0.003}, "physics_dt"),
        (EdgeParams, {"seed": -1}, "seed"),
        (EdgeParams, {"slip_threshold": 0.0}, "slip_threshold"),
        (EdgeParams, {"mass": 0.0}, "mass"),
        (EdgeParams, {"segments": ((-1.0, 0.0, 0.3), (0.1, 1.0, 0.9))}, "contiguous"),
        (EdgeParams, {"segments": ((-1.0, 1.0, 3.0),)}, "mu"),
        (EdgeParams, {"start": (9.0, 0.0)}, "start"),
        (EdgeParams, {"start": (0.0, -0.1)}, "edge_y"),
        (EdgeParams, {"force": ((0.0, 1.0, 0.0), (0.0, 2.0, 0.0))}, "increase"),
        (EdgeParams, {"force": ((0.5, 1.0, 0.0),)}, "t = 0"),
        (EdgeParams, {"friction_prior": (0.2, 0.2)}, "sum to 1"),
        (GripperParams, {"vertices": tuple(reversed(equilateral_triangle(0.06)))}, "counter"),
        (GripperParams, {"vertices": ((0.0, 0.0), (0.1, 0.0), (0.0, 0.1))}, "centroid"),
        (GripperParams, {"lower_start": -0.01}, "outside the open jaws"),
        (GripperParams, {"jaw_force": 0.0}, "jaw_force"),
        (GripperParams, {"wrench": ((0.0, 1.0, 2.0),)}, "4 numbers"),
        (PushParams, {"side_position": 1.5}, "side_position"),
        (PushParams, {"angle": 2.0}, "angle"),
        (PushParams, {"support_pair": "pusher"}, "support_pair"),
        (NoiseParams, {"force": -1.0}, "noise.force"),
    ],
)
def test_bad_values_name_the_parameter(cls: Any, kwargs: dict[str, Any], match: str) -> None:
    with pytest.raises(ParamError, match=match):
        cls(**kwargs)


def test_load_params_merges_common_and_section(tmp_path: Path) -> None:
    f = tmp_path / "params.yaml"
    f.write_text(
        "seed: 4\n"
        "noise: {position: 0.005}\n"
        "edge:\n"
        "  duration: 2.0\n"
        "  noise: {yaw: 0.1}\n"
        "  segments: [[-1, 0, 0.3], [0, 1, 0.9]]\n"
        "  force: [[0, 1, 0], [1, 2, 0]]\n"
        "push: {shape: hex}\n",
        encoding="utf-8",
    )
    edge = load_params("edge", f)
    assert isinstance(edge, EdgeParams)
    assert edge.seed == 4 and edge.duration == 2.0
    assert edge.noise.position == 0.005 and edge.noise.yaw == 0.1
    assert edge.noise.joint == EdgeParams().noise.joint
    assert edge.segments == ((-1.0, 0.0, 0.3), (0.0, 1.0, 0.9))
    push = load_params("push", f, seed=9)
    assert isinstance(push, PushParams)
    assert push.shape == "hex" and push.seed == 9
    assert push.noise.position == 0.005 and push.noise.force == PushParams().noise.force
    assert load_params("gripper") == GripperParams()


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("edge: {bogus: 1}\n", "bogus"),
        ("edge: {duration: fast}\n", "duration"),
        ("edge: {segments: [[0, 1]]}\n", "segments"),
        ("noise: {position: 0.1, colour: 2}\n", "colour"),
        ("edge: [1, 2]\n", "section 'edge'"),
        ("- 1\n- 2\n", "mapping"),
        ("edge: {duration: [\n", "not valid YAML"),
    ],
)
def test_load_params_errors_name_file_and_key(tmp_path: Path, text: str, match: str) -> None:
    f = tmp_path / "bad.yaml"
    f.write_text(text, encoding="utf-8")
    with pytest.raises(ParamError, match=match) as info:
        load_params("edge", f)
    assert str(f) in str(info.value)


def test_load_params_unknown_scenario_and_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ParamError, match="valid scenarios"):
        params_class("table")
    with pytest.raises(ParamError, match="cannot read"):
        load_params("edge", tmp_path / "missing.yaml")


@pytest.mark.parametrize("shape", sorted(SHAPES))
def test_shipped_outlines_are_centred_ccw_with_table_mass(shape: str) -> None:
    o = load_outline(shape)
    assert o.area > 0.0
    assert abs(o.vertices.mean(axis=0)).max() < 1e-3
    assert o.mass == SHAPES[shape].mass and o.inertia == SHAPES[shape].inertia
    # a uniform steel plate of the outline reproduces the table within 1 %
    assert 7950.0 * o.area * 0.013 == pytest.approx(o.mass, rel=0.01)


def test_unknown_shape_is_a_param_error() -> None:
    with pytest.raises(ParamError, match="unknown shape"):
        PushSimulation(PushParams(shape="banana"))


@pytest.mark.parametrize("cls", [EdgeParams, GripperParams, PushParams])
def test_params_round_trip_through_yaml(cls: Any, tmp_path: Path) -> None:
    p = cls(seed=11, duration=1.25)
    f = tmp_path / "p.yaml"
    f.write_text(yaml.safe_dump(params_to_dict(p)), encoding="utf-8")
    name = next(iter(params_to_dict(p)))
    assert load_params(name, f) == p

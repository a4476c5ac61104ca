"""Tests of the /scenario YAML model (dbcslam_core.scenario)."""

from __future__ import annotations

import math
from typing import Any

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from dbcslam_core.errors import ScenarioError
from dbcslam_core.scenario import (
    Disk,
    HalfSpace,
    Scenario,
    edge_scenario,
    equilateral_triangle,
    gripper_scenario,
    push_scenario,
)

CONTRACT_EXAMPLE = """
scenario: edge            # edge | gripper | push
dt: 0.01                  # s, model step
gravity: 9.81             # m/s^2
body: {mass: 1.0, inertia: 0.0, shape: point}     # kg, kg m^2; shape: point | polygon
vertices: []              # polygon body only: [[x, y], ...] in the body frame, m
contacts: [edge]          # names of potential contacts, order of /dbcslam/contact_modes dim 0
friction:
  pairs: [edge]           # order of /dbcslam/friction dim 0
  candidates: [0.3, 0.9]  # discrete support of the friction posterior
  prior: [0.5, 0.5]
noise: {position: 0.01, yaw: 0.02, joint: 0.0005}   # observation noise std: m, rad, m
edge: {y: 0.0}            # edge scenario: the edge is the line y = edge.y, body in y >= edge.y
"""

SQUARE = [[-0.05, -0.05], [0.05, -0.05], [0.05, 0.05], [-0.05, 0.05]]


@pytest.fixture(params=["edge", "gripper", "push"])
def preset(request: pytest.FixtureRequest) -> Scenario:
    if request.param == "edge":
        return edge_scenario()
    if request.param == "gripper":
        return gripper_scenario()
    return push_scenario(SQUARE, mass=0.8, support_pair="support")


def test_contract_example_parses() -> None:
    sc = Scenario.from_yaml(CONTRACT_EXAMPLE)
    assert sc.kind == "edge"
    assert sc.dt == 0.01
    assert sc.body.shape == "point"
    assert sc.nq == 2
    assert sc.contacts == ("edge",)
    assert sc.friction.candidates == ((0.3, 0.9),)
    assert sc.friction.prior == ((0.5, 0.5),)
    assert sc.noise.position == 0.01
    assert sc.joints == ()
    (pc,) = sc.potential_contacts
    assert (pc.name, pc.feature, pc.pair) == ("edge", "origin", 0)
    (obst,) = sc.obstacles
    assert isinstance(obst, HalfSpace)
    assert obst.normal == (0.0, 1.0)
    assert obst.tangent == (1.0, 0.0)
    assert sc == edge_scenario()


def test_yaml_round_trip(preset: Scenario) -> None:
    text = preset.to_yaml()
    back = Scenario.from_yaml(text)
    assert back == preset
    assert back.to_dict() == preset.to_dict()
    # the YAML is plain data (safe_load)
    assert isinstance(yaml.safe_load(text), dict)


def test_gripper_layout() -> None:
    sc = gripper_scenario()
    assert sc.joints == ("lower_jaw", "upper_jaw")
    assert sc.contacts == (
        "v0_lower",
        "v1_lower",
        "v2_lower",
        "v0_upper",
        "v1_upper",
        "v2_upper",
    )
    lower, upper = sc.obstacles
    assert isinstance(lower, HalfSpace) and isinstance(upper, HalfSpace)
    assert lower.normal == (0.0, 1.0) and lower.sign == 1.0 and lower.joint == "lower_jaw"
    assert upper.normal == (0.0, -1.0) and upper.sign == -1.0 and upper.joint == "upper_jaw"
    assert sc.contact_pairs == (0,) * 6
    assert sc.friction.candidates == ((0.1, 0.4, 0.7),)
    assert [c.vertex for c in sc.potential_contacts] == [0, 1, 2, 0, 1, 2]
    assert [c.obstacle for c in sc.potential_contacts] == [0, 0, 0, 1, 1, 1]


def test_push_layout() -> None:
    sc = push_scenario(SQUARE, mass=0.8, support_pair="support")
    assert sc.joints == ("pusher_x", "pusher_y")
    (obst,) = sc.obstacles
    assert isinstance(obst, Disk)
    assert sc.contacts == ("pusher",)
    assert sc.potential_contacts[0].feature == "outline"
    assert sc.surface.pair == "support"
    assert sc.friction.pairs == ("pusher", "support")
    # uniform square of side 0.1 m: I = m (a^2 + a^2) / 12
    assert math.isclose(sc.body.inertia, 0.8 * 0.02 / 12.0)


def test_contacts_subset_and_order_define_dim0() -> None:
    d = gripper_scenario().to_dict()
    d["contacts"] = ["v2_upper", "v0_lower"]
    sc = Scenario.from_dict(d)
    assert [c.name for c in sc.potential_contacts] == ["v2_upper", "v0_lower"]
    assert [c.vertex for c in sc.potential_contacts] == [2, 0]
    assert sc.n_contacts == 2


def test_clockwise_vertices_are_normalised() -> None:
    d = gripper_scenario().to_dict()
    d["vertices"] = list(reversed(d["vertices"]))
    sc = Scenario.from_dict(d)
    assert sc.body.vertices == gripper_scenario().body.vertices


def test_per_pair_candidates_and_obstacle_map() -> None:
    d = gripper_scenario().to_dict()
    d["friction"] = {
        "pairs": ["low", "up"],
        "candidates": [[0.1, 0.4], [0.2, 0.5, 0.8]],
        "obstacles": {"lower": "low", "upper": "up"},
    }
    sc = Scenario.from_dict(d)
    assert sc.contact_pairs == (0, 0, 0, 1, 1, 1)
    assert sc.friction.prior[1] == pytest.approx((1 / 3, 1 / 3, 1 / 3))
    assert Scenario.from_yaml(sc.to_yaml()) == sc


def _mutate(base: dict[str, Any], path: list[str], value: Any) -> dict[str, Any]:
    d: dict[str, Any] = yaml.safe_load(yaml.safe_dump(base))
    node = d
    for k in path[:-1]:
        node = node[k]
    if value is _DELETE:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return d


_DELETE = object()


@pytest.mark.parametrize(
    ("kind", "path", "value", "needle"),
    [
        ("edge", ["scenario"], "table", "scenario"),
        ("edge", ["dt"], 0.0, "dt"),
        ("edge", ["dt"], "fast", "dt"),
        ("edge", ["dt"], _DELETE, "dt"),
        ("edge", ["body", "mass"], -1.0, "body.mass"),
        ("edge", ["body", "shape"], "sphere", "body.shape"),
        ("edge", ["body", "colour"], "red", "colour"),
        ("edge", ["contacts"], ["edge", "edge"], "duplicate"),
        ("edge", ["contacts"], ["floor"], "floor"),
        ("edge", ["contacts"], [], "contacts"),
        ("edge", ["friction", "prior"], [0.2, 0.2], "prior"),
        ("edge", ["friction", "prior"], [1.0], "prior"),
        ("edge", ["friction", "candidates"], [0.3, -0.9], "candidates"),
        ("edge", ["friction", "pairs"], ["a", "b"], "friction"),
        ("edge", ["noise", "position"], -0.1, "noise.position"),
        ("edge", ["jaws"], {}, "jaws"),
        ("edge", ["extra"], 1, "extra"),
        ("edge", ["vertices"], [[0, 0], [1, 0], [0, 1]], "vertices"),
        ("gripper", ["vertices"], [[0, 0], [1, 0], [2, 0]], "vertices"),
        ("gripper", ["vertices"], [[0, 0], [1, 0]], "vertices"),
        ("gripper", ["vertices"], [[0, 0], [1, 0], [0.2, 0.2], [0, 1]], "convex"),
        ("gripper", ["body", "inertia"], 0.0, "body.inertia"),
        ("gripper", ["jaws", "lower_joint"], "upper_jaw", "joint"),
        ("push", ["pusher", "radius"], 0.0, "pusher.radius"),
        ("push", ["surface", "pair"], "ice", "ice"),
    ],
)
def test_invalid_values_name_the_key(kind: str, path: list[str], value: Any, needle: str) -> None:
    base = {
        "edge": edge_scenario(),
        "gripper": gripper_scenario(),
        "push": push_scenario(SQUARE, mass=0.8),
    }[kind].to_dict()
    with pytest.raises(ScenarioError, match=needle):
        Scenario.from_dict(_mutate(base, path, value))


@pytest.mark.parametrize("text", ["[1, 2]", "scenario: [", "", "dt: 0.01"])
def test_malformed_yaml(text: str) -> None:
    with pytest.raises(ScenarioError):
        Scenario.from_yaml(text)


def test_triangle_is_centred() -> None:
    verts = equilateral_triangle(0.06)
    assert sum(v[0] for v in verts) == pytest.approx(0.0, abs=1e-15)
    assert sum(v[1] for v in verts) == pytest.approx(0.0, abs=1e-15)
    sides = [math.dist(verts[i], verts[(i + 1) % 3]) for i in range(3)]
    assert sides == pytest.approx([0.06] * 3)


def test_polygon_inertia_defaults_to_uniform_density() -> None:
    d = gripper_scenario().to_dict()
    del d["body"]["inertia"]
    sc = Scenario.from_dict(d)
    assert sc.body.inertia == pytest.approx(gripper_scenario().body.inertia)


_JUNK = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(-3, 3),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=6),
    st.lists(st.floats(-1, 1), max_size=4),
    st.lists(st.lists(st.floats(-1, 1), max_size=3), max_size=4),
    st.dictionaries(st.text(max_size=6), st.floats(-1, 1), max_size=3),
)


@settings(max_examples=300, deadline=None)
@given(
    kind=st.sampled_from(["edge", "gripper", "push"]),
    data=st.data(),
    value=_JUNK,
)
def test_fuzzed_scenarios_raise_only_scenario_error(
    kind: str, data: st.DataObject, value: Any
) -> None:
    """Any mutation of a valid scenario either validates or raises ScenarioError."""
    base = {
        "edge": edge_scenario(),
        "gripper": gripper_scenario(),
        "push": push_scenario(SQUARE, mass=0.8),
    }[kind].to_dict()
    paths: list[list[str]] = [[k] for k in base]
    paths += [[k, kk] for k, v in base.items() if isinstance(v, dict) for kk in v]
    path = data.draw(st.sampled_from(paths))
    try:
        sc = Scenario.from_dict(_mutate(base, path, value))
    except ScenarioError:
        return
    assert Scenario.from_yaml(sc.to_yaml()) == sc


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("a: &x [1, 2]\nb: *x\n", "aliases are not accepted"),
        (
            'l0: &a ["lol", "lol"]\nl1: &b [*a, *a, *a]\nl2: [*b, *b, *b, *b]\n',
            "aliases are not accepted",
        ),
        ("x: " + "9" * (300 * 1024), "at most"),
        ("[" * 5000 + "]" * 5000, "nested too deeply"),
        ("!!python/object/apply:os.system ['true']", "does not parse"),
    ],
)
def test_hostile_scenario_yaml_is_refused(text: str, match: str) -> None:
    with pytest.raises(ScenarioError, match=match):
        Scenario.from_yaml(text)


def test_presets_still_round_trip_through_the_guarded_loader() -> None:
    pushed = push_scenario(SQUARE, mass=0.8, support_pair="support")
    for sc in (edge_scenario(), gripper_scenario(), pushed):
        assert Scenario.from_yaml(sc.to_yaml()) == sc

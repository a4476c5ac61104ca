"""The research entry points' shared command-line helpers."""

from __future__ import annotations

import argparse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dbcslam_research.cli import ints_argument, key_values, pool_map, settings_dirname

_values = st.one_of(
    st.integers(),
    st.floats(allow_nan=False, allow_infinity=False),
    st.booleans(),
    st.none(),
    st.tuples(st.floats(allow_nan=False, allow_infinity=False), st.integers()),
)


@given(st.dictionaries(st.from_regex(r"[a-z_][a-z0-9_]{0,12}", fullmatch=True), _values))
def test_key_values_round_trip_python_literals(pairs: dict[str, object]) -> None:
    items = [f"{k}={v!r}" for k, v in pairs.items()]
    assert key_values(items, "--x", None, "") == pairs


def test_key_values_keeps_text_that_is_no_literal() -> None:
    assert key_values(["solver=pgs", "a = 1"], "--x", None, "") == {"solver": "pgs", "a": 1}


@pytest.mark.parametrize("item", ["nokey", "=1", "other=1"])
def test_key_values_names_the_bad_item_and_what_is_valid(item: str) -> None:
    with pytest.raises(ValueError, match=r"--opt '.*': expected KEY=VALUE with KEY in a, b"):
        key_values(["a=1", item], "--opt", ("a", "b"), "with KEY in a, b")


def test_ints_argument() -> None:
    assert ints_argument("100, 1000,") == [100, 1000]
    for bad in ("0", "a,1", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            ints_argument(bad)


def test_settings_dirname_names_each_setting_apart() -> None:
    assert settings_dirname("sim_", {"jaw_mu": 0.7}) == "sim_jaw_mu=0.7"
    assert settings_dirname("sim_", {"start": (0.0, 0.0, 0.5)}) == "sim_start=-0.0--0.0--0.5-"
    assert settings_dirname("c_", {"b": 1, "a": "x y"}) == "c_a=x-y_b=1"  # key order


@given(st.dictionaries(st.from_regex(r"[a-z_]{1,8}", fullmatch=True), _values, min_size=1))
def test_settings_dirname_is_one_path_component_whatever_the_values(a: dict[str, object]) -> None:
    name = settings_dirname("sim_", a)
    assert "/" not in name
    assert name.startswith("sim_")
    assert all(f"{k}=" in name for k in a)
    assert settings_dirname("sim_", dict(reversed(list(a.items())))) == name  # order-free


def test_pool_map_keeps_the_order_and_reports_progress() -> None:
    lines: list[str] = []
    tasks = [-3, 1, -4, 1, -5, 9, -2, 6, -5, 3, -5]
    assert pool_map(abs, tasks, 2, lines.append, "abs") == [abs(t) for t in tasks]
    assert [ln.split(",")[0] for ln in lines] == [
        "  abs: 1/11",
        *[f"  abs: {i}/11" for i in range(2, 12)],
    ]

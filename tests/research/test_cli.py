"""The research entry points' shared command-line helpers."""

from __future__ import annotations

import argparse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dbcslam_research.cli import ints_argument, key_values

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

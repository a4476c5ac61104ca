"""dbcslam_ros.contract and dbcslam_ros.qos: one table of the contract, one QoS rule."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from dbcslam_ros import contract
from dbcslam_ros import runtime as rt
from dbcslam_ros.bag.qos import LATCHED_QOS, RELIABLE_QOS, SENSOR_DATA_QOS, contract_qos
from dbcslam_ros.cli._common import bag_qos_to_runtime, subscription_qos_for
from dbcslam_ros.qos import PROFILES, QoSProfile, adapt_to_offers, from_bag_qos, to_bag_qos

README = Path(__file__).resolve().parents[2] / "README.md"


def _readme_topic_rows() -> dict[str, str]:
    rows: dict[str, str] = {}
    for line in README.read_text(encoding="utf-8").splitlines():
        m = re.match(r"\| `(/[a-z_/]+)` \| ([a-z_]+/[A-Za-z0-9]+) \|", line)
        if m:
            rows.setdefault(m.group(1), m.group(2))
    return rows


def test_contract_table_matches_the_readme_tables() -> None:
    rows = _readme_topic_rows()
    for name, topic in contract.TOPICS.items():
        assert name in rows, f"{name} is not in the README's topic tables"
        pkg, typ = rows[name].split("/")
        assert topic.type == f"{pkg}/msg/{typ}"


def test_contract_qos_follows_the_contract() -> None:
    assert {
        "/object/pose",
        "/object/wrench",
        "/joint_states",
        "/pusher/wrench",
    } == contract.SENSOR_TOPICS
    for name in contract.SENSOR_TOPICS:
        assert contract_qos(name) == SENSOR_DATA_QOS
    assert contract_qos(contract.SCENARIO) == LATCHED_QOS
    for name in (*contract.TRUTH_TOPICS, *contract.OUTPUT_TOPICS, "/not/in/contract"):
        assert contract_qos(name) == RELIABLE_QOS
    assert contract.OUTPUT_TOPICS[0] == contract.POSE
    assert contract.INPUT_TOPICS[-1] == contract.OBJECT_POSE
    with pytest.raises(KeyError, match="not a contract topic"):
        contract.message_type("/nope")


def test_no_offer_means_reliable_everywhere() -> None:
    """The one rule for an empty offer list (rosbag2's default): reliable, volatile."""
    expected = ("reliable", "volatile")
    for got in (
        adapt_to_offers([]),
        subscription_qos_for([]),
        bag_qos_to_runtime([]),
        rt.neutral_qos(rt.adapted_subscription_qos([])),
    ):
        assert (got.reliability, got.durability) == expected


profiles = st.builds(
    QoSProfile,
    st.sampled_from(["reliable", "best_effort"]),
    st.sampled_from(["volatile", "transient_local"]),
    st.just("keep_last"),
    st.integers(1, 1000),
)


@given(profiles)
def test_bag_conversion_round_trips(prof: QoSProfile) -> None:
    assert from_bag_qos(to_bag_qos(prof)) == prof
    assert rt.neutral_qos(rt.native_qos(prof)) == prof


@given(st.lists(profiles, min_size=1, max_size=4))
def test_adapted_qos_is_compatible_with_every_offer(offers: list[QoSProfile]) -> None:
    sub = adapt_to_offers(offers)
    for pub in offers:
        # a reliable reader needs a reliable writer; transient local needs transient local
        assert sub.reliability == "best_effort" or pub.reliability == "reliable"
        assert sub.durability == "volatile" or pub.durability == "transient_local"
    assert (sub.reliability == "reliable") == all(p.reliability == "reliable" for p in offers)


def test_named_profiles_are_the_bag_constants() -> None:
    assert to_bag_qos(PROFILES["sensor_data"]) == SENSOR_DATA_QOS
    assert to_bag_qos(PROFILES["latched"]) == LATCHED_QOS
    assert to_bag_qos(PROFILES["default"]) == RELIABLE_QOS

"""DDS traffic stays on loopback: generated config, and the locators Cyclone really used."""

from __future__ import annotations

import ipaddress
import re

import pytest

from dbcslam_ros import runtime as rt
from dbcslam_ros.errors import UsageError
from dbcslam_ros.runtime import dds_config

pytestmark = pytest.mark.skipif(rt.BACKEND != "dds", reason="needs the dds backend")

_UDP = re.compile(r"udp/(\d+\.\d+\.\d+\.\d+)")


def test_default_config_is_loopback_only(monkeypatch) -> None:
    for var in ("DBCSLAM_DDS_INTERFACE", "DBCSLAM_DDS_PEERS", "DBCSLAM_DDS_RESPECT_URI"):
        monkeypatch.delenv(var, raising=False)
    # A user's own Cyclone configuration in the environment is ignored by default.
    monkeypatch.setenv("CYCLONEDDS_URI", "file:///etc/cyclonedds/site-wide.xml")
    cfg = dds_config.config_from_env()
    xml = cfg.to_xml()
    assert xml is not None
    assert '<NetworkInterface name="lo"/>' in xml
    assert "<AllowMulticast>false</AllowMulticast>" in xml
    assert '<Peers><Peer address="127.0.0.1"/></Peers>' in xml
    assert "<ParticipantIndex>auto</ParticipantIndex>" in xml
    assert "<MaxAutoParticipantIndex>64</MaxAutoParticipantIndex>" in xml


def test_leaving_loopback_is_explicit(monkeypatch) -> None:
    monkeypatch.setenv("DBCSLAM_DDS_INTERFACE", "eth0")
    cfg = dds_config.config_from_env()
    assert (cfg.interface, cfg.multicast, cfg.peers) == ("eth0", True, ())
    monkeypatch.setenv("DBCSLAM_DDS_RESPECT_URI", "1")
    assert dds_config.config_from_env().to_xml() is None


def test_domain_id_from_env(monkeypatch) -> None:
    monkeypatch.setenv("ROS_DOMAIN_ID", "17")
    assert dds_config.domain_id_from_env() == 17
    monkeypatch.setenv("ROS_DOMAIN_ID", "999")
    with pytest.raises(UsageError, match="232"):
        dds_config.domain_id_from_env()


def _addresses(trace: str) -> tuple[set[str], set[str]]:
    """(addresses used for traffic/discovery, all addresses mentioned) in a Cyclone trace.

    Skipped lines: the config dump, the list of all host interfaces Cyclone looked at, and the
    configured-but-disabled multicast addresses (``SPDP MC``/``default MC``).
    """
    used: set[str] = set()
    mentioned: set[str] = set()
    for line in trace.splitlines():
        found = set(_UDP.findall(line))
        mentioned |= found
        if (
            " config: " in line
            or ": interfaces:" in line
            or "SPDP MC:" in line
            or "default MC:" in line
        ):
            continue
        used |= found
    return used, mentioned


def test_participant_locators_are_loopback_only(node_process, tmp_path) -> None:
    traces = [tmp_path / "talker.trace", tmp_path / "listener.trace"]
    listener = node_process(
        "dbcslam_ros.demo_nodes",
        "listener",
        "--ros-args",
        "-p",
        "count:=3",
        env={"DBCSLAM_DDS_TRACE": str(traces[1])},
    )
    talker = node_process(
        "dbcslam_ros.demo_nodes",
        "talker",
        "--ros-args",
        "-p",
        "rate_hz:=50.0",
        env={"DBCSLAM_DDS_TRACE": str(traces[0])},
    )
    assert listener.proc.wait(20) == 0, listener.log()
    assert talker.terminate() == 0
    for path in traces:
        text = path.read_text(errors="replace")
        assert "selected interfaces: lo " in text
        assert "ownip: udp/127.0.0.1" in text
        # the peer's discovery data (SPDP) advertised loopback locators
        spdp = [ln for ln in text.splitlines() if "SPDP" in ln and " NEW " in ln]
        assert spdp, f"no participant discovered in {path.name}"
        used, _ = _addresses(text)
        assert used, path.name
        assert all(ipaddress.ip_address(a).is_loopback for a in used), sorted(used)

"""Nodes as separate processes over DDS on loopback: talk, parameters, clean signal shutdown."""

from __future__ import annotations

import os
import signal

import pytest


def test_talker_and_listener_processes_talk(node_process) -> None:
    listener = node_process(
        "dbcslam_ros.node.demo_nodes", "listener", "--ros-args", "-p", "count:=5"
    )
    talker = node_process(
        "dbcslam_ros.node.demo_nodes", "talker", "--ros-args", "-p", "rate_hz:=50.0"
    )
    # the listener exits by itself (code 0) after 5 messages + scenario: -p reached it
    assert listener.proc.wait(20) == 0, listener.log()
    log = listener.log()
    assert "I heard: 'hello" in log
    assert log.count("I heard:") >= 5
    assert "scenario: 'scenario: edge" in log  # latched string arrived too
    assert talker.terminate() == 0, talker.log()


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_shuts_node_down_cleanly(node_process, sig: signal.Signals) -> None:
    talker = node_process(
        "dbcslam_ros.node.demo_nodes", "talker", "--ros-args", "-p", "rate_hz:=20.0"
    )
    assert talker.wait_for_log("sent 'hello 1'", 10.0), talker.log()
    os.kill(talker.pid, sig)
    assert talker.proc.wait(10) == 0, talker.log()
    assert "Traceback" not in talker.log()


def test_bad_parameter_override_fails_with_message(node_process) -> None:
    talker = node_process(
        "dbcslam_ros.node.demo_nodes", "talker", "--ros-args", "-p", "rate_hz:=fast"
    )
    assert talker.proc.wait(10) != 0
    assert "rate_hz" in talker.log() and "DOUBLE" in talker.log()

"""DDS traffic stays on loopback: the network defaults and the sockets of running nodes.

The live test starts the simulator, the filter and a plain rclpy listener as three processes
on their own ROS_DOMAIN_ID, reads every socket each process holds (``/proc/<pid>/fd`` inodes
matched against ``/proc/<pid>/net/{udp,udp6,tcp,tcp6}``) while data flows, and requires
every local address to be loopback; it also requires the listener to receive estimates, so
"no sockets because nothing ran" cannot pass.
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import socket
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from dbcslam_ros.errors import UsageError
from dbcslam_ros.network import (
    DISCOVERY_RANGE_VAR,
    NETWORK_MODE_VAR,
    PROFILE_VARS,
    apply_loopback_defaults,
    loopback_profile_path,
)

# ---------------------------------------------------------------------- the defaults (unit)


def test_default_uses_the_shipped_profile() -> None:
    env: dict[str, str] = {}
    setup = apply_loopback_defaults(env)
    assert setup.mode == "shipped_profile"
    for var in PROFILE_VARS:
        assert env[var] == str(loopback_profile_path())
    assert loopback_profile_path().is_file()
    text = loopback_profile_path().read_text()
    assert "<address>127.0.0.1</address>" in text
    assert "<useBuiltinTransports>false</useBuiltinTransports>" in text


@pytest.mark.parametrize("rng", ["SUBNET", "OFF"])
def test_user_discovery_range_is_kept(rng: str) -> None:
    env = {DISCOVERY_RANGE_VAR: rng}
    apply_loopback_defaults(env)
    assert env[DISCOVERY_RANGE_VAR] == rng


def test_localhost_range_becomes_subnet_under_the_shipped_profile() -> None:
    """LOCALHOST makes rmw_fastrtps add a wildcard locator (sockets off loopback)."""
    env = {DISCOVERY_RANGE_VAR: "LOCALHOST"}
    setup = apply_loopback_defaults(env)
    assert setup.mode == "shipped_profile" and env[DISCOVERY_RANGE_VAR] == "SUBNET"


@pytest.mark.parametrize("var", PROFILE_VARS)
def test_user_profile_is_kept_and_range_localhost(var: str, tmp_path: Path) -> None:
    mine = tmp_path / "mine.xml"
    mine.write_text("<dds/>")
    env = {var: str(mine)}
    setup = apply_loopback_defaults(env)
    assert setup.mode == "user_profile"
    assert env[var] == str(mine)
    assert env[DISCOVERY_RANGE_VAR] == "LOCALHOST"


def test_missing_user_profile_is_an_error(tmp_path: Path) -> None:
    env = {PROFILE_VARS[0]: str(tmp_path / "nope.xml")}
    with pytest.raises(UsageError, match=r"nope\.xml.*does not exist"):
        apply_loopback_defaults(env)


def test_other_rmw_gets_localhost_range() -> None:
    env = {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
    setup = apply_loopback_defaults(env)
    assert setup.mode == "other_rmw"
    assert env[DISCOVERY_RANGE_VAR] == "LOCALHOST"
    assert not any(v in env for v in PROFILE_VARS)


def test_system_mode_changes_nothing() -> None:
    env = {NETWORK_MODE_VAR: "system"}
    setup = apply_loopback_defaults(env)
    assert setup.mode == "system"
    assert env == {NETWORK_MODE_VAR: "system"}


def test_bad_mode_names_the_valid_ones() -> None:
    with pytest.raises(UsageError, match=r"'wan'.*'loopback'.*'system'"):
        apply_loopback_defaults({NETWORK_MODE_VAR: "wan"})


# ---------------------------------------------------------------------- sockets of live nodes


def _socket_inodes(pid: int) -> set[str]:
    out: set[str] = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    for fd in fd_dir.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            out.add(target[8:-1])
    return out


def _decode(hex_addr: str, v6: bool) -> str:
    ip_hex, _port = hex_addr.split(":")
    raw = bytes.fromhex(ip_hex)
    if v6:  # four little-endian 32-bit words
        raw = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
        return socket.inet_ntop(socket.AF_INET6, raw)
    return socket.inet_ntop(socket.AF_INET, raw[::-1])


def local_addresses(pid: int) -> set[tuple[str, str]]:
    """(protocol, local address) of every IP socket the process holds."""
    inodes = _socket_inodes(pid)
    found: set[tuple[str, str]] = set()
    for proto in ("udp", "udp6", "tcp", "tcp6"):
        lines = Path(f"/proc/{pid}/net/{proto}").read_text().splitlines()[1:]
        for line in lines:
            fields = line.split()
            if fields[9] in inodes:
                found.add((proto, _decode(fields[1], proto.endswith("6"))))
    return found


def _is_loopback(addr: str) -> bool:
    ip = ipaddress.ip_address(addr)
    mapped = getattr(ip, "ipv4_mapped", None)
    return bool(ip.is_loopback or (mapped is not None and mapped.is_loopback))


_LISTENER = textwrap.dedent(
    """
    import sys, time
    from dbcslam_ros.network import apply_loopback_defaults
    apply_loopback_defaults()
    import rclpy
    from geometry_msgs.msg import PoseWithCovarianceStamped
    rclpy.init()
    node = rclpy.create_node("loopback_probe")
    got = []
    node.create_subscription(
        PoseWithCovarianceStamped, "/dbcslam/pose", lambda m: got.append(m), 100
    )
    deadline = time.monotonic() + float(sys.argv[1])
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    print("received", len(got), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    """
)


@pytest.fixture
def clean_env(isolated_env: Callable[..., dict[str, str]]) -> dict[str, str]:
    """The test environment with the network variables unset (but the LOCALHOST range the
    ROS docs advise), on its own domain."""
    env = isolated_env("RMW_IMPLEMENTATION")
    env[DISCOVERY_RANGE_VAR] = "LOCALHOST"  # as the ROS 2 docs advise: must stay on loopback
    return env


@pytest.mark.slow
def test_running_nodes_bind_only_loopback(
    clean_env: dict[str, str], processes: list[subprocess.Popen[bytes]], tmp_path: Path
) -> None:
    def start(name: str, *argv: str) -> subprocess.Popen[bytes]:
        out = (tmp_path / f"{name}.log").open("wb")
        proc = subprocess.Popen(
            [sys.executable, *argv], stdout=out, stderr=subprocess.STDOUT, env=clean_env
        )
        processes.append(proc)
        return proc

    cli = ("-m", "dbcslam_ros.cli")
    listener = start("listener", "-c", _LISTENER, "14")
    flt = start("filter", *cli, "filter", "--ros-args", "-p", "particles:=50")
    time.sleep(1.0)
    sim = start("sim", *cli, "sim", "--scenario", "edge", "--engine", "core", "--duration", "4")
    seen: dict[str, set[tuple[str, str]]] = {"listener": set(), "filter": set(), "sim": set()}
    deadline = time.monotonic() + 14.0
    while time.monotonic() < deadline and listener.poll() is None:
        for name, proc in (("listener", listener), ("filter", flt), ("sim", sim)):
            if proc.poll() is None:
                with contextlib.suppress(FileNotFoundError, ProcessLookupError):
                    seen[name] |= local_addresses(proc.pid)
        time.sleep(0.25)
    listener.wait(10)
    logs = {p.name: p.read_text(errors="replace") for p in tmp_path.glob("*.log")}
    received = [ln for ln in logs["listener.log"].splitlines() if ln.startswith("received")]
    assert received, logs
    assert int(received[-1].split()[1]) >= 100, logs  # estimates really flowed between them
    for name, addrs in seen.items():
        assert addrs, f"{name}: no socket was ever seen (the process did not run?)"
        outside = sorted(a for a in addrs if not _is_loopback(a[1]))
        assert not outside, f"{name} holds sockets off loopback: {outside} (all: {sorted(addrs)})"

"""Shared fixtures of the dbcslam_ros tests: runtime nodes in-process and node processes.

Every process started here inherits the per-run random ``ROS_DOMAIN_ID`` of tests/conftest.py
and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``; it is stopped by PID (SIGTERM, then SIGKILL)
in the fixture finalizer even when the test fails.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from dbcslam_ros import runtime as rt
from dbcslam_ros.network import NETWORK_MODE_VAR, PROFILE_VARS


def stop_process(proc: subprocess.Popen[bytes], timeout: float = 10.0) -> int:
    """Stop one started process by PID: SIGTERM, wait ``timeout`` s, then SIGKILL; returns
    the exit code (at once if it has already exited)."""
    if proc.poll() is None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGTERM)
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, signal.SIGKILL)
    return proc.wait(5)


def _isolated_env(*drop: str) -> dict[str, str]:
    """This environment without the network variables of :mod:`dbcslam_ros.network` (and
    ``drop``), on a random ROS domain of its own, unbuffered output."""
    env = dict(os.environ)
    for var in (*PROFILE_VARS, NETWORK_MODE_VAR, *drop):
        env.pop(var, None)
    env["ROS_DOMAIN_ID"] = str(random.Random().randint(120, 200))
    env["PYTHONUNBUFFERED"] = "1"
    return env


@pytest.fixture
def isolated_env() -> Callable[..., dict[str, str]]:
    """``isolated_env(*drop)``: the environment for a started node (see :func:`_isolated_env`)."""
    return _isolated_env


@pytest.fixture
def processes() -> Iterator[list[subprocess.Popen[bytes]]]:
    """A list to append started processes to; each is stopped by PID (SIGTERM, then SIGKILL)
    at teardown, even when the test fails."""
    procs: list[subprocess.Popen[bytes]] = []
    yield procs
    for proc in procs:
        stop_process(proc, 8.0)


@dataclass
class NodeProcess:
    """A started node process with its log files."""

    proc: subprocess.Popen[bytes]
    stdout: Path
    stderr: Path

    @property
    def pid(self) -> int:
        return self.proc.pid

    def log(self) -> str:
        """stdout + stderr so far."""
        return self.stdout.read_text(errors="replace") + self.stderr.read_text(errors="replace")

    def wait_for_log(self, text: str, timeout: float = 10.0) -> bool:
        """Poll the logs until ``text`` appears or the process exits."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.log():
                return True
            if self.proc.poll() is not None:
                return text in self.log()
            time.sleep(0.05)
        return False

    def terminate(self, timeout: float = 10.0) -> int:
        """SIGTERM and wait; returns the exit code (SIGKILL after ``timeout``)."""
        return stop_process(self.proc, timeout)


class ProcessGroup:
    """Starts ``python -m module args`` node processes (real rclpy) and stops them by PID."""

    def __init__(self, log_dir: Path) -> None:
        self.log_dir = log_dir
        self.started: list[NodeProcess] = []

    def start(self, module: str, *args: str, env: dict[str, str] | None = None) -> NodeProcess:
        full_env = dict(os.environ)
        full_env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        full_env["PYTHONUNBUFFERED"] = "1"
        full_env.update(env or {})
        idx = len(self.started)
        out = self.log_dir / f"proc{idx}.out"
        err = self.log_dir / f"proc{idx}.err"
        with out.open("wb") as fo, err.open("wb") as fe:
            proc = subprocess.Popen(
                [sys.executable, "-m", module, *args], stdout=fo, stderr=fe, env=full_env
            )
        np = NodeProcess(proc, out, err)
        self.started.append(np)
        return np

    def stop_all(self) -> None:
        """SIGTERM every process still running (SIGKILL after 5 s), by PID."""
        for np in self.started:
            stop_process(np.proc, 5.0)


@pytest.fixture
def node_process(tmp_path: Path) -> Iterator[Callable[..., NodeProcess]]:
    """Factory ``start(module, *args, env=None) -> NodeProcess`` running
    ``python -m module args`` (real rclpy); all are stopped at teardown."""
    group = ProcessGroup(tmp_path)
    yield group.start
    group.stop_all()


@pytest.fixture(scope="module")
def module_processes(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ProcessGroup]:
    """A module-scoped :class:`ProcessGroup` (for runs shared by several tests)."""
    group = ProcessGroup(tmp_path_factory.mktemp("procs"))
    yield group
    group.stop_all()


@pytest.fixture
def rt_context() -> Iterator[Callable[..., Any]]:
    """Initialise the runtime in this process; yields ``make_node(name, args=(), **kw)``.

    ``args`` are ROS arguments for this init (only the first call's args apply). Nodes and the
    runtime are destroyed at teardown.
    """
    nodes: list[Any] = []
    state = {"inited": False}

    def make_node(name: str, args: tuple[str, ...] = (), **kw: Any) -> Any:
        if not state["inited"]:
            rt.init(["test", *args])
            state["inited"] = True
        node = rt.Node(name, **kw)
        nodes.append(node)
        return node

    yield make_node
    for node in nodes:
        node.destroy_node()
    rt.try_shutdown()


# ------------------------------------------------------------------------------ message values
# A message "value tree" is a dict field -> value (nested messages: dicts; arrays and sequences:
# lists). It is built into our runtime message objects and, independently, into rosbags objects,
# so codec tests compare two independent serializers.

STACK_TYPES = (
    "std_msgs/msg/String",
    "std_msgs/msg/Float64MultiArray",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "geometry_msgs/msg/WrenchStamped",
    "sensor_msgs/msg/JointState",
    "nav_msgs/msg/Odometry",
    "nav_msgs/msg/OccupancyGrid",
    "visualization_msgs/msg/MarkerArray",
    "diagnostic_msgs/msg/DiagnosticArray",
    "rosgraph_msgs/msg/Clock",
)

_INT_RANGES = {
    "int8": (-(2**7), 2**7 - 1),
    "uint8": (0, 2**8 - 1),
    "byte": (0, 2**7 - 1),  # scalar byte: signed in rosbags, octet elsewhere
    "char": (0, 2**8 - 1),
    "int16": (-(2**15), 2**15 - 1),
    "uint16": (0, 2**16 - 1),
    "int32": (-(2**31), 2**31 - 1),
    "uint32": (0, 2**32 - 1),
    "int64": (-(2**63), 2**63 - 1),
    "uint64": (0, 2**64 - 1),
}
_NP_DTYPES = {
    "bool": "bool",
    "int8": "int8",
    "uint8": "uint8",
    "byte": "uint8",
    "char": "uint8",
    "int16": "int16",
    "uint16": "uint16",
    "int32": "int32",
    "uint32": "uint32",
    "int64": "int64",
    "uint64": "uint64",
    "float32": "float32",
    "float64": "float64",
}


def fielddefs(name: str) -> list[tuple[str, tuple[int, Any]]]:
    """rosbags field definitions of a type."""
    from dbcslam_ros.runtime.typestore import get_typestore

    return list(get_typestore().fielddefs[name][1])


def value_strategy(name: str, max_len: int = 3) -> Any:
    """Hypothesis strategy of value trees of ROS type ``name``."""
    from hypothesis import strategies as st

    def base(kind: str) -> Any:
        if kind == "bool":
            return st.booleans()
        if kind in _INT_RANGES:
            lo, hi = _INT_RANGES[kind]
            return st.integers(lo, hi)
        if kind == "float32":
            return st.floats(width=32, allow_nan=False)
        if kind == "float64":
            return st.floats(allow_nan=False)
        if kind == "string":
            return st.text(
                st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"),
                max_size=8,
            )
        raise AssertionError(kind)

    def elem(node: tuple[int, Any]) -> Any:
        kind, detail = node
        if kind == 1:
            return base(detail[0])
        return st.deferred(lambda: value_strategy(detail, max_len))

    fields = {}
    for fname, (kind, detail) in fielddefs(name):
        if kind in (1, 2):
            fields[fname] = elem((kind, detail))
        elif kind == 3:
            sub, n = detail
            fields[fname] = st.lists(elem(sub), min_size=n, max_size=n)
        else:
            sub, _bound = detail
            fields[fname] = st.lists(elem(sub), max_size=max_len)
    return st.fixed_dictionaries(fields)


def random_tree(name: str, rng: Any, max_len: int = 3) -> dict[str, Any]:
    """A value tree with random contents from a numpy Generator (deterministic tests)."""

    def base(kind: str) -> Any:
        if kind == "bool":
            return bool(rng.integers(0, 2))
        if kind in _INT_RANGES:
            lo, hi = _INT_RANGES[kind]
            return int(rng.integers(max(lo, -(2**62)), min(hi, 2**62), endpoint=True))
        if kind == "float32":
            return float(rng.integers(-(2**20), 2**20)) / 64.0
        if kind == "float64":
            return float(rng.normal() * 10.0)
        return "".join(rng.choice(list("abcxyz_/ äé€"), size=int(rng.integers(0, 9))))

    def elem(node: tuple[int, Any]) -> Any:
        kind, detail = node
        return base(detail[0]) if kind == 1 else random_tree(detail, rng, max_len)

    tree: dict[str, Any] = {}
    for fname, (kind, detail) in fielddefs(name):
        if kind in (1, 2):
            tree[fname] = elem((kind, detail))
        elif kind == 3:
            sub, n = detail
            tree[fname] = [elem(sub) for _ in range(n)]
        else:
            sub, _bound = detail
            tree[fname] = [elem(sub) for _ in range(int(rng.integers(1, max_len + 1)))]
    return tree


def build_ours(name: str, tree: dict[str, Any]) -> Any:
    """Runtime message object of a value tree."""
    kwargs: dict[str, Any] = {}
    for fname, (kind, detail) in fielddefs(name):
        value = tree[fname]
        if kind == 2:
            value = build_ours(detail, value)
        elif kind in (3, 4) and detail[0][0] == 2:
            value = [build_ours(detail[0][1], v) for v in value]
        elif kind == 3 and detail[0][1][0] in ("uint8", "byte"):
            value = bytes(value)
        kwargs[fname] = value
    return rt.message_class(name)(**kwargs)


def build_rosbags(name: str, tree: dict[str, Any]) -> Any:
    """rosbags message object of a value tree (numpy arrays for numeric arrays/sequences)."""
    import numpy as np

    from dbcslam_ros.runtime.typestore import get_typestore

    store = get_typestore()
    kwargs: dict[str, Any] = {}
    for fname, (kind, detail) in fielddefs(name):
        value = tree[fname]
        if kind == 2:
            value = build_rosbags(detail, value)
        elif kind in (3, 4):
            sub = detail[0]
            if sub[0] == 2:
                value = [build_rosbags(sub[1], v) for v in value]
            elif sub[1][0] != "string":
                value = np.array(value, dtype=_NP_DTYPES[sub[1][0]])
        kwargs[fname] = value
    return store.types[name](**kwargs)


def pytest_generate_tests(metafunc: pytest.Metafunc) -> None:
    """Parametrize any test taking ``stack_type`` over every message type of the stack."""
    if "stack_type" in metafunc.fixturenames:
        metafunc.parametrize("stack_type", STACK_TYPES)


@pytest.fixture(scope="session")
def msgvals() -> SimpleNamespace:
    """Value-tree helpers: value_strategy, random_tree, build_ours, build_rosbags, types."""
    return SimpleNamespace(
        value_strategy=value_strategy,
        random_tree=random_tree,
        build_ours=build_ours,
        build_rosbags=build_rosbags,
        types=STACK_TYPES,
    )

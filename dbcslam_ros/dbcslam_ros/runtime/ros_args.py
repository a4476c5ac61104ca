"""Parsing of ROS 2 command line arguments (``--ros-args ... [--]``) for the ``dds`` backend.

Supported inside ``--ros-args``: ``-p name:=value`` / ``--param``, ``--params-file FILE``,
``-r from:=to`` / ``--remap`` (``__node``, ``__ns`` and topic names), ``--log-level LEVEL``.
Values are parsed as YAML scalars like rcl does (``1`` int, ``1.0`` float, ``true`` bool,
``[1, 2]`` list, anything else a string). Later arguments win over earlier ones.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dbcslam_ros.errors import UsageError

__all__ = ["RosArgs", "parse_ros_args", "remove_ros_args"]


@dataclass
class RosArgs:
    """Parsed ROS arguments.

    ``param_sources`` keeps, in order, ``("file", path)`` and ``("param", (name, value))``
    entries; they are matched against a node's name when the node is created.
    """

    param_sources: list[tuple[str, Any]] = field(default_factory=list)
    remaps: dict[str, str] = field(default_factory=dict)
    node_name: str | None = None
    namespace: str | None = None
    log_level: str | None = None


def _split_assign(text: str, flag: str) -> tuple[str, str]:
    if ":=" not in text:
        msg = f"bad {flag} argument {text!r}: expected NAME:=VALUE"
        raise UsageError(msg)
    name, value = text.split(":=", 1)
    return name, value


def _sections(argv: Sequence[str]) -> tuple[list[str], list[str]]:
    """Split argv into (non-ROS args, ROS args)."""
    plain: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in argv:
        if arg == "--ros-args":
            inside = True
        elif inside and arg == "--":
            inside = False
        elif inside:
            ros.append(arg)
        else:
            plain.append(arg)
    return plain, ros


def remove_ros_args(argv: Sequence[str]) -> list[str]:
    """Return ``argv`` without the ``--ros-args ... [--]`` sections (like rclpy's)."""
    return _sections(argv)[0]


def parse_ros_args(argv: Sequence[str]) -> RosArgs:
    """Parse the ROS sections of ``argv``.

    Raises:
        UsageError: malformed argument or unreadable params file.
    """
    _, ros = _sections(argv)
    out = RosArgs()
    it = iter(ros)
    for arg in it:
        if arg in ("-p", "--param", "-r", "--remap", "--params-file", "--log-level"):
            try:
                value = next(it)
            except StopIteration as err:
                msg = f"ROS argument {arg} needs a value"
                raise UsageError(msg) from err
            if arg in ("-p", "--param"):
                name, text = _split_assign(value, arg)
                out.param_sources.append(("param", (name, yaml.safe_load(text))))
            elif arg in ("-r", "--remap"):
                src, dst = _split_assign(value, arg)
                if src in {"__node", "__name"}:
                    out.node_name = dst
                elif src == "__ns":
                    out.namespace = dst
                else:
                    out.remaps[src] = dst
            elif arg == "--params-file":
                out.param_sources.append(("file", load_params_file(value)))
            else:
                out.log_level = value.lower()
        else:
            msg = (
                f"unsupported ROS argument {arg!r}: supported are -p, -r, --params-file, "
                "--log-level"
            )
            raise UsageError(msg)
    return out


def load_params_file(path: str | Path) -> dict[str, dict[str, Any]]:
    """Read a ROS 2 params YAML file: ``{node_key: {"ros__parameters": {...}}}``.

    Nested dicts are flattened to dotted names as ROS does. Returns ``{node_key: params}``.

    Raises:
        UsageError: file missing, not YAML, or not of this shape.
    """
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
    except (OSError, yaml.YAMLError) as err:
        msg = f"cannot read params file {p}: {err}"
        raise UsageError(msg) from err
    if not isinstance(data, dict):
        msg = f"params file {p}: expected a mapping 'node_name: {{ros__parameters: ...}}'"
        raise UsageError(msg)
    out: dict[str, dict[str, Any]] = {}
    for key, body in data.items():
        if not isinstance(body, dict) or "ros__parameters" not in body:
            msg = f"params file {p}: entry {key!r} has no 'ros__parameters' mapping"
            raise UsageError(msg)
        params = body["ros__parameters"] or {}
        if not isinstance(params, dict):
            msg = f"params file {p}: {key}.ros__parameters is not a mapping"
            raise UsageError(msg)
        out[str(key)] = _flatten(params)
    return out


def _flatten(params: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def node_key_matches(key: str, node_name: str, namespace: str) -> bool:
    """Whether a params-file node key applies to the node (``/**``, name, ``/ns/name``)."""
    fq = (
        (namespace.rstrip("/") + "/" + node_name)
        if namespace not in ("", "/")
        else f"/{node_name}"
    )
    key = key.strip()
    if key in ("/**", "**"):
        return True
    if key.startswith("/**/"):
        return key[4:] == node_name
    return key in (node_name, f"/{node_name}", fq)


def params_for_node(args: RosArgs, node_name: str, namespace: str) -> dict[str, Any]:
    """Parameter overrides that apply to the node, later sources winning."""
    out: dict[str, Any] = {}
    for kind, payload in args.param_sources:
        if kind == "param":
            name, value = payload
            if ":" in name:  # node-specific form node:name:=value
                target, name = name.split(":", 1)
                if target != node_name:
                    continue
            out[name] = value
        else:
            # wildcard entries first so node-specific entries of the same file win
            items = sorted(payload.items(), key=lambda kv: "**" not in kv[0])
            for key, params in items:
                if node_key_matches(key, node_name, namespace):
                    out.update(params)
    return out

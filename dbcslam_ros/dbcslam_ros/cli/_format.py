"""Messages as YAML the way ``ros2 topic echo`` prints them (one document per message)."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import yaml

from dbcslam_ros.errors import UsageError

__all__ = ["message_to_data", "message_to_yaml", "select_field"]


class _Dumper(yaml.SafeDumper):
    """SafeDumper that writes ``.nan``/``.inf`` and never emits aliases."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _str_representer(dumper: yaml.SafeDumper, value: str) -> yaml.ScalarNode:
    style = "|" if "\n" in value else None
    return dumper.represent_scalar("tag:yaml.org,2002:str", value, style=style)


_Dumper.add_representer(str, _str_representer)


def message_to_data(value: Any) -> Any:
    """Plain YAML-able data (dicts in field order, lists, numbers, strings) of a message."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {
            f.name: message_to_data(getattr(value, f.name))
            for f in dataclasses.fields(value)
            if not f.name.startswith("_")
        }
    if isinstance(value, bytes | bytearray | memoryview):
        return list(bytes(value))
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        return message_to_data(value.tolist())
    if isinstance(value, list | tuple):
        return [message_to_data(v) for v in value]
    if isinstance(value, bool | int | float | str) or value is None:
        return value
    return str(value)


def select_field(data: Any, path: str) -> Any:
    """The value at ``a.b.c`` (list indices allowed: ``data.0``) in message data.

    Raises:
        UsageError: a part of the path does not exist.
    """
    current = data
    for part in path.split("."):
        if isinstance(current, dict) and part in current:
            current = current[part]
        elif (
            isinstance(current, list)
            and part.lstrip("-").isdigit()
            and -len(current) <= int(part) < len(current)
        ):
            current = current[int(part)]
        else:
            have = sorted(current) if isinstance(current, dict) else type(current).__name__
            msg = f"field {path!r}: no {part!r} (available: {have})"
            raise UsageError(msg)
    return current


def message_to_yaml(message: Any, field: str | None = None) -> str:
    """YAML text of a message (or of one field of it), ending in a newline, no ``---``."""
    data = message_to_data(message)
    if field:
        data = select_field(data, field)
    if not isinstance(data, dict | list):
        text = yaml.dump(data, Dumper=_Dumper, width=math.inf)
        return text.removesuffix("...\n")
    return yaml.dump(
        data, Dumper=_Dumper, default_flow_style=False, sort_keys=False, width=math.inf
    )

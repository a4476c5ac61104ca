"""Shared ROS 2 Jazzy type store (rosbags) and ROS type-name helpers.

Message types are named the ROS 2 way, ``pkg/msg/Type``; this module normalises the spellings
users write (``pkg/Type``, ``pkg.msg.Type``) and holds the one rosbags typestore that bag files
are read and written with (and that :func:`dbcslam_ros.runtime.encode` canonicalises CDR with).
"""

from __future__ import annotations

import threading
from typing import Any

from dbcslam_ros.errors import MessageTypeError

__all__ = [
    "get_typestore",
    "normalize_type_name",
    "register_msgdefs",
]

_LOCK = threading.RLock()
_STORE: Any = None


def get_typestore() -> Any:
    """Return the process-wide rosbags typestore (ROS 2 Jazzy, plus registered extra types)."""
    global _STORE  # noqa: PLW0603
    with _LOCK:
        if _STORE is None:
            from rosbags.typesys import Stores
            from rosbags.typesys import get_typestore as _get

            _STORE = _get(Stores.ROS2_JAZZY)
        return _STORE


def normalize_type_name(name: str) -> str:
    """Return ``pkg/msg/Type`` for ``pkg/msg/Type``, ``pkg/Type`` or ``pkg.msg.Type``.

    Raises:
        MessageTypeError: the name has none of these shapes.
    """
    parts = name.replace(".", "/").strip("/").split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts) or parts[1] != "msg":
        msg = (
            f"bad ROS message type name {name!r}: "
            "expected 'pkg/msg/Type' (e.g. std_msgs/msg/String)"
        )
        raise MessageTypeError(msg)
    return "/".join(parts)


def register_msgdefs(msgdefs: dict[str, str]) -> None:
    """Add message definitions (``{"pkg/msg/Type": "<.msg text>"}``) to the typestore.

    Used for bag types that ROS 2 Jazzy does not ship. Already known types are left unchanged.

    Raises:
        MessageTypeError: a definition cannot be parsed.
    """
    from rosbags.typesys import get_types_from_msg

    store = get_typestore()
    types: dict[str, Any] = {}
    for name, text in msgdefs.items():
        try:
            types.update(get_types_from_msg(text, normalize_type_name(name)))
        except Exception as err:
            msg = f"cannot parse message definition of {name!r}: {err}"
            raise MessageTypeError(msg) from err
    with _LOCK:
        new = {k: v for k, v in types.items() if k not in store.fielddefs}
        if new:
            store.register(new)

"""Message types of bags: the ROS 2 Jazzy typestore of rosbags, extended from bag schemas.

Messages are the dataclasses of :mod:`rosbags.typesys` (``msg.__msgtype__`` names the type,
for example ``std_msgs/msg/String``). Writers need the full concatenated ``.msg`` definition
(``ros2msg`` schema text, as rosbag2 stores it) and the RIHS01 type hash; readers may meet types
the Jazzy store does not know and register them from the schema text stored in the bag.
"""

from __future__ import annotations

import threading
from functools import lru_cache
from typing import Any

from rosbags.typesys import get_types_from_idl, get_types_from_msg
from rosbags.typesys.store import Typestore

from dbcslam_ros.errors import BagError
from dbcslam_ros.runtime.typestore import get_typestore

__all__ = [
    "deserialize",
    "jazzy_typestore",
    "message_definition",
    "register_schema",
    "serialize",
]

_LOCK = threading.Lock()


def jazzy_typestore() -> Typestore:
    """The process-wide ROS 2 Jazzy typestore of the node runtime.

    Types found in bags are added to it on the fly, so the runtime can publish them too.
    """
    store: Typestore = get_typestore()
    return store


@lru_cache(maxsize=256)
def message_definition(msgtype: str) -> tuple[str, str]:
    """Concatenated ``ros2msg`` definition text and RIHS01 hash of a known message type.

    Raises:
        BagError: the type is unknown to the typestore.
    """
    store = jazzy_typestore()
    if msgtype not in store.fielddefs:
        msg = f"unknown message type {msgtype!r} (expected e.g. 'std_msgs/msg/String')"
        raise BagError(msg)
    text, _md5 = store.generate_msgdef(msgtype, ros_version=2)
    return text, store.hash_rihs01(msgtype)


def register_schema(msgtype: str, encoding: str, text: str) -> None:
    """Make ``msgtype`` known from a bag schema (``ros2msg`` or ``ros2idl``) unless it is known.

    Raises:
        BagError: the schema text cannot be parsed.
    """
    store = jazzy_typestore()
    if msgtype in store.fielddefs:
        return
    try:
        if encoding == "ros2idl":
            types = get_types_from_idl(text)
        else:
            types = _types_from_concatenated_msg(msgtype, text)
    except Exception as err:
        msg = f"cannot parse the {encoding} schema of {msgtype!r}: {err}".splitlines()[0]
        raise BagError(msg) from err
    with _LOCK:
        store.register({k: v for k, v in types.items() if k not in store.fielddefs})


def _types_from_concatenated_msg(msgtype: str, text: str) -> dict[str, Any]:
    """Parse rosbag2's ``ros2msg`` text: the main definition, then ``MSG: pkg/Name`` blocks."""
    types: dict[str, Any] = {}
    sep = "=" * 80 + "\n"
    blocks = text.split(sep)
    types.update(get_types_from_msg(blocks[0], msgtype))
    for block in blocks[1:]:
        header, _, body = block.partition("\n")
        if not header.startswith("MSG: "):
            continue
        name = header[5:].strip()
        if "/msg/" not in name:
            pkg, _, base = name.partition("/")
            name = f"{pkg}/msg/{base}"
        types.update(get_types_from_msg(body, name))
    return types


def serialize(message: object) -> tuple[str, bytes]:
    """CDR bytes (little endian, with encapsulation header) of a message object.

    Accepts rosbags dataclasses (``__msgtype__``) and the node runtime's message objects
    (classes from :func:`dbcslam_ros.runtime.message_class`, or rclpy's on a ROS machine).

    Returns:
        (message type name, CDR bytes).

    Raises:
        BagError: the object is not a message of a known type.
    """
    msgtype = getattr(message, "__msgtype__", None)
    # The dds runtime's generated classes also carry __msgtype__; their __idl__ tells them
    # apart from rosbags dataclasses (rclpy's messages have no __msgtype__ at all).
    if not isinstance(msgtype, str) or hasattr(type(message), "__idl__"):
        return _serialize_runtime(message)
    try:
        data = jazzy_typestore().serialize_cdr(message, msgtype)
    except Exception as err:
        msg = f"cannot serialize a {msgtype} message: {err}".splitlines()[0]
        raise BagError(msg) from err
    return msgtype, bytes(data)


def _serialize_runtime(message: object) -> tuple[str, bytes]:
    from dbcslam_ros import runtime as rt

    try:
        name = rt.type_name_of(message)
        return name, rt.encode(message)
    except Exception as err:
        msg = f"{type(message).__name__} is not a ROS message object: {err}".splitlines()[0]
        raise BagError(msg) from err


def deserialize(data: bytes | memoryview, msgtype: str) -> Any:
    """Decode CDR bytes into a rosbags message dataclass of ``msgtype``.

    Raises:
        BagError: the type is unknown or the bytes do not hold such a message.
    """
    store = jazzy_typestore()
    if msgtype not in store.fielddefs:
        msg = f"unknown message type {msgtype!r}: no schema for it in the typestore or the bag"
        raise BagError(msg)
    try:
        return store.deserialize_cdr(bytes(data), msgtype)
    except Exception as err:
        msg = f"cannot decode {len(data)} bytes as {msgtype}: {err}".splitlines()[0]
        raise BagError(msg) from err

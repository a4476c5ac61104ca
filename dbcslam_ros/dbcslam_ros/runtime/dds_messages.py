"""ROS message classes generated at runtime for the ``dds`` backend, and their CDR codec.

Classes are generated from the ROS 2 Jazzy message definitions carried by rosbags' typestore
(``typestore.fielddefs``), never written by hand. Each class is a Cyclone DDS ``IdlStruct``
dataclass with the DDS type name rmw_cyclonedds_cpp uses (``pkg::msg::dds_::Type_``), the ROS
field names and nesting, keyword construction and defaults (zeros, empty strings and
sequences, default-constructed nested messages), and the message constants as class
attributes (e.g. ``Marker.ADD``). Numeric sequences and fixed arrays hold Python lists
(``uint8``/``byte`` fixed arrays hold ``bytes``); assigning a numpy array, tuple or
``array.array`` converts it to that form. ``byte`` and ``char`` are ``uint8`` in the DDS type
(as rmw_cyclonedds_cpp declares them); a scalar ``byte`` accepts rclpy's ``b"\x01"`` and
rosbags' signed ints and holds 0..255.

The codec is plain CDR, little endian, XCDR1 (encapsulation header ``00 01 00 00``): the same
bytes as ``typestore.serialize_cdr`` (rosbag2 layout), proven by tests/ros/test_codec_*.py.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import struct
import threading
from typing import Any

from dbcslam_ros.errors import MessageTypeError
from dbcslam_ros.runtime.typestore import dds_type_name, get_typestore, normalize_type_name

__all__ = ["cdr_length", "decode", "encode", "message_class", "type_name_of"]

_LOCK = threading.RLock()
_CLASSES: dict[str, Any] = {}

# rosbags base type name -> (cyclonedds annotation attribute, default value)
_BASE = {
    "bool": ("bool", False),
    # byte and char are uint8 in the DDS types rmw_cyclonedds_cpp registers (XTypes matching)
    "byte": ("uint8", 0),
    "char": ("uint8", 0),
    "int8": ("int8", 0),
    "uint8": ("uint8", 0),
    "int16": ("int16", 0),
    "uint16": ("uint16", 0),
    "int32": ("int32", 0),
    "uint32": ("uint32", 0),
    "int64": ("int64", 0),
    "uint64": ("uint64", 0),
    "float32": ("float32", 0.0),
    "float64": ("float64", 0.0),
    "string": ("string", ""),
}

_NODE_BASE, _NODE_NAME, _NODE_ARRAY, _NODE_SEQUENCE = 1, 2, 3, 4


def _mod(name: str) -> Any:
    """Import a cyclonedds module untyped (its IDL machinery is dynamic)."""
    return importlib.import_module(name)


def _base_annotation(base: str, bound: int) -> Any:
    types = _mod("cyclonedds.idl.types")

    if base not in _BASE:
        msg = f"unsupported ROS base type {base!r} (supported: {sorted(_BASE)})"
        raise MessageTypeError(msg)
    if base == "string":
        return types.bounded_str[bound] if bound else str
    if base == "bool":
        return bool
    return getattr(types, _BASE[base][0])


def _element(node: tuple[int, Any]) -> tuple[Any, Any]:
    """Return (annotation, default factory) of one element node of a fielddef."""
    kind, detail = node
    if kind == _NODE_BASE:
        base, bound = detail
        default = _BASE[base][1] if base in _BASE else None
        return _base_annotation(base, bound), (lambda d=default: d)
    if kind == _NODE_NAME:
        cls = message_class(detail)
        return cls, cls
    msg = f"nested arrays are not ROS messages: {node!r}"
    raise MessageTypeError(msg)


def _repeat(factory: Any, n: int) -> list[Any]:
    return [factory() for _ in range(n)]


def _is_bytes_elem(node: tuple[int, Any]) -> bool:
    return node[0] == _NODE_BASE and node[1][0] in ("uint8", "byte")


def _build(name: str) -> Any:
    idl = _mod("cyclonedds.idl")
    types = _mod("cyclonedds.idl.types")
    idl_meta, idl_struct = idl.IdlMeta, idl.IdlStruct

    store = get_typestore()
    try:
        consts, fields = store.fielddefs[name]
    except KeyError as err:
        msg = (
            f"unknown ROS message type {name!r}: not in the ROS 2 Jazzy typestore "
            "(register its definition with runtime.register_msgdefs)"
        )
        raise MessageTypeError(msg) from err
    pkg, _, typ = name.split("/")
    namespace: Any = idl_meta.__prepare__(typ, (idl_struct,), typename=dds_type_name(name))
    # field -> "bytes" (uint8/byte fixed array), "list" (other arrays/sequences) or "byte"
    # (scalar byte: rclpy spells values as 1-byte bytes, rosbags as a signed int; both are
    # accepted and stored as an unsigned int 0..255, the same bits on the wire)
    list_fields: dict[str, str] = {}
    for fname, (kind, detail) in fields:
        if kind in (_NODE_BASE, _NODE_NAME):
            ann, factory = _element((kind, detail))
            if kind == _NODE_BASE and detail[0] == "byte":
                list_fields[fname] = "byte"
        elif kind == _NODE_ARRAY:
            elem, length = detail
            eann, efactory = _element(elem)
            ann = types.array[eann, length]
            if _is_bytes_elem(elem):
                list_fields[fname] = "bytes"
                factory = functools.partial(bytes, length)
            else:
                list_fields[fname] = "list"
                factory = functools.partial(_repeat, efactory, length)
        elif kind == _NODE_SEQUENCE:
            elem, bound = detail
            eann, _ = _element(elem)
            ann = types.sequence[eann, bound] if bound else types.sequence[eann]
            list_fields[fname] = "list"
            factory = list
        else:
            msg = f"unsupported field node {kind!r} in {name}.{fname}"
            raise MessageTypeError(msg)
        namespace["__annotations__"][fname] = ann
        namespace[fname] = dataclasses.field(default_factory=factory)
    for cname, _ctype, cvalue in consts:
        namespace[cname] = cvalue
    namespace["__msgtype__"] = name
    namespace["__dbcslam_list_fields__"] = list_fields
    namespace["__setattr__"] = _setattr
    namespace["__module__"] = f"dbcslam_ros.runtime.generated.{pkg}.msg"
    cls: Any = dataclasses.dataclass(idl_meta(typ, (idl_struct,), namespace))
    cls.__qualname__ = typ
    return cls


def _setattr(self: Any, name: str, value: Any) -> None:
    spec = type(self).__dbcslam_list_fields__.get(name)
    if spec == "list":
        if not isinstance(value, list):
            value = value.tolist() if hasattr(value, "tolist") else list(value)
    elif spec == "bytes":
        if not isinstance(value, bytes):
            value = bytes(value.tolist() if hasattr(value, "tolist") else value)
    elif spec == "byte":
        if isinstance(value, (bytes, bytearray)) and len(value) == 1:
            value = value[0]
        elif isinstance(value, int) and -128 <= value < 0:
            value += 256
    object.__setattr__(self, name, value)


def message_class(name: str) -> Any:
    """Return the generated class of ROS message type ``name`` (e.g. ``std_msgs/msg/String``).

    Raises:
        MessageTypeError: the type is not in the typestore.
    """
    key = normalize_type_name(name)
    with _LOCK:
        cls = _CLASSES.get(key)
        if cls is None:
            cls = _build(key)
            _CLASSES[key] = cls
        return cls


def type_name_of(msg_or_cls: Any) -> str:
    """Return ``pkg/msg/Type`` of a generated message object or class."""
    name = getattr(msg_or_cls, "__msgtype__", None)
    if not isinstance(name, str):
        msg = f"{msg_or_cls!r} is not a generated ROS message (object or class)"
        raise MessageTypeError(msg)
    return name


def encode(msg: Any) -> bytes:
    """Serialize a generated message object to CDR (4-byte header + payload, XCDR1 LE).

    Raises:
        MessageTypeError: the object is not a generated message or a field has a wrong value.
    """
    endianness = _mod("cyclonedds.idl._support").Endianness

    name = type_name_of(msg)
    try:
        data: bytes = type(msg).__idl__.serialize(
            msg, use_version_2=False, endianness=endianness.Little
        )
    except Exception as err:
        text = f"cannot serialize {name} object {msg!r}: {err}"
        raise MessageTypeError(text) from err
    return data


def decode(data: bytes | bytearray | memoryview, cls_or_name: Any) -> Any:
    """Deserialize CDR bytes (header + payload, either endianness) into a message object.

    Raises:
        MessageTypeError: the bytes do not hold a message of this type.
    """
    cls: Any = message_class(cls_or_name) if isinstance(cls_or_name, str) else cls_or_name
    name = type_name_of(cls)
    raw = bytes(data)
    if len(raw) < 4 or raw[0] != 0 or raw[1] not in (0, 1):
        msg = f"not a plain CDR {name} buffer: header {raw[:4].hex()!r} (expected 0000 or 0001)"
        raise MessageTypeError(msg)
    try:
        obj = cls.__idl__.deserialize(raw)
    except Exception as err:
        msg = f"cannot deserialize {len(raw)} bytes as {name}: {err}"
        raise MessageTypeError(msg) from err
    return obj


# --------------------------------------------------------------------------- length scanner
# Walks a CDR buffer without building objects (about 10x faster than decoding), to find where
# the message ends: DDS pads samples to a multiple of 4 bytes, the rosbag2 layout does not.

_SIZES = {
    "bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2,
    "int32": 4, "uint32": 4, "int64": 8, "uint64": 8, "float32": 4, "float64": 8,
}  # fmt: skip
_Scan = Any  # Callable[[bytes, int, str], int]: (payload, pos, "<"|">") -> new pos
_SCANNERS: dict[str, _Scan] = {}


def _align(pos: int, size: int) -> int:
    return (pos + size - 1) & -size


def _scan_string(buf: bytes, pos: int, end: str) -> int:
    pos = _align(pos, 4)
    (n,) = struct.unpack_from(end + "I", buf, pos)
    return pos + 4 + int(n)


def _element_scanner(node: tuple[int, Any]) -> tuple[int, _Scan | None]:
    """(fixed primitive size or 0, scanner for non-primitive elements)."""
    kind, detail = node
    if kind == _NODE_BASE:
        if detail[0] == "string":
            return 0, _scan_string
        return _SIZES[detail[0]], None
    return 0, _scanner(detail)


def _field_scanner(kind: int, detail: Any) -> _Scan:
    if kind in (_NODE_BASE, _NODE_NAME):
        size, sub = _element_scanner((kind, detail))
        if sub is not None:
            return sub
        return lambda buf, pos, end: _align(pos, size) + size
    elem, count = detail
    size, sub = _element_scanner(elem)
    if kind == _NODE_ARRAY:
        if sub is None:
            return lambda buf, pos, end: _align(pos, size) + size * count if count else pos

        def scan_array(buf: bytes, pos: int, end: str) -> int:
            for _ in range(count):
                pos = sub(buf, pos, end)
            return pos

        return scan_array

    def scan_sequence(buf: bytes, pos: int, end: str) -> int:
        pos = _align(pos, 4)
        (n,) = struct.unpack_from(end + "I", buf, pos)
        pos += 4
        if sub is None:
            return _align(pos, size) + size * n if n else pos
        for _ in range(n):
            pos = sub(buf, pos, end)
        return pos

    return scan_sequence


def _scanner(name: str) -> _Scan:
    with _LOCK:
        scan = _SCANNERS.get(name)
        if scan is not None:
            return scan
        try:
            fields = get_typestore().fielddefs[name][1]
        except KeyError as err:
            msg = f"unknown ROS message type {name!r}"
            raise MessageTypeError(msg) from err
        ops = [_field_scanner(kind, detail) for _, (kind, detail) in fields]

        def scan_struct(buf: bytes, pos: int, end: str) -> int:
            for op in ops:
                pos = op(buf, pos, end)
            return pos

        _SCANNERS[name] = scan_struct
        return scan_struct


def cdr_length(data: bytes | bytearray | memoryview, cls_or_name: Any) -> int:
    """Length in bytes (header included) of the CDR message at the start of ``data``.

    Used to strip the 0-3 alignment padding bytes DDS appends to a sample.

    Raises:
        MessageTypeError: the bytes are too short or not plain CDR for this type.
    """
    name = cls_or_name if isinstance(cls_or_name, str) else type_name_of(cls_or_name)
    name = normalize_type_name(name)
    raw = bytes(data)
    if len(raw) < 4 or raw[0] != 0 or raw[1] not in (0, 1):
        msg = f"not a plain CDR buffer: header {raw[:4].hex()!r}"
        raise MessageTypeError(msg)
    try:
        end = int(_scanner(name)(raw[4:], 0, "<" if raw[1] == 1 else ">")) + 4
    except struct.error as err:
        msg = f"{len(raw)} bytes are too short for a {name} message: {err}"
        raise MessageTypeError(msg) from err
    if end > len(raw):
        msg = f"{len(raw)} bytes are too short for a {name} message (needs {end})"
        raise MessageTypeError(msg)
    return end

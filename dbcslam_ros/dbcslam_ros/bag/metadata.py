"""rosbag2 ``metadata.yaml`` (bag format version 9, ROS 2 Jazzy) build and parse.

Only what this package writes and reads is modelled: one or more MCAP files per bag, no
compression, CDR serialization. Times are integers in nanoseconds (since the Unix epoch for
``starting_time``).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from dbcslam_ros.bag.qos import Qos, qos_from_yaml, qos_to_dicts
from dbcslam_ros.errors import BagError

__all__ = [
    "METADATA_FILE",
    "METADATA_VERSION",
    "ROS_DISTRO",
    "BagMetadata",
    "TopicInfo",
    "dump_metadata",
    "load_metadata",
]

METADATA_FILE = "metadata.yaml"
METADATA_VERSION = 9
#: Distribution whose message definitions and type hashes the bags carry.
ROS_DISTRO = "jazzy"


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: name, type, serialization, offered QoS, type hash, message count."""

    name: str
    msgtype: str
    message_count: int
    offered_qos: tuple[Qos, ...] = ()
    serialization_format: str = "cdr"
    type_description_hash: str = ""


@dataclass(frozen=True)
class BagMetadata:
    """Content of a bag's ``metadata.yaml`` (times in ns)."""

    files: tuple[str, ...]
    topics: tuple[TopicInfo, ...]
    starting_time_ns: int
    duration_ns: int
    message_count: int
    storage_identifier: str = "mcap"
    version: int = METADATA_VERSION
    ros_distro: str = ROS_DISTRO
    compression_format: str = ""
    compression_mode: str = ""
    custom_data: Mapping[str, str] = field(default_factory=dict)


def _bag_info_dict(meta: BagMetadata) -> dict[str, Any]:
    return {
        "version": meta.version,
        "storage_identifier": meta.storage_identifier,
        "duration": {"nanoseconds": meta.duration_ns},
        "starting_time": {"nanoseconds_since_epoch": meta.starting_time_ns},
        "message_count": meta.message_count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": t.name,
                    "type": t.msgtype,
                    "serialization_format": t.serialization_format,
                    "offered_qos_profiles": qos_to_dicts(t.offered_qos),
                    "type_description_hash": t.type_description_hash,
                },
                "message_count": t.message_count,
            }
            for t in meta.topics
        ],
        "compression_format": meta.compression_format,
        "compression_mode": meta.compression_mode,
        "relative_file_paths": list(meta.files),
        "files": [
            {
                "path": name,
                "starting_time": {"nanoseconds_since_epoch": meta.starting_time_ns},
                "duration": {"nanoseconds": meta.duration_ns},
                "message_count": meta.message_count,
            }
            for name in meta.files
        ],
        "custom_data": dict(meta.custom_data) or None,
        "ros_distro": meta.ros_distro,
    }


def dump_metadata(meta: BagMetadata, *, inner_only: bool = False) -> str:
    """YAML text of ``metadata.yaml`` (or of its inner mapping, as MCAP's ``rosbag2`` record)."""
    info = _bag_info_dict(meta)
    doc: dict[str, Any] = info if inner_only else {"rosbag2_bagfile_information": info}
    return yaml.safe_dump(doc, default_flow_style=False, sort_keys=False)


def _int(mapping: Mapping[str, Any], key: str, where: str) -> int:
    value = mapping.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        msg = f"{where}: {key!r} must be an integer, got {value!r}"
        raise BagError(msg)
    return value


def load_metadata(path: Path) -> BagMetadata:
    """Read and check a ``metadata.yaml``.

    Raises:
        BagError: unreadable, not YAML, or missing required keys (message names the file).
    """
    where = str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as err:
        msg = f"{where}: cannot read: {err.strerror or err}"
        raise BagError(msg) from err
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as err:
        msg = f"{where}: not valid YAML: {str(err).splitlines()[0]}"
        raise BagError(msg) from err
    if not isinstance(doc, Mapping) or not isinstance(
        doc.get("rosbag2_bagfile_information"), Mapping
    ):
        msg = f"{where}: no 'rosbag2_bagfile_information' mapping (not a rosbag2 metadata file)"
        raise BagError(msg)
    info = doc["rosbag2_bagfile_information"]
    version = _int(info, "version", where)
    files_raw = info.get("relative_file_paths") or []
    if not isinstance(files_raw, Sequence) or isinstance(files_raw, str):
        msg = f"{where}: 'relative_file_paths' must be a list, got {files_raw!r}"
        raise BagError(msg)
    topics: list[TopicInfo] = []
    for entry in info.get("topics_with_message_count") or []:
        tmeta = entry.get("topic_metadata") if isinstance(entry, Mapping) else None
        if not isinstance(tmeta, Mapping):
            msg = f"{where}: malformed 'topics_with_message_count' entry {entry!r}"
            raise BagError(msg)
        try:
            qos = qos_from_yaml(tmeta.get("offered_qos_profiles"))
        except BagError as err:
            msg = f"{where}: topic {tmeta.get('name')!r}: {err}"
            raise BagError(msg) from err
        topics.append(
            TopicInfo(
                name=str(tmeta.get("name", "")),
                msgtype=str(tmeta.get("type", "")),
                message_count=_int(entry, "message_count", where),
                offered_qos=qos,
                serialization_format=str(tmeta.get("serialization_format", "cdr")),
                type_description_hash=str(tmeta.get("type_description_hash", "") or ""),
            )
        )
    duration = info.get("duration") or {}
    start = info.get("starting_time") or {}
    custom = info.get("custom_data") or {}
    return BagMetadata(
        files=tuple(str(f) for f in files_raw),
        topics=tuple(topics),
        starting_time_ns=_int(start, "nanoseconds_since_epoch", where) if start else 0,
        duration_ns=_int(duration, "nanoseconds", where) if duration else 0,
        message_count=_int(info, "message_count", where),
        storage_identifier=str(info.get("storage_identifier", "")),
        version=version,
        ros_distro=str(info.get("ros_distro", "") or ""),
        compression_format=str(info.get("compression_format", "") or ""),
        compression_mode=str(info.get("compression_mode", "") or ""),
        custom_data={str(k): str(v) for k, v in custom.items()}
        if isinstance(custom, Mapping)
        else {},
    )

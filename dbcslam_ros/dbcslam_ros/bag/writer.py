"""Write rosbag2 bags: a directory with ``metadata.yaml`` (version 9) and one MCAP file.

The MCAP file follows the ``ros2`` profile the way rosbag2's MCAP storage plugin writes it:
``ros2msg`` schemas holding the full concatenated message definition, ``cdr`` channels whose
metadata carries ``offered_qos_profiles`` (YAML string) and ``topic_type_hash`` (RIHS01), a
``rosbag2`` metadata record with the serialized bag metadata, chunk and message indexes and a
summary section. Chunks are not compressed, so a file cut short (power loss, SIGKILL) can be
salvaged up to the damage (see :mod:`dbcslam_ros.bag.salvage`).

Log times are integers in nanoseconds since the Unix epoch (or since sim-time zero).
"""

from __future__ import annotations

import os
import shutil
import threading
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from types import TracebackType
from typing import IO, Any, Self

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from dbcslam_ros.bag.metadata import (
    METADATA_FILE,
    ROS_DISTRO,
    BagMetadata,
    TopicInfo,
    dump_metadata,
)
from dbcslam_ros.bag.qos import Qos, contract_qos, qos_to_yaml_string
from dbcslam_ros.bag.types import message_definition, serialize
from dbcslam_ros.errors import BagError

__all__ = ["BagWriter", "TopicSpec", "write_bag"]

_MAX_LOG_TIME = 2**64 - 1


def _library_name() -> str:
    try:
        own = version("dbcslam_ros")
    except PackageNotFoundError:
        own = "0"
    return f"dbcslam_ros {own} (mcap python writer)"


@dataclass(frozen=True)
class TopicSpec:
    """A topic to record: name, message type and the QoS profiles its publishers offered."""

    name: str
    msgtype: str
    offered_qos: tuple[Qos, ...] = ()


@dataclass
class _Channel:
    spec: TopicSpec
    channel_id: int
    type_hash: str
    count: int = 0


def _looks_like_bag_dir(path: Path) -> bool:
    """True for an empty directory or one holding only rosbag2 files (safe to replace)."""
    for child in path.iterdir():
        if child.is_dir():
            return False
        if child.name != METADATA_FILE and not child.name.endswith((".mcap", ".db3", ".tmp")):
            return False
    return True


class BagWriter:
    """Writer of one rosbag2 MCAP bag; use as a context manager or call :meth:`close`.

    Thread-safe: :meth:`write` may be called from middleware callback threads. The bag is
    finished (summary, indexes, ``metadata.yaml``) by :meth:`close`, also when the ``with``
    block exits with an exception, so everything written so far is kept.

    Args:
        path: bag directory to create.
        overwrite: replace an existing bag at ``path``; without it an existing path is an error.
        chunk_size: MCAP chunk size in bytes (smaller chunks lose less on a hard kill).
        custom_data: free-form string pairs stored in ``metadata.yaml`` ``custom_data``.

    Raises:
        BagError: the path exists (and ``overwrite`` is false), or cannot be created.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        overwrite: bool = False,
        chunk_size: int = 256 * 1024,
        custom_data: Mapping[str, str] | None = None,
    ) -> None:
        self.path = Path(path)
        self._overwrite = overwrite
        self._chunk_size = chunk_size
        self._custom_data = dict(custom_data or {})
        self._lock = threading.RLock()
        self._channels: dict[str, _Channel] = {}
        self._schemas: dict[str, int] = {}
        self._stream: IO[bytes] | None = None
        self._mcap: McapWriter | None = None
        self._start = _MAX_LOG_TIME
        self._end = 0
        self._closed_metadata: BagMetadata | None = None
        self.mcap_path = self.path / f"{self.path.name}_0.mcap"

    # -- lifecycle ---------------------------------------------------------------------------
    def open(self) -> Self:
        """Create the bag directory and start the MCAP file."""
        if self._mcap is not None or self._closed_metadata is not None:
            msg = f"{self.path}: bag writer already opened"
            raise BagError(msg)
        if self.path.exists() or self.path.is_symlink():
            if not self._overwrite:
                msg = f"{self.path}: already exists; not overwriting (pass --overwrite to replace)"
                raise BagError(msg)
            if not self.path.is_dir() or not _looks_like_bag_dir(self.path):
                msg = f"{self.path}: exists and is not a bag directory; refusing to replace it"
                raise BagError(msg)
            shutil.rmtree(self.path)
        try:
            self.path.mkdir(parents=True)
            self._stream = self.mcap_path.open("xb")
        except OSError as err:
            msg = f"{self.path}: cannot create bag: {err.strerror or err}"
            raise BagError(msg) from err
        self._mcap = McapWriter(
            self._stream, chunk_size=self._chunk_size, compression=CompressionType.NONE
        )
        self._mcap.start(profile="ros2", library=_library_name())
        return self

    def __enter__(self) -> Self:
        return self.open()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if self._mcap is not None:
            self.close()

    @property
    def is_open(self) -> bool:
        """True between :meth:`open` and :meth:`close`."""
        return self._mcap is not None

    # -- topics and messages -----------------------------------------------------------------
    def add_topic(self, topic: str, msgtype: str, offered_qos: Sequence[Qos] = ()) -> None:
        """Register a topic (idempotent for the same type; QoS of the first call is kept).

        Raises:
            BagError: the bag is not open, the type is unknown, or the topic was registered
                with another type.
        """
        with self._lock:
            mcap = self._require_open()
            known = self._channels.get(topic)
            if known is not None:
                if known.spec.msgtype != msgtype:
                    msg = (
                        f"{self.path}: topic {topic} is recorded as {known.spec.msgtype}; "
                        f"cannot add it again as {msgtype}"
                    )
                    raise BagError(msg)
                return
            text, type_hash = message_definition(msgtype)
            schema_id = self._schemas.get(msgtype)
            if schema_id is None:
                schema_id = mcap.register_schema(
                    name=msgtype, encoding="ros2msg", data=text.encode("utf-8")
                )
                self._schemas[msgtype] = schema_id
            spec = TopicSpec(topic, msgtype, tuple(offered_qos))
            channel_id = mcap.register_channel(
                topic=topic,
                message_encoding="cdr",
                schema_id=schema_id,
                metadata={
                    "offered_qos_profiles": qos_to_yaml_string(spec.offered_qos),
                    "topic_type_hash": type_hash,
                },
            )
            self._channels[topic] = _Channel(spec, channel_id, type_hash)

    def write(
        self,
        topic: str,
        data: bytes | bytearray | memoryview,
        log_time_ns: int,
        publish_time_ns: int | None = None,
    ) -> None:
        """Append one CDR-serialized message of a registered topic.

        Args:
            topic: topic registered with :meth:`add_topic`.
            data: CDR bytes including the 4-byte encapsulation header.
            log_time_ns: receive/log time, ns (>= 0).
            publish_time_ns: publish time, ns; defaults to ``log_time_ns`` (as rosbag2 does).
        """
        if not 0 <= log_time_ns <= _MAX_LOG_TIME:
            msg = f"{self.path}: log time {log_time_ns} ns of {topic} is outside [0, 2^64)"
            raise BagError(msg)
        with self._lock:
            mcap = self._require_open()
            channel = self._channels.get(topic)
            if channel is None:
                msg = f"{self.path}: topic {topic} was not added before writing to it"
                raise BagError(msg)
            mcap.add_message(
                channel_id=channel.channel_id,
                log_time=log_time_ns,
                data=bytes(data),
                publish_time=log_time_ns if publish_time_ns is None else publish_time_ns,
                sequence=channel.count & 0xFFFFFFFF,
            )
            channel.count += 1
            self._start = min(self._start, log_time_ns)
            self._end = max(self._end, log_time_ns)

    def write_message(
        self,
        topic: str,
        message: object,
        log_time_ns: int,
        offered_qos: Sequence[Qos] | None = None,
    ) -> None:
        """Serialize a rosbags message dataclass and append it.

        The topic is added on first use with ``offered_qos`` (default: the contract QoS of the
        topic, :func:`dbcslam_ros.bag.qos.contract_qos`).
        """
        msgtype, data = serialize(message)
        if topic not in self._channels:
            qos = (contract_qos(topic),) if offered_qos is None else tuple(offered_qos)
            self.add_topic(topic, msgtype, qos)
        self.write(topic, data, log_time_ns)

    def flush(self) -> None:
        """Finish the current chunk and push it to the file (bounds the loss on a hard kill)."""
        with self._lock:
            if self._mcap is not None and self._stream is not None:
                if self.message_count:
                    self._mcap.flush()  # type: ignore[no-untyped-call]
                self._stream.flush()

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(c.count for c in self._channels.values())

    def counts(self) -> dict[str, int]:
        """Messages written so far, per topic."""
        with self._lock:
            return {name: c.count for name, c in self._channels.items()}

    def topics(self) -> tuple[TopicSpec, ...]:
        """Registered topics in registration order."""
        with self._lock:
            return tuple(c.spec for c in self._channels.values())

    def metadata(self) -> BagMetadata:
        """The bag metadata as it stands (what :meth:`close` writes to ``metadata.yaml``)."""
        with self._lock:
            count = self.message_count
            start = self._start if count else 0
            return BagMetadata(
                files=(self.mcap_path.name,),
                topics=tuple(
                    TopicInfo(
                        name=c.spec.name,
                        msgtype=c.spec.msgtype,
                        message_count=c.count,
                        offered_qos=c.spec.offered_qos,
                        type_description_hash=c.type_hash,
                    )
                    for c in self._channels.values()
                ),
                starting_time_ns=start,
                duration_ns=max(0, self._end - start) if count else 0,
                message_count=count,
                custom_data=self._custom_data,
            )

    def close(self) -> BagMetadata:
        """Finish the MCAP file (summary, indexes) and write ``metadata.yaml``.

        Safe to call twice; returns the metadata written.
        """
        with self._lock:
            if self._closed_metadata is not None:
                return self._closed_metadata
            mcap = self._require_open()
            meta = self.metadata()
            try:
                mcap.add_metadata(
                    "rosbag2",
                    {
                        "serialized_metadata": dump_metadata(meta, inner_only=True),
                        "ROS_DISTRO": ROS_DISTRO,
                    },
                )
                mcap.finish()  # type: ignore[no-untyped-call]
                assert self._stream is not None
                self._stream.flush()
                os.fsync(self._stream.fileno())
                self._stream.close()
                tmp = self.path / (METADATA_FILE + ".tmp")
                tmp.write_text(dump_metadata(meta), encoding="utf-8")
                tmp.replace(self.path / METADATA_FILE)
            except OSError as err:
                msg = f"{self.path}: cannot finish bag: {err.strerror or err}"
                raise BagError(msg) from err
            finally:
                self._mcap = None
                self._stream = None
            self._closed_metadata = meta
            return meta

    def _require_open(self) -> McapWriter:
        if self._mcap is None:
            state = "closed" if self._closed_metadata is not None else "not opened"
            msg = f"{self.path}: bag writer is {state}"
            raise BagError(msg)
        return self._mcap


def write_bag(
    path: str | os.PathLike[str],
    messages: Iterable[tuple[str, Any, int]],
    *,
    topics: Iterable[TopicSpec] = (),
    overwrite: bool = False,
    custom_data: Mapping[str, str] | None = None,
) -> BagMetadata:
    """Write a whole bag from ``(topic, message, log_time_ns)`` triples.

    ``message`` is a rosbags message dataclass (serialized here) or CDR ``bytes`` (then the
    topic must be declared in ``topics``). Topics not declared get their contract QoS.

    Example::

        from rosbags.typesys import Stores, get_typestore
        String = get_typestore(Stores.ROS2_JAZZY).types["std_msgs/msg/String"]
        write_bag("out/bag", [("/scenario", String(data="scenario: edge"), 0)])

    Returns:
        The metadata written to ``metadata.yaml``.
    """
    with BagWriter(path, overwrite=overwrite, custom_data=custom_data) as writer:
        for spec in topics:
            writer.add_topic(spec.name, spec.msgtype, spec.offered_qos)
        for topic, message, log_time_ns in messages:
            if isinstance(message, bytes | bytearray | memoryview):
                writer.write(topic, message, log_time_ns)
            else:
                writer.write_message(topic, message, log_time_ns)
        return writer.close()

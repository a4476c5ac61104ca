"""Read rosbag2 MCAP bags (a bag directory or a bare ``.mcap`` file) in log-time order.

Every problem with the input raises :class:`dbcslam_ros.errors.BagError` with a one-line
message that names the file and the problem (missing, empty, not MCAP, truncated, corrupt,
inconsistent metadata). With ``salvage=True`` a damaged file yields the messages that lie
before the damage instead, and :attr:`BagReader.damage` says what was wrong.

Times are integers in nanoseconds (log time = receive time of the recorder, or the stamp the
writer chose, e.g. ``header.stamp`` for ``dbcslam replay`` outputs).
"""

from __future__ import annotations

import heapq
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple, Self

from mcap.reader import make_reader

from dbcslam_ros.bag.metadata import METADATA_FILE, BagMetadata, TopicInfo, load_metadata
from dbcslam_ros.bag.qos import Qos, qos_from_yaml
from dbcslam_ros.bag.salvage import MCAP_MAGIC, scan_mcap
from dbcslam_ros.bag.types import deserialize, register_schema
from dbcslam_ros.errors import BagError

__all__ = ["BagMessage", "BagReader", "TopicSummary", "find_bags", "open_bag", "read_bag"]

_SALVAGE_HINT = "pass --salvage to read the messages before the damage"


class BagMessage(NamedTuple):
    """One recorded message: topic, type, log time (ns), CDR bytes, offered QoS of the topic."""

    topic: str
    msgtype: str
    log_time_ns: int
    data: bytes
    qos: tuple[Qos, ...]
    publish_time_ns: int = 0


@dataclass(frozen=True)
class TopicSummary:
    """A topic of an opened bag (counts are what the files hold, not what metadata claims)."""

    name: str
    msgtype: str
    message_count: int
    offered_qos: tuple[Qos, ...]
    serialization_format: str
    schema_encoding: str
    schema_text: str
    type_description_hash: str


@dataclass(frozen=True)
class _Channel:
    topic: str
    msgtype: str
    encoding: str
    schema_encoding: str
    schema_text: str
    qos: tuple[Qos, ...]
    type_hash: str


class _File:
    """One MCAP file: channels, per-channel counts, time range, and how to get its messages."""

    def __init__(self, path: Path, *, salvage: bool) -> None:
        self.path = path
        self.damage: str | None = None
        self.channels: dict[int, _Channel] = {}
        self.counts: dict[int, int] = {}
        self.start_ns = 0
        self.end_ns = 0
        self._scanned: list[BagMessage] | None = None
        self._check_bytes(salvage)
        if self._scanned is None:
            self._open_indexed()

    def _fail(self, problem: str) -> BagError:
        return BagError(f"{self.path}: {problem}")

    def _check_bytes(self, salvage: bool) -> None:
        try:
            size = self.path.stat().st_size
            with self.path.open("rb") as fh:
                head = fh.read(len(MCAP_MAGIC))
                fh.seek(max(0, size - len(MCAP_MAGIC)))
                tail = fh.read(len(MCAP_MAGIC))
        except OSError as err:
            raise self._fail(f"cannot read: {err.strerror or err}") from err
        if size == 0:
            raise self._fail("empty file (0 bytes), not an MCAP bag")
        if head != MCAP_MAGIC:
            raise self._fail("not an MCAP file (bad magic bytes at the start)")
        if salvage:
            # A linear scan checks every chunk CRC and stops at the first damage.
            self._salvage()
        elif tail != MCAP_MAGIC or size < 2 * len(MCAP_MAGIC) + 9:
            raise self._fail(
                f"truncated MCAP file ({size} bytes, no footer at the end); {_SALVAGE_HINT}"
            )

    def _salvage(self) -> None:
        try:
            data = self.path.read_bytes()
        except OSError as err:
            raise self._fail(f"cannot read: {err.strerror or err}") from err
        result = scan_mcap(data)
        self.damage = result.damage
        for cid, ch in result.channels.items():
            self.channels[cid] = _Channel(
                topic=ch.topic,
                msgtype=ch.schema_name,
                encoding=ch.message_encoding,
                schema_encoding=ch.schema_encoding,
                schema_text=ch.schema_text,
                qos=self._qos(ch.metadata.get("offered_qos_profiles", ""), ch.topic),
                type_hash=ch.metadata.get("topic_type_hash", ""),
            )
        messages: list[BagMessage] = []
        for m in result.messages:
            ch2 = self.channels.get(m.channel_id)
            if ch2 is None:
                continue
            self.counts[m.channel_id] = self.counts.get(m.channel_id, 0) + 1
            messages.append(
                BagMessage(
                    ch2.topic, ch2.msgtype, m.log_time_ns, m.data, ch2.qos, m.publish_time_ns
                )
            )
        messages.sort(key=lambda x: x.log_time_ns)  # stable: file order within equal times
        self._scanned = messages
        if messages:
            self.start_ns = messages[0].log_time_ns
            self.end_ns = messages[-1].log_time_ns

    def _qos(self, text: str, topic: str) -> tuple[Qos, ...]:
        try:
            return qos_from_yaml(text)
        except BagError as err:
            raise self._fail(f"channel {topic}: {err}") from err

    def _open_indexed(self) -> None:
        try:
            with self.path.open("rb") as fh:
                reader = make_reader(fh, validate_crcs=True)
                summary = reader.get_summary()
        except Exception as err:
            raise self._fail(f"corrupt MCAP summary: {_one_line(err)}; {_SALVAGE_HINT}") from err
        if summary is None or not summary.chunk_indexes:
            # Valid but unindexed MCAP (or no messages at all): a linear scan reads it.
            self._salvage()
            if self.damage is not None:
                raise self._fail(f"corrupt MCAP data: {self.damage}; {_SALVAGE_HINT}")
            return
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            self.channels[cid] = _Channel(
                topic=channel.topic,
                msgtype=schema.name if schema is not None else "",
                encoding=channel.message_encoding,
                schema_encoding=schema.encoding if schema is not None else "",
                schema_text=schema.data.decode("utf-8", errors="replace") if schema else "",
                qos=self._qos(channel.metadata.get("offered_qos_profiles", ""), channel.topic),
                type_hash=channel.metadata.get("topic_type_hash", ""),
            )
        stats = summary.statistics
        if stats is not None:
            self.counts = dict(stats.channel_message_counts)
            if stats.message_count:
                self.start_ns = stats.message_start_time
                self.end_ns = stats.message_end_time
        else:
            self.start_ns = min(c.message_start_time for c in summary.chunk_indexes)
            self.end_ns = max(c.message_end_time for c in summary.chunk_indexes)

    def messages(self, topics: frozenset[str] | None) -> Iterator[BagMessage]:
        if self._scanned is not None:
            for m in self._scanned:
                if topics is None or m.topic in topics:
                    yield m
            return
        try:
            with self.path.open("rb") as fh:
                reader = make_reader(fh, validate_crcs=True)
                for _schema, channel, message in reader.iter_messages(
                    topics=list(topics) if topics is not None else None, log_time_order=True
                ):
                    ch = self.channels[channel.id]
                    yield BagMessage(
                        ch.topic,
                        ch.msgtype,
                        message.log_time,
                        bytes(message.data),
                        ch.qos,
                        message.publish_time,
                    )
        except BagError:
            raise
        except Exception as err:
            raise self._fail(f"corrupt MCAP data: {_one_line(err)}; {_SALVAGE_HINT}") from err


def _one_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0]}" if text else type(err).__name__


class BagReader:
    """Reader of one bag: a rosbag2 directory (``metadata.yaml`` + MCAP files) or a ``.mcap``.

    Args:
        path: bag directory, its ``metadata.yaml``, or an MCAP file.
        salvage: read damaged files up to the damage instead of raising.

    Raises:
        BagError: missing, empty, not a bag, truncated or corrupt (unless ``salvage``).

    Example::

        with BagReader("bags/edge") as bag:
            for msg in bag.messages(["/object/pose"]):
                pose = bag.decode(msg)          # geometry_msgs/msg/PoseStamped dataclass
    """

    def __init__(self, path: str | os.PathLike[str], *, salvage: bool = False) -> None:
        self.path = Path(path)
        self.salvage = salvage
        self.metadata: BagMetadata | None = None
        files = self._resolve_files()
        self._files = [_File(f, salvage=salvage) for f in files]
        self._topics = self._collect_topics()
        self._check_consistency()

    # -- opening -----------------------------------------------------------------------------
    def _resolve_files(self) -> list[Path]:
        path = self.path
        if not path.exists():
            msg = f"{path}: no such bag (file or directory does not exist)"
            raise BagError(msg)
        if path.is_file() and path.name == METADATA_FILE:
            path = self.path = path.parent
        if path.is_file():
            return [path]
        meta_path = path / METADATA_FILE
        if meta_path.is_file():
            meta = load_metadata(meta_path)
            if meta.storage_identifier != "mcap":
                msg = (
                    f"{meta_path}: storage {meta.storage_identifier!r} is not supported "
                    "(only 'mcap' bags)"
                )
                raise BagError(msg)
            if meta.compression_mode:
                msg = f"{meta_path}: compression mode {meta.compression_mode!r} not supported"
                raise BagError(msg)
            if not meta.files:
                msg = f"{meta_path}: lists no bag files (relative_file_paths is empty)"
                raise BagError(msg)
            files = [path / name for name in meta.files]
            for f in files:
                if not f.is_file():
                    msg = f"{f}: listed in {METADATA_FILE} but missing"
                    raise BagError(msg)
            self.metadata = meta
            return files
        mcaps = sorted(p for p in path.glob("*.mcap") if p.is_file())
        if mcaps:
            return mcaps
        if any((sub / METADATA_FILE).is_file() for sub in path.iterdir() if sub.is_dir()):
            msg = f"{path}: is a directory of bags, not a bag; name one of them"
        else:
            msg = f"{path}: not a bag (no {METADATA_FILE} and no .mcap file in it)"
        raise BagError(msg)

    def _check_consistency(self) -> None:
        """Metadata counts must match the files (only when every file is intact)."""
        meta = self.metadata
        if meta is None or self.damage is not None:
            return
        actual = self.counts()
        for topic in meta.topics:
            have = actual.get(topic.name, 0)
            if have != topic.message_count:
                msg = (
                    f"{self.path / METADATA_FILE}: says {topic.message_count} messages on "
                    f"{topic.name}, the bag file holds {have}"
                )
                raise BagError(msg)

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def close(self) -> None:
        """Release resources (files are opened per iteration; nothing stays open)."""

    # -- content -----------------------------------------------------------------------------
    @property
    def files(self) -> tuple[Path, ...]:
        """MCAP files of the bag."""
        return tuple(f.path for f in self._files)

    @property
    def damage(self) -> str | None:
        """What was wrong with a salvaged file (``file: problem``), or None if intact."""
        problems = [f"{f.path}: {f.damage}" for f in self._files if f.damage is not None]
        return "; ".join(problems) if problems else None

    def topics(self) -> dict[str, TopicSummary]:
        """Topics by name, with the counts the files hold and the offered QoS."""
        return dict(self._topics)

    def _collect_topics(self) -> dict[str, TopicSummary]:
        meta_topics: dict[str, TopicInfo] = (
            {t.name: t for t in self.metadata.topics} if self.metadata else {}
        )
        out: dict[str, TopicSummary] = {}
        for f in self._files:
            for cid, ch in f.channels.items():
                count = f.counts.get(cid, 0)
                prev = out.get(ch.topic)
                if prev is not None:
                    count += prev.message_count
                qos = ch.qos
                if not qos and ch.topic in meta_topics:
                    qos = meta_topics[ch.topic].offered_qos
                out[ch.topic] = TopicSummary(
                    name=ch.topic,
                    msgtype=ch.msgtype,
                    message_count=count,
                    offered_qos=qos,
                    serialization_format=ch.encoding,
                    schema_encoding=ch.schema_encoding,
                    schema_text=ch.schema_text,
                    type_description_hash=ch.type_hash,
                )
        return out

    def counts(self) -> dict[str, int]:
        """Messages per topic."""
        return {name: t.message_count for name, t in self.topics().items()}

    @property
    def message_count(self) -> int:
        """Total messages."""
        return sum(self.counts().values())

    @property
    def start_ns(self) -> int:
        """Log time of the first message, ns (0 for an empty bag)."""
        starts = [f.start_ns for f in self._files if sum(f.counts.values())]
        return min(starts) if starts else 0

    @property
    def end_ns(self) -> int:
        """Log time of the last message, ns (0 for an empty bag)."""
        ends = [f.end_ns for f in self._files if sum(f.counts.values())]
        return max(ends) if ends else 0

    @property
    def duration_ns(self) -> int:
        """Time from first to last message, ns."""
        return self.end_ns - self.start_ns

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Messages in log-time order (ties keep file order), optionally of some topics only.

        Raises:
            BagError: a damaged chunk is met while iterating (not in salvage mode).
        """
        wanted = frozenset(topics) if topics is not None else None
        streams = [f.messages(wanted) for f in self._files]
        if len(streams) == 1:
            yield from streams[0]
        else:
            yield from heapq.merge(*streams, key=lambda m: m.log_time_ns)

    def decode(self, message: BagMessage) -> Any:
        """The rosbags message dataclass of a :class:`BagMessage` (types from the bag if needed).

        Raises:
            BagError: the type is unknown or the bytes do not decode.
        """
        topic = self._topics.get(message.topic)
        if topic is not None and topic.schema_text:
            register_schema(topic.msgtype, topic.schema_encoding, topic.schema_text)
        return deserialize(message.data, message.msgtype)

    def decoded(self, topics: Iterable[str] | None = None) -> Iterator[tuple[BagMessage, Any]]:
        """``(raw message, decoded dataclass)`` pairs in log-time order."""
        for topic in self._topics.values():
            if topic.schema_text:
                register_schema(topic.msgtype, topic.schema_encoding, topic.schema_text)
        for msg in self.messages(topics):
            yield msg, deserialize(msg.data, msg.msgtype)

    def verify(self) -> int:
        """Read every message (checking chunk CRCs); return how many were read.

        Raises:
            BagError: a chunk is damaged (not in salvage mode).
        """
        return sum(1 for _ in self.messages())


def open_bag(path: str | os.PathLike[str], *, salvage: bool = False) -> BagReader:
    """Open a bag directory or ``.mcap`` file (see :class:`BagReader`)."""
    return BagReader(path, salvage=salvage)


def read_bag(
    path: str | os.PathLike[str],
    topics: Iterable[str] | None = None,
    *,
    salvage: bool = False,
) -> list[BagMessage]:
    """All messages of a bag (optionally of some topics) in log-time order."""
    with BagReader(path, salvage=salvage) as bag:
        return list(bag.messages(topics))


def find_bags(path: str | os.PathLike[str]) -> list[Path]:
    """Bags named by a command-line argument: the bag itself, or the bags inside a directory.

    A directory with ``metadata.yaml`` or ``.mcap`` files is one bag; otherwise each
    sub-directory holding a bag (and each ``.mcap`` file) is one, sorted by name.

    Raises:
        BagError: the path does not exist or holds no bag.
    """
    p = Path(path)
    if not p.exists():
        msg = f"{p}: no such bag or directory"
        raise BagError(msg)
    if p.is_file():
        return [p]
    if (p / METADATA_FILE).is_file() or any(p.glob("*.mcap")):
        return [p]
    found = sorted(
        sub
        for sub in p.iterdir()
        if sub.is_dir() and ((sub / METADATA_FILE).is_file() or any(sub.glob("*.mcap")))
    )
    if not found:
        msg = f"{p}: holds no bag (no {METADATA_FILE} or .mcap file in it or its sub-directories)"
        raise BagError(msg)
    return found

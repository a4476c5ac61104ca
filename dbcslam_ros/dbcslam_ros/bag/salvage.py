"""Linear scan of an MCAP file that stops cleanly at the first damage.

Used for ``--salvage``: a file cut short (no footer or summary, a chunk cut in the middle) or
damaged (bad CRC, garbage record) still yields every message that lies before the damage,
including the complete messages at the start of a truncated uncompressed chunk. The scanner
follows the MCAP specification (little-endian records: opcode u8, length u64, content).
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field

__all__ = ["MCAP_MAGIC", "ScanResult", "ScannedChannel", "ScannedMessage", "scan_mcap"]

MCAP_MAGIC = b"\x89MCAP0\r\n"

_OP_FOOTER = 0x02
_OP_SCHEMA = 0x03
_OP_CHANNEL = 0x04
_OP_MESSAGE = 0x05
_OP_CHUNK = 0x06
_OP_DATA_END = 0x0F


class _Damage(Exception):
    """A record could not be parsed (the reason is the message)."""


@dataclass(frozen=True)
class ScannedChannel:
    """A channel record: topic, message encoding, schema name/encoding/text, metadata."""

    channel_id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_text: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class ScannedMessage:
    """A message record in file order (times in ns)."""

    channel_id: int
    sequence: int
    log_time_ns: int
    publish_time_ns: int
    data: bytes


@dataclass
class ScanResult:
    """What a scan found; ``damage`` is None for an intact file (footer reached)."""

    channels: dict[int, ScannedChannel] = field(default_factory=dict)
    messages: list[ScannedMessage] = field(default_factory=list)
    damage: str | None = None


class _Cursor:
    def __init__(self, data: bytes | memoryview, base: int = 0) -> None:
        self.data = memoryview(data)
        self.pos = 0
        self.base = base

    def need(self, n: int, what: str) -> memoryview:
        if n < 0 or self.pos + n > len(self.data):
            raise _Damage(f"{what} needs {n} bytes, only {len(self.data) - self.pos} left")
        out = self.data[self.pos : self.pos + n]
        self.pos += n
        return out

    def u16(self) -> int:
        return int(struct.unpack("<H", self.need(2, "u16"))[0])

    def u32(self) -> int:
        return int(struct.unpack("<I", self.need(4, "u32"))[0])

    def u64(self) -> int:
        return int(struct.unpack("<Q", self.need(8, "u64"))[0])

    def string(self) -> str:
        n = self.u32()
        try:
            return bytes(self.need(n, "string")).decode("utf-8")
        except UnicodeDecodeError as err:
            raise _Damage(f"string is not UTF-8: {err}") from err

    def remaining(self) -> int:
        return len(self.data) - self.pos


class _Scanner:
    def __init__(self) -> None:
        self.result = ScanResult()
        self.schemas: dict[int, tuple[str, str, str]] = {}
        self.pending: dict[int, tuple[int, str, str, dict[str, str]]] = {}

    def handle(self, opcode: int, body: memoryview) -> None:
        cur = _Cursor(body)
        if opcode == _OP_SCHEMA:
            sid = cur.u16()
            name = cur.string()
            encoding = cur.string()
            n = cur.u32()
            text = bytes(cur.need(n, "schema data")).decode("utf-8", errors="replace")
            self.schemas[sid] = (name, encoding, text)
            self._resolve()
        elif opcode == _OP_CHANNEL:
            cid = cur.u16()
            sid = cur.u16()
            topic = cur.string()
            encoding = cur.string()
            meta_len = cur.u32()
            meta_cur = _Cursor(cur.need(meta_len, "channel metadata"))
            meta: dict[str, str] = {}
            while meta_cur.remaining():
                key = meta_cur.string()
                meta[key] = meta_cur.string()
            self.pending[cid] = (sid, topic, encoding, meta)
            self._resolve()
        elif opcode == _OP_MESSAGE:
            cid = cur.u16()
            seq = cur.u32()
            log_time = cur.u64()
            pub_time = cur.u64()
            data = bytes(cur.need(cur.remaining(), "message data"))
            if cid not in self.result.channels and cid not in self.pending:
                raise _Damage(f"message on unknown channel id {cid}")
            self.result.messages.append(ScannedMessage(cid, seq, log_time, pub_time, data))

    def _resolve(self) -> None:
        for cid, (sid, topic, encoding, meta) in list(self.pending.items()):
            if sid == 0 or sid in self.schemas:
                name, senc, text = self.schemas.get(sid, ("", "", ""))
                self.result.channels[cid] = ScannedChannel(
                    cid, topic, encoding, name, senc, text, meta
                )
                del self.pending[cid]

    def chunk(self, body: memoryview, offset: int, complete: bool) -> None:
        """Parse a chunk; for an incomplete uncompressed chunk, the records present."""
        cur = _Cursor(body)
        cur.u64()  # message_start_time
        cur.u64()  # message_end_time
        uncompressed_size = cur.u64()
        crc = cur.u32()
        compression = cur.string()
        declared = cur.u64()
        available = min(declared, cur.remaining())
        records = cur.need(available, "chunk records")
        if compression != "":
            if not complete:
                raise _Damage(f"{compression}-compressed chunk at byte {offset} is cut short")
            records = memoryview(_decompress(compression, bytes(records), uncompressed_size))
        if complete and crc and zlib.crc32(records) != crc:
            raise _Damage(f"chunk at byte {offset} fails its CRC check")
        self.records(records, offset, inner=True)
        if not complete:
            raise _Damage(f"chunk at byte {offset} is cut short")

    def records(self, data: memoryview, base: int, *, inner: bool) -> int | None:
        """Parse a sequence of records; the offset after the footer, None if none was met."""
        cur = _Cursor(data, base)
        while cur.remaining():
            start = base + cur.pos
            if cur.remaining() < 9:
                raise _Damage(f"record header at byte {start} is cut short")
            opcode = cur.data[cur.pos]
            cur.pos += 1
            length = cur.u64()
            complete = length <= cur.remaining()
            if not complete and not (opcode == _OP_CHUNK and not inner):
                raise _Damage(
                    f"record 0x{opcode:02x} at byte {start} needs {length} bytes, "
                    f"only {cur.remaining()} left"
                )
            body = cur.data[cur.pos : cur.pos + min(length, cur.remaining())]
            cur.pos += len(body)
            try:
                if opcode == _OP_CHUNK and not inner:
                    self.chunk(body, start, complete)
                elif opcode == _OP_FOOTER and not inner:
                    return cur.pos
                else:
                    self.handle(opcode, body)
            except _Damage as err:
                raise _Damage(f"{err} (record 0x{opcode:02x} at byte {start})") from err
            if opcode == _OP_DATA_END and not inner:
                # The summary section repeats schemas and channels; messages are all read.
                continue
        return None


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    try:
        if compression == "zstd":
            import zstandard

            return bytes(zstandard.ZstdDecompressor().decompress(data, max_output_size=size))
        if compression == "lz4":
            import lz4.frame

            return bytes(lz4.frame.decompress(data))
    except Exception as err:
        raise _Damage(f"cannot decompress {compression} chunk: {err}") from err
    raise _Damage(f"unsupported chunk compression {compression!r}")


def scan_mcap(data: bytes | memoryview) -> ScanResult:
    """Scan a whole MCAP file image; never raises on damage, reports it in the result."""
    scanner = _Scanner()
    view = memoryview(data)
    if len(view) < len(MCAP_MAGIC) or bytes(view[: len(MCAP_MAGIC)]) != MCAP_MAGIC:
        scanner.result.damage = "not an MCAP file (bad magic bytes at the start)"
        return scanner.result
    try:
        end = scanner.records(view[len(MCAP_MAGIC) :], len(MCAP_MAGIC), inner=False)
    except _Damage as err:
        scanner.result.damage = str(err)
        return scanner.result
    if end is None:
        scanner.result.damage = f"file ends after {len(view)} bytes without an MCAP footer"
    elif bytes(view[len(MCAP_MAGIC) + end :]) != MCAP_MAGIC:
        scanner.result.damage = "no MCAP magic bytes after the footer (file cut or extended)"
    return scanner.result

"""The MCAP file writer, from the MCAP specification (https://mcap.dev/spec), as rosbag2 lays bags out.

File: magic, Header (profile "ros2"), the Schemas and Channels (in the data section, before any
chunk, so a cut file still names its topics), then Chunks, each followed by its Message Index
records; at close a Metadata record "rosbag2" (the bag's metadata, as rosbag2's MCAP plugin
writes it), Data End with the CRC-32 of the data section, the summary section (Schemas, Channels,
Statistics, Chunk Indexes, Metadata Index, then Summary Offsets), the Footer with the CRC-32 of
the summary, and the closing magic. Every chunk carries the CRC-32 of its records (before
compression). CRC-32 is zlib's, as the specification defines it (record/crc.py: ISA-L's when installed).

Schemas and channels hold what rosbag2 writes: schema name the message type, encoding "ros2msg",
data the message definition (rosbags' typestore); channel message encoding "cdr" and metadata
`offered_qos_profiles` (YAML) and `topic_type_hash` (RIHS01).

Messages arrive as ready records (`Records`, built with numpy); a chunk is closed after the
record that takes it past CHUNK_LIMIT bytes, or on `flush`; nothing is kept after its chunk is
written, so memory does not grow with the bag.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.crc import COMBINE_FROM, combine, crc32
from haptic_teleop.record.layouts import typestore
from haptic_teleop.record.metadata import DEFAULT_QOS, bag_info, metadata_text, qos_yaml, write_metadata
from haptic_teleop.record.streams import Records, Stream, stream_records

MAGIC = b"\x89MCAP0\r\n"
CHUNK_LIMIT = 2**20  # a chunk is closed after the message that takes it past this many bytes
PROFILE = "ros2"
LIBRARY = "haptic_teleop"
# Compression as the scene and CLI name it -> the MCAP compression string.
COMPRESSION = {"none": "", "zstd": "zstd", "lz4": "lz4"}

OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX = 0x07, 0x08, 0x0B, 0x0C, 0x0D
OP_SUMMARY_OFFSET, OP_DATA_END = 0x0E, 0x0F


def string(s: str) -> bytes:
    b = s.encode()
    return struct.pack("<I", len(b)) + b


def record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def string_map(items: Sequence[tuple[str, str]]) -> bytes:
    body = b"".join(string(k) + string(v) for k, v in items)
    return struct.pack("<I", len(body)) + body


def _zstd() -> Any:
    """Zstandard: the standard library's (Python 3.14+) or its backport."""
    try:
        from compression import zstd  # type: ignore[import-not-found]
    except ImportError:
        from backports import zstd
    return zstd


def compressor(name: str) -> Callable[[bytes], bytes]:
    """The compressor of an MCAP compression string ("" none, "zstd", "lz4" frame)."""
    if name == "":
        return bytes
    if name == "zstd":
        zstd = _zstd()
        return lambda b: bytes(zstd.compress(b, level=3))
    if name == "lz4":
        import lz4.frame  # type: ignore[import-untyped]

        return lambda b: bytes(lz4.frame.compress(b))
    raise BagError(f"compression {name!r} is not one of {', '.join(COMPRESSION)}")


def decompressor(name: str) -> Callable[[bytes, int], bytes]:
    """The decompressor of an MCAP compression string (data, uncompressed size) -> bytes."""
    if name == "":
        return lambda b, n: b
    if name == "zstd":
        zstd = _zstd()
        return lambda b, n: bytes(zstd.decompress(b))
    if name == "lz4":
        import lz4.frame

        return lambda b, n: bytes(lz4.frame.decompress(b))
    raise BagError(f"chunk compression {name!r} is not supported (none, zstd, lz4 are)")


@cache
def message_definition(msgtype: str) -> tuple[str, str]:
    """Message definition (ros2msg text) and RIHS01 type hash of a message type, from rosbags' typestore."""
    ts = typestore()
    msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
    return msgdef, ts.hash_rihs01(msgtype)


@dataclass
class Topic:
    name: str
    msgtype: str
    channel_id: int
    schema_id: int
    qos: list[dict[str, Any]]
    digest: str


class BagSink:
    """An open rosbag2 directory with one MCAP file, taking messages as ready records."""

    def __init__(
        self,
        bag_dir: Path,
        topics: Sequence[tuple[str, str]],
        compression: str = "none",
        qos: dict[str, list[dict[str, Any]]] | None = None,
        chunk_limit: int = CHUNK_LIMIT,
    ) -> None:
        if compression not in COMPRESSION:
            raise BagError(f"compression {compression!r} is not one of {', '.join(COMPRESSION)}")
        self.bag_dir = Path(bag_dir)
        if self.bag_dir.exists():
            raise BagError(f"{self.bag_dir} exists already; choose a new --out directory or remove it")
        try:
            self.bag_dir.mkdir(parents=True)
            self.path = self.bag_dir / f"{self.bag_dir.name}.mcap"
            self.file = open(self.path, "xb")  # noqa: SIM115 - open for the writer's life
        except OSError as exc:
            raise BagError(f"{self.bag_dir}: cannot create the bag ({exc.strerror or exc})") from None
        self.compression = COMPRESSION[compression]
        self._compress = compressor(self.compression)
        self.chunk_limit = chunk_limit
        self.pos = 0
        self.crc = 0  # of the data section so far
        self.topics: list[Topic] = []
        self.schemas: list[tuple[int, str, str]] = []  # id, message type, definition
        schema_ids: dict[str, int] = {}
        offered = {**DEFAULT_QOS, **(qos or {})}
        for cid, (topic, msgtype) in enumerate(topics, start=1):
            if msgtype not in schema_ids:
                schema_ids[msgtype] = len(self.schemas) + 1
                self.schemas.append((schema_ids[msgtype], msgtype, message_definition(msgtype)[0]))
            profiles = offered.get(topic, offered["*"])
            self.topics.append(
                Topic(topic, msgtype, cid, schema_ids[msgtype], profiles, message_definition(msgtype)[1])
            )
        self.cids = {t.name: t.channel_id for t in self.topics}
        self.counts = {t.channel_id: 0 for t in self.topics}
        self.start_ns = 2**63 - 1
        self.end_ns = 0
        self.chunk_indexes: list[bytes] = []
        self._new_chunk()
        self._write(MAGIC + record(OP_HEADER, string(PROFILE) + string(LIBRARY)))
        self._write(b"".join(self._schema_records()) + b"".join(self._channel_records()))

    # -- records
    def _schema_records(self) -> list[bytes]:
        return [
            record(OP_SCHEMA, struct.pack("<H", sid) + string(msgtype) + string("ros2msg") + string(text))
            for sid, msgtype, text in self.schemas
        ]

    def _channel_records(self) -> list[bytes]:
        return [
            record(
                OP_CHANNEL,
                struct.pack("<HH", t.channel_id, t.schema_id)
                + string(t.name)
                + string("cdr")
                + string_map([("offered_qos_profiles", qos_yaml(t.qos)), ("topic_type_hash", t.digest)]),
            )
            for t in self.topics
        ]

    def _write(self, data: bytes | memoryview) -> None:
        self.file.write(data)
        self.crc = crc32(data, self.crc)
        self.pos += len(data)

    def _new_chunk(self) -> None:
        self._parts: list[np.ndarray] = []
        self._pending = 0
        # channel id -> [(log times, offsets in the chunk)], channels in the order their first
        # message entered the chunk
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}
        self._chunk_start_ns = 2**63 - 1
        self._chunk_end_ns = 0

    # -- messages
    def write(self, streams: Sequence[Stream]) -> None:
        """A few messages of any size (scene, packet batches, run facts), in log time order."""
        if streams:
            self.append(stream_records(streams, self.cids))

    def append(self, recs: Records) -> None:
        """Add message records to the open chunk, closing it after the record that takes it past the limit."""
        ends = recs.ends
        total = int(ends[-1]) if ends.size else 0
        pos = first = 0
        while pos < total:
            base = self._pending
            k = min(int(ends.searchsorted(pos + self.chunk_limit - base, side="right")), ends.size - 1)
            stop = int(ends[k])
            self._parts.append(recs.buf[pos:stop])
            self._pending += stop - pos
            bounds = np.array((pos, stop))
            here = []
            for cid, starts, times in recs.groups:
                lo, hi = starts.searchsorted(bounds).tolist()
                if hi > lo:
                    here.append((int(starts[lo]), cid, starts[lo:hi], times[lo:hi]))
            here.sort()
            times_here = recs.times[first : k + 1]
            t_lo, t_hi = int(times_here.min()), int(times_here.max())
            first = k + 1
            for _, cid, starts, times in here:
                self._index.setdefault(cid, []).append((times, starts + (base - pos)))
                self.counts[cid] += starts.size
            self._chunk_start_ns = min(self._chunk_start_ns, t_lo)
            self._chunk_end_ns = max(self._chunk_end_ns, t_hi)
            self.start_ns = min(self.start_ns, t_lo)
            self.end_ns = max(self.end_ns, t_hi)
            if base + stop - pos > self.chunk_limit:
                self._close_chunk()
            pos = stop

    def _close_chunk(self) -> None:
        """The chunk record (CRC-32 of its records), one message index per channel, its chunk index."""
        if not self._pending:
            return
        size = self._pending
        crc = 0
        for part in self._parts:
            crc = crc32(part.data, crc)
        if self.compression:
            data: Any = self._compress(b"".join(p.tobytes() for p in self._parts))
            parts: list[Any] = [data]
            stored = len(data)
        else:
            parts = self._parts
            stored = size
        comp = string(self.compression)
        chunk_start = self.pos
        body_len = 8 + 8 + 8 + 4 + len(comp) + 8 + stored
        head = struct.pack("<BQQQQI", OP_CHUNK, body_len, self._chunk_start_ns, self._chunk_end_ns, size, crc)
        self._write(head + comp + struct.pack("<Q", stored))
        if self.compression or size < COMBINE_FROM:
            for part in parts:
                self._write(part)
        else:  # the records as stored: the data section's CRC continues with the chunk's (record/crc.py)
            for part in parts:
                self.file.write(part)
            self.crc = combine(self.crc, crc, size)
            self.pos += size
        chunk_end = self.pos
        offsets: list[tuple[int, int]] = []
        for cid, pieces in self._index.items():
            pairs = np.empty((sum(t.size for t, _ in pieces), 2), dtype="<u8")
            k = 0
            for t, o in pieces:
                pairs[k : k + t.size, 0] = t
                pairs[k : k + t.size, 1] = o
                k += t.size
            offsets.append((cid, self.pos))
            self._write(struct.pack("<BQHI", OP_MESSAGE_INDEX, 6 + pairs.nbytes, cid, pairs.nbytes) + pairs.tobytes())
        index = (
            struct.pack("<QQQQ", self._chunk_start_ns, self._chunk_end_ns, chunk_start, chunk_end - chunk_start)
            + struct.pack("<I", len(offsets) * 10)
            + b"".join(struct.pack("<HQ", cid, off) for cid, off in offsets)
            + struct.pack("<Q", self.pos - chunk_end)
            + comp
            + struct.pack("<QQ", stored, size)
        )
        self.chunk_indexes.append(record(OP_CHUNK_INDEX, index))
        self._new_chunk()

    def flush(self) -> None:
        """Close the open chunk (if it holds anything) and hand the file's buffer to the system."""
        self._close_chunk()
        self.file.flush()

    # -- closing
    def info(self) -> dict[str, Any]:
        return bag_info(
            self.path.name,
            [(t.name, t.msgtype, t.qos, t.digest, self.counts[t.channel_id]) for t in self.topics],
            self.start_ns,
            self.end_ns,
        )

    def close(self) -> None:
        """Summary section, footer and metadata.yaml: the bag is complete."""
        if self.file.closed:
            return
        try:
            self._close_chunk()
            info = self.info()
            inner, whole = metadata_text(info)
            meta_start = self.pos
            meta = record(OP_METADATA, string("rosbag2") + string_map([("serialized_metadata", inner.strip())]))
            self._write(meta)
            self._write(record(OP_DATA_END, struct.pack("<I", self.crc)))
            write_summary(self, meta_start, len(meta))
            self.file.close()
        except OSError as exc:
            self.file.close()
            raise BagError(f"{self.bag_dir}: writing the bag failed ({exc.strerror or exc})") from None
        write_metadata(self.bag_dir, whole)


def summary_bytes(
    schemas: list[bytes],
    channels: list[bytes],
    statistics: bytes,
    chunk_indexes: list[bytes],
    metadata: list[tuple[int, int, str]],
    summary_start: int,
) -> bytes:
    """The summary section (groups, then their Summary Offset records) and the footer, CRC included."""
    groups = [
        (OP_SCHEMA, schemas),
        (OP_CHANNEL, channels),
        (OP_STATISTICS, [statistics]),
        (OP_CHUNK_INDEX, chunk_indexes),
        (
            OP_METADATA_INDEX,
            [record(OP_METADATA_INDEX, struct.pack("<QQ", s, n) + string(name)) for s, n, name in metadata],
        ),
    ]
    out = bytearray()
    offsets = []
    for op, recs in groups:
        if not recs:
            continue
        start = summary_start + len(out)
        for r in recs:
            out += r
        offsets.append(record(OP_SUMMARY_OFFSET, struct.pack("<BQQ", op, start, summary_start + len(out) - start)))
    offset_start = summary_start + len(out)
    for r in offsets:
        out += r
    out += struct.pack("<BQQQ", OP_FOOTER, 20, summary_start, offset_start)
    out += struct.pack("<I", crc32(out))
    return bytes(out) + MAGIC


def statistics_record(
    counts: dict[int, int], n_schemas: int, n_channels: int, n_metadata: int, n_chunks: int, start: int, end: int
) -> bytes:
    total = sum(counts.values())
    body = struct.pack(
        "<QHIIIIQQ", total, n_schemas, n_channels, 0, n_metadata, n_chunks, start if total else 0, end if total else 0
    )
    body += struct.pack("<I", 10 * len(counts)) + b"".join(struct.pack("<HQ", c, n) for c, n in sorted(counts.items()))
    return record(OP_STATISTICS, body)


def write_summary(sink: BagSink, meta_start: int, meta_len: int) -> None:
    stats = statistics_record(
        sink.counts, len(sink.schemas), len(sink.topics), 1, len(sink.chunk_indexes), sink.start_ns, sink.end_ns
    )
    sink.file.write(
        summary_bytes(
            sink._schema_records(),
            sink._channel_records(),
            stats,
            sink.chunk_indexes,
            [(meta_start, meta_len, "rosbag2")],
            sink.pos,
        )
    )

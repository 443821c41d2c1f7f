"""Reading MCAP files, validating as it goes (https://mcap.dev/spec).

`McapFile` opens a complete file through its footer and summary section (summary CRC checked),
finds a topic's messages through the chunk and message indexes, and checks each chunk's CRC as
it reads it. `scan` walks a file record by record from the start, as `bag recover` and `bag
info` need: which chunks are complete and sound, where the data stops, what is damaged. Every
problem is a `BagError` with one line naming the file, what is wrong and what can be done.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.crc import crc32
from haptic_teleop.record.mcap import (
    MAGIC,
    OP_CHANNEL,
    OP_CHUNK,
    OP_CHUNK_INDEX,
    OP_DATA_END,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_SCHEMA,
    OP_STATISTICS,
    decompressor,
)

_FOOTER_LEN = 1 + 8 + 20 + 8  # footer record, then the closing magic


class _Buf:
    """Little-endian fields read one after another from bytes."""

    def __init__(self, data: bytes | memoryview, pos: int = 0) -> None:
        self.data = memoryview(data)
        self.pos = pos

    def u8(self) -> int:
        self.pos += 1
        return int(self.data[self.pos - 1])

    def unpack(self, fmt: str) -> tuple[int, ...]:
        s = struct.calcsize(fmt)
        v = struct.unpack_from(fmt, self.data, self.pos)
        self.pos += s
        return v

    def u16(self) -> int:
        return self.unpack("<H")[0]

    def u32(self) -> int:
        return self.unpack("<I")[0]

    def u64(self) -> int:
        return self.unpack("<Q")[0]

    def bytes_(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise struct.error("field runs past its record")
        self.pos += n
        return bytes(self.data[self.pos - n : self.pos])

    def string(self) -> str:
        return self.bytes_(self.u32()).decode()

    def string_map(self) -> dict[str, str]:
        n = self.u32()
        end = self.pos + n
        out = {}
        while self.pos < end:
            k = self.string()
            out[k] = self.string()
        return out


@dataclass
class Channel:
    id: int
    schema_id: int
    topic: str
    encoding: str
    metadata: dict[str, str]


@dataclass
class Schema:
    id: int
    name: str
    encoding: str
    data: bytes


@dataclass
class ChunkIndex:
    start_ns: int
    end_ns: int
    offset: int  # of the chunk record in the file
    length: int
    index_offsets: dict[int, int]  # channel id -> offset of its message index record
    index_length: int
    compression: str
    compressed_size: int
    size: int


def parse_schema(body: bytes) -> Schema:
    b = _Buf(body)
    sid = b.u16()
    name = b.string()
    enc = b.string()
    data = b.bytes_(b.u32())
    return Schema(sid, name, enc, data)


def parse_channel(body: bytes) -> Channel:
    b = _Buf(body)
    cid, sid = b.unpack("<HH")
    topic = b.string()
    enc = b.string()
    return Channel(cid, sid, topic, enc, b.string_map())


def parse_chunk_index(body: bytes) -> ChunkIndex:
    b = _Buf(body)
    t0, t1, off, length = b.unpack("<QQQQ")
    n = b.u32()
    offsets = {}
    for _ in range(n // 10):
        cid, o = b.unpack("<HQ")
        offsets[cid] = o
    index_len = b.u64()
    comp = b.string()
    csize, size = b.unpack("<QQ")
    return ChunkIndex(t0, t1, off, length, offsets, index_len, comp, csize, size)


def chunk_records(body: bytes | memoryview, where: str, check: bool = True) -> tuple[int, int, bytes]:
    """(start, end, records) of a chunk record's body; the records decompressed and CRC-checked."""
    b = _Buf(body)
    t0, t1, size, crc = b.unpack("<QQQI")
    comp = b.string()
    n = b.u64()
    data = b.bytes_(n)
    try:
        raw = decompressor(comp)(data, size)
    except BagError:
        raise
    except Exception as exc:  # noqa: BLE001 - every codec error means the same
        raise BagError(f"{where} is damaged: its {comp} data do not decompress ({exc})") from None
    if len(raw) != size:
        raise BagError(f"{where} is damaged: {len(raw)} bytes of records where its header says {size}")
    if check and crc and crc32(raw) != crc:
        raise BagError(f"{where} is damaged (CRC mismatch)")
    return t0, t1, raw


def messages_in(records: bytes, offsets: np.ndarray | None = None) -> Iterator[tuple[int, int, bytes]]:
    """(channel id, log time, payload) of the message records in a chunk's records."""
    view = memoryview(records)
    if offsets is None:
        pos = 0
        while pos + 9 <= len(view):
            op, n = struct.unpack_from("<BQ", view, pos)
            if op == OP_MESSAGE:
                cid, _, log = struct.unpack_from("<HIQ", view, pos + 9)
                yield cid, log, bytes(view[pos + 31 : pos + 9 + n])
            pos += 9 + n
        return
    for off in offsets.tolist():
        _, n, cid, _, log = struct.unpack_from("<BQHIQ", view, off)
        yield cid, log, bytes(view[off + 31 : off + 9 + n])


def fixed_rows(records: bytes, offsets: np.ndarray) -> np.ndarray | None:
    """The payloads at `offsets` as (n, size) uint8 rows when they all have one size, else None."""
    arr = np.frombuffer(records, dtype=np.uint8)
    if offsets.size == 0:
        return np.zeros((0, 0), dtype=np.uint8)
    lens = np.frombuffer(records, dtype="<u8", count=1, offset=int(offsets[0]) + 1)
    size = int(lens[0]) - 22
    idx = offsets[:, None] + 1 + np.arange(8)
    if idx.max() >= arr.size:
        return None
    all_lens = arr[idx].copy().view("<u8")[:, 0]
    if not (all_lens == size + 22).all() or int(offsets.max()) + 31 + size > arr.size:
        return None
    return arr[offsets[:, None] + 31 + np.arange(size)]


class McapFile:
    """A complete MCAP file, opened through its summary (CRC checked)."""

    def __init__(self, path: Path, hint: str = "") -> None:
        self.path = Path(path)
        self.hint = hint  # what to do about damage, appended to errors
        try:
            self.f: BinaryIO = open(self.path, "rb")  # noqa: SIM115 - kept open while reading
        except OSError as exc:
            raise BagError(f"{self.path}: cannot read ({exc.strerror or exc})") from None
        self.size = self.path.stat().st_size
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.chunks: list[ChunkIndex] = []
        self.counts: dict[int, int] = {}
        self.loose = False  # messages outside chunks (or no chunk index): read by scanning
        self._verified: set[int] = set()  # chunks whose CRC held (each is checked once)
        try:
            self._open()
        except BaseException:
            self.f.close()
            raise

    def _err(self, what: str) -> BagError:
        return BagError(f"{self.path}: {what}{self.hint}")

    def _open(self) -> None:
        f = self.f
        if f.read(8) != MAGIC:
            raise BagError(f"{self.path}: not an MCAP file (it does not start with the MCAP magic)")
        head = f.read(9)
        if len(head) < 9 or head[0] != OP_HEADER:
            raise self._err("is truncated or damaged: no header record after the magic")
        if self.size < 8 + 9 + _FOOTER_LEN:
            raise self._err(f"is truncated ({self.size} bytes, no summary and footer)")
        f.seek(self.size - _FOOTER_LEN)
        tail = f.read(_FOOTER_LEN)
        if tail[-8:] != MAGIC or tail[0] != OP_FOOTER or struct.unpack_from("<Q", tail, 1)[0] != 20:
            raise self._err(f"is truncated (ends at byte {self.size} without its summary and footer)")
        summary_start, offset_start, crc = struct.unpack_from("<QQI", tail, 9)
        footer_at = self.size - _FOOTER_LEN
        if summary_start == 0:  # no summary: read by scanning
            self.loose = True
            self._scan_all()
            return
        if not 8 <= summary_start <= footer_at or (offset_start and not summary_start <= offset_start <= footer_at):
            raise self._err("has a damaged footer (its summary offsets point outside the file)")
        f.seek(summary_start)
        summary = f.read(footer_at - summary_start)
        if crc and crc32(tail[: 1 + 8 + 16], crc32(summary)) != crc:
            raise self._err("has a damaged summary section (CRC mismatch)")
        pos = 0
        view = memoryview(summary)
        stats = False
        while pos + 9 <= len(view):
            op, n = struct.unpack_from("<BQ", view, pos)
            body = view[pos + 9 : pos + 9 + n]
            if len(body) < n:
                raise self._err("has a damaged summary section (a record runs past it)")
            try:
                if op == OP_SCHEMA:
                    s = parse_schema(bytes(body))
                    self.schemas[s.id] = s
                elif op == OP_CHANNEL:
                    c = parse_channel(bytes(body))
                    self.channels[c.id] = c
                elif op == OP_CHUNK_INDEX:
                    self.chunks.append(parse_chunk_index(bytes(body)))
                elif op == OP_STATISTICS:
                    b = _Buf(bytes(body), 8 + 2 + 4 + 4 + 4 + 4 + 8 + 8)
                    m = b.u32()
                    for _ in range(m // 10):
                        cid, cnt = b.unpack("<HQ")
                        self.counts[cid] = cnt
                    stats = True
            except (struct.error, UnicodeDecodeError):
                raise self._err(f"has a damaged summary section (record 0x{op:02x} is malformed)") from None
            pos += 9 + n
        if not self.chunks or not self.channels:
            self.loose = True  # an unchunked file, or one whose summary lists no chunks
            self._scan_all()
        elif not stats:
            self.counts = {}

    def _scan_all(self) -> None:
        """Channels, schemas and counts of a file read record by record (no usable summary)."""
        self._loose_messages: list[tuple[int, int, bytes]] = []
        for op, body, where in _records(self.f, self.size, self.path):
            if op == OP_SCHEMA:
                s = parse_schema(body)
                self.schemas[s.id] = s
            elif op == OP_CHANNEL:
                c = parse_channel(body)
                self.channels[c.id] = c
            elif op == OP_MESSAGE:
                cid, _, log = struct.unpack_from("<HIQ", body)
                self._loose_messages.append((cid, log, body[22:]))
            elif op == OP_CHUNK:
                _, _, raw = chunk_records(body, where)
                for rec in _records_in(raw):
                    if rec[0] == OP_SCHEMA:
                        s = parse_schema(rec[1])
                        self.schemas[s.id] = s
                    elif rec[0] == OP_CHANNEL:
                        c = parse_channel(rec[1])
                        self.channels[c.id] = c
                self._loose_messages.extend(messages_in(raw))
            elif op == OP_DATA_END:
                break
        self.counts = {}
        for cid, _, _ in self._loose_messages:
            self.counts[cid] = self.counts.get(cid, 0) + 1

    def close(self) -> None:
        self.f.close()

    def chunk(self, i: int) -> bytes:
        """Chunk i's records, decompressed and CRC-checked."""
        c = self.chunks[i]
        self.f.seek(c.offset)
        data = self.f.read(c.length)
        where = f"chunk {i + 1} of {len(self.chunks)} (byte {c.offset})"
        if len(data) < c.length or data[0] != OP_CHUNK:
            raise self._err(f"{where} is missing or damaged")
        try:
            raw = chunk_records(memoryview(data)[9:], where, check=i not in self._verified)[2]
            self._verified.add(i)
            return raw
        except BagError as exc:
            raise self._err(str(exc)) from None
        except struct.error:
            raise self._err(f"{where} is damaged (malformed record)") from None

    def message_offsets(self, i: int, cid: int) -> tuple[np.ndarray, np.ndarray]:
        """(log times, offsets in the chunk's records) of channel `cid` in chunk i, from its message index."""
        c = self.chunks[i]
        off = c.index_offsets.get(cid)
        if off is None:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        self.f.seek(off)
        head = self.f.read(15)
        if len(head) < 15 or head[0] != OP_MESSAGE_INDEX:
            raise self._err(f"the message index of chunk {i + 1} (byte {off}) is damaged")
        _, _, got, n = struct.unpack("<BQHI", head)
        pairs = np.frombuffer(self.f.read(n), dtype="<u8")
        if got != cid or pairs.size * 8 != n or n % 16:
            raise self._err(f"the message index of chunk {i + 1} (byte {off}) is damaged")
        pairs = pairs.reshape(-1, 2).astype(np.int64)
        if pairs.size and (pairs[:, 1].max() + 31 > c.size or pairs[:, 1].min() < 0):
            raise self._err(f"the message index of chunk {i + 1} (byte {off}) points outside its chunk")
        return pairs[:, 0], pairs[:, 1]

    def topic_messages(self, cids: list[int]) -> tuple[np.ndarray, list[bytes] | np.ndarray]:
        """Log times and payloads of the messages of channels `cids`: payloads as (n, size) rows when
        they all have one size, else a list; in log time order (stable)."""
        if self.loose:
            sel = [(t, p) for c, t, p in self._loose_messages if c in cids]
            log = np.array([t for t, _ in sel], dtype=np.int64)
            order = np.argsort(log, kind="stable")
            return log[order], [sel[i][1] for i in order.tolist()]
        logs: list[np.ndarray] = []
        parts: list[np.ndarray | list[bytes]] = []
        for i, c in enumerate(self.chunks):
            if not any(cid in c.index_offsets for cid in cids):
                continue
            raw = self.chunk(i)
            for cid in cids:
                t, o = self.message_offsets(i, cid)
                if not t.size:
                    continue
                rows = fixed_rows(raw, o)
                logs.append(t)
                parts.append(rows if rows is not None else [p for _, _, p in messages_in(raw, o)])
        if not logs:
            return np.zeros(0, dtype=np.int64), []
        log = np.concatenate(logs)
        order = np.argsort(log, kind="stable")
        arrays = [p for p in parts if isinstance(p, np.ndarray)]
        if len(arrays) == len(parts) and len({p.shape[1] for p in arrays}) == 1:
            return log[order], np.concatenate(arrays)[order]
        flat: list[bytes] = []
        for p in parts:
            flat.extend(bytes(r) for r in p) if isinstance(p, np.ndarray) else flat.extend(p)
        return log[order], [flat[i] for i in order.tolist()]


def _records_in(raw: bytes) -> Iterator[tuple[int, bytes]]:
    pos = 0
    view = memoryview(raw)
    while pos + 9 <= len(view):
        op, n = struct.unpack_from("<BQ", view, pos)
        yield op, bytes(view[pos + 9 : pos + 9 + n])
        pos += 9 + n


def _records(f: BinaryIO, size: int, path: Path) -> Iterator[tuple[int, bytes, str]]:
    """(opcode, body, where) of each complete record of the data section, from the start."""
    pos = 8
    f.seek(pos)
    while pos + 9 <= size:
        head = f.read(9)
        op, n = struct.unpack("<BQ", head)
        if pos + 9 + n > size:
            return
        body = f.read(n)
        yield op, body, f"{path}: record at byte {pos}"
        pos += 9 + n


@dataclass
class ScannedChunk:
    offset: int  # of the chunk record
    end: int  # after the chunk and the message index records that follow it
    start_ns: int
    end_ns: int
    length: int  # of the chunk record
    indexes: list[tuple[int, int, int]] = field(default_factory=list)  # (channel, file offset, record length)
    counts: dict[int, int] = field(default_factory=dict)
    has_crc: bool = True  # a chunk written without CRC holds 0 (nothing to check)


@dataclass
class Scan:
    """What walking a file from the start found."""

    size: int
    header: bytes = b""  # magic and header record
    schemas: dict[int, bytes] = field(default_factory=dict)  # id -> record
    channels: dict[int, bytes] = field(default_factory=dict)
    chunks: list[ScannedChunk] = field(default_factory=list)  # complete and sound
    damaged: list[str] = field(default_factory=list)  # chunks dropped and why
    data_end: int = 0  # the end of the last complete, sound piece of data
    complete: bool = False  # a Data End record was found
    cut_at: int | None = None  # where a record runs past the end of the file
    data_crc: int | None = None  # the CRC-32 the Data End record holds (None: no Data End)
    data_crc_found: int = 0  # the CRC-32 of the data section as read
    summary_start: int | None = None  # from the footer, if the file ends with one

    @property
    def messages(self) -> int:
        return sum(sum(c.counts.values()) for c in self.chunks)

    @property
    def seconds(self) -> float:
        if not self.chunks:
            return 0.0
        return (max(c.end_ns for c in self.chunks) - min(c.start_ns for c in self.chunks)) * 1e-9


def scan(path: Path) -> Scan:
    """Walk an MCAP file: its schemas, channels and every complete chunk whose CRC holds."""
    size = path.stat().st_size
    out = Scan(size)
    with open(path, "rb") as f:
        if f.read(8) != MAGIC:
            raise BagError(f"{path}: not an MCAP file (it does not start with the MCAP magic)")
        head = f.read(9)
        if len(head) < 9 or head[0] != OP_HEADER:
            raise BagError(f"{path}: not a usable MCAP file (no header record after the magic)")
        n = struct.unpack_from("<Q", head, 1)[0]
        body = f.read(n)
        if len(body) < n:
            raise BagError(f"{path}: not a usable MCAP file (its header record is cut)")
        out.header = MAGIC + head + body
        crc = crc32(out.header)
        pos = out.data_end = 8 + 9 + n
        last: ScannedChunk | None = None
        while True:
            head = f.read(9)
            if len(head) < 9:
                if head:
                    out.cut_at = pos
                break
            op, n = struct.unpack("<BQ", head)
            if pos + 9 + n > size:
                out.cut_at = pos
                break
            body = f.read(n)
            rec_end = pos + 9 + n
            if op == OP_DATA_END:
                out.complete = True
                out.data_crc = struct.unpack_from("<I", body)[0] if n >= 4 else 0
                out.data_crc_found = crc
                break
            crc = crc32(body, crc32(head, crc))
            if op == OP_SCHEMA:
                out.schemas[struct.unpack_from("<H", body)[0]] = head + body
                out.data_end = rec_end
            elif op == OP_CHANNEL:
                out.channels[struct.unpack_from("<H", body)[0]] = head + body
                out.data_end = rec_end
            elif op == OP_CHUNK:
                last = None
                try:
                    t0, t1, raw = chunk_records(body, f"chunk at byte {pos}")
                    counts: dict[int, int] = {}
                    for rop, rbody in _records_in(raw):
                        if rop == OP_MESSAGE:
                            cid = struct.unpack_from("<H", rbody)[0]
                            counts[cid] = counts.get(cid, 0) + 1
                        elif rop == OP_SCHEMA:
                            out.schemas[struct.unpack_from("<H", rbody)[0]] = record_bytes(rop, rbody)
                        elif rop == OP_CHANNEL:
                            out.channels[struct.unpack_from("<H", rbody)[0]] = record_bytes(rop, rbody)
                    has_crc = struct.unpack_from("<I", body, 24)[0] != 0
                    last = ScannedChunk(pos, rec_end, t0, t1, 9 + n, counts=counts, has_crc=has_crc)
                    out.chunks.append(last)
                    out.data_end = rec_end
                except (BagError, struct.error) as exc:
                    msg = str(exc) if isinstance(exc, BagError) else f"chunk at byte {pos} is damaged (malformed)"
                    out.damaged.append(msg)
            elif op == OP_MESSAGE_INDEX:
                if last is not None:
                    last.indexes.append((struct.unpack_from("<H", body)[0], pos, 9 + n))
                    last.end = rec_end
                    out.data_end = rec_end
            else:
                last = None  # attachments, metadata: not kept by recover
            pos = rec_end
        if size >= 8 + _FOOTER_LEN:
            f.seek(size - _FOOTER_LEN)
            tail = f.read(_FOOTER_LEN)
            if tail[-8:] == MAGIC and tail[0] == OP_FOOTER:
                out.summary_start = struct.unpack_from("<Q", tail, 9)[0]
    return out


def record_bytes(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body

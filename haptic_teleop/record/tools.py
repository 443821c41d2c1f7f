"""`haptic-teleop bag info BAG` and `haptic-teleop bag recover BAG`.

info: what `ros2 bag info` shows (files, size, storage, duration, start and end, message count,
per topic type, count, serialization format and offered QoS) plus the chunk compression and an
integrity check (every chunk's CRC, the data section's CRC, the summary's CRC).

An NVE run's bag also gets a line naming its clients.

recover: rebuilds a bag whose file was cut (a killed run) or lost its summary or metadata.yaml,
from every complete chunk whose CRC holds: the file is rewritten as those chunks and their
message indexes (rebuilt where they were cut off), then the summary section, footer and
metadata.yaml. What was dropped (the cut-off tail, damaged chunks) is reported.
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.crc import crc32
from haptic_teleop.record.mcap import (
    OP_DATA_END,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    record,
    statistics_record,
    string,
    string_map,
    summary_bytes,
)
from haptic_teleop.record.mcapread import Scan, chunk_records, parse_channel, parse_schema, scan
from haptic_teleop.record.metadata import bag_info, metadata_text, write_metadata
from haptic_teleop.record.nve_columns import nve_clients


def _bag_paths(bag: Path) -> tuple[Path, Path]:
    """(the bag directory, its MCAP file) for a directory, its metadata.yaml or an .mcap file."""
    bag = Path(bag)
    if not bag.exists():
        raise BagError(f"{bag}: no such bag (give the rosbag2 directory)")
    if bag.is_file():
        if bag.name == "metadata.yaml":
            bag = bag.parent
        elif bag.suffix == ".mcap":
            return bag.parent, bag
        else:
            raise BagError(f"{bag}: not a bag (give the rosbag2 directory, its metadata.yaml or its .mcap file)")
    found = sorted(bag.glob("*.mcap"))
    if (bag / "metadata.yaml").exists():
        from haptic_teleop.record.reader import _load_metadata

        meta = _load_metadata(bag)
        if meta["storage"] != "mcap":
            raise BagError(f"{bag}: storage {meta['storage']!r}: only MCAP bags can be checked or recovered")
        listed = [bag / f for f in meta["files"] if (bag / f).is_file()]
        found = listed or found
    if not found:
        raise BagError(f"{bag}: not a rosbag2 directory with an MCAP file (no .mcap file in it)")
    if len(found) > 1:
        raise BagError(f"{bag}: {len(found)} MCAP files; only one-file bags are supported")
    return bag, found[0]


def _qos_text(channel_meta: dict[str, str]) -> str:
    from haptic_teleop.record.metadata import _ruamel_load

    profiles = _ruamel_load(channel_meta.get("offered_qos_profiles", "")) or []
    parts = []
    for p in profiles if isinstance(profiles, list) else []:
        if isinstance(p, dict):
            hist = p.get("history", "?")
            depth = f" {p.get('depth')}" if hist == "keep_last" else ""
            parts.append(f"{p.get('reliability', '?')}, {hist}{depth}, {p.get('durability', '?')}")
    return "; ".join(parts) or "-"


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{n} B"
        n /= 1024  # type: ignore[assignment]
    return f"{n} B"


def _checked(mcap: Path, s: Scan) -> str:
    """What the integrity check could check: files written without CRCs hold 0 in their place."""
    with_crc = sum(c.has_crc for c in s.chunks)
    parts = [
        f"{with_crc} chunk CRCs" + (f" ({len(s.chunks) - with_crc} chunks without)" if with_crc < len(s.chunks) else "")
    ]
    parts.append("data section CRC" if s.data_crc else "no data section CRC")
    summary_crc = 0
    if s.summary_start:
        with open(mcap, "rb") as f:
            f.seek(-8 - 4, 2)
            summary_crc = struct.unpack("<I", f.read(4))[0]
    parts.append("summary CRC" if summary_crc else "no summary CRC")
    if not with_crc and not s.data_crc and not summary_crc:
        return "structure only: the file carries no CRCs"
    return ", ".join(parts)


def _check(mcap: Path, s: Scan) -> list[str]:
    """Problems found: damaged chunks, a cut, a wrong data or summary CRC, no summary."""
    problems = list(s.damaged)
    if s.cut_at is not None:
        problems.append(f"the file is cut at byte {s.size} (a record at byte {s.cut_at} runs past its end)")
    if not s.complete:
        problems.append("no Data End record (the bag was not closed)")
    elif s.data_crc and s.data_crc != s.data_crc_found:
        problems.append("the data section's CRC does not match")
    if s.summary_start is None:
        if s.complete:
            problems.append("no footer")
    elif s.summary_start:
        with open(mcap, "rb") as f:
            f.seek(s.summary_start)
            rest = f.read()
        summary, footer = rest[: -8 - 29], rest[-8 - 29 :]
        crc = struct.unpack_from("<I", footer, 25)[0]
        if crc and crc32(footer[:25], crc32(summary)) != crc:
            problems.append("the summary section's CRC does not match")
    return problems


def info(bag_path: Path) -> tuple[str, bool]:
    """The report of `bag info` and whether the bag is sound."""
    bag, mcap = _bag_paths(bag_path)
    s = scan(mcap)
    problems = _check(mcap, s)
    schemas = {sid: parse_schema(r[9:]) for sid, r in s.schemas.items()}
    channels = {cid: parse_channel(r[9:]) for cid, r in s.channels.items()}
    counts: dict[int, int] = {}
    compressions = set()
    with open(mcap, "rb") as f:
        for c in s.chunks:
            for cid, n in c.counts.items():
                counts[cid] = counts.get(cid, 0) + n
            f.seek(c.offset + 9 + 28)
            (n,) = struct.unpack("<I", f.read(4))
            compressions.add(f.read(n).decode() or "none")
    start = min((c.start_ns for c in s.chunks), default=0)
    end = max((c.end_ns for c in s.chunks), default=0)
    total = sum(counts.values())
    has_meta = (bag / "metadata.yaml").exists()
    lines = [
        f"Files:             {mcap.name}" + ("" if has_meta else "  (no metadata.yaml)"),
        f"Bag size:          {_size(mcap.stat().st_size)}",
        "Storage id:        mcap",
        f"Duration:          {(end - start) * 1e-9:.9f}s",
        f"Start:             {start * 1e-9:.9f} s ({start} ns)",
        f"End:               {end * 1e-9:.9f} s ({end} ns)",
        f"Messages:          {total}",
        f"Chunks:            {len(s.chunks)} (compression: {', '.join(sorted(compressions)) or 'none'})",
    ]
    clients = nve_clients([channels[cid].topic for cid in sorted(channels)])
    if clients:  # an NVE run's bag: its clients, from the topics (the run facts may be lost)
        lines.append(f"Run:               NVE, clients {', '.join(clients)}")
    if problems:
        lines.append(
            f"Integrity:         DAMAGED: {'; '.join(problems)}. `haptic-teleop bag recover {bag}` keeps its "
            f"{len(s.chunks)} complete chunks ({total} messages, {s.seconds:.3f} s)"
        )
    else:
        lines.append(f"Integrity:         ok ({_checked(mcap, s)})")
    lines.append("Topic information:")
    for cid in sorted(channels):
        ch = channels[cid]
        sch = schemas.get(ch.schema_id)
        lines.append(
            f"  Topic: {ch.topic} | Type: {sch.name if sch else '?'} | Count: {counts.get(cid, 0)} | "
            f"Serialization Format: {ch.encoding} | QoS: {_qos_text(ch.metadata)}"
        )
    return "\n".join(lines), not problems


@dataclass
class Recovered:
    bag: Path
    chunks: int
    messages: int
    seconds: float
    dropped_bytes: int
    damaged: list[str]
    already_complete: bool = False

    def report(self) -> str:
        if self.already_complete:
            return f"{self.bag}: the bag is complete and sound; nothing to recover"
        out = [
            f"{self.bag}: recovered {self.chunks} chunks, {self.messages} messages, {self.seconds:.3f} s of messages"
        ]
        if self.dropped_bytes:
            out.append(f"dropped the {self.dropped_bytes} bytes after the last complete chunk")
        out += [f"dropped {d}" for d in self.damaged]
        return "\n".join(out)


def _message_index(records: bytes) -> dict[int, list[tuple[int, int]]]:
    """(log time, offset) per channel of a chunk's records, channels in the order of their first message."""
    out: dict[int, list[tuple[int, int]]] = {}
    view = memoryview(records)
    pos = 0
    while pos + 9 <= len(view):
        op, n = struct.unpack_from("<BQ", view, pos)
        if op == OP_MESSAGE:
            cid, _, log = struct.unpack_from("<HIQ", view, pos + 9)
            out.setdefault(cid, []).append((log, pos))
        pos += 9 + n
    return out


def recover(bag_path: Path) -> Recovered:
    """Rebuild the bag from every complete, sound chunk (see the module's doc)."""
    bag, mcap = _bag_paths(bag_path)
    s = scan(mcap)
    problems = _check(mcap, s)
    if not problems and (bag / "metadata.yaml").exists():
        return Recovered(bag, len(s.chunks), s.messages, s.seconds, 0, [], already_complete=True)
    tmp = mcap.with_name(mcap.name + ".recovering")
    schemas = {sid: parse_schema(r[9:]) for sid, r in s.schemas.items()}
    channels = {cid: parse_channel(r[9:]) for cid, r in s.channels.items()}
    pos = 0
    crc = 0
    chunk_indexes: list[bytes] = []
    counts = {cid: 0 for cid in channels}
    try:
        with open(mcap, "rb") as src, open(tmp, "wb") as out:

            def put(data: bytes) -> None:
                nonlocal pos, crc
                out.write(data)
                crc = crc32(data, crc)
                pos += len(data)

            put(s.header)
            put(b"".join(s.schemas[k] for k in sorted(s.schemas)))
            put(b"".join(s.channels[k] for k in sorted(s.channels)))
            for c in s.chunks:
                src.seek(c.offset)
                rec = src.read(c.length)
                chunk_at = pos
                put(rec)
                chunk_end = pos
                have = {cid for cid, _, _ in c.indexes}
                offsets: list[tuple[int, int]] = []
                if have == set(c.counts):  # the chunk's message indexes all follow it: copied
                    for cid, at, length in c.indexes:
                        src.seek(at)
                        offsets.append((cid, pos))
                        put(src.read(length))
                else:  # cut off: rebuilt from the chunk's records
                    _, _, raw = chunk_records(memoryview(rec)[9:], f"chunk at byte {c.offset}")
                    for cid, pairs in _message_index(raw).items():
                        arr = np.array(pairs, dtype="<u8").tobytes()
                        offsets.append((cid, pos))
                        put(record(OP_MESSAGE_INDEX, struct.pack("<HI", cid, len(arr)) + arr))
                for cid, n in c.counts.items():
                    counts[cid] = counts.get(cid, 0) + n
                body = memoryview(rec)[9:]
                _, _, size, _ = struct.unpack_from("<QQQI", body)
                (clen,) = struct.unpack_from("<I", body, 28)
                comp = bytes(body[32 : 32 + clen]).decode()
                (stored,) = struct.unpack_from("<Q", body, 32 + clen)
                chunk_indexes.append(
                    record(
                        0x08,
                        struct.pack("<QQQQ", c.start_ns, c.end_ns, chunk_at, chunk_end - chunk_at)
                        + struct.pack("<I", 10 * len(offsets))
                        + b"".join(struct.pack("<HQ", cid, o) for cid, o in offsets)
                        + struct.pack("<Q", pos - chunk_end)
                        + string(comp)
                        + struct.pack("<QQ", stored, size),
                    )
                )
            start = min((c.start_ns for c in s.chunks), default=0)
            end = max((c.end_ns for c in s.chunks), default=0)
            topics = []
            for cid in sorted(channels):
                ch = channels[cid]
                sch = schemas.get(ch.schema_id)
                topics.append(
                    (
                        ch.topic,
                        sch.name if sch else "",
                        _qos_list(ch.metadata),
                        ch.metadata.get("topic_type_hash", ""),
                        counts.get(cid, 0),
                    )
                )
            binfo = bag_info(mcap.name, topics, start, end)
            inner, whole = metadata_text(binfo)
            meta_at = pos
            meta = record(OP_METADATA, string("rosbag2") + string_map([("serialized_metadata", inner.strip())]))
            put(meta)
            put(record(OP_DATA_END, struct.pack("<I", crc)))
            out.write(
                summary_bytes(
                    [s.schemas[k] for k in sorted(s.schemas)],
                    [s.channels[k] for k in sorted(s.channels)],
                    statistics_record(
                        {k: v for k, v in counts.items()}, len(schemas), len(channels), 1, len(s.chunks), start, end
                    ),
                    chunk_indexes,
                    [(meta_at, len(meta), "rosbag2")],
                    pos,
                )
            )
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, mcap)
        write_metadata(bag, whole)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise BagError(f"{bag}: cannot rewrite the bag ({exc.strerror or exc})") from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    dropped = 0 if s.complete else s.size - s.data_end
    return Recovered(bag, len(s.chunks), sum(counts.values()), s.seconds, dropped, list(s.damaged))


def _qos_list(channel_meta: dict[str, str]) -> list[dict[str, Any]]:
    from haptic_teleop.record.metadata import _ruamel_load

    profiles = _ruamel_load(channel_meta.get("offered_qos_profiles", ""))
    return profiles if isinstance(profiles, list) else []

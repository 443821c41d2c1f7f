"""MCAP file writer."""

from __future__ import annotations

import struct
from collections.abc import Sequence
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.layouts import typestore
from haptic_teleop.record.metadata import yaml_block
from haptic_teleop.record.streams import Records, Stream, stream_records

_CHUNK_LIMIT = 2**20  # rosbags closes an MCAP chunk once it grows past this many bytes


class BagSink:
    """An open bag that takes messages as they come: streams of payloads, or ready records (bulk)."""

    def __init__(self, bag_dir: Path, topics: Sequence[tuple[str, str]], bulk: bool = True) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        if bag_dir.exists():
            raise BagError(f"{bag_dir} exists already; choose a new --out directory or remove it")
        # rosbags' writer and its MCAP storage internals (chunk, bio, counts): typed Any on purpose.
        self.writer: Any = Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        ts = typestore()
        self.conns = {}
        for topic, msgtype in topics:
            msgdef, digest = message_definition(msgtype)
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=ts, msgdef=msgdef, rihs01=digest)
        self.cids = {t: c.id for t, c in self.conns.items()}
        self.bulk = bulk and _bulk_supported(self.writer)
        # The open chunk (bulk path): its records after what rosbags wrote into it (the schemas and
        # channels), and its message index: channel id -> (log times, offsets) arrays, channels in
        # the order their first message entered the chunk, as rosbags keeps them.
        self._parts: list[np.ndarray] = []
        self._pending = 0
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    def write(self, streams: Sequence[Stream]) -> None:
        if not streams:
            return
        if self.bulk:
            self.append(stream_records(streams, self.cids))
            return
        all_times = np.concatenate([s.log_ns for s in streams])
        which = np.concatenate([np.full(len(s.log_ns), k, dtype=np.int64) for k, s in enumerate(streams)])
        index = np.concatenate([np.arange(len(s.log_ns), dtype=np.int64) for s in streams])
        order = np.lexsort((which, all_times))
        conns = [self.conns[s.topic] for s in streams]
        write = self.writer.write
        for k, i, tm in zip(which[order].tolist(), index[order].tolist(), all_times[order].tolist(), strict=True):
            write(conns[k], tm, streams[k].payload(i))

    def append(self, recs: Records) -> None:
        """Add records to the open chunk, closing it where rosbags would, and keep rosbags' counts."""
        writer = self.writer
        storage = writer.storage
        ends = recs.ends
        total = int(ends[-1]) if ends.size else 0
        pos = first = 0
        while pos < total:
            base = storage.chunk.bio.tell() + self._pending
            # The chunk closes after the first record that takes it past the limit.
            k = min(int(ends.searchsorted(pos + _CHUNK_LIMIT - base, side="right")), ends.size - 1)
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
            t_lo, t_hi = int(recs.times[first]), int(recs.times[k])  # records are in time order
            first = k + 1
            for _, cid, starts, times in here:
                self._index.setdefault(cid, []).append((times, starts + (base - pos)))
                storage.channel_stats[cid] += starts.size
                writer.counts[cid] += starts.size
            chunk = storage.chunk
            chunk.message_start_time = min(chunk.message_start_time, t_lo)
            chunk.message_end_time = max(chunk.message_end_time, t_hi)
            storage.message_start_time = min(storage.message_start_time, t_lo)
            storage.message_end_time = max(storage.message_end_time, t_hi)
            writer.min_timestamp = min(writer.min_timestamp, t_lo)
            writer.max_timestamp = max(writer.max_timestamp, t_hi)
            if base + stop - pos > _CHUNK_LIMIT:
                self._close_chunk()
            pos = stop

    def _close_chunk(self) -> None:
        """rosbags' McapWriter.close_chunk, byte for byte, for the records kept as arrays.

        Writes the chunk record (what rosbags wrote into the chunk, then the records), one message
        index record per channel (in `_index` order), queues the chunk index for the summary
        section, and starts a new chunk."""
        from collections import defaultdict
        from io import BytesIO

        from rosbags.rosbag2.storage_mcap import PendingChunk

        storage = self.writer.storage
        chunk = storage.chunk
        head = chunk.bio.getvalue()
        size = len(head) + self._pending
        comp = storage.compression.encode()  # "": the bulk path runs without compression
        bio = storage.bio
        chunk_start = bio.tell()
        rec_len = 28 + 4 + len(comp) + 8 + size
        bio.write(
            struct.pack("<BQQQQI", 6, rec_len, chunk.message_start_time, chunk.message_end_time, size, 0)
            + struct.pack("<I", len(comp))
            + comp
            + struct.pack("<Q", size)
        )
        if head:
            bio.write(head)
        for part in self._parts:
            bio.write(part)
        self._parts = []
        self._pending = 0
        chunk_end = where = chunk_start + 9 + rec_len
        offsets: list[tuple[int, int]] = []
        for cid, parts in self._index.items():
            # (log time, offset) pairs as little-endian uint64 (both are >= 0 int64 here)
            pairs = np.empty((sum(t.size for t, _ in parts), 2), dtype="<i8")
            k = 0
            for t, o in parts:
                pairs[k : k + t.size, 0] = t
                pairs[k : k + t.size, 1] = o
                k += t.size
            offsets.append((cid, where))
            bio.write(struct.pack("<BQHI", 7, 6 + pairs.nbytes, cid, pairs.nbytes))
            bio.write(pairs)
            where += 15 + pairs.nbytes
        self._index = {}
        index = BytesIO()
        index.write(
            struct.pack("<QQQQ", chunk.message_start_time, chunk.message_end_time, chunk_start, chunk_end - chunk_start)
        )
        index.write(struct.pack("<I", len(offsets) * 10))
        for cid, off in offsets:
            index.write(struct.pack("<HQ", cid, off))
        index.write(struct.pack("<Q", where - chunk_end))
        index.write(struct.pack("<I", len(comp)) + comp)
        index.write(struct.pack("<QQ", size, size))
        storage.chunks.append(index)
        storage.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))

    def flush(self) -> None:
        """Close the open chunk (if it holds anything) and push the file's buffer to the system."""
        storage = self.writer.storage
        if self.bulk:
            if storage.chunk.bio.tell() or self._pending:
                self._close_chunk()
        elif storage.chunk.bio.tell():
            storage.close_chunk()
        storage.bio.flush()

    def close(self) -> None:
        if self.bulk:
            if self.writer.storage.chunk.bio.tell() or self._pending:
                self._close_chunk()
            _close_bag(self.writer)
        else:
            self.writer.close()


def _bulk_supported(writer: Any) -> bool:
    st = getattr(writer, "storage", None)
    chunk = getattr(st, "chunk", None)
    return (
        chunk is not None
        and hasattr(chunk, "bio")
        and hasattr(chunk, "msgs")
        and hasattr(st, "close_chunk")
        and hasattr(st, "chunks")
        and getattr(st, "compression", None) == ""
        and hasattr(st, "channel_stats")
        and hasattr(writer, "counts")
        and getattr(getattr(writer, "compression_mode", None), "name", "") == "NONE"
    )


@cache
def message_definition(msgtype: str) -> tuple[str, str]:
    """Message definition and type hash of a message type, as rosbags' add_connection derives them."""
    ts = typestore()
    msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
    return msgdef, ts.hash_rihs01(msgtype)


def _close_bag(writer: Any) -> None:
    """rosbags' Writer.close (summary section, then metadata.yaml) with the metadata text from
    `yaml_block` instead of ruamel: ruamel's pure-Python emitter took 30 to 50 ms per bag for
    the two dumps (the metadata goes into the MCAP file and into metadata.yaml).

    The metadata is built from the writer's connections and counts exactly as Writer.close builds
    it; anything this does not cover (compression, another version, text outside `yaml_block`'s
    subset) is left to Writer.close itself. A test holds both files equal to Writer.close's."""
    from rosbags.interfaces import ConnectionExtRosbag2
    from rosbags.rosbag2.metadata import dump_qos_v9

    storage = writer.storage
    if writer.version != 9 or writer.compression_mode.name != "NONE" or writer.storage_plugin.name != "MCAP":
        writer.close()
        return
    duration = max(0, writer.max_timestamp - writer.min_timestamp)
    start = writer.min_timestamp
    count = sum(writer.counts.values())
    name = storage.path.name
    info = {
        "version": writer.version,
        "storage_identifier": "mcap",
        "relative_file_paths": [name],
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": c.topic,
                    "type": c.msgtype,
                    "serialization_format": c.ext.serialization_format,
                    "offered_qos_profiles": dump_qos_v9(c.ext.offered_qos_profiles),
                    "type_description_hash": c.digest,
                },
                "message_count": writer.counts[c.id],
            }
            for c in writer.connections
            if isinstance(c.ext, ConnectionExtRosbag2)
        ],
        "compression_format": "",
        "compression_mode": "",
        "files": [
            {
                "path": name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": writer.custom_data or None,
        "ros_distro": "rosbags",
    }
    inner = yaml_block(info)
    whole = yaml_block({"rosbag2_bagfile_information": info})
    if inner is None or whole is None:
        writer.close()
        return
    storage.close(writer.version, inner.strip())
    writer.storage = None
    tmp = writer.metapath.with_suffix(".yaml.tmp")
    tmp.write_text(whole, "utf8")
    tmp.replace(writer.metapath)

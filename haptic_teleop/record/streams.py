"""Tick and packet encoders: blocks of engine columns -> the bag's MCAP message records."""

from __future__ import annotations

import json
import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.columns import MULTIARRAY, ONE_DOF, SchemaError, TickSchema, tick_topics
from haptic_teleop.record.layouts import (
    PACKET_BATCH,
    STRING,
    nve_topic_specs,
    packet_batch_bytes,
    packet_rows,
    string_bytes,
    topic_specs,
)
from haptic_teleop.record.metadata import BATCH_QOS
from haptic_teleop.record.nve_columns import NveSchema


class Stream:
    """One topic's messages: log times and payloads, as fixed-size rows or a list of bytes."""

    def __init__(
        self,
        topic: str,
        msgtype: str,
        log_ns: np.ndarray,
        rows: np.ndarray | None = None,
        blobs: list[bytes] | None = None,
    ) -> None:
        self.topic = topic
        self.msgtype = msgtype
        self.log_ns = np.asarray(log_ns, dtype=np.int64)
        self.rows = rows
        self.blobs = blobs

    def payload(self, i: int) -> bytes:
        if self.rows is not None:
            return bytes(self.rows[i].tobytes())
        assert self.blobs is not None
        return self.blobs[i]


BLOCK_TICKS = 1000  # ticks per block handed to the recorder

# The topics every tick writes come from the tick schema (record/columns.py, `tick_topics`), in
# the order their messages follow one another in a tick; then the received samples (name, the
# column holding the released sample's tick or -1; the values are those sent at that tick).
RECEIVED_TOPICS: tuple[tuple[str, str], ...] = (
    ("/forward/received", "fwd_rx_seq"),
    ("/backward/received", "bwd_rx_seq"),
)
_SENT_OF = {"/forward/received": "/forward/sent", "/backward/received": "/backward/sent"}

# The columns a received sample is read from (the values sent at its tick: /forward/sent and
# /backward/sent), kept for the ticks a playout buffer may still release: from the oldest tick
# either direction released last (buffers release in sequence order) and at most HISTORY_TICKS
# back. 1-DoF: 5 float64 columns, 21 MB at most; 3 task axes: 15 columns, 63 MB at most.
HISTORY_TICKS = 2**19  # about 8.7 min at 1 kHz


class _History:
    """The sent columns of recent ticks: a buffer that is compacted, not grown, once in steady state."""

    def __init__(self, width: int) -> None:
        self.buf = np.zeros((4 * BLOCK_TICKS, width))
        self.start = 0  # tick of buf[0]
        self.used = 0
        self.keep_from = 0  # the oldest tick a later block may still reference

    def add(self, cols: np.ndarray) -> None:
        n = cols.shape[0]
        if self.used + n > self.buf.shape[0]:
            drop = min(max(0, self.keep_from - self.start), self.used)
            if drop:
                self.buf[: self.used - drop] = self.buf[drop : self.used]
                self.start += drop
                self.used -= drop
            if self.used + n > self.buf.shape[0]:
                grown = np.zeros((max(2 * self.buf.shape[0], self.used + n), self.buf.shape[1]))
                grown[: self.used] = self.buf[: self.used]
                self.buf = grown
        self.buf[self.used : self.used + n] = cols
        self.used += n

    def rows(self, ticks: np.ndarray) -> np.ndarray:
        """The kept rows of `ticks` (each >= start and < start + used)."""
        if ticks.size and int(ticks.min()) < self.start:
            raise BagError(
                f"a playout buffer released the sample of tick {int(ticks.min())}, older than the "
                f"{HISTORY_TICKS} ticks (or the last release) the recorder keeps"
            )
        out: np.ndarray = self.buf[ticks - self.start]
        return out


class _Streams:
    """What both kinds of run streams share: the scene message, packet batches, the run facts."""

    scene_yaml: str
    period: int
    packets: bool
    ticks: int
    _scene_written: bool

    def _scene_stream(self) -> Stream:
        return Stream("/haptic_teleop/scene", STRING, np.zeros(1), blobs=[string_bytes(self.scene_yaml)])

    def _packet_batches(self, topic: str, rows: np.ndarray) -> Stream | None:
        """Packet records as batch messages of up to PACKET_BATCH rows each, logged at the time the
        recording has reached (the end of the ticks appended so far)."""
        rows = packet_rows(rows)
        if not self.packets or rows.shape[0] == 0:
            return None
        starts = range(0, rows.shape[0], PACKET_BATCH)
        times = np.full(len(starts), self.ticks * self.period, dtype=np.int64)
        blobs = [packet_batch_bytes(rows[s : s + PACKET_BATCH]) for s in starts]
        return Stream(topic, MULTIARRAY, times, blobs=blobs)

    def _final(self, run_info: dict[str, Any]) -> list[Stream]:
        """The run facts, logged at the end of the last tick; the scene first if no tick was
        recorded (a run stopped before its first tick still has its scene in the bag)."""
        end = np.array([self.ticks * self.period], dtype=np.int64)
        info = Stream(
            "/haptic_teleop/run_info", STRING, end, blobs=[string_bytes(json.dumps(run_info, sort_keys=True))]
        )
        if self._scene_written:
            return [info]
        self._scene_written = True
        return [self._scene_stream(), info]


class RunStreams(_Streams):
    """Turns blocks of engine columns into the bag's messages (same code in and out of process).

    Memory is bounded: only the columns of recent ticks a received sample may still refer to are
    kept (`_History`). `records` gives a block's messages as ready MCAP records."""

    def __init__(
        self,
        scene_yaml: str,
        period_ns: int,
        eba_internals: bool,
        packets: bool,
        n_columns: int,
        schema: TickSchema = ONE_DOF,
    ) -> None:
        if n_columns != schema.width:
            raise BagError(f"n_columns {n_columns} is not the tick schema's width {schema.width}")
        self.schema = schema
        self.specs = topic_specs(schema)
        self.scene_yaml = scene_yaml
        self.period = period_ns
        self.eba_internals = eba_internals
        self.packets = packets
        self.n_columns = n_columns
        self.ticks = 0
        received = {t for t, _ in RECEIVED_TOPICS}
        self.fixed = [t.topic for t in tick_topics(schema) if t.topic not in received and (eba_internals or not t.eba)]
        # the sent columns kept for received samples, and where each sits in the history rows
        self.hist_cols = list(dict.fromkeys(c for t in _SENT_OF.values() for c in self.specs[t].columns))
        self.hist_index = {c: i for i, c in enumerate(self.hist_cols)}
        self.history = _History(len(self.hist_cols))
        self._seq_cols = [schema.index(c) for _, c in RECEIVED_TOPICS]
        self._encoder: TickEncoder | None = None
        self._scene_written = False

    def tick_topics(self) -> list[tuple[str, tuple[int, ...]]]:
        """The fixed per-tick topics and the row columns of their values, in message order."""
        return [(t, self.specs[t].columns) for t in self.fixed]

    def received_topics(self) -> list[tuple[str, tuple[int, ...]]]:
        """The received topics and the history columns of their values (those of the sent topic)."""
        return [(t, tuple(self.hist_index[c] for c in self.specs[_SENT_OF[t]].columns)) for t, _ in RECEIVED_TOPICS]

    def received_seq_cols(self) -> list[int]:
        """Per received topic, the row column holding the tick of the sample released (-1: none)."""
        return list(self._seq_cols)

    def default_qos(self) -> dict[str, list[dict[str, Any]]]:
        """Offered QoS of topics metadata.DEFAULT_QOS does not name (none: it names the packet topics)."""
        return {}

    @staticmethod
    def packet_topic(direction: str) -> str:
        """/forward/packets or /backward/packets; BagError for another direction."""
        if direction not in ("forward", "backward"):
            raise BagError(f"packet direction must be 'forward' or 'backward'; got {direction!r}")
        return f"/{direction}/packets"

    def topics(self) -> list[tuple[str, str]]:
        """Every topic in the order its connection is added (fixed: connection ids are part of the bytes)."""
        names = [*self.fixed, *(t for t, _ in RECEIVED_TOPICS)]
        out = [("/haptic_teleop/scene", STRING)] + [(t, self.specs[t].layout.msgtype) for t in names]
        if self.packets:
            out += [("/forward/packets", MULTIARRAY), ("/backward/packets", MULTIARRAY)]
        return [*out, ("/haptic_teleop/run_info", STRING)]

    def _take(self, rows: np.ndarray) -> tuple[int, int]:
        """Keep the sent columns of a block of rows; returns its tick range."""
        if rows.ndim != 2 or rows.shape[1] != self.n_columns:
            raise BagError(f"tick rows must be a float64 array of shape (ticks, {self.n_columns}); got {rows.shape}")
        a = self.ticks
        b = a + rows.shape[0]
        self.history.add(rows[:, self.hist_cols])
        self.ticks = b
        return a, b

    def _released(self, rows: np.ndarray) -> None:
        """After a block: the oldest tick a later block may still release."""
        last = []
        for c in self._seq_cols:
            seq = rows[:, c]
            got = seq[seq >= 0]
            last.append(int(got.max()) if got.size else self.history.keep_from)
        self.history.keep_from = max(min(last), self.ticks - HISTORY_TICKS)

    def records(self, rows: np.ndarray, cids: dict[str, int]) -> list[Records]:
        """The next block of ticks as MCAP message records."""
        a, b = self._take(rows)
        if self._encoder is None:
            self._encoder = TickEncoder(self, cids)
        out = [] if self._scene_written else [stream_records([self._scene_stream()], cids)]
        self._scene_written = True
        if b > a:
            out.append(self._encoder.encode(rows, a, self.history))
        self._released(rows)
        return out

    def packet_stream(self, direction: str, rows: np.ndarray) -> Stream | None:
        """Packet records of one direction as batch messages of up to PACKET_BATCH rows each.

        A batch is logged at the time the recording has reached when it is handed over (the end of
        the ticks appended so far): deterministic given the calls, and in time order with the
        tick messages around it in the file."""
        return self._packet_batches(self.packet_topic(direction), rows)

    def final(self, run_info: dict[str, Any]) -> list[Stream]:
        """The run facts, logged at the end of the last tick; the scene first if no tick was
        recorded (a run stopped before its first tick still has its scene in the bag)."""
        if self.schema != ONE_DOF:  # 1-DoF run facts keep their bytes; the reader assumes ONE_DOF
            run_info = {**run_info, "tick_schema": self.schema.facts()}
        return self._final(run_info)


class NveStreams(_Streams):
    """An NVE run's blocks of tick rows into the bag's messages: the same interface as
    `RunStreams` (the writer process uses either), the same encoder. Every value of a tick's
    messages is in the tick's own row (no received samples referring back), so nothing of past
    ticks is kept. `eba_internals` is ignored (an NVE run has no energy bound)."""

    def __init__(
        self,
        scene_yaml: str,
        period_ns: int,
        eba_internals: bool,
        packets: bool,
        n_columns: int,
        schema: NveSchema,
    ) -> None:
        if n_columns != schema.width:
            raise BagError(f"n_columns {n_columns} is not the NVE schema's width {schema.width}")
        self.schema = schema
        self.specs = nve_topic_specs(schema)
        self.scene_yaml = scene_yaml
        self.period = period_ns
        self.packets = packets
        self.n_columns = n_columns
        self.ticks = 0
        self.fixed = list(self.specs)
        self._encoder: TickEncoder | None = None
        self._scene_written = False

    def tick_topics(self) -> list[tuple[str, tuple[int, ...]]]:
        return [(t, self.specs[t].columns) for t in self.fixed]

    def received_topics(self) -> list[tuple[str, tuple[int, ...]]]:
        return []

    def received_seq_cols(self) -> list[int]:
        return []

    def packet_topic(self, direction: str) -> str:
        """/nve/<client>/up/packets for "<client>/up" (and down); BagError for another direction."""
        try:
            return self.schema.packet_topic(direction)
        except SchemaError as exc:
            raise BagError(str(exc)) from None

    def default_qos(self) -> dict[str, list[dict[str, Any]]]:
        """The packet batches are offered as teleoperation's are (reliable, keep last 10)."""
        return {t: BATCH_QOS for t in self.schema.packet_topics()} if self.packets else {}

    def topics(self) -> list[tuple[str, str]]:
        """Every topic in the order its connection is added: the scene, the per-tick topics, the
        packet batches per client (up, down), the run facts."""
        out = [("/haptic_teleop/scene", STRING)] + [(t, self.specs[t].layout.msgtype) for t in self.fixed]
        if self.packets:
            out += [(t, MULTIARRAY) for t in self.schema.packet_topics()]
        return [*out, ("/haptic_teleop/run_info", STRING)]

    def records(self, rows: np.ndarray, cids: dict[str, int]) -> list[Records]:
        """The next block of ticks as MCAP message records."""
        if rows.ndim != 2 or rows.shape[1] != self.n_columns:
            raise BagError(f"tick rows must be a float64 array of shape (ticks, {self.n_columns}); got {rows.shape}")
        a = self.ticks
        self.ticks = b = a + rows.shape[0]
        if self._encoder is None:
            self._encoder = TickEncoder(self, cids)
        out = [] if self._scene_written else [stream_records([self._scene_stream()], cids)]
        self._scene_written = True
        if b > a:
            out.append(self._encoder.encode(rows, a, None))
        return out

    def packet_stream(self, direction: str, rows: np.ndarray) -> Stream | None:
        """Packet records of one link ("<client>/up" or "<client>/down") as batch messages, logged
        as teleoperation's are (RunStreams.packet_stream)."""
        return self._packet_batches(self.packet_topic(direction), rows)

    def final(self, run_info: dict[str, Any]) -> list[Stream]:
        """The run facts with `nve_schema` (NveSchema.facts()), logged at the end of the last tick."""
        return self._final({**run_info, "nve_schema": self.schema.facts()})


def make_streams(
    scene_yaml: str,
    period_ns: int,
    eba_internals: bool,
    packets: bool,
    n_columns: int,
    schema: TickSchema | NveSchema = ONE_DOF,
) -> RunStreams | NveStreams:
    """The streams of a run of this schema's kind: teleoperation (TickSchema) or NVE (NveSchema)."""
    if isinstance(schema, NveSchema):
        return NveStreams(scene_yaml, period_ns, eba_internals, packets, n_columns, schema)
    return RunStreams(scene_yaml, period_ns, eba_internals, packets, n_columns, schema)


# --------------------------------------------------------------------------------------------
# Bulk writing: MCAP message records built with numpy, appended to rosbags' open chunk.
#
# rosbags' McapWriter.write makes, per message, a record: opcode 0x05, length (u64), channel id
# (u16), sequence 0 (u32), log time and publish time (u64 each, both the log time), then the
# CDR bytes; it keeps a (log time, offset in chunk) pair per message for the chunk's message index
# and closes the chunk after the message that takes it past 1 MiB. The bulk writer makes the same
# bytes without a Python call per message (a test holds the files equal).

REC_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log time, publish time
_REC_LOG_AT = 15  # where the log time sits in a record (the publish time follows)


@dataclass
class Records:
    """MCAP message records back to back in `buf`, time-ordered as rosbags would write them.

    `ends[i]` is where record i ends in `buf` and `times[i]` its log time; `groups` holds, per
    channel, (channel id, where each of its records starts in `buf`, their log times), ascending."""

    buf: np.ndarray
    ends: np.ndarray
    times: np.ndarray
    groups: list[tuple[int, np.ndarray, np.ndarray]]


def stream_records(streams: Sequence[Stream], cids: dict[str, int]) -> Records:
    """Records of a few messages of any size (scene, packet batches, run facts), one by one."""
    times = np.concatenate([s.log_ns for s in streams])
    which = np.concatenate([np.full(len(s.log_ns), k, dtype=np.int64) for k, s in enumerate(streams)])
    index = np.concatenate([np.arange(len(s.log_ns), dtype=np.int64) for s in streams])
    order = np.lexsort((which, times))  # rosbags' order: by log time, then stream
    pieces: list[bytes] = []
    ends: list[int] = []
    rec_times: list[int] = []
    starts: list[list[int]] = [[] for _ in streams]
    logs: list[list[int]] = [[] for _ in streams]
    pos = 0
    for k, i, t in zip(which[order].tolist(), index[order].tolist(), times[order].tolist(), strict=True):
        payload = streams[k].payload(i)
        size = REC_HEAD.size + len(payload)
        pieces += (REC_HEAD.pack(5, size - 9, cids[streams[k].topic], 0, t, t), payload)
        starts[k].append(pos)
        logs[k].append(t)
        pos += size
        ends.append(pos)
        rec_times.append(t)
    groups = [
        (cids[s.topic], np.array(starts[k], dtype=np.int64), np.array(logs[k], dtype=np.int64))
        for k, s in enumerate(streams)
        if starts[k]
    ]
    return Records(
        np.frombuffer(b"".join(pieces), dtype=np.uint8),
        np.array(ends, dtype=np.int64),
        np.array(rec_times, dtype=np.int64),
        groups,
    )


def _stamps(t_ns: np.ndarray) -> np.ndarray:
    """builtin_interfaces/Time (sec int32, nanosec uint32, adjacent) of times >= 0 as one 8-byte word."""
    sec, nsec = np.divmod(t_ns, 1_000_000_000)
    word: np.ndarray = (sec + (nsec << 32)).view(np.uint64)
    return word


class TickEncoder:
    """A block of ticks -> its MCAP records, with numpy, one operation per field.

    Every tick writes the same records (one per tick topic), then the received samples released
    in that tick (0 or 1 per direction; an NVE run has no received topics). A tick's records are
    laid out as one row: the records' bytes with placeholder values (record headers included), and
    a structured dtype names where each value, header stamp and log time sits in the row. A block
    is a (ticks, row) array filled field by field; when every tick released a sample both ways, it
    is the records as they go to the chunk, otherwise the records are moved together around the
    missing ones."""

    def __init__(self, streams: RunStreams | NveStreams, cids: dict[str, int]) -> None:
        specs = streams.specs
        self.period = streams.period
        slots = streams.tick_topics() + streams.received_topics()
        self.cids = [cids[t] for t, _ in slots]
        self.sizes = [REC_HEAD.size + specs[t].layout.size for t, _ in slots]
        self.bases = [sum(self.sizes[:j]) for j in range(len(slots))]
        self.n_fixed = len(slots) - len(streams.received_topics())
        self.width = sum(self.sizes)
        self.fixed_width = sum(self.sizes[: self.n_fixed])
        self.seq_cols = streams.received_seq_cols()
        template = []
        names: list[str] = []
        formats: list[Any] = []
        offsets: list[int] = []
        # (field, column) per value; stamp and log-time fields of the fixed slots, then per received slot.
        self.values: list[list[tuple[str, int]]] = []
        self.stamp_fields: list[str] = []
        self.time_fields: list[str] = []
        for j, (topic, cols) in enumerate(slots):
            lay = specs[topic].layout
            size, base = self.sizes[j], self.bases[j]
            head = REC_HEAD.pack(5, size - 9, self.cids[j], 0, 0, 0)
            template.append(np.frombuffer(head, dtype=np.uint8))
            template.append(lay.template)
            vals = []
            for k, col in enumerate(cols):
                vals.append((f"v{j}_{k}", col))
                names.append(f"v{j}_{k}")
                formats.append("<f8")
                offsets.append(base + REC_HEAD.size + lay.float_offsets[k])
            self.values.append(vals)
            if lay.sec_offset >= 0:
                if lay.nsec_offset != lay.sec_offset + 4:
                    raise AssertionError(f"{topic}: stamp fields not adjacent in the serialized template")
                names.append(f"s{j}")
                formats.append("<u8")
                offsets.append(base + REC_HEAD.size + lay.sec_offset)
            self.stamp_fields.append(f"s{j}" if lay.sec_offset >= 0 else "")
            names.append(f"t{j}")
            formats.append(("<u8", (2,)))  # log time and publish time
            offsets.append(base + _REC_LOG_AT)
            self.time_fields.append(f"t{j}")
        self.template = np.concatenate(template)
        self.row_ends = np.cumsum(self.sizes)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.width})

    def encode(self, block: np.ndarray, a: int, history: _History | None) -> Records:
        """Records of ticks [a, a + len(block)) of the engine's columns; received samples are read
        from `history` (which holds the block's ticks already; None when there are none)."""
        n = block.shape[0]
        b = a + n
        period = self.period
        t = np.arange(a, b, dtype=np.int64) * period
        rows = np.empty((n, self.width), dtype=np.uint8)
        rows[:] = self.template
        rec = rows.view(self.dtype)[:, 0]
        stamps = _stamps(t)
        t2 = t.view(np.uint64)[:, None]  # (times are >= 0) log time = publish time
        nf = self.n_fixed
        for j in range(nf):
            for name, col in self.values[j]:
                rec[name] = block[:, col]
            if self.stamp_fields[j]:
                rec[self.stamp_fields[j]] = stamps
            rec[self.time_fields[j]] = t2
        present = []
        for r, seq_col in enumerate(self.seq_cols):
            assert history is not None
            j = nf + r
            seq = block[:, seq_col]
            here = seq >= 0
            src = seq[here].astype(np.int64)  # a released sample was sent at tick seq <= this tick
            s0 = int(src[0]) if src.size else 0
            if src.size == n and int(src[-1]) - s0 == n - 1 and not (np.diff(src) - 1).any() and s0 >= history.start:
                # a constant delay: the samples sent a fixed number of ticks earlier
                sent = history.buf[s0 - history.start : s0 - history.start + n]
                src_all = src
            else:
                src_all = np.full(n, a, dtype=np.int64)  # ticks releasing nothing: any kept row (dropped below)
                src_all[here] = src
                sent = history.rows(src_all)
            for name, col in self.values[j]:
                rec[name] = sent[:, col]
            rec[self.stamp_fields[j]] = _stamps(src_all * period)
            rec[self.time_fields[j]] = t2
            present.append(here)
        return self._layout(rows, t, present)

    def _layout(self, rows: np.ndarray, t: np.ndarray, present: list[np.ndarray]) -> Records:
        """Drop the received slots of ticks that released nothing; ends and channel groups of what is left."""
        n = rows.shape[0]
        nf = self.n_fixed
        nr = len(present)
        if all(p.all() for p in present):  # the usual tick: the rows are the records as they go to the chunk
            off = np.arange(n, dtype=np.int64) * self.width
            groups = [(self.cids[j], off + self.bases[j], t) for j in range(nf + nr)]
            ends = (off[:, None] + self.row_ends).reshape(-1)
            return Records(rows.reshape(-1), ends, np.repeat(t, nf + nr), groups)
        # Some tick released nothing (teleoperation: the two received topics).
        fw = self.fixed_width
        sizes = self.sizes
        pf, pb = present
        rf, rb = sizes[nf], sizes[nf + 1]
        tick_size = fw + rf * pf + rb * pb
        off = np.cumsum(tick_size) - tick_size
        buf = np.empty(int(off[-1] + tick_size[-1]), dtype=np.uint8)
        _scatter_rows(buf, off, rows[:, :fw])
        _scatter_rows(buf, off[pf] + fw, rows[pf, fw : fw + rf])
        _scatter_rows(buf, off[pb] + fw + rf * pf[pb], rows[pb, fw + rf :])
        groups = [(self.cids[j], off + self.bases[j], t) for j in range(nf)]
        groups.append((self.cids[nf], off[pf] + fw, t[pf]))
        groups.append((self.cids[nf + 1], off[pb] + fw + rf * pf[pb], t[pb]))
        # Record ends in order: per tick, the fixed records, then the received ones that exist.
        slot_sizes = np.empty((n, nf + 2), dtype=np.int64)
        slot_sizes[:, :nf] = sizes[:nf]
        slot_sizes[:, nf] = rf * pf
        slot_sizes[:, nf + 1] = rb * pb
        ends = np.cumsum(slot_sizes.reshape(-1))
        keep = np.ones((n, nf + 2), dtype=bool)
        keep[:, nf] = pf
        keep[:, nf + 1] = pb
        counts = nf + pf.astype(np.int64) + pb
        return Records(buf, ends[keep.reshape(-1)], np.repeat(t, counts), [g for g in groups if g[1].size])


def _scatter_rows(buf: np.ndarray, offsets: np.ndarray, rows: np.ndarray) -> None:
    """buf[o : o + width] = row for each offset and row, as whole rows (not byte by byte).

    A strided view in which row i starts at byte i of `buf` turns the byte scatter into a row
    scatter: numpy copies each row in one piece. The rows written never overlap one another.
    """
    if rows.shape[0] == 0:
        return
    width = rows.shape[1]
    view = np.lib.stride_tricks.as_strided(buf, shape=(buf.size - width + 1, width), strides=(1, 1), writeable=True)
    view[offsets] = rows

"""rosbag2 (MCAP) writing and reading through `rosbags`, with bulk encoding of fixed-layout messages.

Building one message object per sample costs far more than a 1 kHz tick can afford, so the engine
records plain columns and this module encodes each topic in bulk: a message is serialized once
with marker values, the byte offsets of its float64 and stamp fields are found, and every sample
is written into a copy of that template with numpy. The bulk writer goes one step further: a
tick's MCAP message records (headers included) form one row, a block of ticks is one array filled
field by field, and it goes into rosbags' open chunk as is; the metadata is written without ruamel
(`_yaml_block`). Both give the bytes rosbags' own API writes (tests hold them equal). Reading uses
the same layouts in reverse, after checking the first message against a full deserialization, and
falls back to deserializing each message for bags written by other tools.

Topics (standard types only; header.stamp is the send time, a sample's index is stamp / period):
  /haptic_teleop/scene      std_msgs/String                  resolved scene (YAML), at t = 0
  /haptic_teleop/run_info   std_msgs/String                  run facts (JSON), at the end
  /operator/joint_states    sensor_msgs/JointState           intended position, velocity; hand force
  /master/joint_states      sensor_msgs/JointState           position, velocity; actuator force applied
  /slave/joint_states       sensor_msgs/JointState           position, velocity; actuator force applied
  /slave/contact_wrench     geometry_msgs/WrenchStamped      wall force on the robot (force.x)
  /master/eba, /slave/eba   std_msgs/Float64MultiArray       [reservoir_j, force_desired_n] per axis
  /forward/sent|received    sensor_msgs/JointState           master sample (position, velocity)
  /backward/sent|received   sensor_msgs/JointState           slave sample (position, velocity; effort = wall force)
  /forward|backward/packets std_msgs/Float64MultiArray       batches of rows [seq, send_time_s,
                                                             arrival_time_s (NaN if lost), fate, duplicate,
                                                             size_bytes (serialized message)]
"""

from __future__ import annotations

import contextlib
import itertools
import json
import operator
import re
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import cache, lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop.errors import BagError

if TYPE_CHECKING:
    from haptic_teleop.engine import RunResult

JOINT_STATE = "sensor_msgs/msg/JointState"
WRENCH = "geometry_msgs/msg/WrenchStamped"
MULTIARRAY = "std_msgs/msg/Float64MultiArray"
STRING = "std_msgs/msg/String"
PACKET_FIELDS = ("seq", "send_time_s", "arrival_time_s", "fate", "duplicate", "size_bytes")
PACKET_BATCH = 1000

_SEC_MARK = 0x0A1B2C3D
_NSEC_MARK = 0x1E2F3A4B


@lru_cache(maxsize=1)
def typestore() -> Any:
    from rosbags.typesys import Stores, get_typestore

    store = getattr(Stores, "ROS2_KILTED", Stores.LATEST)
    return get_typestore(store)


def _stamp(ts: Any, sec: int, nsec: int) -> Any:
    return ts.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)


def _header(ts: Any, sec: int, nsec: int, frame: str = "") -> Any:
    return ts.types["std_msgs/msg/Header"](stamp=_stamp(ts, sec, nsec), frame_id=frame)


def make_joint_state(joint: str, fields: Sequence[str]) -> Callable[[Sequence[float], int, int], Any]:
    """Message builder: values in order of `fields` (subset of position, velocity, effort)."""
    ts = typestore()
    cls = ts.types[JOINT_STATE]

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        arrays = {f: np.array([values[i]], dtype=np.float64) for i, f in enumerate(fields)}
        empty = np.array([], dtype=np.float64)
        return cls(
            header=_header(ts, sec, nsec),
            name=[joint],
            position=arrays.get("position", empty),
            velocity=arrays.get("velocity", empty),
            effort=arrays.get("effort", empty),
        )

    return make


def make_wrench(frame: str) -> Callable[[Sequence[float], int, int], Any]:
    ts = typestore()
    t = ts.types

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        v3 = t["geometry_msgs/msg/Vector3"]
        wrench = t["geometry_msgs/msg/Wrench"](force=v3(x=values[0], y=0.0, z=0.0), torque=v3(x=0.0, y=0.0, z=0.0))
        return t[WRENCH](header=_header(ts, sec, nsec, frame), wrench=wrench)

    return make


def make_multiarray(labels: Sequence[str]) -> Callable[[Sequence[float], int, int], Any]:
    ts = typestore()
    t = ts.types

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        dims = [t["std_msgs/msg/MultiArrayDimension"](label=lab, size=1, stride=1) for lab in labels]
        layout = t["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0)
        return t[MULTIARRAY](layout=layout, data=np.asarray(values, dtype=np.float64))

    return make


class FixedLayout:
    """Where the float64 values and the stamp sit in one message type's CDR bytes."""

    def __init__(self, msgtype: str, make: Callable[[Sequence[float], int, int], Any], nfloats: int) -> None:
        ts = typestore()
        self.msgtype = msgtype
        self.make = make
        self.nfloats = nfloats
        markers = [1.0e9 + 7.0 * i + 0.123456789 for i in range(nfloats)]
        raw = bytes(ts.serialize_cdr(make(markers, _SEC_MARK, _NSEC_MARK), msgtype))
        self.size = len(raw)
        self.template = np.frombuffer(raw, dtype=np.uint8).copy()
        self.float_offsets = [self._find(raw, struct.pack("<d", m)) for m in markers]
        has_header = msgtype != MULTIARRAY
        self.sec_offset = self._find(raw, struct.pack("<i", _SEC_MARK)) if has_header else -1
        self.nsec_offset = self._find(raw, struct.pack("<I", _NSEC_MARK)) if has_header else -1

    @staticmethod
    def _find(raw: bytes, pattern: bytes) -> int:
        i = raw.find(pattern)
        if i < 0 or raw.find(pattern, i + 1) >= 0:
            raise AssertionError("marker not found exactly once in the serialized template")
        return i

    def encode(self, values: np.ndarray, stamps_ns: np.ndarray | None) -> np.ndarray:
        """(N, nfloats) values and (N,) stamps -> (N, size) uint8 rows of CDR bytes."""
        n = values.shape[0]
        out = np.tile(self.template, (n, 1))
        vals = np.ascontiguousarray(values, dtype="<f8")
        for j, off in enumerate(self.float_offsets):
            out[:, off : off + 8] = vals[:, j : j + 1].view(np.uint8)
        if self.sec_offset >= 0:
            if stamps_ns is None:
                raise ValueError("this message type has a header: stamps are required")
            sec = (stamps_ns // 1_000_000_000).astype("<i4")
            nsec = (stamps_ns % 1_000_000_000).astype("<u4")
            out[:, self.sec_offset : self.sec_offset + 4] = sec.reshape(n, 1).view(np.uint8)
            out[:, self.nsec_offset : self.nsec_offset + 4] = nsec.reshape(n, 1).view(np.uint8)
        return out

    def decode(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(N, size) uint8 -> (N, nfloats) values and stamps (ns) or None."""
        vals = np.empty((rows.shape[0], self.nfloats))
        for j, off in enumerate(self.float_offsets):
            vals[:, j] = rows[:, off : off + 8].copy().view("<f8")[:, 0]
        stamps = None
        if self.sec_offset >= 0:
            sec = rows[:, self.sec_offset : self.sec_offset + 4].copy().view("<i4")[:, 0].astype(np.int64)
            nsec = rows[:, self.nsec_offset : self.nsec_offset + 4].copy().view("<u4")[:, 0].astype(np.int64)
            stamps = sec * 1_000_000_000 + nsec
        return vals, stamps


@dataclass(frozen=True)
class TopicSpec:
    name: str
    layout: FixedLayout
    fields: tuple[str, ...]


@lru_cache(maxsize=1)
def topic_specs() -> dict[str, TopicSpec]:
    """The fixed-layout topics of a 1-axis run."""
    pvE = ("position", "velocity", "effort")
    specs = [
        TopicSpec("/operator/joint_states", FixedLayout(JOINT_STATE, make_joint_state("operator_x", pvE), 3), pvE),
        TopicSpec("/master/joint_states", FixedLayout(JOINT_STATE, make_joint_state("master_x", pvE), 3), pvE),
        TopicSpec("/slave/joint_states", FixedLayout(JOINT_STATE, make_joint_state("slave_x", pvE), 3), pvE),
        TopicSpec("/slave/contact_wrench", FixedLayout(WRENCH, make_wrench("wall"), 1), ("force_x",)),
        TopicSpec(
            "/master/eba",
            FixedLayout(MULTIARRAY, make_multiarray(("reservoir_j", "force_desired_n")), 2),
            ("reservoir_j", "force_desired_n"),
        ),
        TopicSpec(
            "/slave/eba",
            FixedLayout(MULTIARRAY, make_multiarray(("reservoir_j", "force_desired_n")), 2),
            ("reservoir_j", "force_desired_n"),
        ),
    ]
    pv = ("position", "velocity")
    for d in ("sent", "received"):
        specs.append(TopicSpec(f"/forward/{d}", FixedLayout(JOINT_STATE, make_joint_state("master_x", pv), 2), pv))
        specs.append(TopicSpec(f"/backward/{d}", FixedLayout(JOINT_STATE, make_joint_state("slave_x", pvE), 3), pvE))
    return {s.name: s for s in specs}


def joint_state_size(floats: int) -> int:
    """CDR size in bytes of a one-joint JointState carrying `floats` of position/velocity/effort."""
    fields = ("position", "velocity", "effort")[:floats]
    return FixedLayout(JOINT_STATE, make_joint_state("master_x", fields), floats).size


def _packet_rows(log: Sequence[Any] | np.ndarray) -> np.ndarray:
    """Rows per PACKET_FIELDS; times in s, arrival NaN unless the packet arrived (delivered or late).

    `log` is a link's log of packets, or the rows themselves: a float64 array of shape
    (packets, len(PACKET_FIELDS)) in this function's output format, which is used as is."""
    if isinstance(log, np.ndarray):
        if log.dtype != np.float64 or log.ndim != 2 or log.shape[1] != len(PACKET_FIELDS):
            raise BagError(
                f"packet records must be a float64 array of shape (packets, {len(PACKET_FIELDS)}) with columns "
                f"{', '.join(PACKET_FIELDS)}; got {log.dtype} of shape {log.shape}"
            )
        return np.ascontiguousarray(log)
    # Every field of every packet into one float64 array in C (attrgetter, chain, fromiter), then
    # column arithmetic: the same values as converting each packet on its own (int ns -> float64
    # -> * 1e-9), at a fifth of the cost.
    fields = operator.attrgetter("seq", "send_time_ns", "arrival_time_ns", "fate", "duplicate", "size_bytes")
    raw = np.fromiter(
        itertools.chain.from_iterable(map(fields, log)), dtype=np.float64, count=len(log) * len(PACKET_FIELDS)
    ).reshape(len(log), len(PACKET_FIELDS))
    rows = raw.copy()
    rows[:, 1] = raw[:, 1] * 1e-9
    arrived = (raw[:, 3] == 0) | (raw[:, 3] == 4)
    rows[:, 2] = np.where(arrived, raw[:, 2] * 1e-9, np.nan)
    return rows


def _multiarray_bytes(rows: np.ndarray) -> bytes:
    ts = typestore()
    t = ts.types
    dims = [
        t["std_msgs/msg/MultiArrayDimension"](label="packet", size=rows.shape[0], stride=rows.size),
        t["std_msgs/msg/MultiArrayDimension"](label=",".join(PACKET_FIELDS), size=rows.shape[1], stride=rows.shape[1]),
    ]
    msg = t[MULTIARRAY](layout=t["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0), data=rows.ravel())
    return bytes(ts.serialize_cdr(msg, MULTIARRAY))


@lru_cache(maxsize=8)
def _packet_batch_head(n_rows: int) -> bytes:
    """The CDR bytes of a batch of `n_rows` packet records up to its data: rosbags serializes the
    batch once with zeros; the float64 data are the message's last bytes, so a batch is this head
    followed by its rows' bytes (a test holds it equal to `_multiarray_bytes`)."""
    zeros = np.zeros((n_rows, len(PACKET_FIELDS)))
    raw = _multiarray_bytes(zeros)
    head = raw[: len(raw) - zeros.nbytes]
    if raw[len(head) :] != zeros.tobytes():
        raise AssertionError("Float64MultiArray data are not the last bytes of its serialization")
    return head


def _packet_batch_bytes(rows: np.ndarray) -> bytes:
    """`_multiarray_bytes(rows)` for a (packets, len(PACKET_FIELDS)) float64 batch, without a message object."""
    return _packet_batch_head(rows.shape[0]) + np.ascontiguousarray(rows, dtype="<f8").tobytes()


def _string_bytes(text: str) -> bytes:
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.types[STRING](data=text), STRING))


class _Stream:
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
            return self.rows[i].tobytes()
        assert self.blobs is not None
        return self.blobs[i]


BLOCK_TICKS = 1000  # ticks per block handed to the recorder

# The topics every tick writes (name, engine columns, only with recording.eba_internals), in the
# order their messages follow one another in a tick, then the received samples (name, the column
# holding the released sample's tick or -1, the columns sent at that tick).
_FWD = ("m_x_m", "m_v_m_per_s")
_BWD = ("s_x_m", "s_v_m_per_s", "s_contact_n")
_TICK_TOPICS: tuple[tuple[str, tuple[str, ...], bool], ...] = (
    ("/operator/joint_states", ("op_x_m", "op_v_m_per_s", "op_force_n"), False),
    ("/master/joint_states", ("m_x_m", "m_v_m_per_s", "m_force_n"), False),
    ("/slave/joint_states", ("s_x_m", "s_v_m_per_s", "s_force_n"), False),
    ("/slave/contact_wrench", ("s_contact_n",), False),
    ("/master/eba", ("m_energy_j", "m_force_desired_n"), True),
    ("/slave/eba", ("s_energy_j", "s_force_desired_n"), True),
    ("/forward/sent", _FWD, False),
    ("/backward/sent", _BWD, False),
)
_RECEIVED_TOPICS: tuple[tuple[str, str, tuple[str, ...]], ...] = (
    ("/forward/received", "fwd_rx_seq", _FWD),
    ("/backward/received", "bwd_rx_seq", _BWD),
)


class RunStreams:
    """Turns blocks of engine columns into the bag's messages (same code in and out of process).

    `block` gives them as streams of payloads, for rosbags' message-by-message API; `records`
    gives the same messages as ready MCAP records, for the bulk writer."""

    def __init__(self, scene_yaml: str, period_ns: int, eba_internals: bool, packets: bool, n_columns: int) -> None:
        self.scene_yaml = scene_yaml
        self.period = period_ns
        self.eba_internals = eba_internals
        self.packets = packets
        self.data = np.zeros((0, n_columns))
        self.ticks = 0
        self._encoder: _TickEncoder | None = None

    def tick_topics(self) -> list[tuple[str, tuple[str, ...]]]:
        return [(t, cols) for t, cols, eba in _TICK_TOPICS if self.eba_internals or not eba]

    def topics(self) -> list[tuple[str, str]]:
        """Every topic in the order its connection is added (fixed: connection ids are part of the bytes)."""
        specs = topic_specs()
        names = ["/operator/joint_states", "/master/joint_states", "/slave/joint_states", "/slave/contact_wrench"]
        if self.eba_internals:
            names += ["/master/eba", "/slave/eba"]
        names += ["/forward/sent", "/backward/sent", "/forward/received", "/backward/received"]
        out = [("/haptic_teleop/scene", STRING)] + [(t, specs[t].layout.msgtype) for t in names]
        if self.packets:
            out += [("/forward/packets", MULTIARRAY), ("/backward/packets", MULTIARRAY)]
        return [*out, ("/haptic_teleop/run_info", STRING)]

    def _take(self, rows: np.ndarray) -> tuple[int, int]:
        """Append a block of rows to the columns kept so far; returns its tick range."""
        a = self.ticks
        b = a + rows.shape[0]
        if self.data.shape[0] < b:
            grown = np.empty((max(b, 2 * self.data.shape[0]), rows.shape[1]))
            grown[:a] = self.data[:a]
            self.data = grown
        self.data[a:b] = rows
        self.ticks = b
        return a, b

    def _scene_stream(self) -> _Stream:
        return _Stream("/haptic_teleop/scene", STRING, np.zeros(1), blobs=[_string_bytes(self.scene_yaml)])

    def block(self, rows: np.ndarray) -> list[_Stream]:
        """Streams for the next block of ticks (rows continue where the last block ended)."""
        from haptic_teleop.engine import COL

        a, b = self._take(rows)
        d = self.data
        period = self.period
        ticks_ns = np.arange(a, b, dtype=np.int64) * period
        specs = topic_specs()
        streams: list[_Stream] = []
        if a == 0:
            streams.append(self._scene_stream())

        def add(topic: str, values: np.ndarray, stamps: np.ndarray, log_times: np.ndarray) -> None:
            spec = specs[topic]
            streams.append(_Stream(topic, spec.layout.msgtype, log_times, rows=spec.layout.encode(values, stamps)))

        def cols(*names: str, src: np.ndarray | slice = slice(a, b)) -> np.ndarray:
            return d[src][:, [COL[c] for c in names]]

        for topic, names in self.tick_topics():
            add(topic, cols(*names), ticks_ns, ticks_ns)
        for topic, col, names in _RECEIVED_TOPICS:
            seq = d[a:b, COL[col]]
            at = np.nonzero(seq >= 0)[0]
            src = seq[at].astype(np.int64)  # a released sample was sent at tick seq <= this tick
            add(topic, cols(*names, src=src), src * period, (at + a).astype(np.int64) * period)
        return streams

    def records(self, rows: np.ndarray, cids: dict[str, int]) -> list[_Records]:
        """The next block of ticks as MCAP message records (the messages `block` gives, in the same order)."""
        a, b = self._take(rows)
        if self._encoder is None:
            self._encoder = _TickEncoder(self, cids)
        out = [_stream_records([self._scene_stream()], cids)] if a == 0 else []
        if b > a:
            out.append(self._encoder.encode(self.data, a, b))
        return out

    def final(self, forward_rows: np.ndarray, backward_rows: np.ndarray, run_info: dict[str, Any]) -> list[_Stream]:
        """Packet records (their fates are only final at the end) and the run facts."""
        streams: list[_Stream] = []
        if self.packets:
            for topic, rows in (("/forward/packets", forward_rows), ("/backward/packets", backward_rows)):
                starts = range(0, rows.shape[0], PACKET_BATCH)
                # A batch is logged at its first packet's send time; live, a relay's clock can put
                # that a little before scene time 0 (rosbag2 times are unsigned).
                times = [max(0, int(round(rows[s, 1] * 1e9))) for s in starts]
                blobs = [_packet_batch_bytes(rows[s : s + PACKET_BATCH]) for s in starts]
                streams.append(_Stream(topic, MULTIARRAY, np.asarray(times, dtype=np.int64), blobs=blobs))
        end = np.array([self.ticks * self.period], dtype=np.int64)
        streams.append(
            _Stream("/haptic_teleop/run_info", STRING, end, blobs=[_string_bytes(json.dumps(run_info, sort_keys=True))])
        )
        return streams


# --------------------------------------------------------------------------------------------
# Bulk writing: MCAP message records built with numpy, appended to rosbags' open chunk.
#
# rosbags' McapWriter.write makes, per message, a record: opcode 0x05, length (u64), channel id
# (u16), sequence 0 (u32), log time and publish time (u64 each, both the log time), then the
# CDR bytes; it keeps a (log time, offset in chunk) pair per message for the chunk's message index
# and closes the chunk after the message that takes it past 1 MiB. The bulk writer makes the same
# bytes without a Python call per message (a test holds the files equal).

_CHUNK_LIMIT = 2**20  # rosbags closes an MCAP chunk once it grows past this many bytes
_REC_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel id, sequence, log time, publish time
_REC_LOG_AT = 15  # where the log time sits in a record (the publish time follows)


@dataclass
class _Records:
    """MCAP message records back to back in `buf`, time-ordered as rosbags would write them.

    `ends[i]` is where record i ends in `buf` and `times[i]` its log time; `groups` holds, per
    channel, (channel id, where each of its records starts in `buf`, their log times), ascending."""

    buf: np.ndarray
    ends: np.ndarray
    times: np.ndarray
    groups: list[tuple[int, np.ndarray, np.ndarray]]


def _stream_records(streams: Sequence[_Stream], cids: dict[str, int]) -> _Records:
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
        size = _REC_HEAD.size + len(payload)
        pieces += (_REC_HEAD.pack(5, size - 9, cids[streams[k].topic], 0, t, t), payload)
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
    return _Records(
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


class _TickEncoder:
    """A block of ticks -> its MCAP records, with numpy, one operation per field.

    Every tick writes the same records (one per tick topic), then the received samples released
    in that tick (0 or 1 per direction). A tick's records are laid out as one row: the records'
    bytes with placeholder values (record headers included), and a structured dtype names where
    each value, header stamp and log time sits in the row. A block is a (ticks, row) array filled
    field by field; when every tick released a sample both ways, it is the records as they go to
    the chunk, otherwise the records are moved together around the missing ones."""

    def __init__(self, streams: RunStreams, cids: dict[str, int]) -> None:
        from haptic_teleop.engine import COL

        specs = topic_specs()
        self.period = streams.period
        slots = [(t, cols) for t, cols in streams.tick_topics()] + [(t, names) for t, _, names in _RECEIVED_TOPICS]
        self.cids = [cids[t] for t, _ in slots]
        self.sizes = [_REC_HEAD.size + specs[t].layout.size for t, _ in slots]
        self.bases = [sum(self.sizes[:j]) for j in range(len(slots))]
        self.n_fixed = len(slots) - len(_RECEIVED_TOPICS)
        self.width = sum(self.sizes)
        self.fixed_width = self.bases[self.n_fixed]
        self.seq_cols = [COL[c] for _, c, _ in _RECEIVED_TOPICS]
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
            head = _REC_HEAD.pack(5, size - 9, self.cids[j], 0, 0, 0)
            template.append(np.frombuffer(head, dtype=np.uint8))
            template.append(lay.template)
            vals = []
            for k, col in enumerate(cols):
                vals.append((f"v{j}_{k}", COL[col]))
                names.append(f"v{j}_{k}")
                formats.append("<f8")
                offsets.append(base + _REC_HEAD.size + lay.float_offsets[k])
            self.values.append(vals)
            if lay.sec_offset >= 0:
                if lay.nsec_offset != lay.sec_offset + 4:
                    raise AssertionError(f"{topic}: stamp fields not adjacent in the serialized template")
                names.append(f"s{j}")
                formats.append("<u8")
                offsets.append(base + _REC_HEAD.size + lay.sec_offset)
            self.stamp_fields.append(f"s{j}" if lay.sec_offset >= 0 else "")
            names.append(f"t{j}")
            formats.append(("<u8", (2,)))  # log time and publish time
            offsets.append(base + _REC_LOG_AT)
            self.time_fields.append(f"t{j}")
        self.template = np.concatenate(template)
        self.row_ends = np.cumsum(self.sizes)
        self.dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": self.width})

    def encode(self, data: np.ndarray, a: int, b: int) -> _Records:
        """Records of ticks [a, b) of the engine's columns `data` (rows before a are earlier ticks)."""
        n = b - a
        period = self.period
        t = np.arange(a, b, dtype=np.int64) * period
        rows = np.empty((n, self.width), dtype=np.uint8)
        rows[:] = self.template
        rec = rows.view(self.dtype)[:, 0]
        block = data[a:b]
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
            j = nf + r
            seq = block[:, seq_col]
            here = seq >= 0
            src = np.where(here, seq, 0).astype(np.int64)  # a released sample was sent at tick seq <= this tick
            s0 = int(src[0])
            if int(src[-1]) - s0 == n - 1 and not (np.diff(src) - 1).any():
                sent = data[s0 : s0 + n]  # a constant delay: the samples sent a fixed number of ticks earlier
            else:
                sent = data[src]
            for name, col in self.values[j]:
                rec[name] = sent[:, col]
            rec[self.stamp_fields[j]] = _stamps(src * period)
            rec[self.time_fields[j]] = t2
            present.append(here)
        return self._layout(rows, t, present)

    def _layout(self, rows: np.ndarray, t: np.ndarray, present: list[np.ndarray]) -> _Records:
        """Drop the received slots of ticks that released nothing; ends and channel groups of what is left."""
        n = rows.shape[0]
        nf = self.n_fixed
        fw = self.fixed_width
        sizes = self.sizes
        pf, pb = present
        rf, rb = sizes[nf], sizes[nf + 1]
        if pf.all() and pb.all():  # the usual tick: the rows are the records as they go to the chunk
            off = np.arange(n, dtype=np.int64) * self.width
            groups = [(self.cids[j], off + self.bases[j], t) for j in range(nf + 2)]
            ends = (off[:, None] + self.row_ends).reshape(-1)
            return _Records(rows.reshape(-1), ends, np.repeat(t, nf + 2), groups)
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
        return _Records(buf, ends[keep.reshape(-1)], np.repeat(t, counts), [g for g in groups if g[1].size])


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


class _BagSink:
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
            msgdef, digest = _msgdef(msgtype)
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=ts, msgdef=msgdef, rihs01=digest)
        self.cids = {t: c.id for t, c in self.conns.items()}
        self.bulk = bulk and _bulk_supported(self.writer)
        # The open chunk (bulk path): its records after what rosbags wrote into it (the schemas and
        # channels), and its message index: channel id -> (log times, offsets) arrays, channels in
        # the order their first message entered the chunk, as rosbags keeps them.
        self._parts: list[np.ndarray] = []
        self._pending = 0
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    def write(self, streams: Sequence[_Stream]) -> None:
        if not streams:
            return
        if self.bulk:
            self.append(_stream_records(streams, self.cids))
            return
        all_times = np.concatenate([s.log_ns for s in streams])
        which = np.concatenate([np.full(len(s.log_ns), k, dtype=np.int64) for k, s in enumerate(streams)])
        index = np.concatenate([np.arange(len(s.log_ns), dtype=np.int64) for s in streams])
        order = np.lexsort((which, all_times))
        conns = [self.conns[s.topic] for s in streams]
        write = self.writer.write
        for k, i, tm in zip(which[order].tolist(), index[order].tolist(), all_times[order].tolist(), strict=True):
            write(conns[k], tm, streams[k].payload(i))

    def append(self, recs: _Records) -> None:
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

    def close(self) -> None:
        if self.bulk:
            if self.writer.storage.chunk.bio.tell() or self._pending:
                self._close_chunk()
            _close_bag(self.writer)
        else:
            self.writer.close()


def _write_block(sink: _BagSink, streams: RunStreams, rows: np.ndarray) -> None:
    """The next block of ticks into the bag: ready records (bulk) or streams for rosbags' API."""
    if sink.bulk:
        for recs in streams.records(rows, sink.cids):
            sink.append(recs)
    else:
        sink.write(streams.block(rows))


def _writer_process(
    conn: Any,
    bag_dir: str,
    topics: list[tuple[str, str]],
    args: tuple[Any, ...],
    bulk: bool,
    shared: np.ndarray | None = None,
    sink: _BagSink | None = None,
) -> None:
    """Child process: write blocks as they arrive; close the bag however the parent ends.

    A block comes either in the message ("block", rows) or, with `shared` (rows the parent
    copies into memory both processes map), as ("rows", start, stop). With fork, the parent
    opens the bag (`sink`) and the child inherits it."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and finishes the bag
    streams = RunStreams(*args)
    if sink is None:
        sink = _BagSink(Path(bag_dir), topics, bulk)
    try:
        while True:
            try:
                kind, payload = conn.recv()
            except EOFError:  # the parent died: keep what was written
                break
            if kind == "block":
                _write_block(sink, streams, payload)
            elif kind == "rows":
                assert shared is not None
                a, b = payload
                _write_block(sink, streams, shared[a:b])
            elif kind == "final":
                sink.write(streams.final(*payload))
                break
    except BaseException as exc:  # noqa: BLE001 - report any failure, then still close the bag
        with contextlib.suppress(OSError):
            conn.send(("error", f"{type(exc).__name__}: {exc}"))
        sink.close()
        return
    sink.close()
    with contextlib.suppress(OSError):
        conn.send(("done", None))


class RunRecorder:
    """Records an engine run into a bag, in a second process by default so writing overlaps the loop.

    The engine hands it blocks of tick columns (`block`) and, at the end, the packet logs
    (`finish`). Whatever ends the run (last tick, Ctrl-C, an exception), `finish` closes the bag
    so it is complete and readable; if the parent dies, the child closes it on its own.
    """

    def __init__(
        self,
        bag_dir: Path,
        scene_yaml: str,
        period_ns: int,
        eba_internals: bool,
        packets: bool,
        n_columns: int,
        parallel: bool = True,
        bulk: bool = True,
        max_ticks: int | None = None,
    ) -> None:
        self.bag_dir = Path(bag_dir)
        if self.bag_dir.exists():
            raise BagError(f"{self.bag_dir} exists already; choose a new --out directory or remove it")
        args = (scene_yaml, period_ns, eba_internals, packets, n_columns)
        self._streams = RunStreams(*args)
        topics = self._streams.topics()
        self._proc: Any = None
        self._conn: Any = None
        self._sink: _BagSink | None = None
        self._sent = 0
        self._shared: np.ndarray | None = None
        if parallel:
            import multiprocessing as mp

            methods = mp.get_all_start_methods()
            fork = "fork" in methods
            ctx = mp.get_context("fork" if fork else "spawn")
            opened = None
            if fork:
                # Open the bag here and let the child inherit it: importing rosbags' writer (about
                # 0.1 s), adding the connections (ruamel dumps their QoS: 4 to 36 ms) and the
                # packet batch head were the child's first work while the loop ran.
                opened = _BagSink(self.bag_dir, topics, bulk)
                opened.writer.storage.bio.flush()  # nothing buffered may be written twice
                _packet_batch_head(PACKET_BATCH)
            if fork and max_ticks:
                # Blocks go through memory both processes map (inherited at fork); the pipe only
                # carries their bounds. A 144 kB block through a 64 kB pipe made the loop wait
                # whenever the writer was not scheduled right then.
                import mmap

                buf = mmap.mmap(-1, max(1, max_ticks * n_columns * 8))
                self._shared = np.frombuffer(buf, dtype=np.float64).reshape(-1, n_columns)[:max_ticks]
            parent, child = ctx.Pipe()
            self._proc = ctx.Process(
                target=_writer_process,
                args=(child, str(self.bag_dir), topics, args, bulk, self._shared, opened),
                daemon=True,
                name="bag-writer",
            )
            try:
                self._proc.start()
            except BaseException:
                if opened is not None:
                    opened.close()  # a complete, empty bag rather than a dangling file
                raise
            child.close()
            if opened is not None:
                opened.writer.storage.bio.close()  # the parent's copy of the descriptor; the child writes
            self._conn = parent
        else:
            self._sink = _BagSink(self.bag_dir, topics, bulk)

    def block(self, data: np.ndarray, stop: int) -> None:
        """Hand over ticks [last stop, stop) of the engine's column array."""
        start = self._sent
        if stop <= start:
            return
        self._sent = stop
        if self._shared is not None and stop <= self._shared.shape[0]:
            self._shared[start:stop] = data[start:stop]
            self._conn.send(("rows", (start, stop)))
            return
        if self._conn is not None:
            self._conn.send(("block", np.array(data[start:stop])))
        else:
            assert self._sink is not None
            _write_block(self._sink, self._streams, data[start:stop])

    def finish(
        self,
        data: np.ndarray,
        ticks: int,
        forward_log: Sequence[Any] | np.ndarray,
        backward_log: Sequence[Any] | np.ndarray,
        run_info: dict[str, Any],
    ) -> Path:
        """Write the ticks not handed over yet, the packet records and the run facts; close the bag.

        Each log is a link's list of packets, or their records ready made: a float64 array of
        shape (packets, len(PACKET_FIELDS)) as `_packet_rows` returns them. If a log cannot be
        turned into records, the bag is still closed (without packet records) before the error
        is raised."""
        self.block(data, ticks)
        try:
            rows = (_packet_rows(forward_log), _packet_rows(backward_log))
        except BaseException:
            empty = np.zeros((0, len(PACKET_FIELDS)))
            self._final((empty, empty, run_info))
            raise
        return self._final((*rows, run_info))

    def _final(self, payload: tuple[np.ndarray, np.ndarray, dict[str, Any]]) -> Path:
        if self._conn is not None:
            self._conn.send(("final", payload))
            kind, msg = self._conn.recv()
            self._proc.join(timeout=30)
            if kind == "error":
                raise BagError(f"{self.bag_dir}: writing the bag failed: {msg}")
        else:
            assert self._sink is not None
            self._sink.write(self._streams.final(*payload))
            self._sink.close()
        return self.bag_dir


def write_run(
    result: RunResult, bag_dir: Path, run_info: dict[str, Any], bulk: bool = True, parallel: bool = False
) -> Path:
    """Write a finished run as a rosbag2 directory with MCAP storage, in the same blocks as live recording.

    `bulk=False` writes message by message through rosbags' public API; the bulk path produces
    the same bytes (a test holds them equal) at a fraction of the cost.
    """
    from haptic_teleop.engine import COLUMNS

    rec = RunRecorder(
        bag_dir,
        result.scene.to_yaml(),
        result.period_ns,
        result.scene.config.recording.eba_internals,
        result.scene.config.recording.packets,
        len(COLUMNS),
        parallel=parallel,
        bulk=bulk,
    )
    for stop in range(BLOCK_TICKS, result.ticks, BLOCK_TICKS):
        rec.block(result.data, stop)
    return rec.finish(result.data, result.ticks, result.forward_log, result.backward_log, run_info)


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
def _msgdef(msgtype: str) -> tuple[str, str]:
    """Message definition and type hash of a message type, as rosbags' add_connection derives them."""
    ts = typestore()
    msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
    return msgdef, ts.hash_rihs01(msgtype)


def _close_bag(writer: Any) -> None:
    """rosbags' Writer.close (summary section, then metadata.yaml) with the metadata text from
    `_yaml_block` instead of ruamel: ruamel's pure-Python emitter took 30 to 50 ms per bag for
    the two dumps (the metadata goes into the MCAP file and into metadata.yaml).

    The metadata is built from the writer's connections and counts exactly as Writer.close builds
    it; anything this does not cover (compression, another version, text outside `_yaml_block`'s
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
    inner = _yaml_block(info)
    whole = _yaml_block({"rosbag2_bagfile_information": info})
    if inner is None or whole is None:
        writer.close()
        return
    storage.close(writer.version, inner.strip())
    writer.storage = None
    tmp = writer.metapath.with_suffix(".yaml.tmp")
    tmp.write_text(whole, "utf8")
    tmp.replace(writer.metapath)


# --------------------------------------------------------------------------------------------
# Block-style YAML for plain data, as ruamel's YAML(typ="safe") with default_flow_style=False
# writes it (the way rosbags writes metadata): keys sorted, two-space indentation, sequences at
# their key's indentation, a scalar that would end past column 80 moved to a line of its own
# (after a space). Only words ruamel writes unquoted, integers, booleans, None, "" and empty
# containers are written; for anything else `_yaml_block` returns None and the caller uses
# ruamel. A test compares it with ruamel on generated data.

_YAML_WIDTH = 80
_YAML_PLAIN = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*\Z")
# Words a YAML reader could take for something other than a string (ruamel would quote them).
_YAML_WORDS = frozenset({"y", "yes", "n", "no", "on", "off", "true", "false", "null", "inf", "nan"})


class _NotPlain(Exception):
    """Data outside what `_yaml_block` writes."""


def _yaml_scalar(value: Any) -> tuple[str, bool]:
    """(text, whether it is a plain scalar, which ruamel may move to the next line)."""
    if value is None:
        return "null", True
    if value is True or value is False:
        return ("true" if value else "false"), True
    if type(value) is int:
        return str(value), True
    if type(value) is str:
        if not value:
            return "''", False
        if _yaml_word(value, True):
            return value, True
    if type(value) is dict and not value:
        return "{}", False
    if type(value) is list and not value:
        return "[]", False
    raise _NotPlain


@lru_cache(maxsize=1024)
def _yaml_word(text: str, value: bool) -> bool:
    """Whether `text` is written unquoted as a key (value=False: only plain-looking words) or a value."""
    if _YAML_PLAIN.match(text) and text.lower() not in _YAML_WORDS:
        return True
    return value and text.isascii() and text.isprintable() and " " not in text and _ruamel_writes_plain(text)


@lru_cache(maxsize=256)
def _ruamel_writes_plain(word: str) -> bool:
    """Whether ruamel writes `word` (no spaces) unquoted, as it decides it: a one-key dump, once per word.

    For words that could read as something else (a number, a date, a boolean) or start with an
    indicator character; the bag's own strings (topics, types, hashes, "bag.mcap") never get here."""
    from io import StringIO

    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump({"k": word}, out)
    return out.getvalue() in (f"k: {word}\n", f"k: \n  {word}\n")


def _yaml_mapping(m: dict[Any, Any], indent: int, out: list[str], seen: set[int], inline: bool = False) -> None:
    """Keys at `indent`; with `inline`, the first key continues a "- " already written."""
    keys = list(m)
    for k in keys:
        if type(k) is not str or not _yaml_word(k, False):
            raise _NotPlain
    for i, key in enumerate(sorted(keys)):
        lead = "" if inline and i == 0 else " " * indent
        value = m[key]
        if type(value) in (dict, list) and value:
            if id(value) in seen:  # ruamel writes a shared object once, with an anchor
                raise _NotPlain
            seen.add(id(value))
            out.append(f"{lead}{key}:\n")
            if type(value) is dict:
                _yaml_mapping(value, indent + 2, out, seen)
            else:
                _yaml_sequence(value, indent, out, seen)
            continue
        text, plain = _yaml_scalar(value)
        if type(value) in (dict, list):
            if id(value) in seen:
                raise _NotPlain
            seen.add(id(value))
        column = indent + len(key) + 2
        if column + len(text) <= _YAML_WIDTH:
            out.append(f"{lead}{key}: {text}\n")
        elif plain:
            out.append(f"{lead}{key}: \n{' ' * (indent + 2)}{text}\n")
        else:
            raise _NotPlain


def _yaml_sequence(seq: list[Any], indent: int, out: list[str], seen: set[int]) -> None:
    for item in seq:
        if type(item) in (dict, list):
            if id(item) in seen:
                raise _NotPlain
            seen.add(id(item))
        if type(item) is dict and item:
            out.append(" " * indent + "- ")
            _yaml_mapping(item, indent + 2, out, seen, inline=True)
            continue
        if type(item) is list and item:
            raise _NotPlain
        text, _ = _yaml_scalar(item)
        if indent + 2 + len(text) > _YAML_WIDTH:
            raise _NotPlain
        out.append(f"{' ' * indent}- {text}\n")


def _yaml_block(data: dict[str, Any]) -> str | None:
    """`data` as ruamel's safe block-style dump writes it, or None if it is outside the plain subset."""
    if type(data) is not dict or not data:
        return None
    out: list[str] = []
    try:
        _yaml_mapping(data, 0, out, {id(data)})
    except _NotPlain:
        return None
    return "".join(out)


@dataclass
class TopicData:
    """One topic read back: log times (ns), header stamps (ns, or None) and values (N, k)."""

    log_ns: np.ndarray
    stamp_ns: np.ndarray | None
    values: np.ndarray
    fields: tuple[str, ...]

    def field(self, name: str) -> np.ndarray:
        return self.values[:, self.fields.index(name)]


def _deserialize_values(spec: TopicSpec, msg: Any) -> list[float]:
    if spec.layout.msgtype == JOINT_STATE:
        return [float(getattr(msg, f)[0]) for f in spec.fields]
    if spec.layout.msgtype == WRENCH:
        return [float(msg.wrench.force.x)]
    return [float(v) for v in msg.data[: len(spec.fields)]]


def _stamp_of(msg: Any) -> int | None:
    h = getattr(msg, "header", None)
    return None if h is None else int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


class BagReader:
    """Read what analysis needs from a bag written by `write_run` or by the live recorder."""

    def __init__(self, path: str | Path) -> None:
        from rosbags.rosbag2 import Reader

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (give the rosbag2 directory that holds metadata.yaml)")
        if self.path.is_file() and self.path.name == "metadata.yaml":
            self.path = self.path.parent
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types; all mean unreadable
            raise BagError(f"{self.path}: not a readable rosbag2 directory ({exc})") from None
        self.topics = {c.topic: c for c in self._reader.connections}

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _raw(self, topic: str) -> Iterable[tuple[int, bytes]]:
        if topic not in self.topics:
            raise BagError(f"{self.path}: topic {topic} is missing (topics here: {', '.join(sorted(self.topics))})")
        conns = [c for c in self._reader.connections if c.topic == topic]
        for _, t, raw in self._reader.messages(connections=conns):
            yield t, bytes(raw)

    def has(self, topic: str) -> bool:
        return topic in self.topics

    def string(self, topic: str) -> str:
        ts = typestore()
        for _, raw in self._raw(topic):
            return str(ts.deserialize_cdr(raw, STRING).data)
        raise BagError(f"{self.path}: topic {topic} has no messages")

    def read(self, topic: str) -> TopicData:
        """Decode one fixed-layout topic (bulk where the layout matches, else message by message)."""
        spec = topic_specs().get(topic)
        if spec is None:
            raise BagError(f"{topic} is not a fixed-layout topic of haptic_teleop")
        items = list(self._raw(topic))
        log = np.array([t for t, _ in items], dtype=np.int64)
        if not items:
            return TopicData(log, np.zeros(0, dtype=np.int64), np.zeros((0, len(spec.fields))), spec.fields)
        ts = typestore()
        size = spec.layout.size
        first = ts.deserialize_cdr(items[0][1], spec.layout.msgtype)
        if all(len(r) == size for _, r in items):
            rows = np.frombuffer(b"".join(r for _, r in items), dtype=np.uint8).reshape(len(items), size)
            vals, stamps = spec.layout.decode(rows[:1])
            if vals[0].tolist() == _deserialize_values(spec, first) and (
                stamps is None or int(stamps[0]) == _stamp_of(first)
            ):
                vals, stamps = spec.layout.decode(rows)
                return TopicData(log, stamps, vals, spec.fields)
        values = np.empty((len(items), len(spec.fields)))
        stamps_l = np.empty(len(items), dtype=np.int64)
        for i, (_, raw) in enumerate(items):
            msg = ts.deserialize_cdr(raw, spec.layout.msgtype)
            values[i] = _deserialize_values(spec, msg)
            s = _stamp_of(msg)
            stamps_l[i] = -1 if s is None else s
        return TopicData(log, stamps_l if spec.layout.msgtype != MULTIARRAY else None, values, spec.fields)

    def packets(self, topic: str) -> np.ndarray:
        """All packet rows of /forward/packets or /backward/packets: (N, 5) per PACKET_FIELDS."""
        ts = typestore()
        chunks = []
        for _, raw in self._raw(topic):
            msg = ts.deserialize_cdr(raw, MULTIARRAY)
            chunks.append(np.asarray(msg.data, dtype=np.float64).reshape(-1, len(PACKET_FIELDS)))
        return np.concatenate(chunks) if chunks else np.zeros((0, len(PACKET_FIELDS)))

"""rosbag2 (MCAP) writing and reading through `rosbags`, with bulk encoding of fixed-layout messages.

Building one message object per sample costs far more than a 1 kHz tick can afford, so the engine
records plain columns and this module encodes each topic in bulk: a message is serialized once
with marker values, the byte offsets of its float64 and stamp fields are found, and every sample
is written into a copy of that template with numpy. Reading uses the same layouts in reverse,
after checking the first message against a full deserialization, and falls back to deserializing
each message for bags written by other tools.

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
import struct
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache
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


def _packet_rows(log: Sequence[Any]) -> np.ndarray:
    """Rows per PACKET_FIELDS; times in s, arrival NaN unless the packet arrived (delivered or late)."""
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


class RunStreams:
    """Turns blocks of engine columns into the bag's streams (same code in and out of process)."""

    def __init__(self, scene_yaml: str, period_ns: int, eba_internals: bool, packets: bool, n_columns: int) -> None:
        self.scene_yaml = scene_yaml
        self.period = period_ns
        self.eba_internals = eba_internals
        self.packets = packets
        self.data = np.zeros((0, n_columns))
        self.ticks = 0

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

    def block(self, rows: np.ndarray) -> list[_Stream]:
        """Streams for the next block of ticks (rows continue where the last block ended)."""
        from haptic_teleop.engine import COL

        a = self.ticks
        b = a + rows.shape[0]
        if self.data.shape[0] < b:
            grown = np.zeros((max(b, 2 * self.data.shape[0]), rows.shape[1]))
            grown[:a] = self.data[:a]
            self.data = grown
        self.data[a:b] = rows
        self.ticks = b
        d = self.data
        period = self.period
        ticks_ns = np.arange(a, b, dtype=np.int64) * period
        specs = topic_specs()
        streams: list[_Stream] = []
        if a == 0:
            streams.append(_Stream("/haptic_teleop/scene", STRING, np.zeros(1), blobs=[_string_bytes(self.scene_yaml)]))

        def add(topic: str, values: np.ndarray, stamps: np.ndarray, log_times: np.ndarray) -> None:
            spec = specs[topic]
            streams.append(_Stream(topic, spec.layout.msgtype, log_times, rows=spec.layout.encode(values, stamps)))

        def cols(*names: str, src: np.ndarray | slice = slice(a, b)) -> np.ndarray:
            return d[src][:, [COL[c] for c in names]]

        add("/operator/joint_states", cols("op_x_m", "op_v_m_per_s", "op_force_n"), ticks_ns, ticks_ns)
        add("/master/joint_states", cols("m_x_m", "m_v_m_per_s", "m_force_n"), ticks_ns, ticks_ns)
        add("/slave/joint_states", cols("s_x_m", "s_v_m_per_s", "s_force_n"), ticks_ns, ticks_ns)
        add("/slave/contact_wrench", cols("s_contact_n"), ticks_ns, ticks_ns)
        if self.eba_internals:
            add("/master/eba", cols("m_energy_j", "m_force_desired_n"), ticks_ns, ticks_ns)
            add("/slave/eba", cols("s_energy_j", "s_force_desired_n"), ticks_ns, ticks_ns)
        fwd = ("m_x_m", "m_v_m_per_s")
        bwd = ("s_x_m", "s_v_m_per_s", "s_contact_n")
        add("/forward/sent", cols(*fwd), ticks_ns, ticks_ns)
        add("/backward/sent", cols(*bwd), ticks_ns, ticks_ns)
        for topic, col, names in (("/forward/received", "fwd_rx_seq", fwd), ("/backward/received", "bwd_rx_seq", bwd)):
            seq = d[a:b, COL[col]]
            at = np.nonzero(seq >= 0)[0]
            src = seq[at].astype(np.int64)  # a released sample was sent at tick seq <= this tick
            add(topic, cols(*names, src=src), src * period, (at + a).astype(np.int64) * period)
        return streams

    def final(self, forward_rows: np.ndarray, backward_rows: np.ndarray, run_info: dict[str, Any]) -> list[_Stream]:
        """Packet records (their fates are only final at the end) and the run facts."""
        streams: list[_Stream] = []
        if self.packets:
            for topic, rows in (("/forward/packets", forward_rows), ("/backward/packets", backward_rows)):
                starts = range(0, rows.shape[0], PACKET_BATCH)
                # A batch is logged at its first packet's send time; live, a relay's clock can put
                # that a little before scene time 0 (rosbag2 times are unsigned).
                times = [max(0, int(round(rows[s, 1] * 1e9))) for s in starts]
                blobs = [_multiarray_bytes(rows[s : s + PACKET_BATCH]) for s in starts]
                streams.append(_Stream(topic, MULTIARRAY, np.asarray(times, dtype=np.int64), blobs=blobs))
        end = np.array([self.ticks * self.period], dtype=np.int64)
        streams.append(
            _Stream("/haptic_teleop/run_info", STRING, end, blobs=[_string_bytes(json.dumps(run_info, sort_keys=True))])
        )
        return streams


class _BagSink:
    """An open bag that takes streams as they come."""

    def __init__(self, bag_dir: Path, topics: Sequence[tuple[str, str]], bulk: bool = True) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        if bag_dir.exists():
            raise BagError(f"{bag_dir} exists already; choose a new --out directory or remove it")
        self.writer = Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        ts = typestore()
        self.conns = {t: self.writer.add_connection(t, m, typestore=ts) for t, m in topics}
        self.bulk = bulk and _bulk_supported(self.writer)
        # The open chunk's message index (bulk path): channel id -> (log times, offsets) arrays,
        # channels in the order their first message entered the chunk, as rosbags keeps them.
        self._index: dict[int, list[tuple[np.ndarray, np.ndarray]]] = {}

    def write(self, streams: Sequence[_Stream]) -> None:
        if not streams:
            return
        all_times = np.concatenate([s.log_ns for s in streams])
        which = np.concatenate([np.full(len(s.log_ns), k, dtype=np.int64) for k, s in enumerate(streams)])
        index = np.concatenate([np.arange(len(s.log_ns), dtype=np.int64) for s in streams])
        order = np.lexsort((which, all_times))
        which, index, all_times = which[order], index[order], all_times[order]
        conns = [self.conns[s.topic] for s in streams]
        if self.bulk:
            _bulk_write(self.writer, conns, streams, which, index, all_times, self._index)
        else:
            write = self.writer.write
            for k, i, tm in zip(which.tolist(), index.tolist(), all_times.tolist(), strict=True):
                write(conns[k], tm, streams[k].payload(i))

    def close(self) -> None:
        if self.bulk and self.writer.storage.chunk.bio.tell():
            _bulk_close_chunk(self.writer.storage, self._index)
        self.writer.close()


def _writer_process(
    conn: Any,
    bag_dir: str,
    topics: list[tuple[str, str]],
    args: tuple[Any, ...],
    bulk: bool,
    shared: np.ndarray | None = None,
) -> None:
    """Child process: write blocks as they arrive; close the bag however the parent ends.

    A block comes either in the message ("block", rows) or, with `shared` (rows the parent
    copies into memory both processes map), as ("rows", start, stop)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C and finishes the bag
    streams = RunStreams(*args)
    sink = _BagSink(Path(bag_dir), topics, bulk)
    try:
        while True:
            try:
                kind, payload = conn.recv()
            except EOFError:  # the parent died: keep what was written
                break
            if kind == "block":
                sink.write(streams.block(payload))
            elif kind == "rows":
                assert shared is not None
                a, b = payload
                sink.write(streams.block(shared[a:b]))
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
                args=(child, str(self.bag_dir), topics, args, bulk, self._shared),
                daemon=True,
                name="bag-writer",
            )
            self._proc.start()
            child.close()
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
        rows = np.array(data[start:stop])
        if self._conn is not None:
            self._conn.send(("block", rows))
        else:
            assert self._sink is not None
            self._sink.write(self._streams.block(rows))

    def finish(
        self,
        data: np.ndarray,
        ticks: int,
        forward_log: Sequence[Any],
        backward_log: Sequence[Any],
        run_info: dict[str, Any],
    ) -> Path:
        self.block(data, ticks)
        payload = (_packet_rows(forward_log), _packet_rows(backward_log), run_info)
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


_CHUNK_LIMIT = 2**20  # rosbags closes an MCAP chunk once it grows past this many bytes
_REC_HEADER = np.dtype([("op", "u1"), ("len", "<u8"), ("cid", "<u2"), ("seq", "<u4"), ("log", "<u8"), ("pub", "<u8")])


def _bulk_supported(writer: Any) -> bool:
    st = getattr(writer, "storage", None)
    chunk = getattr(st, "chunk", None)
    return (
        chunk is not None
        and hasattr(chunk, "bio")
        and hasattr(chunk, "msgs")
        and hasattr(st, "close_chunk")
        and hasattr(st, "chunks")
        and hasattr(st, "compressor")
        and hasattr(st, "compression")
        and hasattr(st, "channel_stats")
        and hasattr(writer, "counts")
        and getattr(getattr(writer, "compression_mode", None), "name", "") == "NONE"
    )


def _bulk_write(
    writer: Any,
    conns: Sequence[Any],
    streams: Sequence[_Stream],
    which: np.ndarray,
    index: np.ndarray,
    times: np.ndarray,
    pending_index: dict[int, list[tuple[np.ndarray, np.ndarray]]],
) -> None:
    """Append MCAP message records chunk by chunk with numpy, keeping rosbags' bookkeeping.

    Reproduces, record for record, what rosbags' McapWriter.write does per message (opcode 0x05,
    length, channel id, sequence 0, log and publish time, data; a chunk is closed after the
    message that takes it past 1 MiB), so the file is the same as the message-by-message path.
    """
    storage = writer.storage
    sizes = np.array([s.rows.shape[1] if s.rows is not None else -1 for s in streams], dtype=np.int64)
    lengths = sizes[which]
    var = np.nonzero(lengths < 0)[0]
    for j in var.tolist():
        lengths[j] = len(streams[int(which[j])].payload(int(index[j])))
    rec_sizes = 31 + lengths
    cids = np.array([c.id for c in conns], dtype=np.int64)[which]
    total = len(which)
    start = 0
    while start < total:
        base = storage.chunk.bio.tell()
        cum = base + np.cumsum(rec_sizes[start:])
        over = np.nonzero(cum > _CHUNK_LIMIT)[0]
        stop = start + (int(over[0]) + 1 if over.size else total - start)
        sl = slice(start, stop)
        offs = base + np.concatenate([[0], np.cumsum(rec_sizes[sl])[:-1]])
        buf = np.empty(int(rec_sizes[sl].sum()), dtype=np.uint8)
        hdr = np.empty(stop - start, dtype=_REC_HEADER)
        hdr["op"] = 5
        hdr["len"] = rec_sizes[sl] - 9
        hdr["cid"] = cids[sl]
        hdr["seq"] = 0
        hdr["log"] = times[sl]
        hdr["pub"] = times[sl]
        rel = offs - base
        hdr_bytes = hdr.view(np.uint8).reshape(-1, 31)
        wk = which[sl]
        ik = index[sl]
        for k, s in enumerate(streams):
            sel = np.nonzero(wk == k)[0]
            if sel.size == 0:
                continue
            if s.rows is not None:
                # Whole records (header + payload) of one stream, scattered in one numpy call.
                width = 31 + s.rows.shape[1]
                recs = np.empty((sel.size, width), dtype=np.uint8)
                recs[:, :31] = hdr_bytes[sel]
                recs[:, 31:] = s.rows[ik[sel]]
                _scatter_rows(buf, rel[sel], recs)
            else:
                for j in sel.tolist():
                    p = np.frombuffer(s.payload(int(ik[j])), dtype=np.uint8)
                    o = rel[j]
                    buf[o : o + 31] = hdr_bytes[j]
                    buf[o + 31 : o + 31 + p.size] = p
        chunk = storage.chunk
        chunk.bio.write(buf.tobytes())
        tl = times[sl]
        t_lo, t_hi = int(tl.min()), int(tl.max())
        chunk.message_start_time = min(chunk.message_start_time, t_lo)
        chunk.message_end_time = max(chunk.message_end_time, t_hi)
        storage.message_start_time = min(storage.message_start_time, t_lo)
        storage.message_end_time = max(storage.message_end_time, t_hi)
        writer.min_timestamp = min(writer.min_timestamp, t_lo)
        writer.max_timestamp = max(writer.max_timestamp, t_hi)
        # The message index: rosbags keeps a (time, offset) pair per message and writes them one
        # by one when the chunk closes; here they stay arrays until _bulk_close_chunk.
        cid_sl = cids[sl]
        present, first = np.unique(cid_sl, return_index=True)
        for cid in present[np.argsort(first)].tolist():
            sel = cid_sl == cid
            pending_index.setdefault(cid, []).append((tl[sel], offs[sel]))
        for k, c in enumerate(conns):
            cnt = int(np.count_nonzero(wk == k))
            if cnt:
                storage.channel_stats[c.id] += cnt
                writer.counts[c.id] += cnt
        if chunk.bio.tell() > _CHUNK_LIMIT:
            _bulk_close_chunk(storage, pending_index)
        start = stop


def _scatter_rows(buf: np.ndarray, offsets: np.ndarray, rows: np.ndarray) -> None:
    """buf[o : o + width] = row for each offset and row, as whole rows (not byte by byte).

    A strided view in which row i starts at byte i of `buf` turns the byte scatter into a row
    scatter: numpy copies each row in one piece. The rows written never overlap one another.
    """
    width = rows.shape[1]
    view = np.lib.stride_tricks.as_strided(buf, shape=(buf.size - width + 1, width), strides=(1, 1), writeable=True)
    view[offsets] = rows


def _bulk_close_chunk(storage: Any, pending_index: dict[int, list[tuple[np.ndarray, np.ndarray]]]) -> None:
    """rosbags' McapWriter.close_chunk, byte for byte, with the message index written from arrays.

    Writes the chunk record, one message index record per channel (in `pending_index` order),
    queues the chunk index for the summary section, and starts a new chunk.
    """
    from collections import defaultdict
    from io import BytesIO

    from rosbags.rosbag2.storage_mcap import PendingChunk

    chunk = storage.chunk
    size = chunk.bio.tell()
    compressed = storage.compressor(chunk.bio.getvalue())
    comp = storage.compression.encode()
    rec = b"".join(
        (
            struct.pack("<QQQI", chunk.message_start_time, chunk.message_end_time, size, 0),
            struct.pack("<I", len(comp)),
            comp,
            struct.pack("<Q", len(compressed)),
            compressed,
        )
    )
    bio = storage.bio
    chunk_start = bio.tell()
    bio.write(b"\x06" + struct.pack("<Q", len(rec)))
    bio.write(rec)
    chunk_end = bio.tell()
    offsets: list[tuple[int, int]] = []
    for cid, parts in pending_index.items():
        offsets.append((cid, bio.tell()))
        pairs = np.empty((sum(len(t) for t, _ in parts), 2), dtype="<u8")
        pairs[:, 0] = np.concatenate([t for t, _ in parts])
        pairs[:, 1] = np.concatenate([o for _, o in parts])
        body = struct.pack("<HI", cid, pairs.size * 8) + pairs.tobytes()
        bio.write(b"\x07" + struct.pack("<Q", len(body)))
        bio.write(body)
    pending_index.clear()
    index = BytesIO()
    index.write(
        struct.pack("<QQQQ", chunk.message_start_time, chunk.message_end_time, chunk_start, chunk_end - chunk_start)
    )
    index.write(struct.pack("<I", len(offsets) * 10))
    for cid, off in offsets:
        index.write(struct.pack("<HQ", cid, off))
    index.write(struct.pack("<Q", bio.tell() - chunk_end))
    index.write(struct.pack("<I", len(comp)) + comp)
    index.write(struct.pack("<QQ", len(compressed), size))
    storage.chunks.append(index)
    storage.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))


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

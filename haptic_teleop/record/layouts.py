"""Fixed-layout message templates: the bag's message types, topics and their CDR byte layouts.

Building one message object per sample costs far more than a 1 kHz tick can afford, so a message
is serialized once (rosbags' typestore) with marker values, the byte offsets of its float64 and
stamp fields are found, and every sample is written into a copy of that template with numpy.
Reading uses the same layouts in reverse.
"""

from __future__ import annotations

import itertools
import operator
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.columns import (
    AXES,
    JOINT_STATE,
    MULTIARRAY,
    ONE_DOF,
    POSE,
    WRENCH,
    TickSchema,
    TopicColumns,
    tick_topics,
)
from haptic_teleop.record.nve_columns import TWIST, NveSchema, NveTopic, nve_topics

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


def make_joint_state(
    joints: str | Sequence[str], fields: Sequence[str], frame: str = ""
) -> Callable[[Sequence[float], int, int], Any]:
    """Message builder: values field by field (a subset of position, velocity, effort, in that
    order), one per joint within a field; header.frame_id `frame`."""
    ts = typestore()
    cls = ts.types[JOINT_STATE]
    names = [joints] if isinstance(joints, str) else list(joints)
    n = len(names)

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        arrays = {f: np.array(values[i * n : (i + 1) * n], dtype=np.float64) for i, f in enumerate(fields)}
        empty = np.array([], dtype=np.float64)
        return cls(
            header=_header(ts, sec, nsec, frame),
            name=list(names),
            position=arrays.get("position", empty),
            velocity=arrays.get("velocity", empty),
            effort=arrays.get("effort", empty),
        )

    return make


def _vector3(ts: Any, values: Sequence[float]) -> Any:
    v = [*values, 0.0, 0.0, 0.0]
    return ts.types["geometry_msgs/msg/Vector3"](x=v[0], y=v[1], z=v[2])


def make_wrench(frame: str, forces: int = 1, torques: int = 0) -> Callable[[Sequence[float], int, int], Any]:
    """Message builder: the first `forces` force components (x, y, z), then `torques` torque ones;
    the rest 0."""
    ts = typestore()
    t = ts.types

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        wrench = t["geometry_msgs/msg/Wrench"](
            force=_vector3(ts, values[:forces]), torque=_vector3(ts, values[forces : forces + torques])
        )
        return t[WRENCH](header=_header(ts, sec, nsec, frame), wrench=wrench)

    return make


def make_pose(frame: str, axes: int = 3) -> Callable[[Sequence[float], int, int], Any]:
    """Message builder: the first `axes` position components (x, y, z), the rest 0; orientation
    identity."""
    ts = typestore()
    t = ts.types

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        v = [*values[:axes], 0.0, 0.0, 0.0]
        pose = t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=v[0], y=v[1], z=v[2]),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        return t[POSE](header=_header(ts, sec, nsec, frame), pose=pose)

    return make


def make_twist(frame: str, axes: int = 3) -> Callable[[Sequence[float], int, int], Any]:
    """Message builder: the first `axes` linear velocity components (x, y, z), the rest 0; angular 0."""
    ts = typestore()
    t = ts.types

    def make(values: Sequence[float], sec: int, nsec: int) -> Any:
        twist = t["geometry_msgs/msg/Twist"](linear=_vector3(ts, values[:axes]), angular=_vector3(ts, ()))
        return t[TWIST](header=_header(ts, sec, nsec, frame), twist=twist)

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
    fields: tuple[str, ...]  # a name per value (TopicColumns.value_names)
    columns: tuple[int, ...] = ()  # the tick row's column of each value


def _layout(t: TopicColumns, schema: TickSchema) -> FixedLayout:
    n = len(t.columns(schema))
    if t.msgtype == JOINT_STATE:
        return FixedLayout(JOINT_STATE, make_joint_state(t.names, [f for f, _ in t.fields]), n)
    if t.msgtype == POSE:
        return FixedLayout(POSE, make_pose(t.frame, n), n)
    if t.msgtype == WRENCH:
        widths = [len(range(*schema.group(g).indices(schema.width))) for _, g in t.fields]
        return FixedLayout(WRENCH, make_wrench(t.frame, widths[0], sum(widths[1:])), n)
    return FixedLayout(MULTIARRAY, make_multiarray(t.names), n)


@lru_cache(maxsize=16)
def topic_specs(schema: TickSchema = ONE_DOF) -> dict[str, TopicSpec]:
    """The fixed-layout topics of a run with this tick schema (record/columns.py, `tick_topics`)."""
    return {
        t.topic: TopicSpec(t.topic, _layout(t, schema), t.value_names(schema), tuple(t.columns(schema)))
        for t in tick_topics(schema)
    }


def _nve_layout(t: NveTopic, n: int) -> FixedLayout:
    if t.msgtype == JOINT_STATE:
        return FixedLayout(JOINT_STATE, make_joint_state(t.names, [f for f, _ in t.fields]), n)
    if t.msgtype == POSE:
        return FixedLayout(POSE, make_pose(t.frame, n), n)
    if t.msgtype == TWIST:
        return FixedLayout(TWIST, make_twist(t.frame, n), n)
    if t.msgtype == WRENCH:
        return FixedLayout(WRENCH, make_wrench(t.frame, n, 0), n)
    return FixedLayout(MULTIARRAY, make_multiarray(t.names), n)


@lru_cache(maxsize=16)
def nve_topic_specs(schema: NveSchema) -> dict[str, TopicSpec]:
    """The fixed-layout topics of an NVE run with this schema (record/nve_columns.py, `nve_topics`)."""
    out = {}
    for t in nve_topics(schema):
        cols = t.columns(schema)
        out[t.topic] = TopicSpec(t.topic, _nve_layout(t, len(cols)), t.value_names(schema), tuple(cols))
    return out


# TDPA's samples carry the sender's observed input energy as a second joint of the sample's
# JointState, whose position is the energy in J (docs/stabilizers.md, "On the wire").
ENERGY_JOINT = "energy_in_j"


@lru_cache(maxsize=64)
def joint_state_size(floats: int, axes: int = 1, energy: bool = False) -> int:
    """CDR size in bytes of a packet's JointState: one name per task axis, `floats` of
    position/velocity/effort per axis; `energy`: with TDPA's second joint (ENERGY_JOINT)."""
    fields = ("position", "velocity", "effort")[:floats]
    names = [f"master_{a}" for a in AXES[:axes]] + ([ENERGY_JOINT] if energy else [])
    return FixedLayout(JOINT_STATE, make_joint_state(names, fields), floats * len(names)).size


def packet_rows(log: Sequence[Any] | np.ndarray) -> np.ndarray:
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


def multiarray_bytes(rows: np.ndarray) -> bytes:
    ts = typestore()
    t = ts.types
    dims = [
        t["std_msgs/msg/MultiArrayDimension"](label="packet", size=rows.shape[0], stride=rows.size),
        t["std_msgs/msg/MultiArrayDimension"](label=",".join(PACKET_FIELDS), size=rows.shape[1], stride=rows.shape[1]),
    ]
    msg = t[MULTIARRAY](layout=t["std_msgs/msg/MultiArrayLayout"](dim=dims, data_offset=0), data=rows.ravel())
    return bytes(ts.serialize_cdr(msg, MULTIARRAY))


@lru_cache(maxsize=8)
def packet_batch_head(n_rows: int) -> bytes:
    """The CDR bytes of a batch of `n_rows` packet records up to its data: rosbags serializes the
    batch once with zeros; the float64 data are the message's last bytes, so a batch is this head
    followed by its rows' bytes (a test holds it equal to `multiarray_bytes`)."""
    zeros = np.zeros((n_rows, len(PACKET_FIELDS)))
    raw = multiarray_bytes(zeros)
    head = raw[: len(raw) - zeros.nbytes]
    if raw[len(head) :] != zeros.tobytes():
        raise AssertionError("Float64MultiArray data are not the last bytes of its serialization")
    return head


def packet_batch_bytes(rows: np.ndarray) -> bytes:
    """`multiarray_bytes(rows)` for a (packets, len(PACKET_FIELDS)) float64 batch, without a message object."""
    return packet_batch_head(rows.shape[0]) + np.ascontiguousarray(rows, dtype="<f8").tobytes()


def string_bytes(text: str) -> bytes:
    ts = typestore()
    return bytes(ts.serialize_cdr(ts.types[STRING](data=text), STRING))

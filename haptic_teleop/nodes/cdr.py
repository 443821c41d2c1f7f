"""One-joint sensor_msgs/JointState as CDR bytes, written and read without rclpy's message objects.

rclpy turns each message into a Python object and back: here that costs about 16 us to publish
and 50 us to take one JointState, several times the rest of a node's 1 kHz tick (docs/live_measured.md,
"CPU per node"). The teleop topics have fixed layouts (bag.FixedLayout: one joint, a known subset
of position/velocity/effort), so a node patches the stamp and values into a serialized template
and publishes the bytes, and reads values at fixed offsets from raw bytes. A message of any other
layout (another joint name, more joints, another driver) is recognised as such and deserialized
the ordinary way, so nothing is misread.
"""

from __future__ import annotations

import operator
import struct
import typing
from collections.abc import Callable, Sequence
from typing import Any

_STAMP = struct.Struct("<iI")
_DOUBLE = struct.Struct("<d")

Decoded = tuple[int, tuple[float, ...]]  # (header.stamp in ns, values in the requested order)


def _getter(indices: Sequence[int]) -> Callable[[tuple[Any, ...]], tuple[Any, ...]]:
    """A function picking `indices` out of a tuple, always as a tuple."""
    if len(indices) == 1:
        i = indices[0]
        return lambda t: (t[i],)
    return typing.cast(Callable[[tuple[Any, ...]], tuple[Any, ...]], operator.itemgetter(*indices))


class JointStateCodec:
    """Encoder and layout check for a JointState of one joint (a name) or of several (a tuple of
    names: an arm's joints, a task's axes) with `fields` filled, values field by field, one per
    name within a field (record.layouts.make_joint_state)."""

    def __init__(self, joint: str | Sequence[str], fields: Sequence[str], frame: str = "") -> None:
        from haptic_teleop.record.layouts import JOINT_STATE, FixedLayout, make_joint_state

        names = (joint,) if isinstance(joint, str) else tuple(joint)
        self.names = names
        layout = FixedLayout(JOINT_STATE, make_joint_state(list(names), fields, frame), len(fields) * len(names))
        self.joint = joint
        self.fields = tuple(fields)
        self.size = layout.size
        self._template = bytes(layout.template)
        self._sec = layout.sec_offset
        self._offsets = tuple(layout.float_offsets)
        # The whole message as one struct: the stamp, the values, and everything else (the frame,
        # the joint name and the array lengths, i.e. what identifies this layout) as byte strings.
        # One unpack reads a message and tells whether it has this layout.
        variable = sorted([(self._sec, "stamp")] + [(o, j) for j, o in enumerate(self._offsets)])
        fmt, pos, n = "<", 0, 0
        fixed_idx: list[int] = []
        fixed_vals: list[bytes] = []
        value_idx: dict[int, int] = {}
        stamp_idx = 0
        for off, what in variable:
            if off > pos:
                fmt += f"{off - pos}s"
                fixed_idx.append(n)
                fixed_vals.append(self._template[pos:off])
                n += 1
            if what == "stamp":
                fmt += "iI"
                stamp_idx = n
                n += 2
            else:
                fmt += "d"
                value_idx[int(what)] = n
                n += 1
            pos = off + 8
        if pos < self.size:
            fmt += f"{self.size - pos}s"
            fixed_idx.append(n)
            fixed_vals.append(self._template[pos:])
        self._whole = struct.Struct(fmt)
        if self._whole.size != self.size:
            raise AssertionError(f"{joint}: the layout's struct covers {self._whole.size} of {self.size} bytes")
        self._identity = _getter(fixed_idx)
        self._identity_vals = tuple(fixed_vals)
        self._stamp_idx = stamp_idx
        self._value_idx = value_idx

    def encode(self, stamp_ns: int, values: Sequence[float]) -> bytes:
        buf = bytearray(self._template)
        _STAMP.pack_into(buf, self._sec, stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
        for off, v in zip(self._offsets, values, strict=True):
            _DOUBLE.pack_into(buf, off, v)
        return bytes(buf)

    def matches(self, raw: bytes) -> bool:
        return len(raw) == self.size and self._identity(self._whole.unpack(raw)) == self._identity_vals

    def reader(self, want: Sequence[str]) -> Callable[[bytes], Decoded] | None:
        """A function reading `want` (in that order) from bytes of this layout, or None if the layout
        does not carry all of them."""
        read = self._tuple_reader(want)
        if read is None:
            return None
        unpack = self._whole.unpack
        return lambda raw: read(unpack(raw))

    def _tuple_reader(self, want: Sequence[str]) -> Callable[[tuple[Any, ...]], Decoded] | None:
        """Like `reader`, on the message already unpacked by `self._whole`."""
        if any(f not in self.fields for f in want):
            return None
        n = len(self.names)
        values = _getter([self._value_idx[self.fields.index(f) * n + i] for f in want for i in range(n)])
        si = self._stamp_idx

        def read(t: tuple[Any, ...]) -> Decoded:
            return t[si] * 1_000_000_000 + t[si + 1], values(t)

        return read


class FixedCodec:
    """Encoder of a message type with a fixed layout (`bag.FixedLayout`: e.g. WrenchStamped with
    force.x, a labelled Float64MultiArray of n values): its serialized template with the stamp, if
    it has one, and the values patched in at fixed offsets."""

    def __init__(self, layout: Any) -> None:
        self.size = int(layout.size)
        self._template = bytes(layout.template)
        self._sec = int(layout.sec_offset)  # -1: no header
        self._offsets = tuple(int(o) for o in layout.float_offsets)
        # Runs of values stored back to back (a JointState's array, a Vector3, the data of a
        # multiarray): one pack per run, not per value (an arm's JointState has 18 values in 3 runs).
        runs: list[tuple[int, int, int]] = []  # (offset, first value, count)
        for i, off in enumerate(self._offsets):
            if runs and runs[-1][0] + 8 * runs[-1][2] == off:
                o, first, k = runs[-1]
                runs[-1] = (o, first, k + 1)
            else:
                runs.append((off, i, 1))
        self._runs = tuple((struct.Struct(f"<{k}d").pack_into, o, first, first + k) for o, first, k in runs)
        self._count = len(self._offsets)

    def encode(self, stamp_ns: int | None, values: Sequence[float]) -> bytes:
        buf = bytearray(self._template)
        if self._sec >= 0:
            if stamp_ns is None:
                raise ValueError("this message type has a header: a stamp is required")
            _STAMP.pack_into(buf, self._sec, stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
        if len(values) != self._count:
            raise ValueError(f"{self._count} values expected, got {len(values)}")
        for pack, off, a, b in self._runs:
            pack(buf, off, *values[a:b])
        return bytes(buf)


def wrench_codec(frame: str) -> FixedCodec:
    """geometry_msgs/WrenchStamped in `frame` carrying force.x (the rest zero)."""
    from haptic_teleop.record.layouts import WRENCH, FixedLayout, make_wrench

    return FixedCodec(FixedLayout(WRENCH, make_wrench(frame), 1))


def multiarray_codec(labels: Sequence[str]) -> FixedCodec:
    """std_msgs/Float64MultiArray of one value per label (dimensions of size 1, stride 1)."""
    from haptic_teleop.record.layouts import MULTIARRAY, FixedLayout, make_multiarray

    return FixedCodec(FixedLayout(MULTIARRAY, make_multiarray(labels), len(labels)))


# The due tag of a relayed sample (nodes/network_relay.py hands samples on ahead of the time the
# network delivers them; nodes/sync_buffer.py holds each until then): header.frame_id
# "due_ns=<19 digits>", the node clock's time of delivery. A message with an empty frame_id (the
# teleop topics' layouts) gets it spliced in: the frame's 1-byte string (length, NUL, 3 bytes of
# padding: offsets 12 to 19) becomes the 27-byte tag (length, 26 characters, NUL, 1 byte of
# padding: 12 to 43), so everything after it moves by 24 bytes, a multiple of 8, and every later
# field keeps its CDR alignment. Untagging restores the original bytes exactly.
DUE_PREFIX = b"due_ns="
DUE_DIGITS = 19
_EMPTY_FRAME = struct.pack("<I", 1) + b"\0\0\0\0"  # length 1, NUL, padding
_DUE_LEN = struct.pack("<I", len(DUE_PREFIX) + DUE_DIGITS + 1)
_DUE_AT = 16 + len(DUE_PREFIX)  # the digits
_DUE_END = _DUE_AT + DUE_DIGITS  # the NUL; then one byte of padding
_SHIFT = 24


def tag_due(raw: bytes, due_ns: int) -> bytes | None:
    """`raw` (a serialized message whose header.frame_id is empty) with frame_id the due tag of
    `due_ns` (>= 0), or None if its frame_id is not empty (the caller re-encodes it then)."""
    if raw[12:20] != _EMPTY_FRAME:
        return None
    return b"".join((raw[:12], _DUE_LEN, DUE_PREFIX, b"%019d" % due_ns, b"\0\0", raw[20:]))


def untag_due(raw: bytes) -> tuple[bytes, int | None]:
    """(the message without its due tag, the due time in ns) for a tagged message; (`raw`,
    None) for any other (a sample that did not come through a relay)."""
    if raw[12:16] != _DUE_LEN or raw[16:_DUE_AT] != DUE_PREFIX:
        return raw, None
    digits = raw[_DUE_AT:_DUE_END]
    if not digits.isdigit():
        return raw, None
    return raw[:12] + _EMPTY_FRAME + raw[20 + _SHIFT :], int(digits)


class JointStateReader:
    """Reads `want` values and the stamp from raw JointState bytes: fast for the `known` layouts
    ((joint or names, fields) pairs this topic's publishers use), by deserializing otherwise.
    `width`: values per field (the first `width` of each wanted array; an arm's payload has one
    per task axis). Raises IndexError when a message lacks a wanted value."""

    def __init__(
        self, want: Sequence[str], known: Sequence[tuple[str | Sequence[str], Sequence[str]]] = (), width: int = 1
    ) -> None:
        self.want = tuple(want)
        self.width = width
        # Per known layout: size, whole-message unpack, identity check, reader of the unpacked tuple.
        self._fast: list[tuple[int, Any, Any, tuple[bytes, ...], Callable[[tuple[Any, ...]], Decoded]]] = []
        for joint, fields in known:
            codec = JointStateCodec(joint, fields)
            read = codec._tuple_reader(self.want)
            if read is not None:
                self._fast.append((codec.size, codec._whole.unpack, codec._identity, codec._identity_vals, read))

    def __call__(self, raw: bytes) -> Decoded:
        n = len(raw)
        for size, unpack, identity, expected, read in self._fast:
            if n == size:
                t = unpack(raw)
                if identity(t) == expected:
                    return read(t)
        return self._slow(raw)

    def _slow(self, raw: bytes) -> Decoded:
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import JointState

        m: Any = deserialize_message(raw, JointState)
        stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
        w = self.width
        values = []
        for f in self.want:
            arr = getattr(m, f)
            if len(arr) < w:
                raise IndexError(f"{f}: {len(arr)} values, {w} wanted")
            values += [float(arr[i]) for i in range(w)]
        return stamp, tuple(values)

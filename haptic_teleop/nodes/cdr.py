"""One-joint sensor_msgs/JointState as CDR bytes, written and read without rclpy's message objects.

rclpy turns each message into a Python object and back: here that costs about 16 us to publish
and 50 us to take one JointState, several times the rest of a node's 1 kHz tick (docs/live.md,
"CPU per node"). The teleop topics have fixed layouts (bag.FixedLayout: one joint, a known subset
of position/velocity/effort), so a node patches the stamp and values into a serialized template
and publishes the bytes, and reads values at fixed offsets from raw bytes. A message of any other
layout (another joint name, more joints, another driver) is recognised as such and deserialized
the ordinary way, so nothing is misread.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from typing import Any

_STAMP = struct.Struct("<iI")
_DOUBLE = struct.Struct("<d")

Decoded = tuple[int, tuple[float, ...]]  # (header.stamp in ns, values in the requested order)


class JointStateCodec:
    """Encoder and layout check for a one-joint JointState with `fields` filled (one value each)."""

    def __init__(self, joint: str, fields: Sequence[str]) -> None:
        from haptic_teleop.bag import JOINT_STATE, FixedLayout, make_joint_state

        layout = FixedLayout(JOINT_STATE, make_joint_state(joint, fields), len(fields))
        self.joint = joint
        self.fields = tuple(fields)
        self.size = layout.size
        self._template = bytes(layout.template)
        self._sec = layout.sec_offset
        self._offsets = tuple(layout.float_offsets)
        # Everything but the stamp and the values: the frame, the joint name and the array lengths,
        # i.e. what identifies this layout.
        variable = sorted([(self._sec, self._sec + 8)] + [(o, o + 8) for o in self._offsets])
        fixed, pos = [], 0
        for a, b in variable:
            if a > pos:
                fixed.append((pos, a))
            pos = b
        if pos < self.size:
            fixed.append((pos, self.size))
        self._fixed = tuple((a, b, self._template[a:b]) for a, b in fixed)

    def encode(self, stamp_ns: int, values: Sequence[float]) -> bytes:
        buf = bytearray(self._template)
        _STAMP.pack_into(buf, self._sec, stamp_ns // 1_000_000_000, stamp_ns % 1_000_000_000)
        for off, v in zip(self._offsets, values, strict=True):
            _DOUBLE.pack_into(buf, off, v)
        return bytes(buf)

    def matches(self, raw: bytes) -> bool:
        return len(raw) == self.size and all(raw[a:b] == part for a, b, part in self._fixed)

    def reader(self, want: Sequence[str]) -> Callable[[bytes], Decoded] | None:
        """A function reading `want` (in that order) from bytes of this layout, or None if the layout
        does not carry all of them."""
        if any(f not in self.fields for f in want):
            return None
        offsets = [self._offsets[self.fields.index(f)] for f in want]
        sec_off = self._sec
        unpack_d = _DOUBLE.unpack_from
        unpack_stamp = _STAMP.unpack_from

        def read(raw: bytes) -> Decoded:
            sec, nsec = unpack_stamp(raw, sec_off)
            return sec * 1_000_000_000 + nsec, tuple(unpack_d(raw, o)[0] for o in offsets)

        return read


class JointStateReader:
    """Reads `want` values and the stamp from raw JointState bytes: fast for the `known` layouts
    ((joint, fields) pairs this topic's publishers use), by deserializing otherwise. Raises
    IndexError when a message lacks a wanted value."""

    def __init__(self, want: Sequence[str], known: Sequence[tuple[str, Sequence[str]]] = ()) -> None:
        self.want = tuple(want)
        self._fast: list[tuple[JointStateCodec, Callable[[bytes], Decoded]]] = []
        for joint, fields in known:
            codec = JointStateCodec(joint, fields)
            read = codec.reader(self.want)
            if read is not None:
                self._fast.append((codec, read))

    def __call__(self, raw: bytes) -> Decoded:
        for codec, read in self._fast:
            if codec.matches(raw):
                return read(raw)
        return self._slow(raw)

    def _slow(self, raw: bytes) -> Decoded:
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import JointState

        m: Any = deserialize_message(raw, JointState)
        stamp = int(m.header.stamp.sec) * 1_000_000_000 + int(m.header.stamp.nanosec)
        return stamp, tuple(float(getattr(m, f)[0]) for f in self.want)

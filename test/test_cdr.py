"""Live nodes' JointState bytes (nodes/cdr.py) against rclpy's own serialization."""

import pytest

pytest.importorskip("rclpy")
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from haptic_teleop.nodes.cdr import JointStateCodec, JointStateReader

STAMP_NS = 1_795_000_000_123_456_789


def test_encoded_bytes_deserialize_to_the_values_given():
    raw = JointStateCodec("slave_x", ("position", "velocity", "effort")).encode(STAMP_NS, (0.01, -0.2, -3.5))
    m = deserialize_message(raw, JointState)
    assert list(m.name) == ["slave_x"]
    assert (m.position[0], m.velocity[0], m.effort[0]) == (0.01, -0.2, -3.5)
    assert m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec == STAMP_NS
    raw2 = JointStateCodec("master_x", ("position", "velocity")).encode(STAMP_NS, (1.0, 2.0))
    m2 = deserialize_message(raw2, JointState)
    assert (m2.position[0], m2.velocity[0], len(m2.effort)) == (1.0, 2.0, 0)


def test_reader_returns_the_wanted_fields_in_the_wanted_order():
    raw = JointStateCodec("slave_x", ("position", "velocity", "effort")).encode(STAMP_NS, (0.01, -0.2, -3.5))
    read = JointStateReader(("effort", "position", "velocity"), [("slave_x", ("position", "velocity", "effort"))])
    assert read(raw) == (STAMP_NS, (-3.5, 0.01, -0.2))


def test_other_layouts_are_deserialized_not_misread():
    read = JointStateReader(("effort", "position"), [("slave_x", ("position", "velocity", "effort"))])
    other = JointState()
    other.name = ["joint_a"]  # another driver's name: the fixed layout must not match
    other.position, other.velocity, other.effort = [1.0], [2.0], [3.0]
    other.header.stamp.sec, other.header.stamp.nanosec = 7, 5
    assert read(serialize_message(other)) == (7_000_000_005, (3.0, 1.0))
    # Same joint and the same byte count, values in other arrays: read by field, not by offset.
    shifted = JointState()
    shifted.name = ["slave_x"]
    shifted.position, shifted.velocity, shifted.effort = [], [1.0, 2.0], [3.0]
    with pytest.raises(IndexError):  # it has no position
        read(serialize_message(shifted))
    missing = JointState()
    missing.name = ["slave_x"]
    missing.position = [1.0]
    with pytest.raises(IndexError):
        read(serialize_message(missing))

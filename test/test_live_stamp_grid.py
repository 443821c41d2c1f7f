"""Deliveries on the stamp grid (docs/live_network.md, "Deliveries on the stamp grid"): the relay hands a
sample on ahead of its delivery with its due time in header.frame_id, the sync buffer pushes it at
its due tick and says what it released at which of its own ticks, and the recorder keys the bag
by those ticks; a sample that comes too late for its tick is counted as late by scheduling.

The node tests drive real nodes (rclpy, DDS on localhost) by calling their handlers with times
chosen here (their loops are not started), so what they decide is fixed by their code, not by this
machine's timing.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

P_NS = 1_000_000
START_NS = 1_795_000_000_000_000_000  # a node clock time on the tick grid


def _wait(cond, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


@pytest.mark.parametrize("names", ["master_x", ("slave_x", "slave_y", "slave_z")])
def test_due_tag_is_a_frame_id_that_keeps_every_other_field_and_comes_off_exactly(names):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import JointState

    from haptic_teleop.nodes.cdr import JointStateCodec, tag_due, untag_due

    n = 1 if isinstance(names, str) else len(names)
    codec = JointStateCodec(names, ("position", "velocity"))
    values = [0.1 * (i + 1) for i in range(2 * n)]
    raw = codec.encode(START_NS + 7 * P_NS, values)
    due = START_NS + 57 * P_NS + 123
    tagged = tag_due(raw, due)
    assert tagged is not None
    m = deserialize_message(tagged, JointState)  # rclpy's own reader: still a valid JointState
    assert m.header.frame_id == f"due_ns={due}"
    assert m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec == START_NS + 7 * P_NS
    assert list(m.position) + list(m.velocity) == values
    assert list(m.name) == ([names] if n == 1 else list(names))
    # The same bytes as the message serialized with that frame from the start.
    assert tagged == JointStateCodec(names, ("position", "velocity"), frame=f"due_ns={due}").encode(
        START_NS + 7 * P_NS, values
    )
    assert untag_due(tagged) == (raw, due)
    assert untag_due(raw) == (raw, None)  # a sample that did not come through a relay
    # A message with a frame of its own is not tagged in place (the relay re-encodes it).
    m.header.frame_id = "base"
    assert tag_due(serialize_message(m), due) is None


def _node(context, cls, name: str, **params):
    from rclpy.parameter import Parameter

    values = {"direction": "forward", "scene.period_s": P_NS * 1e-9, **params}
    return cls(context=context, node_name=name, parameter_overrides=[Parameter(k, value=v) for k, v in values.items()])


def _raw_reader(context, topic: str):
    from sensor_msgs.msg import JointState

    from haptic_teleop.nodes.messages import _polled_group_class
    from haptic_teleop.nodes.topics import READER_DEPTH, stream_qos

    node = rclpy.create_node("test_reader", context=context)
    sub = node.create_subscription(JointState, topic, lambda m: None, stream_qos(READER_DEPTH), raw=True,
                                   callback_group=_polled_group_class()())  # fmt: skip
    return node, sub


@pytest.mark.parametrize("lookahead_s", [0.02, 0.0])
def test_relay_hands_a_sample_on_ahead_of_its_delivery_tagged_with_its_due_time(context, lookahead_s):
    """Delay 10 ms: with a lookahead of 20 ms the sample goes out as it comes, tagged with stamp +
    10 ms (node clock) and otherwise the very bytes that were sent; with lookahead 0 it stays in
    flight until its delivery."""
    from haptic_teleop.nodes.cdr import JointStateCodec, untag_due
    from haptic_teleop.nodes.messages import take_all
    from haptic_teleop.nodes.network_relay import NetworkRelay

    relay = _node(context, NetworkRelay, "test_relay", scene_start="first_sample", lookahead_s=lookahead_s,
                  **{"network.forward.effects.delay.delay_s": 0.01})  # fmt: skip
    reader, sub = _raw_reader(context, "/forward/delivered")
    try:
        _wait(lambda: relay._rebuild._pub.get_subscription_count() > 0)
        raw = JointStateCodec("master_x", ("position", "velocity")).encode(START_NS, (0.25, -0.5))
        relay._on_sent(raw, START_NS + P_NS // 4)
        if lookahead_s == 0.0:
            assert relay.link.in_flight == 1 and relay.delivered == 0
            return
        assert relay.link.in_flight == 0 and relay.delivered == 1
        got: list[bytes] = []
        _wait(lambda: bool(got.extend(take_all(sub)) or got))
        assert untag_due(got[0]) == (raw, START_NS + 10 * P_NS)
    finally:
        reader.destroy_node()
        relay.destroy_node()


def test_sync_buffer_pushes_a_tagged_sample_at_its_due_tick_and_counts_one_past_it(context):
    """Three samples reach the buffer early: two held until their due ticks (105, 106), released
    there and reported as released at those ticks; one whose due tick (90) has passed is counted as
    late by scheduling. The playout rows say [seq, fate, tick, arrived]."""
    from haptic_teleop.core.link import DELIVERED
    from haptic_teleop.nodes.cdr import JointStateCodec, tag_due
    from haptic_teleop.nodes.messages import JointStateOut
    from haptic_teleop.nodes.sync_buffer import PLAYOUT_FIELDS, SyncBuffer

    assert PLAYOUT_FIELDS == ("seq", "fate", "tick", "arrived")
    buf = _node(context, SyncBuffer, "test_buffer", **{"network.forward.buffer.policy": "none"})
    pub_node = rclpy.create_node("test_relay_side", context=context)
    out = JointStateOut(pub_node, "/forward/delivered", "master_x", ("position", "velocity"))
    try:
        _wait(lambda: out._pub.get_subscription_count() > 0)
        codec = JointStateCodec("master_x", ("position", "velocity"))
        tick0 = START_NS // P_NS
        for seq, due_tick in ((100, 105), (101, 106), (99, 90)):
            out.publish_raw(tag_due(codec.encode((tick0 + seq) * P_NS, (seq * 1.0, 0.0)), (tick0 + due_tick) * P_NS))
        early: list[bytes] = []

        def all_taken() -> bool:  # at tick 104: the two due later held, the one due at 90 out at once
            early.extend(buf._due((tick0 + 104) * P_NS))
            return len(buf._held) == 2 and len(early) == 1

        _wait(all_taken)
        assert buf.late_by_scheduling == 1 and len(buf._held) == 2
        buf.tick(1, (tick0 + 105) * P_NS)
        buf.tick(2, (tick0 + 106) * P_NS)
        assert buf.released == 2
        rows = np.asarray(buf._decided).reshape(-1, len(PLAYOUT_FIELDS)) - [tick0, 0, tick0, tick0]
        assert rows.tolist() == [[100, DELIVERED, 105, 105], [101, DELIVERED, 106, 106]]
    finally:
        pub_node.destroy_node()
        buf.destroy_node()


def test_a_record_taken_late_by_scheduling_gets_the_time_it_was_taken_as_its_arrival():
    from haptic_teleop.nodes.recorder_grid import as_delivered
    from haptic_teleop.record.layouts import PACKET_FIELDS

    f = {name: i for i, name in enumerate(PACKET_FIELDS)}
    start = 1000
    rows = np.array(
        [  # seq, send, arrival, fate, duplicate, size (scene)
            [1, 0.001, 0.0512, 0, 0, 60],  # due at tick 52, taken at 52: on time
            [2, 0.002, 0.0520, 0, 0, 60],  # due at 52, taken at 54: late by scheduling
            [3, 0.003, 0.0530, 4, 0, 60],  # due at 53, taken at 55 and then skipped: moved too
            [4, 0.004, 0.0540, 0, 0, 60],  # taken at 70: after the recording's end (60), left as sent
        ]
    )
    arrived = {start + 1: start + 52, start + 2: start + 54, start + 3: start + 55, start + 4: start + 70}
    assert as_delivered(rows, arrived, start, start + 60, P_NS, f) == 2
    assert np.allclose(rows[:, f["arrival_time_s"]], [0.0512, 0.054, 0.055, 0.054], rtol=0, atol=1e-12)

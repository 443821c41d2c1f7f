"""The network relay runs its link in scene time, as the engine does: node clock - scene time 0.

A real NetworkRelay node (rclpy, DDS on localhost) whose input handler is called directly with
samples and arrival times chosen here (its loop is not started), so what it decides is fixed by
its code, not by this machine's timing. The node clock is a wall-clock epoch time, as live.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")

P_NS = 1_000_000  # 1 kHz
START_NS = 1_795_000_000_000_000_000  # scene time 0 on the node clock (on the tick grid)
PHASE_NS = 250_000  # a sample reaches the relay a quarter period after its stamp
BLACKOUT = (0.003, 0.005)  # scene time: the samples of ticks 3 and 4 are sent inside it
DELAY_S = 0.002


def _relay(context, **params):
    from rclpy.parameter import Parameter

    from haptic_teleop.nodes.network_relay import NetworkRelay

    values = {
        "direction": "forward",
        "scene.period_s": P_NS * 1e-9,
        "network.forward.effects.blackout.starts_s": [BLACKOUT[0]],
        "network.forward.effects.blackout.ends_s": [BLACKOUT[1]],
        "network.forward.effects.delay.delay_s": DELAY_S,
        **params,
    }
    overrides = [Parameter(k, value=v) for k, v in values.items()]
    return NetworkRelay(context=context, node_name="test_relay", parameter_overrides=overrides)


def _send(relay, tick: int) -> None:
    """The master's sample of scene tick `tick` reaching the relay."""
    from haptic_teleop.nodes.cdr import JointStateCodec

    stamp = START_NS + tick * P_NS
    raw = JointStateCodec("master_x", ("position", "velocity")).encode(stamp, (0.001 * tick, 0.0))
    relay._on_sent(raw, stamp + PHASE_NS)


def _wait(cond, timeout_s: float = 10.0) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.01)


def _records(context, relay) -> np.ndarray:
    """The packet records the relay publishes on /forward/packets (bag row layout), by seq."""
    from std_msgs.msg import Float64MultiArray

    from haptic_teleop.nodes.messages import _polled_group_class, take_all
    from haptic_teleop.nodes.topics import reliable_qos

    node = rclpy.create_node("test_packets", context=context)
    sub = node.create_subscription(Float64MultiArray, "/forward/packets", lambda m: None, reliable_qos(100),
                                   callback_group=_polled_group_class()())  # fmt: skip
    _wait(lambda: relay._packets_pub.get_subscription_count() > 0)
    relay.publish_packets()
    got: list = []
    _wait(lambda: bool(got.extend(take_all(sub)) or got))
    rows = np.concatenate([np.asarray(m.data).reshape(-1, 6) for m in got])
    node.destroy_node()
    return rows[np.argsort(rows[:, 0])]


def test_link_runs_in_scene_time_from_the_scene_start_topic(context):
    """Samples before scene time 0 go through the settling link (the delay, no blackout) and are
    not recorded; two of scene time >= 0 beat the start message (settling link too, recorded in
    scene time); from then on the scene's link decides, in scene time: the blackout [3, 5) ms
    loses exactly the samples of ticks 3 and 4, the others arrive 2 ms after they were sent."""
    from std_msgs.msg import Header

    from haptic_teleop.core.link import DELIVERED, LOST_NETWORK
    from haptic_teleop.nodes.topics import SCENE_START_TOPIC, latched_qos

    relay = _relay(context)
    try:
        for tick in (-3, -2, -1, 0, 1):  # the start message is not out yet
            _send(relay, tick)
        assert relay.scene_start_ns is None and relay.settling.sent == 5 and relay.link.sent == 0
        op = rclpy.create_node("test_operator", context=context)
        pub = op.create_publisher(Header, SCENE_START_TOPIC, latched_qos())
        h = Header(frame_id="scene_time_0")
        h.stamp.sec, h.stamp.nanosec = divmod(START_NS + 123, 1_000_000_000)  # off the grid: floored
        pub.publish(h)

        def learnt() -> bool:
            relay.tick(1, 0)  # not a batch tick: the records stay for _records
            return relay.scene_start_ns is not None

        _wait(learnt)
        assert relay.scene_start_ns == START_NS
        for tick in range(2, 8):
            _send(relay, tick)
        assert relay.settled == 2 and relay.link.sent == 6 and relay.link.lost == 2
        rows = _records(context, relay)
        op.destroy_node()
    finally:
        relay.destroy_node()
    seq = rows[:, 0].astype(np.int64) - START_NS // P_NS
    assert seq.tolist() == list(range(8))  # nothing before scene time 0
    send = rows[:, 1]
    # Sent at its stamp (scene seconds): it came within a period of it, the relay's scheduling aside.
    assert np.allclose(send, seq * P_NS * 1e-9, rtol=0, atol=1e-12)
    assert relay.late_to_relay == 0
    inside = (send >= BLACKOUT[0]) & (send < BLACKOUT[1])
    assert seq[inside].tolist() == [3, 4]
    assert np.all(rows[inside, 3] == LOST_NETWORK) and np.all(rows[~inside, 3] == DELIVERED)
    assert np.allclose(rows[~inside, 2], send[~inside] + DELAY_S, rtol=0, atol=1e-12)
    assert np.all(np.isnan(rows[inside, 2]))


def test_first_sample_mode_starts_scene_time_at_the_first_sample(context):
    """`scene_start: first_sample` (a node set without an operator source): scene time 0 is the
    first sample's stamp, so the blackout [3, 5) ms loses the 4th and 5th samples."""
    from haptic_teleop.core.link import LOST_NETWORK

    relay = _relay(context, scene_start="first_sample")
    try:
        for tick in range(10, 18):
            _send(relay, tick)
        assert relay.scene_start_ns == START_NS + 10 * P_NS
        rows = _records(context, relay)
    finally:
        relay.destroy_node()
    lost = rows[rows[:, 3] == LOST_NETWORK, 0].astype(np.int64) - START_NS // P_NS
    assert lost.tolist() == [13, 14] and rows.shape[0] == 8
    assert rows[0, 1] == 0.0  # the first sample: sent at its stamp, scene time 0


def test_a_sample_is_sent_at_its_stamp_and_one_that_comes_after_its_due_tick_is_counted(context):
    """Deliveries on the stamp grid: a sample is sent at its stamp whatever the scheduling between
    its sender and the relay, so it is due at stamp + delay; one that reaches the relay after the
    tick it is due at (the machine too slow) is counted apart from the network's effects
    (`late_to_relay`), its record keeping the network's times."""
    from haptic_teleop.nodes.cdr import JointStateCodec

    relay = _relay(context, scene_start="first_sample", **{"network.forward.effects.blackout.starts_s": [1.0],
                   "network.forward.effects.blackout.ends_s": [1.1]})  # fmt: skip
    try:
        codec = JointStateCodec("master_x", ("position", "velocity"))
        due = round(DELAY_S * 1e9)
        # tick 2 comes in its due tick (stamp + 2 ms + 0.999 ms), tick 3 in the tick after it
        for tick, late_ns in ((0, 0), (1, P_NS - 1), (2, due + P_NS - 1), (3, due + P_NS + 7)):
            stamp = START_NS + tick * P_NS
            relay._on_sent(codec.encode(stamp, (0.0, 0.0)), stamp + late_ns)
        assert relay.late_to_relay == 1
        rows = _records(context, relay)
    finally:
        relay.destroy_node()
    send_ns = np.round(rows[:, 1] * 1e9).astype(np.int64)
    assert send_ns.tolist() == [0, P_NS, 2 * P_NS, 3 * P_NS]
    assert np.allclose(rows[:, 2] - rows[:, 1], DELAY_S, rtol=0, atol=1e-12)  # the link's own delay


def test_bad_scene_start_mode_is_a_parameter_error(context):
    from haptic_teleop.errors import ConfigError

    with pytest.raises(ConfigError, match="scene_start"):
        _relay(context, scene_start="later")


def test_settling_effects_drop_the_time_dependent_parts():
    """The settling link: no blackout; a time-varying delay held at its value at scene time 0."""
    from haptic_teleop.core.netconfig import (
        BlackoutConfig,
        DelayConfig,
        DelayScheduleConfig,
        DelaySinusoidConfig,
        LossConfig,
        NetworkEffectsConfig,
    )
    from haptic_teleop.nodes.network_relay import settling_effects

    schedule = DelayScheduleConfig(times_s=(0.5, 1.0), delays_s=(0.03, 0.1))
    cfg = NetworkEffectsConfig(
        blackout=BlackoutConfig(starts_s=(0.3,), ends_s=(0.5,)),
        loss=LossConfig(probability=0.1),
        delay=DelayConfig(delay_s=0.02, jitter_s=0.001, schedule=schedule),
    )
    s = settling_effects(cfg)
    assert s.blackout is None and s.loss == cfg.loss
    assert s.delay == DelayConfig(delay_s=pytest.approx(0.05), jitter_s=0.001)  # 0.02 + the schedule at 0
    sine = DelayConfig(delay_s=0.0, sinusoid=DelaySinusoidConfig(min_delay_s=0.01, max_delay_s=0.03, period_s=2.0))
    assert settling_effects(NetworkEffectsConfig(delay=sine)).delay.delay_s == pytest.approx(0.01)  # min at t = 0

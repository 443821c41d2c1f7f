"""Messages of the live nodes: CDR publish of raw bytes, the fixed-layout writers of the messages
the nodes send (`JointStateOut`, `WrenchOut`, `EbaOut`) and the polled take helpers."""

from __future__ import annotations

import typing
from collections.abc import Callable, Sequence
from typing import Any

from haptic_teleop.nodes.topics import EBA_LABELS, stream_qos

# ---------------------------------------------------------------------------------------------
# Messages.


def stamp_ns_of(msg: Any) -> int:
    s = msg.header.stamp
    return int(s.sec) * 1_000_000_000 + int(s.nanosec)


def raw_publish_fn(pub: Any) -> Callable[[bytes], None]:
    """Publish serialized bytes on `pub`, one call into rclpy's C++ publisher.

    `Publisher.publish` wraps each call in a context manager on the handle (which defers the
    handle's destruction while in use) and a type check: three calls through pybind11 where one
    does, about half the cost of a publish in these loops (measured with callgrind, docs/live_measured.md).
    Safe as the nodes use it: only a node's loop publishes this way, and run_nodes destroys a node
    only once its loop has stopped."""
    return typing.cast(Callable[[bytes], None], pub.handle.publish_raw)


class JointStateOut:
    """Publishes a sensor_msgs/JointState of one joint (or of several names: `joint` a tuple) as
    CDR bytes patched into a template (nodes/cdr.py): no message object per tick."""

    def __init__(
        self, node: Any, topic: str, joint: str | Sequence[str], fields: Sequence[str], qos: Any = None
    ) -> None:
        from sensor_msgs.msg import JointState

        from haptic_teleop.nodes.cdr import JointStateCodec

        self.fields = tuple(fields)
        self.joint = joint
        self._encode = JointStateCodec(joint, fields).encode
        self._pub = node.create_publisher(JointState, topic, qos if qos is not None else stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, stamp_ns: int, values: Sequence[float]) -> None:
        self._send(self._encode(stamp_ns, values))

    def encode(self, stamp_ns: int, values: Sequence[float]) -> bytes:
        """The bytes `publish` would send."""
        return self._encode(stamp_ns, values)

    def publish_raw(self, raw: bytes) -> None:
        """Bytes of a JointState as they came (a relay forwarding a message unchanged)."""
        self._send(raw)


class WrenchOut:
    """Publishes geometry_msgs/WrenchStamped with force.x as CDR bytes (nodes/cdr.py)."""

    def __init__(self, node: Any, topic: str, frame: str, qos: Any = None) -> None:
        from geometry_msgs.msg import WrenchStamped

        from haptic_teleop.nodes.cdr import wrench_codec

        self._encode = wrench_codec(frame).encode
        self._pub = node.create_publisher(WrenchStamped, topic, qos if qos is not None else stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, stamp_ns: int, force_x: float) -> None:
        self._send(self._encode(stamp_ns, (force_x,)))


class SpecOut:
    """Publishes one per-tick topic of a run's tick schema (`record.layouts.topic_specs`: the
    bag's own fixed layout, so joint names, frames and labels are the bag's) as CDR bytes; the
    values in the layout's order (JointState field by field, one per name; PoseStamped position;
    WrenchStamped force then torque; Float64MultiArray its labels)."""

    def __init__(self, node: Any, spec: Any, qos: Any = None) -> None:
        import importlib

        from haptic_teleop.nodes.cdr import FixedCodec

        pkg, _, cls = spec.layout.msgtype.split("/")
        msg_type = getattr(importlib.import_module(f"{pkg}.msg"), cls)
        self.topic = spec.name
        self.spec = spec
        self.width = spec.layout.nfloats
        self._encode = FixedCodec(spec.layout).encode
        self._pub = node.create_publisher(msg_type, spec.name, qos if qos is not None else stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, stamp_ns: int | None, values: Sequence[float]) -> None:
        self._send(self._encode(stamp_ns, values))


class EbaOut:
    """Publishes [reservoir_j, force_desired_n] as std_msgs/Float64MultiArray CDR bytes (the bag's
    layout, nodes/cdr.py)."""

    def __init__(self, node: Any, topic: str) -> None:
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.nodes.cdr import multiarray_codec

        self._encode = multiarray_codec(EBA_LABELS).encode
        self._pub = node.create_publisher(Float64MultiArray, topic, stream_qos())
        self._send = raw_publish_fn(self._pub)

    def publish(self, reservoir_j: float, force_desired_n: float) -> None:
        self._send(self._encode(None, (reservoir_j, force_desired_n)))


def _polled_group_class() -> type:
    from rclpy.callback_groups import CallbackGroup

    class PolledGroup(CallbackGroup):
        """Entities the executor never waits on nor runs: the node's loop thread takes them.

        An executor wakes for every message of every subscription it holds; at 1 kHz that costs
        several times what taking the message from the loop does (docs/live.md)."""

        def can_execute(self, entity: Any) -> bool:
            return False

        def beginning_execution(self, entity: Any) -> bool:
            return False

        def ending_execution(self, entity: Any) -> None:
            return None

    return PolledGroup


def _taken(sub: Any) -> list[tuple[Any, dict[str, Any]]]:
    """Every message waiting in a polled subscription's history with its message info, oldest
    first (what rclpy's executor and wait_for_message do: rclpy has no public take call).

    Called on the C++ subscription directly, without rclpy's context manager on the handle (two
    more calls through pybind11 per poll): only the node's loop takes, and run_nodes destroys a
    node only once its loop has stopped (raw_publish_fn)."""
    out = []
    take = sub.handle.take_message
    msg_type, raw = sub.msg_type, sub.raw
    while True:
        r = take(msg_type, raw)
        if r is None:
            return out
        out.append(r)


def take_all(sub: Any) -> list[Any]:
    """Every waiting message of a polled subscription, oldest first."""
    return [m for m, _ in _taken(sub)]


def take_all_published_ns(sub: Any, times: list[int], msgs: list[Any]) -> int:
    """Append every waiting message of a polled subscription to `msgs`, oldest first, and the time
    its publisher wrote it (DDS source timestamp, system clock, ns) to `times`; returns how many."""
    got = _taken(sub)
    for m, info in got:
        times.append(int(info["source_timestamp"]))
        msgs.append(m)
    return len(got)


def take_latest(sub: Any) -> Any:
    """The newest waiting message of a polled subscription, or None. A keep-last-1 reader holds at
    most one: one take, not a second one to find the history empty."""
    take = sub.handle.take_message
    msg_type, raw = sub.msg_type, sub.raw
    r = take(msg_type, raw)
    if r is None:
        return None
    if getattr(sub, "holds_one", False):
        return r[0]
    while True:
        nxt = take(msg_type, raw)
        if nxt is None:
            return r[0]
        r = nxt


# At close, the longest wait for a reliable publisher's last messages to be acknowledged by its
# readers (the recorder). A reliable message lost on its first send is sent again only while its
# writer lives: a node that exits at once loses it (on a busy machine a relay published 49 batches
# of packet records and the recorder got none). Twice per node at most, well within the launcher's
# STOP_TIMEOUT_S (a reader killed by SIGKILL never acknowledges: its writers wait all of it).
FINAL_ACK_S = 4.0


def wait_acknowledged(pub: Any, timeout_s: float = FINAL_ACK_S) -> bool:
    """Wait until every matched reader of `pub` acknowledged what it published (at most
    `timeout_s`); whether they did."""
    from rclpy.duration import Duration

    return bool(pub.wait_for_all_acked(Duration(nanoseconds=round(timeout_s * 1e9))))

"""network_relay: one direction of the network, the core `Link` driven by the node clock.

Each sample arriving on /<direction>/sent goes through `Link.send` at once (time: the node clock
in integer ns, seq: its stamp / period), and everything the link says has arrived is published on
/<direction>/delivered: right away from the callback (so a link with no delay adds only the
relay's own cost), and otherwise from a 1 kHz loop on the absolute tick grid. Both run in the
loop thread, which waits for input and for its next deadline at once (no executor in the path). The delivered
message is the very message that was sent (stamp and values unchanged). The fate of every packet
goes out in batches on /<direction>/packets (reliable), in the bag's row layout.
"""

from __future__ import annotations

import array
from typing import Any

from haptic_teleop.core.network import Packet
from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.common import (
    DIRECTION_JOINT,
    DIRECTIONS,
    PAYLOAD_FIELDS,
    READER_DEPTH,
    WIRE_FIELDS,
    JointStateOut,
    LiveNode,
    declare_scene,
    declare_value,
    delivered_topic,
    node_main,
    packets_topic,
    reliable_qos,
    sent_topic,
    stream_qos,
)

# Sent messages are kept for re-publication this long (in ticks); an older delivery (a delay
# beyond it) is rebuilt from the packet's payload instead.
_KEEP_TICKS = 30_000


def declare_direction_scene(node: LiveNode, executable: str) -> tuple[str, Any]:
    """The node's `direction` parameter and the scene sections `executable` reads for it."""
    d = str(
        declare_value(
            node, "direction", "forward", "forward: master to slave; backward: slave to master", choices=DIRECTIONS
        )
    )
    return d, declare_scene(node, [s.format(direction=d) for s in SCENE_SECTIONS[executable]], ("direction",))


class NetworkRelay(LiveNode):
    default_name = "network_relay"
    loop_phase = 0.25  # after the producers' tick (LiveNode.loop_phase)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        from haptic_teleop.core.network import build_link
        from haptic_teleop.record.layouts import joint_state_size

        d, cfg = declare_direction_scene(self, "network_relay")
        self.direction = d
        period_ns = round(cfg.scene.period_s * 1e9)
        self.link = build_link(getattr(cfg.network, d).effects, cfg.scene.seed, d)
        self._fields = PAYLOAD_FIELDS[d]
        self._read = JointStateReader(self._fields, [(DIRECTION_JOINT[d], WIRE_FIELDS[d])])
        self._size = joint_state_size(3 if d == "backward" else 2)
        self._msgs: dict[int, Any] = {}
        self._newest = 0
        self.delivered = 0
        self.malformed = 0
        # Forwards the sent bytes; rebuilds a message whose original is no longer kept.
        self._rebuild = JointStateOut(self, delivered_topic(d), DIRECTION_JOINT[d], WIRE_FIELDS[d])
        self._packets_pub = self.create_publisher(Float64MultiArray, packets_topic(d), reliable_qos(100))
        self.add_event_subscription(JointState, sent_topic(d), stream_qos(READER_DEPTH), self._on_sent, raw=True)
        # Packet fates go out ten times a second: small batches, no long tick.
        self._batch_ticks = max(1, round(0.1e9 / period_ns))
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"{d}: {sent_topic(d)} -> {delivered_topic(d)}, effects: {[e.name for e in self.link.effects]}"
        )

    def _on_sent(self, msg: bytes, now: int) -> None:
        """`msg`: the sent JointState's bytes, forwarded unchanged when the network delivers it."""
        try:
            stamp, payload = self._read(msg)
        except IndexError:  # not this direction's layout: drop it, say so once
            if not self.malformed:
                self.get_logger().warning(f"dropping messages without {self._fields} values")
            self.malformed += 1
            return
        seq = stamp // self.period_ns
        self._msgs[seq] = msg
        self._newest = max(self._newest, seq)
        self.link.send(Packet(seq, now, payload, self._size))
        out = self.link.deliver(now)
        if out:
            self._publish(out)

    def _publish(self, packets: list[Any]) -> None:
        msgs = self._msgs
        for p in packets:
            m = msgs.get(p.seq)
            if m is not None:
                self._rebuild.publish_raw(m)
            else:
                values = dict(zip(self._fields, p.payload, strict=True))
                self._rebuild.publish(p.seq * self.period_ns, [values[f] for f in self._rebuild.fields])
        self.delivered += len(packets)

    def tick(self, index: int, stamp_ns: int) -> None:
        if self.link.in_flight:
            out = self.link.deliver(self.now_ns())
            if out:
                self._publish(out)
        if index % self._batch_ticks == 0:
            self.publish_packets()

    def publish_packets(self) -> None:
        """Fates of the packets sent since the last batch (bag.py's packet rows)."""
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        from haptic_teleop.record.layouts import PACKET_BATCH, PACKET_FIELDS, packet_rows

        log = list(self.link.log)
        self.link.log.clear()
        horizon = self._newest - _KEEP_TICKS
        if len(self._msgs) > _KEEP_TICKS:
            for seq in [s for s in self._msgs if s < horizon]:
                del self._msgs[seq]
        if not log:
            return
        rows = packet_rows(log)
        for start in range(0, rows.shape[0], PACKET_BATCH):
            chunk = rows[start : start + PACKET_BATCH]
            msg = Float64MultiArray()
            msg.layout.dim = [
                MultiArrayDimension(label="packet", size=chunk.shape[0], stride=chunk.size),
                MultiArrayDimension(label=",".join(PACKET_FIELDS), size=chunk.shape[1], stride=chunk.shape[1]),
            ]
            msg.data = array.array("d", chunk.ravel().tobytes())
            self._packets_pub.publish(msg)

    def diagnostic_values(self) -> dict[str, float | int | str]:
        return {
            "sent": self.link.sent,
            "lost": self.link.lost,
            "delivered": self.delivered,
            "in_flight": self.link.in_flight,
        }

    def close(self) -> None:
        super().close()
        self.publish_packets()


def main() -> None:
    node_main(NetworkRelay)


if __name__ == "__main__":
    main()

"""network_relay: one direction of the network, the core `Link` run in scene time.

The link runs in scene time, as the engine's does: the time given to it is the node clock minus
scene time 0, the stamp the operator source publishes (latched) on /haptic_teleop/scene_start
(`scene_start_ns`, the definition the recorder uses too). So every time-dependent effect
(blackout windows, a delay schedule or sinusoid, a delay trace) is defined in scene time, from 0
at the scene start, exactly as in `haptic-teleop run`. Parameter `scene_start`: `topic` (the
default) waits for that message; `first_sample` takes the first sample's stamp instead, for a
node set without an operator source (the hardware variant).

Each sample arriving on /<direction>/sent goes through `Link.send` at once (time: its arrival
here in scene time, integer ns; seq: its stamp / period), and everything the link says has
arrived is published on /<direction>/delivered: right away from the callback (so a link with no
delay adds only the relay's own cost), and otherwise from a 1 kHz loop on the absolute tick grid.
Both run in the loop thread, which waits for input and for its next deadline at once (no executor
in the path). The delivered message is the very message that was sent (stamp and values unchanged).

Samples stamped before scene time 0 (the graph settling before the operator starts; the engine
has no such phase) and samples that arrive while the scene start is not known yet are forwarded at
once, unshaped, outside the link: its effects and random draws start with the packet of scene
time 0, as the engine's. A sample of scene time >= 0 can beat the scene start message here (they
travel on different topics): it was forwarded unshaped, and once the start is known it gets a
packet record saying so (delivered, arrival = send time) and is counted (`unshaped`).

The fate of every packet of scene time >= 0 goes out in batches on /<direction>/packets
(reliable), in the bag's row layout (`record.layouts.packet_rows`): seq = the sample's stamp /
period (the node clock's tick, which the sync buffers' decisions name too; the recorder
subtracts the scene start's), send and arrival times in scene seconds (the link's own).
"""

from __future__ import annotations

import array
from collections import deque
from collections.abc import Sequence
from typing import Any

from haptic_teleop.core.network import DELIVERED, Packet
from haptic_teleop.nodes import RELAY_SCENE_STARTS, SCENE_SECTIONS
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.common import (
    DIRECTION_JOINT,
    DIRECTIONS,
    PAYLOAD_FIELDS,
    READER_DEPTH,
    SCENE_START_TOPIC,
    WIRE_FIELDS,
    JointStateOut,
    LiveNode,
    declare_scene,
    declare_value,
    delivered_topic,
    latched_qos,
    node_main,
    packets_topic,
    reliable_qos,
    scene_start_ns,
    sent_topic,
    stream_qos,
    take_all,
)

# Sent messages are kept for re-publication this long (in ticks); an older delivery (a delay
# beyond it) is rebuilt from the packet's payload instead.
_KEEP_TICKS = 30_000
# Samples forwarded before the scene start was known, kept (seq, arrival ns) to find those of scene
# time >= 0 among them once it is: the newest ones, so a second's worth is plenty.
_EARLY_KEPT = 1000


def declare_direction_scene(node: LiveNode, executable: str, extra_names: Sequence[str] = ()) -> tuple[str, Any]:
    """The node's `direction` parameter and the scene sections `executable` reads for it
    (`extra_names`: the node's other own parameters)."""
    d = str(
        declare_value(
            node, "direction", "forward", "forward: master to slave; backward: slave to master", choices=DIRECTIONS
        )
    )
    sections = [s.format(direction=d) for s in SCENE_SECTIONS[executable]]
    return d, declare_scene(node, sections, ("direction", *extra_names))


class NetworkRelay(LiveNode):
    default_name = "network_relay"
    loop_phase = 0.25  # after the producers' tick (LiveNode.loop_phase)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray, Header

        from haptic_teleop.core.network import build_link
        from haptic_teleop.record.layouts import joint_state_size

        d, cfg = declare_direction_scene(self, "network_relay", ("scene_start",))
        self.direction = d
        self.start_mode = str(
            declare_value(
                self, "scene_start", "topic",
                f"scene time 0 of the link: topic (the stamp on {SCENE_START_TOPIC}) or first_sample "
                "(the first sample's stamp; for a node set without an operator source)",
                choices=RELAY_SCENE_STARTS,
            )
        )  # fmt: skip
        self.scene_start_ns: int | None = None  # node clock of scene time 0, once known
        self._start_sub = (
            self.create_polled_subscription(Header, SCENE_START_TOPIC, latched_qos())
            if self.start_mode == "topic"
            else None
        )
        self._early: deque[tuple[int, int]] = deque(maxlen=_EARLY_KEPT)
        self._unshaped: list[Packet] = []  # records of unshaped samples of scene time >= 0, not published yet
        self.passed = 0  # samples forwarded unshaped (before scene time 0, or before it was known)
        self.unshaped = 0  # of those, samples of scene time >= 0
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
        start = self.scene_start_ns
        if start is None:
            start = self._learn_start(seq)
        if start is None or seq * self.period_ns < start:
            # Before scene time 0, or not known yet: forwarded at once, outside the link.
            self._rebuild.publish_raw(msg)
            self.passed += 1
            if start is None:
                self._early.append((seq, now))
            return
        self._msgs[seq] = msg
        self._newest = max(self._newest, seq)
        t = now - start
        self.link.send(Packet(seq, t, payload, self._size))
        out = self.link.deliver(t)
        if out:
            self._publish(out)

    def _learn_start(self, seq: int | None = None) -> int | None:
        """Scene time 0 on the node clock, if it can be known now (`seq`: the sample in hand)."""
        if self._start_sub is not None:
            told = take_all(self._start_sub)
            if not told:
                return None
            start = scene_start_ns(told[-1], self.period_ns)
        elif seq is not None:  # first_sample
            start = seq * self.period_ns
        else:
            return None
        self.scene_start_ns = start
        # Samples of scene time >= 0 that came before the start message: forwarded unshaped.
        for s, arrived in self._early:
            if s * self.period_ns >= start:
                t = arrived - start
                self._unshaped.append(Packet(s, t, (), self._size, t, DELIVERED))
        self.unshaped += len(self._unshaped)
        self._early.clear()
        note = ""
        if self.unshaped:
            note = f"; samples of scene time >= 0 that came before it, forwarded unshaped: {self.unshaped}"
        self.get_logger().info(f"scene time 0 at stamp {start} ns: the link runs from there{note}")
        return start

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
        start = self.scene_start_ns
        if start is None:
            self._learn_start()
        elif self.link.in_flight:
            out = self.link.deliver(self.now_ns() - start)
            if out:
                self._publish(out)
        if index % self._batch_ticks == 0:
            self.publish_packets()

    def publish_packets(self) -> None:
        """Fates of the packets sent since the last batch (bag.py's packet rows)."""
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        from haptic_teleop.record.layouts import PACKET_BATCH, PACKET_FIELDS, packet_rows

        log = self._unshaped + self.link.log
        self._unshaped = []
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
            "scene_started": int(self.scene_start_ns is not None),
            "passed_unshaped": self.passed,
            "unshaped_in_scene": self.unshaped,
        }

    def close(self) -> None:
        super().close()
        self.publish_packets()


def main() -> None:
    node_main(NetworkRelay)


if __name__ == "__main__":
    main()

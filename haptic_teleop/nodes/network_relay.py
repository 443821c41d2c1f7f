"""network_relay: one direction of the network, the core `Link` run in scene time.

The link runs in scene time, as the engine's does: the time given to it is the node clock minus
scene time 0, the stamp the operator source publishes (latched) on /haptic_teleop/scene_start
(`scene_start_ns`, the definition the recorder uses too). So every time-dependent effect
(blackout windows, a delay schedule or sinusoid, a delay trace) is defined in scene time, from 0
at the scene start, exactly as in `haptic-teleop run`. Parameter `scene_start`: `topic` (the
default) waits for that message; `first_sample` takes the first sample's stamp instead, for a
node set without an operator source (the hardware variant).

Each sample arriving on /<direction>/sent goes through `Link.send` at once (seq: its stamp /
period; time: its stamp in scene time, integer ns, as the engine's link sends a sample at its
tick, so a sample of stamp s on a link of delay d is due at s + d whatever the scheduling between
its sender and here; one that reaches the relay after the tick it is due at, the machine too slow,
is handed on at once and counted as late by scheduling, `late_to_relay`, apart from the
network's own effects, its packet record keeping the network's times; a codec's packets, whose
retransmissions share a seq, are sent at their arrival), and
everything the link says will have arrived within `lookahead_s` (parameter, default
LOOKAHEAD_S = 20 ms) is published on /<direction>/delivered: right away from the callback (so a
link with no delay adds only the relay's own cost), and otherwise from a 1 kHz loop on the
absolute tick grid. A sample handed on ahead of its delivery carries the time the network
delivers it, its due time on the node clock, in header.frame_id ("due_ns=<ns>", nodes/cdr.py
`tag_due`), and the sync buffer holds it until then (nodes/sync_buffer.py): so the hop from relay
to buffer, a DDS message between two loops, has lookahead_s of room for the machine's scheduling
rather than the quarter period between their phases, and a sample is pushed into the buffer at
its due tick, as in the engine (docs/live_network.md, "Deliveries on the stamp grid"). lookahead_s 0
hands each sample on at its delivery, untagged; a codec's packets and acknowledgements are always
handed on so (their decoder takes each packet as it comes).
Both run in the loop thread, which waits for input and for its next deadline at once (no executor
in the path). The delivered message is the very message that was sent (stamp and values
unchanged; the due tag in its frame_id, which was empty, is the only addition).

Before scene time 0 (the graph settling for the operator's `start.delay_s`; the engine has no
such phase) samples go through a second link, the settling link: the scene's effects without
their time-dependent parts (no blackout; a time-varying delay held at its value at scene time 0;
`settling_effects`), on the node clock, with random streams of its own. So the sync buffers and
the watchdogs settle on the delay, jitter, loss and rate the scene starts with, and the scene's
link starts fresh at scene time 0 (its effects and random draws from the packet of scene time 0
on, as the engine's). Its packets are not recorded, and those in flight at scene time 0 are still
delivered. A sample of scene time >= 0 that reaches the relay before the scene start message does
(they travel on different topics) goes through the settling link too; once the start is known it
gets a packet record with the settling link's decision, in scene time, and is counted
(`settled_in_scene`).

The fate of every packet of scene time >= 0 goes out in batches on /<direction>/packets
(reliable), in the bag's row layout (`record.layouts.packet_rows`): seq = the sample's stamp /
period (the node clock's tick, which the sync buffers' decisions name too; the recorder
subtracts the scene start's), send and arrival times in scene seconds (the link's own).

Parameter `carries` (docs/live_network.md, "Codecs live"): `samples` (the default) relays the direction's
plain samples; `codec` its codec's packets (nodes/codec_stage.py's wire message: each packet
relayed as its own message, retransmissions of one seq included, size the engine's
`message_bytes`); `ack` the acknowledgements of the direction's codec (ARQ): from
/<direction>/ack/sent to /<direction>/ack/delivered over the reverse direction's effects (the scene
sections it reads are the reverse direction's), random streams "<direction>:ack" as the engine's ACK
link, not recorded (the engine counts acknowledgements, it does not record them).
"""

from __future__ import annotations

import array
import dataclasses
from collections.abc import Sequence
from typing import Any

from haptic_teleop.core.link import DELIVERED, Packet, taken_tick
from haptic_teleop.core.netconfig import NetworkEffectsConfig
from haptic_teleop.errors import ConfigError
from haptic_teleop.nodes import NVE_SCENE_SECTIONS, RELAY_SCENE_STARTS, SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.cdr import JointStateReader, tag_due
from haptic_teleop.nodes.messages import JointStateOut, take_all
from haptic_teleop.nodes.params import declare_scene, declare_value
from haptic_teleop.nodes.topics import (
    READER_DEPTH,
    SCENE_START_TOPIC,
    TASK_AXES_PARAM,
    delivered_topic,
    latched_qos,
    packets_topic,
    reliable_qos,
    scene_start_ns,
    sent_topic,
    stream_qos,
)
from haptic_teleop.nodes.wire import direction_problem, nve_direction, scene_law, wire_of

# Sent messages are kept for re-publication this long (in ticks); an older delivery (a delay
# beyond it) is rebuilt from the packet's payload instead.
_KEEP_TICKS = 30_000
# How far ahead of its delivery a sample is handed on (parameter lookahead_s), tagged with its due
# time: room for the relay-to-buffer hop's scheduling jitter.
LOOKAHEAD_S = 0.02
# Records of the settling link kept while the scene start is not known, to find those of scene time
# >= 0 among them once it is: the newest ones, so a second's worth is plenty.
_EARLY_KEPT = 1000


def settling_effects(cfg: NetworkEffectsConfig) -> NetworkEffectsConfig:
    """The effects of the settling link (before scene time 0): `cfg` without its time-dependent
    parts. No blackout; a delay schedule, sinusoid or trace is replaced by its value at scene time
    0, added to the constant delay. What is left depends on no absolute time (the token bucket and
    the jitter use differences and counts only)."""
    from haptic_teleop.core.delay import PiecewiseDelay, SinusoidDelay
    from haptic_teleop.scene.traces import load_delay_trace

    delay = cfg.delay
    if delay is not None:
        extra_s = 0.0
        if delay.schedule is not None:
            sc = delay.schedule
            extra_s = PiecewiseDelay(sc.times_s, sc.delays_s, sc.interpolation)(0) * 1e-9
        elif delay.sinusoid is not None:
            w = delay.sinusoid
            extra_s = SinusoidDelay(w.min_delay_s, w.max_delay_s, w.period_s, w.phase_s)(0) * 1e-9
        elif delay.trace is not None:
            ts, ds = load_delay_trace(delay.trace.file)
            extra_s = PiecewiseDelay(ts.tolist(), ds.tolist(), delay.trace.interpolation)(0) * 1e-9
        delay = dataclasses.replace(delay, delay_s=delay.delay_s + extra_s, schedule=None, sinusoid=None, trace=None)
    return dataclasses.replace(cfg, blackout=None, delay=delay)


def declare_task_axes(node: LiveNode) -> int:
    """The node's `task_axes` parameter: values per payload field (1: a one-axis scene; 3: an arm
    scene, one per axis of the task, or a 3-axis NVE scene; the launcher sets it from the scene)."""
    return int(
        declare_value(
            node, TASK_AXES_PARAM, 1, "values per payload field: 1 (one-axis scene) or 3 (arm or NVE scene: x, y, z)",
            1, 3,
        )
    )  # fmt: skip


def declare_direction_scene(
    node: LiveNode, executable: str, extra_names: Sequence[str] = (), sections_of: str | None = None
) -> tuple[str, Any]:
    """The node's `direction` parameter and the scene sections `executable` reads for it
    (`extra_names`: the node's other own parameters; `sections_of`: "reverse" reads the reverse
    direction's sections, an ack relay's). A direction is teleoperation's `forward` or
    `backward`, or an NVE client's `<client>/up` or `<client>/down`."""
    d = str(
        declare_value(
            node, "direction", "forward",
            "forward: master to slave; backward: slave to master; <client>/up, <client>/down: an NVE client's link",
        )
    )  # fmt: skip
    problem = direction_problem(d)
    if problem is not None:
        raise ConfigError(f"parameters of node {node.get_name()}", "direction", d, problem)
    nd = nve_direction(d)
    if sections_of == "reverse" and nd is not None:
        raise ConfigError(
            f"parameters of node {node.get_name()}", "direction", d,
            "acknowledgements are relayed for teleoperation's codecs only; allowed: forward or backward",
        )  # fmt: skip
    if nd is None:
        of = {"forward": "backward", "backward": "forward"}[d] if sections_of == "reverse" else d
        sections = [s.format(direction=of) for s in SCENE_SECTIONS[executable]]
    else:
        sections = [s.format(client=nd[0], link=nd[1]) for s in NVE_SCENE_SECTIONS[executable]]
    return d, declare_scene(node, sections, ("direction", *extra_names))


def direction_config(cfg: Any, direction: str) -> Any:
    """The scene's DirectionConfig (effects, buffer) of a direction."""
    nd = nve_direction(direction)
    if nd is None:
        return getattr(cfg.network, direction)
    client = next(c for c in cfg.nve.clients if c.name == nd[0])
    return getattr(client, nd[1])


class NetworkRelay(LiveNode):
    default_name = "network_relay"
    loop_phase = 0.25  # after the producers' tick (LiveNode.loop_phase)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray, Header

        from haptic_teleop.nodes.codec_stage import RELAY_CARRIES, ack_delivered_topic, ack_sent_topic
        from haptic_teleop.scene.traces import build_scene_link

        self.carries = str(
            declare_value(
                self, "carries", "samples",
                "samples: the direction's plain samples; codec: its codec's packets; ack: its codec's "
                "acknowledgements, over the reverse direction's effects",
                choices=RELAY_CARRIES,
            )
        )  # fmt: skip
        ack = self.carries == "ack"
        own = ("scene_start", TASK_AXES_PARAM, "carries", "lookahead_s")
        d, cfg = declare_direction_scene(self, "network_relay", own, "reverse" if ack else None)
        self.direction = d
        axes = declare_task_axes(self)
        self.start_mode = str(
            declare_value(
                self, "scene_start", "topic",
                f"scene time 0 of the link: topic (the stamp on {SCENE_START_TOPIC}) or first_sample "
                "(the first sample's stamp; for a node set without an operator source)",
                choices=RELAY_SCENE_STARTS,
            )
        )  # fmt: skip
        lookahead = float(
            declare_value(
                self, "lookahead_s", LOOKAHEAD_S,
                "hand samples on this long before the network delivers them, tagged with their due time "
                "(the sync buffer holds them until then); 0: at their delivery, untagged",
                0.0, 1.0,
            )
        )  # fmt: skip
        self.scene_start_ns: int | None = None  # node clock of scene time 0, once known
        self._start_sub = (
            self.create_polled_subscription(Header, SCENE_START_TOPIC, latched_qos())
            if self.start_mode == "topic"
            else None
        )
        self._settled: list[Packet] = []  # settling link records of scene time >= 0, not published yet
        self.settled = 0  # samples of scene time >= 0 that went through the settling link
        period_ns = round(cfg.scene.period_s * 1e9)
        self.codec_wire: Any = None
        if self.carries != "samples":
            if nve_direction(d) is not None:
                raise ConfigError(
                    f"parameters of node {self.get_name()}", "carries", self.carries,
                    "codec packets and acknowledgements are relayed for teleoperation's directions only; "
                    "allowed: samples",
                )  # fmt: skip
            from haptic_teleop.nodes.codec_stage import CodecWire, direction_wire

            # task_axes 3: an arm scene's codec message (nodes/codec_stage.py); the acknowledgements
            # (ARQ's) take the plain codec message, the data packets their codec's
            arm = axes == 3
            self.codec_wire = CodecWire(arm) if self.carries == "ack" else direction_wire(cfg, d, arm)
        # The link's random streams are named by the direction: "forward", "backward" as the
        # engine's; "<client>/up", "<client>/down" as the NVE engine's (assembly.nve.build_direction);
        # an ack relay's "<direction>:ack" as the engine's ACK link (assembly/channel.py), over
        # the reverse direction's effects.
        stream = f"{d}:ack" if ack else d
        rev = {"forward": "backward", "backward": "forward"}
        effects = direction_config(cfg, rev[d] if ack else d).effects
        self.link = build_scene_link(effects, cfg.scene.seed, stream)  # scene time, from 0
        self.settling = build_scene_link(settling_effects(effects), cfg.scene.seed, f"{stream}:settling")  # node clock
        in_topic = ack_sent_topic(d) if ack else sent_topic(d)
        out_topic = ack_delivered_topic(d) if ack else delivered_topic(d)
        self.wire = w = wire_of(d, axes, scene_law(cfg, axes))
        self._fields = w.want
        self._read = JointStateReader(w.want, [(w.names, w.fields)], w.width)
        self._remap = w.payload if w.maps else None  # None: the read values are the payload
        self._size = w.packet_bytes()
        self._msgs: dict[int, Any] = {}
        self._newest = 0
        self.delivered = 0
        self.malformed = 0
        self.late_to_relay = 0  # samples that came after the tick they were due at
        # Forwards the sent bytes; rebuilds a message whose original is no longer kept.
        self._rebuild = JointStateOut(
            self, out_topic, w.names, w.fields, stream_qos(READER_DEPTH) if self.codec_wire is not None else None
        )
        self._axes = axes
        self._packets_pub = (
            None if ack else self.create_publisher(Float64MultiArray, packets_topic(d), reliable_qos(100))
        )
        self.add_event_subscription(JointState, in_topic, stream_qos(READER_DEPTH), self._on_sent, raw=True)
        # Packet fates go out ten times a second: small batches, no long tick.
        self._batch_ticks = max(1, round(0.1e9 / period_ns))
        # Codec packets and acknowledgements go on at their delivery: their decoder takes them as they come.
        self.lookahead_ns = round(lookahead * 1e9) if self.codec_wire is None else 0
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"{d} ({self.carries}): {in_topic} -> {out_topic}, effects: {[e.name for e in self.link.effects]}"
        )

    def _on_sent(self, msg: bytes, now: int) -> None:
        """`msg`: the sent JointState's bytes, forwarded unchanged when the network delivers it."""
        size = self._size
        try:
            if self.codec_wire is not None:
                stamp, payload = self.codec_wire.decode(msg)
                size = self.codec_wire.size_of(payload)
            else:
                stamp, payload = self._read(msg)
        except (IndexError, ValueError):  # not this direction's layout: drop it, say so once
            if not self.malformed:
                what = "codec messages" if self.codec_wire is not None else f"{self._fields} values"
                self.get_logger().warning(f"dropping messages that are not {what}")
            self.malformed += 1
            return
        if self._remap is not None:
            payload = self._remap(payload)
        seq = stamp // self.period_ns
        if self.codec_wire is None:  # a codec's packets are rebuilt from the link's copy (retransmissions share a seq)
            self._msgs[seq] = msg
        self._newest = max(self._newest, seq)
        start = self.scene_start_ns
        if start is None:
            start = self._learn_start(seq)
        sent = now if self.codec_wire is not None else seq * self.period_ns
        ahead = now + self.lookahead_ns
        if start is None or seq * self.period_ns < start:  # before scene time 0, or not known yet
            p = Packet(seq, sent, payload, size)
            self.settling.send(p)
            self._count_late(p, 0, now)
            out = self.settling.deliver(ahead)
            if out:
                self._publish(out, 0, scene=False)
            return
        p = Packet(seq, sent - start, payload, size)
        self.link.send(p)
        self._count_late(p, start, now)
        out = self.link.deliver(ahead - start)
        if out:
            self._publish(out, start)

    def _count_late(self, p: Packet, offset_ns: int, now: int) -> None:
        """Count `p` (just sent) in `late_to_relay` if the tick it is due at (the first at or after
        its arrival, `offset_ns` the node clock's time of the link's time 0) is before the tick of
        `now`: the relay got it too late to hand it on in time."""
        if self.codec_wire is None and p.fate == DELIVERED:
            period = self.period_ns
            if taken_tick(p.arrival_time_ns + offset_ns, period) < now // period:
                self.late_to_relay += 1

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
        self._take_settled()
        note = ""
        if self.settled:
            note = f"; samples of scene time >= 0 that came before it, through the settling link: {self.settled}"
        self.get_logger().info(f"scene time 0 at stamp {start} ns: the scene's link runs from there{note}")
        return start

    def _take_settled(self) -> None:
        """Move the settling link's records of scene time >= 0 (in scene time) to `_settled`; drop
        the others (before scene time 0: not recorded)."""
        log = self.settling.log
        start = self.scene_start_ns
        if start is None:  # not known yet: keep the newest, the only ones that can be >= 0
            del log[:-_EARLY_KEPT]
            return
        period = self.period_ns
        for p in log:
            if p.seq * period >= start:
                self._settled.append(
                    dataclasses.replace(
                        p, send_time_ns=p.send_time_ns - start, arrival_time_ns=p.arrival_time_ns - start
                    )
                )
                self.settled += not p.duplicate
        log.clear()

    def _publish(self, packets: list[Any], offset_ns: int, scene: bool = True) -> None:
        """Hand `packets` on (`offset_ns`: the node clock's time of the link's time 0, for their due
        tags)."""
        msgs = self._msgs
        wire = self.codec_wire
        period = self.period_ns
        tag = self.lookahead_ns > 0
        for p in packets:
            if wire is not None:
                self._rebuild.publish_raw(wire.encode(p.seq * period, p.payload))
                continue
            m = msgs.get(p.seq)
            if m is None:
                m = self._rebuild.encode(p.seq * period, self.wire.values(p.payload))
            if tag:
                due = p.arrival_time_ns + offset_ns
                tagged = tag_due(m, due)
                if tagged is None:  # the sender's frame_id was not empty: the payload re-encoded
                    tagged = tag_due(self._rebuild.encode(p.seq * period, self.wire.values(p.payload)), due)
                m = tagged
            self._rebuild.publish_raw(m)
        if scene:
            self.delivered += len(packets)

    def tick(self, index: int, stamp_ns: int) -> None:
        start = self.scene_start_ns
        if start is None:
            start = self._learn_start()
        ahead = self.now_ns() + self.lookahead_ns
        if self.settling.in_flight:  # before scene time 0, and still in flight after it
            out = self.settling.deliver(ahead)
            if out:
                self._publish(out, 0, scene=False)
        if start is not None and self.link.in_flight:
            out = self.link.deliver(ahead - start)
            if out:
                self._publish(out, start)
        if index % self._batch_ticks == 0:
            self.publish_packets()

    def publish_packets(self) -> None:
        """Fates of the packets sent since the last batch (record/layouts.py's packet rows)."""
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        from haptic_teleop.record.layouts import PACKET_BATCH, PACKET_FIELDS, packet_rows

        self._take_settled()
        log = self._settled + self.link.log
        self._settled = []
        self.link.log.clear()
        horizon = self._newest - _KEEP_TICKS
        if len(self._msgs) > _KEEP_TICKS:
            for seq in [s for s in self._msgs if s < horizon]:
                del self._msgs[seq]
        if not log or self._packets_pub is None:  # an ack relay's packets are not recorded
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
            "settling_sent": self.settling.sent,
            "settled_in_scene": self.settled,
            "late_to_relay": self.late_to_relay,
        }

    def close(self) -> None:
        from haptic_teleop.nodes.messages import wait_acknowledged

        super().close()
        self.publish_packets()
        if self._packets_pub is not None:  # the recorder has every batch before this writer goes
            wait_acknowledged(self._packets_pub)


def main() -> None:
    node_main(NetworkRelay)


if __name__ == "__main__":
    main()

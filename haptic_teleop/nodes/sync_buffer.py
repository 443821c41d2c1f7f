"""sync_buffer: the receiving side's haptic synchronization (playout) buffer, the core
`PlayoutBuffer` the scene names, driven by the node clock.

Once per tick on the absolute grid, what is due from /<direction>/delivered is pushed with the
tick's time as arrival time (as the engine does; seq = stamp / period, send time = the sender's
stamp), then the buffer's release decides which sample the controller uses, and that sample goes
out on /<direction>/received with the sender's stamp (made-up samples of `gap: extrapolate` carry
the stamp of the slot they fill). A relay hands samples on ahead of their delivery, each tagged
with its due time (nodes/network_relay.py, `lookahead_s`): such a sample waits here until the
first tick at or after its due time, so it is pushed at the tick the engine would push it
whatever the scheduling of the hop between the two nodes. A sample that reaches this node after
its due tick (the relay, the hop or this loop ran late by more than the lookahead) is pushed at the
tick it is taken and counted in `late_by_scheduling` (the launcher's loop table: "late by
scheduling"), as is a sample held past a tick this loop skipped:
lateness of this machine, not of the network. An untagged sample (a relay with lookahead_s 0, or
a real network with no relay) is pushed at the tick it is taken.

What the buffer did goes out on /<direction>/playout (reliable, batched ten times a second,
std_msgs/Float64MultiArray, rows [seq, fate, tick, arrived], PLAYOUT_FIELDS; ticks are the node
clock's tick indices):
- a decision on a packet: fate 0 played, 4 late (arrived but skipped, the engine's LOST_LATE), and
  `arrived` the tick it was pushed into the buffer (for a codec: given to its decoder) at;
- a release: `tick` the buffer's tick (node clock tick index) at which sample `seq` went out on
  /<direction>/received, -1 in rows that are no release; a release that decides no packet (a
  made-up sample, a codec's decoder output) has fate NO_FATE (-1);
- the batch's last row, seq -1: every release up to tick `tick` is in this batch or before it.
The recorder applies the decisions to the relay's packet records, so a live bag counts late packets
as the engine's does, gives a record whose packet was pushed a tick or more after the network
delivered it (late by scheduling) the time it was pushed as its arrival (the delays in the bag and
the summary are then as delivered), and fills the bag's release column (`fwd_rx_seq`, ...) from the releases,
keyed by the buffer's own tick: one release per tick, none lost however late the message that
carried it was taken.

A direction whose scene names a codec (`network.<direction>.codec`; docs/live_network.md, "Codecs live")
runs its decoder here instead of the playout buffer (the scene has `buffer.policy: none`): every
packet delivered goes to the decoder at once (nodes/codec_stage.py's CodecReceiver), its decision
"played" (fate 0) to /<direction>/playout, and each tick the decoder's sample for the tick goes out
on /<direction>/received in the plain sample's layout (the receiving controller is unchanged),
stamped with the newest arrival's seq when one newer than any before came this tick (a release
row) and with stamp 0 otherwise (the bag's release column then holds -1, as the engine's).
"""

from __future__ import annotations

import array
import heapq
from typing import Any

from haptic_teleop.core.link import DELIVERED, LOST_LATE, Packet, taken_tick
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.cdr import JointStateReader, untag_due
from haptic_teleop.nodes.messages import JointStateOut, take_all
from haptic_teleop.nodes.network_relay import declare_direction_scene, declare_task_axes, direction_config
from haptic_teleop.nodes.topics import (
    READER_DEPTH,
    TASK_AXES_PARAM,
    delivered_topic,
    playout_topic,
    received_topic,
    reliable_qos,
    stream_qos,
)
from haptic_teleop.nodes.wire import nve_direction, scene_law, wire_of

PLAYOUT_FIELDS = ("seq", "fate", "tick", "arrived")
NO_FATE = -1  # a release row that decides no packet; tick -1: a row that is no release
_MAX_PENDING = 100_000


class SyncBuffer(LiveNode):
    default_name = "sync_buffer"
    loop_phase = 0.5  # after the producers' tick (LiveNode.loop_phase)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState

        from haptic_teleop.core.playout_config import build_buffer

        d, cfg = declare_direction_scene(self, "sync_buffer", (TASK_AXES_PARAM,))
        self.direction = d
        axes = declare_task_axes(self)
        period_ns = round(cfg.scene.period_s * 1e9)
        self.buffer = build_buffer(direction_config(cfg, d).buffer, period_ns)
        if not cfg.is_nve:
            from haptic_teleop.assembly.parts import configure_network_adaptive

            configure_network_adaptive(self.buffer, cfg, d)  # network_adaptive: d0, D_a, L_a from the scene
        self.wire = w = wire_of(d, axes, scene_law(cfg, axes))
        self._fields = w.want
        out_fields = w.fields
        # payload -> JointState order (an arm payload is in the wire's order, one value per axis;
        # an NVE or TDPA payload is mapped by its wire, nodes/wire.py)
        self._fields_order = (
            [self._fields.index(f) for f in out_fields] if axes == 1 else list(range(len(out_fields) * axes))
        )
        self._to_wire = w.values if w.maps else None
        self._remap = w.payload if w.maps else None
        self.released = 0
        self.out = JointStateOut(self, received_topic(d), w.names, out_fields)
        self._read = JointStateReader(self._fields, [(w.names, out_fields)], w.width)
        self._sub = self.create_polled_subscription(JointState, delivered_topic(d), stream_qos(READER_DEPTH), raw=True)
        # Decisions: packets pushed and not decided yet (seq -> packet), and the decisions not
        # published yet (seq, fate pairs, flat).
        from std_msgs.msg import Float64MultiArray

        self._pending: dict[int, Packet] = {}
        self._decided = array.array("d")  # rows [seq, fate, tick, arrived], flat (PLAYOUT_FIELDS)
        self._held: list[tuple[int, int, bytes]] = []  # tagged samples not due yet: (due ns, order, bytes)
        self._arrivals = 0
        self.late_by_scheduling = 0  # samples taken after their due tick
        self._tick = -1  # the last tick run (node clock tick index)
        self._late_seen = 0
        self._dup_seen = 0
        self._fates_pub = self.create_publisher(Float64MultiArray, playout_topic(d), reliable_qos(100))
        self._batch_ticks = max(1, round(0.1e9 / period_ns))
        self.codec: Any = None
        if nve_direction(d) is None and direction_config(cfg, d).codec is not None:
            from haptic_teleop.nodes.codec_stage import CodecReceiver

            self.codec = CodecReceiver(self, d, cfg, arm=axes == 3)
        self.setup_loop(period_ns)
        policy = direction_config(cfg, d).buffer.policy
        what = f"codec {self.codec.kind}" if self.codec is not None else f"policy {policy}"
        self.get_logger().info(f"{d}: {delivered_topic(d)} -> {received_topic(d)}, {what}")

    def _codec_tick(self, index: int, stamp_ns: int) -> None:
        decided = self._decided

        def arrived(seq: int) -> None:
            decided.extend((seq, DELIVERED, -1, tick))

        self._tick = tick = stamp_ns // self.period_ns
        out, rx = self.codec.tick(take_all(self._sub), stamp_ns, arrived)
        if out is not None:
            self.out.publish(rx * self.period_ns if rx >= 0 else 0, [out[i] for i in self._fields_order])
            self.released += 1
            if rx >= 0:
                decided.extend((rx, NO_FATE, tick, -1))
        if index % self._batch_ticks == 0:
            self.publish_fates()

    def _due(self, now: int) -> list[bytes]:
        """The samples to push at the tick of time `now`: those taken now and due by now (untagged
        ones are due when taken), and those held that are due by now, in order of due time."""
        held = self._held
        period = self.period_ns
        for tagged in take_all(self._sub):
            raw, due = untag_due(tagged)
            if due is None:
                due = now
            elif taken_tick(due, period) * period < now:  # its due tick has passed: late by scheduling
                self.late_by_scheduling += 1
                due = now
            self._arrivals += 1
            heapq.heappush(held, (due, self._arrivals, raw))
        out = []
        while held and held[0][0] <= now:
            due, _, raw = heapq.heappop(held)
            if taken_tick(due, period) * period < now:  # held past its tick: this loop skipped that tick
                self.late_by_scheduling += 1
            out.append(raw)
        return out

    def tick(self, index: int, stamp_ns: int) -> None:
        if self.codec is not None:
            self._codec_tick(index, stamp_ns)
            return
        # The tick's grid stamp, not the clock's reading when this (maybe late) tick runs: the
        # engine's buffer takes arrivals and releases at its tick's time, and so does this one.
        now = stamp_ns
        period, read, push = self.period_ns, self._read, self.buffer.push
        buf = self.buffer
        self._tick = tick = now // period
        for raw in self._due(now):
            try:
                stamp, payload = read(raw)
            except IndexError:  # not this direction's layout
                continue
            if self._remap is not None:
                payload = self._remap(payload)
            packet = Packet(stamp // period, stamp, payload, 0, now)
            push(packet, now)
            if buf.duplicates != self._dup_seen:  # ignored: its first copy is decided
                self._dup_seen = buf.duplicates
            elif packet.fate == LOST_LATE:  # too late on arrival
                self._late_seen += 1
                self._decided.extend((packet.seq, LOST_LATE, -1, tick))
            else:
                self._pending[packet.seq] = packet
        p = buf.release(now)
        if buf.late != self._late_seen:  # skipped at this release: find which
            self._collect_late()
        if p is not None:
            payload = p.payload
            if self._to_wire is not None:
                self.out.publish(p.send_time_ns, self._to_wire(payload))
            else:
                self.out.publish(p.send_time_ns, [payload[i] for i in self._fields_order])
            self.released += 1
            if self._pending.pop(p.seq, None) is not None:
                self._decided.extend((p.seq, DELIVERED, tick, p.arrival_time_ns // period))
            else:  # a made-up sample
                self._decided.extend((p.seq, NO_FATE, tick, -1))
        if index % self._batch_ticks == 0:
            self.publish_fates()

    def _collect_late(self) -> None:
        pending = self._pending
        late = [q for q in pending.values() if q.fate == LOST_LATE]
        period = self.period_ns
        for q in late:
            del pending[q.seq]
            self._decided.extend((q.seq, LOST_LATE, -1, q.arrival_time_ns // period))
        self._late_seen = self.buffer.late
        if len(pending) > _MAX_PENDING:  # never decided (a buffer that lost track): forget the oldest
            for seq in sorted(pending)[: len(pending) - _MAX_PENDING]:
                del pending[seq]

    def publish_fates(self) -> None:
        """The decisions and releases since the last batch, rows [seq, fate, tick, arrived]
        (PLAYOUT_FIELDS), and the row saying every release up to the last tick run is in (module
        docstring)."""
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension

        if self._tick < 0:
            return
        rows = self._decided
        rows.extend((-1, NO_FATE, self._tick, -1))
        self._decided = array.array("d")
        msg = Float64MultiArray()
        k = len(PLAYOUT_FIELDS)
        n = len(rows) // k
        msg.layout.dim = [
            MultiArrayDimension(label="packet", size=n, stride=len(rows)),
            MultiArrayDimension(label=",".join(PLAYOUT_FIELDS), size=k, stride=k),
        ]
        msg.data = rows
        self._fates_pub.publish(msg)

    def close(self) -> None:
        from haptic_teleop.nodes.messages import wait_acknowledged

        super().close()
        self.publish_fates()
        wait_acknowledged(self._fates_pub)  # the recorder has every batch before this writer goes
        if getattr(self, "codec", None) is not None:
            self.codec.close()

    def diagnostic_values(self) -> dict[str, float | int | str]:
        if self.codec is not None:
            c = self.codec
            return {"released": self.released, "late": 0, "decoded": c.decoder.counters.get("received", 0),
                    "acks_sent": c.ack_packets}  # fmt: skip
        b = self.buffer
        return {
            "released": self.released,
            "late": b.late,
            "late_by_scheduling": self.late_by_scheduling,
            "occupancy": getattr(b, "occupancy", 0),
            "duplicates": getattr(b, "duplicates", 0),
            "extrapolated": getattr(b, "extrapolated", 0),
        }


def main() -> None:
    node_main(SyncBuffer)


if __name__ == "__main__":
    main()

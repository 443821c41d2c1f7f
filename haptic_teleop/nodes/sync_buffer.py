"""sync_buffer: the receiving side's haptic synchronization (playout) buffer, the core
`PlayoutBuffer` the scene names, driven by the node clock.

Once per tick on the absolute grid, what arrived on /<direction>/delivered since the last tick is
pushed with the tick's time as arrival time (as the engine does; seq = stamp / period, send time
= the sender's stamp), then the buffer's release decides
which sample the controller uses, and that sample goes out on /<direction>/received with the
sender's stamp (made-up samples of `gap: extrapolate` carry the stamp of the slot they fill).
"""

from __future__ import annotations

from typing import Any

from haptic_teleop.core.network import Packet
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.common import (
    DIRECTION_JOINT,
    PAYLOAD_FIELDS,
    READER_DEPTH,
    WIRE_FIELDS,
    JointStateOut,
    LiveNode,
    delivered_topic,
    node_main,
    received_topic,
    stream_qos,
    take_all,
)
from haptic_teleop.nodes.network_relay import declare_direction_scene


class SyncBuffer(LiveNode):
    default_name = "sync_buffer"
    loop_phase = 0.5  # after the producers' tick (LiveNode.loop_phase)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState

        from haptic_teleop.core.playout import build_buffer

        d, cfg = declare_direction_scene(self, "sync_buffer")
        self.direction = d
        period_ns = round(cfg.scene.period_s * 1e9)
        self.buffer = build_buffer(getattr(cfg.network, d).buffer, period_ns)
        self._fields = PAYLOAD_FIELDS[d]
        out_fields = WIRE_FIELDS[d]
        self._order = [self._fields.index(f) for f in out_fields]  # payload -> JointState order
        self.released = 0
        self.out = JointStateOut(self, received_topic(d), DIRECTION_JOINT[d], out_fields)
        self._read = JointStateReader(self._fields, [(DIRECTION_JOINT[d], out_fields)])
        self._sub = self.create_polled_subscription(JointState, delivered_topic(d), stream_qos(READER_DEPTH), raw=True)
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"{d}: {delivered_topic(d)} -> {received_topic(d)}, policy {getattr(cfg.network, d).buffer.policy}"
        )

    def tick(self, index: int, stamp_ns: int) -> None:
        now = self.now_ns()
        period, read, push = self.period_ns, self._read, self.buffer.push
        for raw in take_all(self._sub):
            try:
                stamp, payload = read(raw)
            except IndexError:  # not this direction's layout
                continue
            push(Packet(stamp // period, stamp, payload, 0, now), now)
        p = self.buffer.release(now)
        if p is not None:
            payload = p.payload
            self.out.publish(p.send_time_ns, [payload[i] for i in self._order])
            self.released += 1

    def diagnostic_values(self) -> dict[str, float | int | str]:
        b = self.buffer
        return {
            "released": self.released,
            "late": b.late,
            "occupancy": getattr(b, "occupancy", 0),
            "duplicates": getattr(b, "duplicates", 0),
            "extrapolated": getattr(b, "extrapolated", 0),
        }


def main() -> None:
    node_main(SyncBuffer)


if __name__ == "__main__":
    main()

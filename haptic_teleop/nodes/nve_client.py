"""nve_client: one client of an NVE scene (parameter `client`: its name), the core `NveClient` and
HIP of `assembly.nve.build_nve_parts` (the engine's) on the 1 kHz absolute-deadline loop, in
scene time (from the server's latched /haptic_teleop/scene_start; nothing before it).

Per tick n (t = n T, docs/nve.md "Model", one tick, its client steps):
  1. the HIP at t from the client's operator profile goes up: /<client>/up/sent, JointState names
     <client>_hip_x.., position x[a], velocity v[a], stamp = this tick;
  3. the object samples its client-side sync buffer released (/<client>/down/received) update the
     object it sees and its measured round trip R = t - echo (the echo is its own send stamp of the
     newest HIP sample the object state reflects, carried back by the server: only this node's
     clock is used); its spring schedule gives k_h at R; F = k_h (x_h - x_o') + d_h (v_h - v_o').
     Before the first object sample F = 0.
Out per tick (the NVE bag's topics): /nve/<client>/hip/joint_states (position x_h, velocity v_h,
effort F), /nve/<client>/feedback_wrench (WrenchStamped, frame world: F), /nve/<client>/object_pose
(PoseStamped: the object as used, NaN before any), /nve/<client>/object_twist (TwistStamped: its
velocity), /nve/<client>/coupling (Float64MultiArray
spring_n_per_m, rtt_s, up_rx_seq, down_rx_seq, up_occupancy, down_occupancy; the values other nodes
hold, up_rx_seq and the occupancies, are NaN here).
"""

from __future__ import annotations

import math
from typing import Any

from haptic_teleop.errors import ConfigError
from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.messages import JointStateOut, SpecOut, take_all
from haptic_teleop.nodes.params import declare_scene, declare_value
from haptic_teleop.nodes.topics import (
    READER_DEPTH,
    SCENE_START_TOPIC,
    latched_qos,
    nve_coupling_topic,
    nve_hip_topic,
    nve_pose_topic,
    nve_twist_topic,
    nve_wrench_topic,
    received_topic,
    scene_start_ns,
    sent_topic,
    stream_qos,
)
from haptic_teleop.nodes.wire import NVE_DOWN, NVE_UP, wire_of


class NveClientNode(LiveNode):
    default_name = "nve_client"
    loop_phase = 0.0  # a producer: its HIP sample leads the tick (LiveNode.loop_phase)

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Header

        from haptic_teleop.assembly.nve import build_nve_parts
        from haptic_teleop.record.layouts import nve_topic_specs
        from haptic_teleop.record.nve_columns import NveSchema

        cfg = declare_scene(self, SCENE_SECTIONS["nve_client"], ("client",))
        name = str(declare_value(self, "client", "", "the NVE client this node is (a name in nve.client_names)"))
        names = [c.name for c in cfg.nve.clients] if cfg.nve is not None else []
        if name not in names:
            raise ConfigError(
                f"parameters of node {self.get_name()}", "client", name, "allowed: one of " + ", ".join(names or ["-"])
            )
        period_ns = round(cfg.scene.period_s * 1e9)
        self.duration_ticks = round(cfg.scene.duration_s / cfg.scene.period_s)
        parts = build_nve_parts(cfg, period_ns)
        mine = next(p for p in parts.clients if p.name == name)
        self.name = name
        self.client = mine.client
        self.hip = mine.hip
        self.axes = a = parts.axes
        up = wire_of(f"{name}/{NVE_UP}", a)
        self.up_out = JointStateOut(self, sent_topic(up.direction), up.names, up.fields)
        self.down = down = wire_of(f"{name}/{NVE_DOWN}", a)
        self._down_sub = self.create_polled_subscription(
            JointState, received_topic(down.direction), stream_qos(READER_DEPTH), raw=True
        )
        self._read_down = JointStateReader(down.want, [(down.names, down.fields)], down.width)
        self._start_sub = self.create_polled_subscription(Header, SCENE_START_TOPIC, latched_qos())
        # The NVE bag's own layouts (record/nve_columns.py): a recorder decodes them at fixed offsets.
        specs = nve_topic_specs(NveSchema(tuple(names), a))
        self.hip_out = SpecOut(self, specs[nve_hip_topic(name)])
        self.pose_out = SpecOut(self, specs[nve_pose_topic(name)])
        self.twist_out = SpecOut(self, specs[nve_twist_topic(name)])
        self.wrench_out = SpecOut(self, specs[nve_wrench_topic(name)])
        self.coupling_out = SpecOut(self, specs[nve_coupling_topic(name)])
        self.start_ns: int | None = None
        self.received = 0
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"NVE client {name}: {sent_topic(up.direction)} up, {received_topic(down.direction)} down, "
            f"spring schedule {self.client.schedule.name}"
        )

    def tick(self, index: int, stamp_ns: int) -> None:
        start = self.start_ns
        if start is None:
            told = take_all(self._start_sub)
            if not told:
                return
            start = self.start_ns = scene_start_ns(told[-1], self.period_ns)
            self.get_logger().info(f"scene time 0 at stamp {start} ns")
        if stamp_ns < start:
            return
        period = self.period_ns
        n = (stamp_ns - start) // period
        if n >= self.duration_ticks:  # the server ends the run; nothing of scene time past the end
            return
        t = n * period * 1e-9
        a = self.axes
        xh, vh = self.hip.at(t)
        hx, hv = xh.tolist(), vh.tolist()
        self.up_out.publish(stamp_ns, (*hx, *hv))
        cl = self.client
        down_rx = -1.0
        remap = self.down.payload
        for raw in take_all(self._down_sub):
            try:
                sent_ns, vals = self._read_down(raw)
            except IndexError:
                continue
            if sent_ns < start:
                continue
            pl = remap(vals)
            cl.receive(pl[:a], pl[a : 2 * a], pl[2 * a], t)
            self.received += 1
            down_rx = float((sent_ns - start) // period)
        f = cl.force(xh, vh).tolist()
        self.hip_out.publish(stamp_ns, (*hx, *hv, *f))
        self.wrench_out.publish(stamp_ns, f)
        self.pose_out.publish(stamp_ns, cl.obj_x.tolist())
        self.twist_out.publish(stamp_ns, cl.obj_v.tolist())
        self.coupling_out.publish(None, (cl.spring_n_per_m, cl.rtt_s, math.nan, down_rx, math.nan, math.nan))

    def diagnostic_values(self) -> dict[str, float | int | str]:
        r = self.client.rtt_s
        return {
            "object_samples": self.received,
            "rtt_s": "nan" if math.isnan(r) else round(r, 6),
            "spring_n_per_m": round(self.client.spring_n_per_m, 6),
        }


def main() -> None:
    node_main(NveClientNode)


if __name__ == "__main__":
    main()

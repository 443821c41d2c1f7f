"""nve_server: an NVE scene's consistency server, the core `ObjectServer` (the engine's, built by
`assembly.nve.build_nve_parts`) on the 1 kHz absolute-deadline loop, in scene time.

Scene time 0: once the node graph is up (every client's node, its relays and buffers), the server
announces the first tick at least `start.delay_s` later on /haptic_teleop/scene_start (latched),
as the operator source does in teleoperation; the clients start their HIPs there and the relays
run their links from there. After scene.duration_s it exits 0, which ends a launched run.

Per tick n (t = n T, engine order: docs/nve.md "Model", one tick, step 2), for each client in scene order:
the HIP samples its server-side sync buffer released (/<client>/up/received: position x[a],
velocity v[a], stamp = the client's send tick) become its held HIP, echo = that stamp in scene
time; the object state at t goes down (/<client>/down/sent: object_x.., hip_echo_s; position
(x_o..., echo_s), velocity (v_o..., 0); stamp = this tick); the object steps t -> t + T. The
object state and the net coupling force over the step go out on /nve/object/joint_states.
"""

from __future__ import annotations

import math
from typing import Any

from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, NodeStopped, node_main
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.messages import JointStateOut, SpecOut, take_all
from haptic_teleop.nodes.params import declare_scene, declare_value
from haptic_teleop.nodes.rtloop import Every
from haptic_teleop.nodes.topics import (
    NVE_OBJECT_STATE,
    READER_DEPTH,
    SCENE_START_TOPIC,
    latched_qos,
    received_topic,
    scene_start_header,
    sent_topic,
    stream_qos,
)
from haptic_teleop.nodes.wire import NVE_DOWN, NVE_UP, wire_of

_NAMES = ("start.delay_s", "start.timeout_s", "start.min_subscribers", "stop_at_end")


class NveServer(LiveNode):
    default_name = "nve_server"
    loop_phase = 0.75  # after the up links' sync buffers (0.5): the engine's step 2 follows step 1

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Header

        from haptic_teleop.assembly.nve import build_nve_parts

        cfg = declare_scene(self, SCENE_SECTIONS["nve_server"], _NAMES)
        if cfg.nve is None:
            from haptic_teleop.errors import ConfigError

            raise ConfigError(f"parameters of node {self.get_name()}", "nve.client_names", [], "an NVE scene is needed")
        self.start_delay_ns = round(
            declare_value(self, "start.delay_s", 1.0, "settling time after the graph is up", 0.0, 60.0) * 1e9
        )
        self.start_timeout_s = float(
            declare_value(self, "start.timeout_s", 30.0, "give up (exit 1) if the graph is not up by then", 0.1, 3600.0)
        )
        self.min_subscribers = int(
            declare_value(
                self, "start.min_subscribers", 0,
                f"start once this many subscribe to {NVE_OBJECT_STATE} (1 when a recorder records the run)", 0, 100,
            )
        )  # fmt: skip
        self.stop_at_end = bool(declare_value(self, "stop_at_end", True, "exit 0 after scene.duration_s"))
        period_ns = round(cfg.scene.period_s * 1e9)
        self.duration_ticks = round(cfg.scene.duration_s / cfg.scene.period_s)
        parts = build_nve_parts(cfg, period_ns)
        self.server = parts.server
        self.axes = a = parts.axes
        self.client_names_ = [p.name for p in parts.clients]
        self._up_subs = []
        self._up_reads = []
        self._down_outs = []
        self._down_wire = []
        for c in self.client_names_:
            up = wire_of(f"{c}/{NVE_UP}", a)
            self._up_subs.append(
                self.create_polled_subscription(
                    JointState, received_topic(up.direction), stream_qos(READER_DEPTH), raw=True
                )
            )
            self._up_reads.append(JointStateReader(up.want, [(up.names, up.fields)], up.width))
            down = wire_of(f"{c}/{NVE_DOWN}", a)
            self._down_wire.append(down)
            self._down_outs.append(JointStateOut(self, sent_topic(down.direction), down.names, down.fields))
        from haptic_teleop.record.layouts import nve_topic_specs
        from haptic_teleop.record.nve_columns import NveSchema

        # The NVE bag's own layout (record/nve_columns.py): a recorder decodes it at fixed offsets.
        self.object_out = SpecOut(self, nve_topic_specs(NveSchema(tuple(self.client_names_), a))[NVE_OBJECT_STATE])
        self._start_pub = self.create_publisher(Header, SCENE_START_TOPIC, latched_qos())
        self.start_index: int | None = None
        self.started = False
        self._created_ns = self.now_ns()
        self._check_graph = Every(50)
        self.received = [0] * len(self.client_names_)  # HIP samples taken, per client
        self.up_rx_seq = [-1] * len(self.client_names_)  # scene tick of the newest HIP sample, per client
        self.setup_loop(period_ns)
        self.get_logger().info(f"NVE server: {len(self.client_names_)} client(s) {self.client_names_}, {a} axis/axes")

    def _graph_missing(self) -> list[str]:
        """What is not there yet of every client's node, its relays and its buffers (and the
        recorder, if asked); empty once the graph is up."""
        missing = []
        n = self.count_subscribers(NVE_OBJECT_STATE)
        if n < self.min_subscribers:
            missing.append(f"{self.min_subscribers} subscribers of {NVE_OBJECT_STATE} (has {n})")
        for c in self.client_names_:
            up, down = f"{c}/{NVE_UP}", f"{c}/{NVE_DOWN}"
            need = (
                ("a publisher", self.count_publishers, sent_topic(up)),  # the client node
                ("a subscriber", self.count_subscribers, received_topic(down)),
                ("a subscriber", self.count_subscribers, sent_topic(up)),  # up relay and buffer
                ("a publisher", self.count_publishers, received_topic(up)),
                ("a subscriber", self.count_subscribers, sent_topic(down)),  # down relay and buffer
                ("a publisher", self.count_publishers, received_topic(down)),
            )
            missing += [f"{what} of {topic}" for what, count, topic in need if count(topic) < 1]
        return missing

    def tick(self, index: int, stamp_ns: int) -> None:
        if self.start_index is None:
            if self._check_graph(index) and not self._graph_missing():
                first = index + max(1, -(-self.start_delay_ns // self.period_ns))
                self.start_index = first
                self._publish_start(first * self.period_ns)
                self.get_logger().info(f"graph is up; scene time starts in {self.start_delay_ns * 1e-9:g} s")
            elif (stamp_ns - self._created_ns) * 1e-9 > self.start_timeout_s:
                raise HapticTeleopError(
                    f"the NVE node graph was not up within start.timeout_s={self.start_timeout_s:g} s; "
                    f"still missing: {'; '.join(self._graph_missing())}"
                )
            return
        if index < self.start_index:
            return
        if not self.started:
            self.started = True
            self.get_logger().info(f"scene time 0 at stamp {self.start_index * self.period_ns} ns")
        n = index - self.start_index
        if n >= self.duration_ticks and self.stop_at_end:
            raise NodeStopped(f"scene duration reached ({n} ticks)")
        start_ns = self.start_index * self.period_ns
        period = self.period_ns
        a = self.axes
        server = self.server
        for k in range(len(self.client_names_)):
            for raw in take_all(self._up_subs[k]):
                try:
                    sent_ns, vals = self._up_reads[k](raw)
                except IndexError:
                    continue
                if sent_ns < start_ns:  # not of this scene
                    continue
                server.receive(k, vals[:a], vals[a : 2 * a], (sent_ns - start_ns) * 1e-9)
                self.received[k] += 1
                self.up_rx_seq[k] = (sent_ns - start_ns) // period
        xo = server.x.tolist()
        vo = server.v.tolist()
        for k, out in enumerate(self._down_outs):
            out.publish(stamp_ns, self._down_wire[k].values((*xo, *vo, float(server.echo_s[k]))))
        server.step()
        self.object_out.publish(stamp_ns, (*xo, *vo, *server.coupling_force_n.tolist()))

    def _publish_start(self, stamp_ns: int) -> None:
        self._start_pub.publish(scene_start_header(stamp_ns))

    def diagnostic_values(self) -> dict[str, float | int | str]:
        out: dict[str, float | int | str] = {"started": int(self.started)}
        for c, r, e in zip(self.client_names_, self.received, self.server.echo_s.tolist(), strict=True):
            out[f"{c}.hip_samples"] = r
            out[f"{c}.echo_s"] = "nan" if math.isnan(e) else round(e, 6)
        return out


def main() -> None:
    node_main(NveServer)


if __name__ == "__main__":
    main()

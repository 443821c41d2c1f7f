"""operator_source: the simulated operator (the core `Operator`): an arm impedance pulled along
the scene's intended trajectory, pressing on the master device.

It reads the device state on /master/joint_states and publishes /operator/joint_states each tick
(position, velocity: intended; effort: the hand force on the device), which master_eba applies.
Its scene time starts once the node graph is up (the master is publishing, the slave's loop runs:
a sample of its state came, the topics it waits for have publishers, enough subscribers listen)
plus a settling delay, so the whole push is seen
by every node and recorded; nothing is published before. After scene.duration_s it exits 0,
which ends a launched run.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import HapticTeleopError
from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, NodeStopped, node_main
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.messages import JointStateOut, take_latest
from haptic_teleop.nodes.params import declare_scene, declare_value
from haptic_teleop.nodes.rtloop import Every
from haptic_teleop.nodes.topics import (
    JOINT_ORDER,
    MASTER_JOINT,
    MASTER_STATE,
    OPERATOR_JOINT,
    OPERATOR_STATE,
    SCENE_START_TOPIC,
    SLAVE_STATE,
    latched_qos,
    received_topic,
    scene_start_header,
    sent_topic,
    stream_qos,
)

DEFAULT_WAIT_FOR = (SLAVE_STATE, received_topic("forward"), received_topic("backward"))
_NAMES = ("start.wait_for_publishers", "start.min_subscribers", "start.delay_s", "start.timeout_s", "stop_at_end")


class OperatorSource(LiveNode):
    default_name = "operator_source"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState

        from haptic_teleop.assembly.parts import build_operator
        from haptic_teleop.scene.traces import read_operator_trace

        cfg = declare_scene(self, SCENE_SECTIONS["operator_source"], _NAMES)
        op = cfg.operator
        trace = None
        if op.trace_file:
            trace = read_operator_trace(Path(op.trace_file), f"node {self.get_name()}", "operator.trace_file")
        self.operator = build_operator(op, trace)
        self.wait_for = list(
            declare_value(
                self, "start.wait_for_publishers", list(DEFAULT_WAIT_FOR), "start once these topics have publishers"
            )
        )
        self.min_subscribers = int(
            declare_value(
                self, "start.min_subscribers", 1, "start once this many subscribe to /operator/joint_states", 0, 100
            )
        )
        self.start_delay_ns = round(
            declare_value(self, "start.delay_s", 1.0, "settling time after the graph is up", 0.0, 60.0) * 1e9
        )
        self.start_timeout_s = float(
            declare_value(self, "start.timeout_s", 30.0, "give up (exit 1) if the graph is not up by then", 0.1, 3600.0)
        )
        self.stop_at_end = bool(declare_value(self, "stop_at_end", True, "exit 0 after scene.duration_s"))
        period_ns = round(cfg.scene.period_s * 1e9)
        self.duration_ticks = round(cfg.scene.duration_s / cfg.scene.period_s)
        self._master: tuple[list[float], list[float]] | None = None
        # A publisher is there as soon as its node declares it, which may be seconds before that
        # node's loop runs (a busy machine building the slave's plant and codec): the slave is up
        # once a sample of its state came.
        self._slave_heard = SLAVE_STATE not in self.wait_for
        self._slave_sub = None
        if not self._slave_heard:
            self._slave_sub = self.create_polled_subscription(JointState, SLAVE_STATE, stream_qos(), raw=True)
        self.arm: Any = None
        # Scene time 0 is a tick of every side: with its own period (<side>.period_s, k scene periods)
        # a side's loop ticks on stamps k * period, so the start is a multiple of every side's k (their
        # least common multiple) and each side ticks at scene ticks 0, k, 2k... as in the engine.
        self.start_every = 1
        if cfg.is_arm:
            import math

            from haptic_teleop.scene.load import side_period_ticks

            where = f"parameters of node {self.get_name()}"
            self.start_every = math.lcm(*(side_period_ticks(cfg, r, where) for r in ("master", "slave")))
            self._init_arm(cfg)
        else:
            self._master_sub = self.create_polled_subscription(JointState, MASTER_STATE, stream_qos(), raw=True)
            self._read_master = JointStateReader(("position", "velocity"), [(MASTER_JOINT, JOINT_ORDER)])
            self.out = JointStateOut(self, OPERATOR_STATE, OPERATOR_JOINT, JOINT_ORDER)
        from std_msgs.msg import Header

        self._start_pub = self.create_publisher(Header, SCENE_START_TOPIC, latched_qos())
        self.start_index: int | None = None  # the tick of scene time 0, announced once the graph is up
        self.started = False  # scene time has begun
        self._ready_ns: int | None = None
        self._check_graph = Every(50)
        self._created_ns = self.now_ns()
        self.setup_loop(period_ns)

    def _init_arm(self, cfg: Any) -> None:
        """An arm scene: the 3-D operator (side.operator_hand: the intended point along
        `operator.direction`, the hand a spring-damper in the device frame) on the master handle's
        newest task-frame state, which the master sends forward (/forward/sent: x, v per axis)."""
        from sensor_msgs.msg import JointState

        from haptic_teleop.assembly.parts import build_arm_parts
        from haptic_teleop.nodes.messages import SpecOut
        from haptic_teleop.nodes.topics import WIRE_FIELDS, wire_names
        from haptic_teleop.record.layouts import topic_specs

        self.arm = parts = build_arm_parts(cfg)
        from haptic_teleop.assembly.side import side_ticks

        side_ticks(parts)  # builds parts.maps (the mapping's functions, compiled)
        parts.master.plant.close()
        parts.slave.plant.close()
        axes = parts.schema.task_axes
        self._x_dev = parts.master.plant.point()[0]  # the start handle until the master is heard
        self._v_dev = np.zeros(axes)
        self._master_sub = self.create_polled_subscription(JointState, sent_topic("forward"), stream_qos(), raw=True)
        self._read_master = JointStateReader(
            WIRE_FIELDS["forward"], [(wire_names("forward", axes), WIRE_FIELDS["forward"])], axes
        )
        self.out = SpecOut(self, topic_specs(parts.schema)[OPERATOR_STATE])

    def _arm_take(self) -> None:
        m = take_latest(self._master_sub)
        if m is not None:
            vals = np.asarray(self._read_master(m)[1])
            k = vals.size // 2
            maps = self.arm.maps
            self._x_dev = maps.to_master_x(vals[:k])
            self._v_dev = maps.to_master_v(vals[k:])
            self._master = ([], [])

    def _arm_publish(self, t: float, stamp_ns: int) -> None:
        from haptic_teleop.assembly.side import operator_hand

        xd_t, vd_t, f_dev = operator_hand(self.arm, t, self._x_dev, self._v_dev)
        self.out.publish(stamp_ns, (*xd_t, *vd_t, *self.arm.maps.force_to_task(f_dev).tolist()))

    def _graph_missing(self) -> list[str]:
        """What the graph still lacks before scene time 0 can be announced (empty once it is up)."""
        if not self._slave_heard and self._slave_sub is not None:
            self._slave_heard = take_latest(self._slave_sub) is not None
        missing = []
        if self._master is None:
            missing.append(f"a sample of {sent_topic('forward') if self.arm is not None else MASTER_STATE}")
        if not self._slave_heard:
            missing.append(f"a sample of {SLAVE_STATE}")
        n = self.count_subscribers(OPERATOR_STATE)
        if n < self.min_subscribers:
            missing.append(f"{self.min_subscribers} subscribers of {OPERATOR_STATE} (has {n})")
        missing += [f"a publisher of {t}" for t in self.wait_for if self.count_publishers(t) == 0]
        return missing

    def tick(self, index: int, stamp_ns: int) -> None:
        if self.arm is not None:
            self._arm_take()
            m = None
        else:
            m = take_latest(self._master_sub)
        if m is not None:
            x, v = self._read_master(m)[1]
            self._master = ([x], [v])
        if self.start_index is None:
            if self._check_graph(index) and not self._graph_missing():
                self._ready_ns = stamp_ns
                # Scene time 0: the first tick at least start.delay_s after now, announced now (latched)
                # so every node knows it before it comes (the arm nodes restart their energy ledgers
                # there: nodes/arm_side.py).
                first = index + max(1, -(-self.start_delay_ns // self.period_ns))
                self.start_index = -(-first // self.start_every) * self.start_every
                self._publish_start(self.start_index * self.period_ns)
                self.get_logger().info(f"graph is up; scene time starts in {self.start_delay_ns * 1e-9:g} s")
            elif (stamp_ns - self._created_ns) * 1e-9 > self.start_timeout_s:
                raise HapticTeleopError(
                    f"the node graph was not up within start.timeout_s={self.start_timeout_s:g} s; "
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
        t = n * self.period_ns * 1e-9
        if self.arm is not None:
            self._arm_publish(t, stamp_ns)
            return
        x, v = self._master if self._master is not None else ([0.0], [0.0])
        fh = self.operator.hand_force(t, x, v)
        xd, vd = self.operator.intended(t)
        self.out.publish(stamp_ns, (xd, vd, fh[0]))

    def _publish_start(self, stamp_ns: int) -> None:
        self._start_pub.publish(scene_start_header(stamp_ns))

    def diagnostic_values(self) -> dict[str, float | int | str]:
        return {"started": int(self.started)}


def main() -> None:
    node_main(OperatorSource)


if __name__ == "__main__":
    main()

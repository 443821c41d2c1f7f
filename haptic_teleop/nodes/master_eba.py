"""master_eba: the operator's haptic device and its EBA controller, one 1 kHz loop in-process.

Per tick (the engine's master half of a tick: docs/architecture.md, "One tick"): read the device, take the newest
backward sample the sync buffer released, watchdog gain, control law + energy bound
(TeleopController), send the master sample forward, then hold the force on the device for one
period with the operator's newest hand force.

The device is the scene's MuJoCo device (`device.source: plant`, the default), or a real haptic
device driver's topics (`device.source: topic`): its sensor_msgs/JointState in, and the force
command out as geometry_msgs/WrenchStamped (force.x). The command's QoS is a parameter
(`device.command_reliability`, `device.command_depth`), reliable by default: a reliable writer
reaches reliable and best-effort readers alike, a best-effort one only best-effort readers.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from haptic_teleop.nodes import DEFAULT_COMMAND_DEPTH, DEVICE_SOURCES, DEVICE_TOPICS, RELIABILITIES, SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.eba_side import WATCHDOG_PARAMS, EbaSide
from haptic_teleop.nodes.messages import JointStateOut, WrenchOut, take_latest
from haptic_teleop.nodes.params import declare_value
from haptic_teleop.nodes.topics import (
    JOINT_ORDER,
    MASTER_JOINT,
    MASTER_STATE,
    OPERATOR_JOINT,
    OPERATOR_STATE,
    RECORDER_LISTENING_TOPIC,
    SCENE_START_TOPIC,
    latched_qos,
    reliable_qos,
    scene_start_header,
    stream_qos,
)


class MasterEba(LiveNode):
    default_name = "master_eba"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState

        from haptic_teleop.assembly.parts import build_master_plant
        from haptic_teleop.nodes.params import declare_scene

        names = (
            *WATCHDOG_PARAMS,
            "device.source",
            "device.state_topic",
            "device.command_topic",
            "device.command_reliability",
            "device.command_depth",
            "device.min_subscribers",
            "device.start_delay_s",
            "device.wait_for_recorder",
        )
        cfg = declare_scene(self, SCENE_SECTIONS["master_eba"], names)
        period_ns = round(cfg.scene.period_s * 1e9)
        self.source = declare_value(
            self,
            "device.source",
            "plant",
            "plant: the scene's simulated device; topic: a driver's topics",
            choices=DEVICE_SOURCES,
        )
        state_topic = declare_value(self, "device.state_topic", DEVICE_TOPICS[0], "driver's JointState")
        command_topic = declare_value(
            self, "device.command_topic", DEVICE_TOPICS[1], "force command to the driver (WrenchStamped)"
        )
        reliability = declare_value(
            self,
            "device.command_reliability",
            "reliable",
            "QoS reliability of the force command: reliable (reaches reliable and best-effort readers) or "
            "best_effort (reaches best-effort readers only)",
            choices=RELIABILITIES,
        )
        depth = int(
            declare_value(
                self, "device.command_depth", DEFAULT_COMMAND_DEPTH, "QoS depth (keep last) of the force command",
                1, 10_000,
            )
        )  # fmt: skip
        self.command_qos = command_qos(str(reliability), depth)
        self.arm: Any = None
        if cfg.is_arm:
            self._init_arm(cfg)
            return
        self.side: Any = EbaSide(self, "master", cfg)
        self.plant: Any = None
        self._hand_n = 0.0
        self._device: tuple[float, float] | None = None
        if self.source == "plant":
            self.plant = build_master_plant(cfg)
            self._hand_sub = self.create_polled_subscription(JointState, OPERATOR_STATE, stream_qos(), raw=True)
            self._read_hand = JointStateReader(("effort",), [(OPERATOR_JOINT, JOINT_ORDER)])
            self.command_out = None
        else:
            self._device_sub = self.create_polled_subscription(JointState, state_topic, stream_qos(), raw=True)
            self._read_device = JointStateReader(("position", "velocity"))  # a driver's layout: deserialized
            self.command_out = WrenchOut(self, command_topic, MASTER_JOINT, self.command_qos)
            # No operator source publishes scene time 0 in a device session: this node does, at a
            # tick after the device's first sample, for the relays' links and the recorder's grid.
            from std_msgs.msg import Header

            self._start_pub = self.create_publisher(Header, SCENE_START_TOPIC, latched_qos())
            self._started = False
            # ... once this many subscribe to /master/joint_states (the recorder, when there is
            # one): a recorder that missed the first samples would have nothing to hold before them.
            self._min_subscribers = int(
                declare_value(
                    self, "device.min_subscribers", 0, f"scene time 0 waits for this many on {MASTER_STATE}", 0, 100
                )
            )
            # ... and, with `device.wait_for_recorder` (set when recording), once the recorder says it
            # takes every stream of its grid (a subscriber the graph lists may take nothing yet: a
            # recorder on a busy machine missed the first 0.35 to 0.45 s of every stream, even 1 s on);
            self._wait_for_recorder = bool(
                declare_value(self, "device.wait_for_recorder", False, "scene time 0 waits for the recorder")
            )
            self._listening_sub = self.create_polled_subscription(Header, RECORDER_LISTENING_TOPIC, latched_qos())
            self._recorder_heard = False
            # then it comes device.start_delay_s later, announced at once (latched), as the operator
            # source's (the relays and buffers settle on the link meanwhile).
            self._start_delay_ns = round(
                declare_value(
                    self, "device.start_delay_s", 1.0, "settling time after those subscribe, before scene time 0",
                    0.0, 60.0,
                ) * 1e9
            )  # fmt: skip
        self.state_out = JointStateOut(self, MASTER_STATE, MASTER_JOINT, JOINT_ORDER)
        self.codec: Any = None
        if cfg.network.forward.codec is not None:  # the forward encoder (nodes/codec_stage.py)
            from haptic_teleop.nodes.codec_stage import CodecSender

            self.codec = CodecSender(self, "forward", cfg)
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"device {self.source}, period {cfg.scene.period_s * 1e3:g} ms, watchdog bound "
            f"{self.side.bound_ms():.0f} ms"
        )

    def _init_arm(self, cfg: Any) -> None:
        """An arm scene: the master device arm in-process, the engine's master half of the arm tick
        (nodes/arm_side.py); the operator's hand force comes in the task frame on
        /operator/joint_states (effort) and is mapped into the device frame."""
        from sensor_msgs.msg import JointState

        from haptic_teleop.errors import ConfigError
        from haptic_teleop.nodes.arm_side import ArmEbaSide
        from haptic_teleop.nodes.codec_stage import CodecSender

        if self.source != "plant":
            raise ConfigError(
                f"parameters of node {self.get_name()}", "device.source", self.source,
                "an arm scene runs its simulated device only for now; allowed: plant",
            )  # fmt: skip
        self.arm = arm = ArmEbaSide(self, "master", cfg)
        # the forward encoder (nodes/codec_stage.py), on the arm tick's payload (x[3], v[3])
        self.codec = CodecSender(self, "forward", cfg) if cfg.network.forward.codec is not None else None
        self.side = arm
        self.plant = arm.plant
        self.command_out = None
        axes = arm.schema.axes
        self._hand_sub = self.create_polled_subscription(JointState, OPERATOR_STATE, stream_qos(), raw=True)
        names = tuple(f"operator_{a}" for a in axes)
        self._read_hand = JointStateReader(("effort",), [(names, JOINT_ORDER)], len(axes))
        self._hand_dev = np.zeros(len(axes))  # the operator's hand force, device frame
        self.setup_loop(round(arm.period_s * 1e9))  # the side's own period (master.period_s), else the scene's
        if arm.hardware:  # a real arm: its operator is a real hand, nothing is commanded at the handle
            from haptic_teleop.nodes.arm_side import HARDWARE_SCHEDULING

            self.normal_scheduling(HARDWARE_SCHEDULING)
        self.get_logger().info(
            f"arm {cfg.master.model} ({', '.join(arm.schema.master_joints)}), period "
            f"{arm.period_s * 1e3:g} ms, watchdog bound {arm.bound_ms():.0f} ms"
        )

    def _arm_tick(self, stamp_ns: int) -> None:
        arm = self.arm
        maps = arm.maps
        q, qd, x_dev, v_dev = arm.read_point()
        x = maps.to_task_x(x_dev)
        v = maps.to_task_v(v_dev)
        tau = arm.torque(x, v, stamp_ns)
        if self.codec is not None:
            self.codec.send(stamp_ns, (*x.tolist(), *v.tolist()))
            arm.publish_sample("forward", stamp_ns, (*x.tolist(), *v.tolist()))
        else:
            arm.send("forward", stamp_ns, (*x.tolist(), *v.tolist()))
        hand = take_latest(self._hand_sub)
        if hand is not None:
            self._hand_dev = maps.force_to_master(np.asarray(self._read_hand(hand)[1]))
        applied = arm.step(tau, None if arm.hardware else self._hand_dev)
        arm.applied(applied)
        arm.publish("/master/joint_states", stamp_ns, (*q.tolist(), *qd.tolist(), *applied.tolist()))
        arm.publish("/master/handle_pose", stamp_ns, x)
        arm.publish_measured(stamp_ns)
        arm.publish_internals(stamp_ns)

    def tick(self, index: int, stamp_ns: int) -> None:
        if self.arm is not None:
            self._arm_tick(stamp_ns)
            return
        if self.plant is not None:
            x, v = self.plant.read()
            hand = take_latest(self._hand_sub)
            if hand is not None:
                self._hand_n = self._read_hand(hand)[1][0]
        else:
            dev = take_latest(self._device_sub)
            if dev is not None:
                self._device = self._read_device(dev)[1]
            if self._device is None:
                return  # no device yet: nothing to control
            if not self._started and self._recorder_ready() and self._subscribed():
                self._started = True
                self._publish_start(stamp_ns + -(-self._start_delay_ns // self.period_ns) * self.period_ns)
            x, v = [self._device[0]], [self._device[1]]
        f = self.side.step(x, v, stamp_ns)
        if self.codec is not None:
            self.codec.send(stamp_ns, (x[0], v[0]))  # the codec's sample layout (x_m, v_m)
        else:
            self.side.send(stamp_ns, x[0], v[0])
        if self.plant is not None:
            applied = self.plant.step(f, [self._hand_n])
            self.side.applied(applied)
        else:
            assert self.command_out is not None
            self.command_out.publish(stamp_ns, f[0])
            applied = f
        self.state_out.publish(stamp_ns, (x[0], v[0], applied[0]))
        self.side.publish_internals()

    def _subscribed(self) -> bool:
        return self.count_subscribers(MASTER_STATE) >= self._min_subscribers

    def _recorder_ready(self) -> bool:
        if self._wait_for_recorder and not self._recorder_heard:
            self._recorder_heard = take_latest(self._listening_sub) is not None
        return self._recorder_heard or not self._wait_for_recorder

    def _publish_start(self, stamp_ns: int) -> None:
        """Scene time 0 at `stamp_ns` (a tick to come) on /haptic_teleop/scene_start (latched), as the
        operator source publishes it in a session with one (`topics.scene_start_ns` reads it)."""
        self._start_pub.publish(scene_start_header(stamp_ns))
        self.get_logger().info(
            f"scene time 0 at stamp {stamp_ns} ns: device.start_delay_s after the start condition held"
        )

    def diagnostic_values(self) -> dict[str, float | int | str]:
        return self.side.diagnostic_values()

    def close(self) -> None:
        super().close()
        if getattr(self, "codec", None) is not None:
            self.codec.close()
        if self.arm is not None:
            self.arm.close(self.get_logger().warning)  # the plant first (a real arm: torque off)
        elif self.plant is not None:
            self.plant.close()
        elif self.command_out is not None:
            self.command_out.publish(self.now_ns(), 0.0)  # torque off on every exit


def command_qos(reliability: str, depth: int) -> Any:
    """The force command's QoS: keep last `depth`, volatile, `reliability` (RELIABILITIES)."""
    if reliability not in RELIABILITIES:
        raise ValueError(f"reliability must be one of {RELIABILITIES}, got {reliability!r}")
    return reliable_qos(depth) if reliability == "reliable" else stream_qos(depth)


def main() -> None:
    node_main(MasterEba)


if __name__ == "__main__":
    main()

"""slave_eba: the robot's EBA controller with its plant hosted in-process (as a ros2_control
hardware interface would be), so the 1 kHz robot loop never crosses DDS.

Per tick (the engine's slave half of a tick: docs/architecture.md, "One tick"): read the robot and the wall force,
take the newest forward sample the sync buffer released, watchdog gain, control law + energy
bound (TeleopController), send the slave sample (wall force, position, velocity) backward, step
the plant one period with the force held.
"""

from __future__ import annotations

from typing import Any

from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.eba_side import WATCHDOG_PARAMS, EbaSide
from haptic_teleop.nodes.messages import JointStateOut, WrenchOut
from haptic_teleop.nodes.params import declare_scene
from haptic_teleop.nodes.topics import SLAVE_CONTACT, SLAVE_JOINT, SLAVE_STATE, WALL_FRAME


class SlaveEba(LiveNode):
    default_name = "slave_eba"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from haptic_teleop.assembly.parts import build_slave_plant

        cfg = declare_scene(self, SCENE_SECTIONS["slave_eba"], WATCHDOG_PARAMS)
        period_ns = round(cfg.scene.period_s * 1e9)
        self.arm: Any = None
        if cfg.is_arm:  # the slave arm in-process, the engine's slave half of the arm tick
            from haptic_teleop.nodes.arm_side import ArmEbaSide
            from haptic_teleop.nodes.codec_stage import CodecSender

            self.arm = self.side = ArmEbaSide(self, "slave", cfg)
            # the backward encoder (nodes/codec_stage.py), on the arm tick's payload (x[3], v[3], f[3])
            self.codec = CodecSender(self, "backward", cfg) if cfg.network.backward.codec is not None else None
            self.plant = self.arm.plant
            self.setup_loop(round(self.arm.period_s * 1e9))  # the side's own period (slave.period_s), else the scene's
            if self.arm.hardware:
                from haptic_teleop.nodes.arm_side import HARDWARE_SCHEDULING

                self.normal_scheduling(HARDWARE_SCHEDULING)
            w = cfg.slave.wall
            self.get_logger().info(
                f"arm {cfg.slave.model} ({', '.join(self.arm.schema.slave_joints)}), wall through "
                f"{list(w.point_m or ())} m, normal {list(w.normal or ())}, period {self.arm.period_s * 1e3:g} ms, "
                f"watchdog bound {self.arm.bound_ms():.0f} ms"
            )
            return
        self.side = EbaSide(self, "slave", cfg)
        s = cfg.slave
        self.plant = build_slave_plant(cfg)
        self.state_out = JointStateOut(self, SLAVE_STATE, SLAVE_JOINT, ("position", "velocity", "effort"))
        self.contact_out = WrenchOut(self, SLAVE_CONTACT, WALL_FRAME)
        self.codec: Any = None
        if cfg.network.backward.codec is not None:  # the backward encoder (nodes/codec_stage.py)
            from haptic_teleop.nodes.codec_stage import CodecSender

            self.codec = CodecSender(self, "backward", cfg)
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"plant {s.backend} ({s.model}), wall at {s.wall.position_m} m, watchdog bound "
            f"{self.side.bound_ms():.0f} ms"
        )

    def _arm_tick(self, stamp_ns: int) -> None:
        arm = self.arm
        plant = arm.plant
        q, qd, x, v = arm.read_point()
        f_env, t_env = plant.contact_wrench()
        tau = arm.torque(x, v, stamp_ns)
        if self.codec is not None:
            self.codec.send(stamp_ns, (*x.tolist(), *v.tolist(), *f_env.tolist()))
            arm.publish_sample("backward", stamp_ns, (*x.tolist(), *v.tolist(), *f_env.tolist()))
        else:
            arm.send("backward", stamp_ns, (*x.tolist(), *v.tolist(), *f_env.tolist()))
        applied = arm.step(tau)
        arm.applied(applied)
        arm.publish("/slave/joint_states", stamp_ns, (*q.tolist(), *qd.tolist(), *applied.tolist()))
        arm.publish("/slave/contact_wrench", stamp_ns, (*f_env.tolist(), *t_env.tolist()))
        arm.publish("/slave/tool_pose", stamp_ns, x)
        arm.publish_measured(stamp_ns)
        arm.publish_internals(stamp_ns)

    def tick(self, index: int, stamp_ns: int) -> None:
        if self.arm is not None:
            self._arm_tick(stamp_ns)
            return
        plant = self.plant
        x, v = plant.read()
        fenv = plant.contact_force()
        f = self.side.step(x, v, stamp_ns)
        if self.codec is not None:
            self.codec.send(stamp_ns, (fenv[0], x[0], v[0]))  # the codec's sample layout (f_env, x_s, v_s)
        else:
            self.side.send(stamp_ns, x[0], v[0], fenv[0])
        applied = plant.step(f)
        self.side.applied(applied)
        self.state_out.publish(stamp_ns, (x[0], v[0], applied[0]))
        self.contact_out.publish(stamp_ns, fenv[0])
        self.side.publish_internals()

    def diagnostic_values(self) -> dict[str, float | int | str]:
        return self.side.diagnostic_values()

    def close(self) -> None:
        super().close()
        if getattr(self, "codec", None) is not None:
            self.codec.close()
        if self.arm is not None:
            self.arm.close(self.get_logger().warning)  # the plant first (a real arm: torque off)
        else:
            self.plant.close()


def main() -> None:
    node_main(SlaveEba)


if __name__ == "__main__":
    main()

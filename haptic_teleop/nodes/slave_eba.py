"""slave_eba: the robot's EBA controller with its plant hosted in-process (as a ros2_control
hardware interface would be), so the 1 kHz robot loop never crosses DDS.

Per tick (the engine's slave half of DESIGN.md section 2): read the robot and the wall force,
take the newest forward sample the sync buffer released, watchdog gain, control law + energy
bound (TeleopController), send the slave sample (wall force, position, velocity) backward, step
the plant one period with the force held.
"""

from __future__ import annotations

from typing import Any

from haptic_teleop.core.watchdog import ForceFade
from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.common import (
    PAYLOAD_FIELDS,
    SLAVE_CONTACT,
    SLAVE_EBA,
    SLAVE_JOINT,
    SLAVE_STATE,
    WALL_FRAME,
    EbaOut,
    JointStateOut,
    LiveNode,
    WrenchOut,
    declare_scene,
    joint_values,
    node_main,
    received_topic,
    sent_topic,
    stream_qos,
    take_latest,
)
from haptic_teleop.nodes.master_eba import declare_watchdog


class SlaveEba(LiveNode):
    default_name = "slave_eba"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from sensor_msgs.msg import JointState

        from haptic_teleop.engine import _controller
        from haptic_teleop.plants import build_slave_plant

        cfg = declare_scene(self, SCENE_SECTIONS["slave_eba"], ("watchdog.timeout_s", "watchdog.fade_s"))
        period_ns = round(cfg.scene.period_s * 1e9)
        self.watchdog = declare_watchdog(self, period_ns)
        self.ctrl = _controller(cfg.controllers.slave, "slave", cfg.scene.period_s, cfg.slave.damping_n_s_per_m)
        self.fade = ForceFade(self.ctrl)
        s = cfg.slave
        self.plant = build_slave_plant(cfg)
        self.remote_samples = 0
        self._remote_fields = PAYLOAD_FIELDS["forward"]
        self._remote_sub = self.create_polled_subscription(JointState, received_topic("forward"), stream_qos())
        self.state_out = JointStateOut(self, SLAVE_STATE, SLAVE_JOINT, ("position", "velocity", "effort"))
        self.contact_out = WrenchOut(self, SLAVE_CONTACT, WALL_FRAME)
        self.backward_out = JointStateOut(self, sent_topic("backward"), SLAVE_JOINT, ("position", "velocity", "effort"))
        self.eba_out = EbaOut(self, SLAVE_EBA)
        self.setup_loop(period_ns)
        self.get_logger().info(
            f"plant {s.backend} ({s.model}), wall at {s.wall.position_m} m, watchdog bound "
            f"{self.watchdog.bound_s(cfg.scene.period_s) * 1e3:.0f} ms"
        )

    def tick(self, index: int, stamp_ns: int) -> None:
        plant = self.plant
        x, v = plant.read()
        fenv = plant.contact_force()
        remote = take_latest(self._remote_sub)
        if remote is not None:
            self.remote_samples += 1
            self.ctrl.set_remote(joint_values(remote, self._remote_fields))
            self.watchdog.feed(stamp_ns)
        self.fade.set_gain(self.watchdog.update(stamp_ns))
        f = self.ctrl.step(x, v)
        # JointState field order (position, velocity, effort) carries the payload (f_env, x, v).
        self.backward_out.publish(stamp_ns, (x[0], v[0], fenv[0]))
        applied = plant.step(f)
        self.state_out.publish(stamp_ns, (x[0], v[0], applied[0]))
        self.contact_out.publish(stamp_ns, fenv[0])
        self.eba_out.publish(self.ctrl.bound.energy_j[0], self.ctrl.force_desired[0])

    def diagnostic_values(self) -> dict[str, float | int | str]:
        wd = self.watchdog
        return {"watchdog_gain": round(wd.gain, 3), "watchdog_trips": wd.trips, "remote_samples": self.remote_samples}

    def close(self) -> None:
        super().close()
        self.plant.close()


def main() -> None:
    node_main(SlaveEba)


if __name__ == "__main__":
    main()

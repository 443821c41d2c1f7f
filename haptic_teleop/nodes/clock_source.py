"""clock_source: publishes simulated time on /clock for nodes started with use_sim_time.

Simulated time advances by one scene period per tick, and ticks run on the wall clock at
`rate` times real time: rate 0.5 gives every node twice the wall time per period, which is how a
loaded or slow machine still runs the live node set without missed deadlines (docs/live_launch.md, "Simulated time").
Time starts at `start_s` (not 0: a ROS clock at 0 means "no time yet").
"""

from __future__ import annotations

from typing import Any

from haptic_teleop.nodes import SCENE_SECTIONS
from haptic_teleop.nodes.base import LiveNode, node_main
from haptic_teleop.nodes.params import declare_scene, declare_value

CLOCK_TOPIC = "/clock"


class ClockSource(LiveNode):
    default_name = "clock_source"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        from rosgraph_msgs.msg import Clock

        from haptic_teleop.errors import ConfigError
        from haptic_teleop.nodes.topics import reliable_qos

        if self.simulated_time:
            raise ConfigError(
                f"parameters of node {self.get_name()}", "use_sim_time", True, "allowed: false (this node makes /clock)"
            )
        cfg = declare_scene(self, SCENE_SECTIONS["clock_source"], ("rate", "start_s"))
        self.rate = float(declare_value(self, "rate", 1.0, "simulated seconds per wall second", 0.01, 10.0))
        self.start_ns = round(float(declare_value(self, "start_s", 1.0, "first /clock time", 0.001, 1e6)) * 1e9)
        self.sim_period_ns = round(cfg.scene.period_s * 1e9)
        self._msg = Clock()
        # Depth 1, reliable: subscribers only need the newest time, and none may miss that it moved.
        self._pub = self.create_publisher(Clock, CLOCK_TOPIC, reliable_qos(1))
        self._first: int | None = None
        self.setup_loop(round(self.sim_period_ns / self.rate))
        self.get_logger().info(f"/clock: {cfg.scene.period_s * 1e3:g} ms steps at {self.rate:g} x real time")

    def tick(self, index: int, stamp_ns: int) -> None:
        if self._first is None:
            self._first = index
        t = self.start_ns + (index - self._first) * self.sim_period_ns
        c = self._msg.clock
        c.sec, c.nanosec = t // 1_000_000_000, t % 1_000_000_000
        self._pub.publish(self._msg)

    def diagnostic_values(self) -> dict[str, float | int | str]:
        return {"rate": self.rate}


def main() -> None:
    node_main(ClockSource)


if __name__ == "__main__":
    main()

"""What master_eba and slave_eba share: one side's TeleopController driven by the newest remote
sample its sync buffer released, behind the remote-data watchdog, and its EBA internals topic."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from haptic_teleop.core.watchdog import ForceFade, Watchdog
from haptic_teleop.nodes import WATCHDOG_FADE_S, WATCHDOG_TIMEOUT_S
from haptic_teleop.nodes.base import LiveNode
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.messages import EbaOut, JointStateOut, take_latest
from haptic_teleop.nodes.params import declare_value
from haptic_teleop.nodes.topics import MASTER_EBA, SLAVE_EBA, received_topic, sent_topic, stream_qos
from haptic_teleop.nodes.wire import scene_law, wire_of

WATCHDOG_PARAMS = ("watchdog.timeout_s", "watchdog.fade_s")


def declare_watchdog(node: LiveNode, period_ns: int) -> Watchdog:
    timeout_s = declare_value(
        node, "watchdog.timeout_s", WATCHDOG_TIMEOUT_S, "remote data older than this (no arrival) starts the fade",
        0.002, 60.0,
    )  # fmt: skip
    fade_s = declare_value(
        node, "watchdog.fade_s", WATCHDOG_FADE_S, "force fades to zero (and back) over this time", 0.0, 60.0
    )
    return Watchdog(round(timeout_s * 1e9), round(fade_s * 1e9), period_ns)


class EbaSide:
    """Per tick: take the newest released remote sample (if any), feed the watchdog, fade the
    saturation limit by its gain, run the control law and the energy bound."""

    def __init__(self, node: LiveNode, role: str, config: Any):
        """`config`: the node's validated scene (haptic_teleop.scene.schema.Scene)."""
        from pathlib import Path

        from sensor_msgs.msg import JointState

        from haptic_teleop.assembly.parts import side_controller
        from haptic_teleop.scene.traces import read_operator_trace

        period_s = config.scene.period_s
        self.period_s = period_s
        self.watchdog = declare_watchdog(node, round(period_s * 1e9))
        op = config.operator
        trace = (
            read_operator_trace(Path(op.trace_file), f"node {node.get_name()}", "operator.trace_file")
            if op.trace_file
            else None
        )
        self.ctrl = side_controller(config, role, trace)
        self.fade = ForceFade(self.ctrl)
        remote, own = ("backward", "forward") if role == "master" else ("forward", "backward")
        # The samples' layouts: the stabilizer's (TDPA's energy joint, a wave port's wave; nodes/wire.py).
        law = scene_law(config)
        self._remote_wire = rw = wire_of(remote, 1, law)
        self._read = JointStateReader(rw.want, [(rw.names, rw.fields)], rw.width)
        self._sub = node.create_polled_subscription(JointState, received_topic(remote), stream_qos(), raw=True)
        self._own_wire = ow = wire_of(own, 1, law)
        # This side's samples, unless its direction has a codec (the node's CodecSender sends them).
        self._sent = (
            JointStateOut(node, sent_topic(own), ow.names, ow.fields)
            if getattr(config.network, own).codec is None
            else None
        )
        self._eba_out = EbaOut(node, MASTER_EBA if role == "master" else SLAVE_EBA)
        self.remote_samples = 0

    def step(self, x: Sequence[float], v: Sequence[float], stamp_ns: int) -> list[float]:
        remote = take_latest(self._sub)
        if remote is not None:
            self.remote_samples += 1
            self.ctrl.set_remote(self._remote_wire.payload(self._read(remote)[1]))
            self.watchdog.feed(stamp_ns)
        self.fade.set_gain(self.watchdog.update(stamp_ns))
        return self.ctrl.step(x, v)

    def send(self, stamp_ns: int, x: float, v: float, f_env: float = 0.0) -> None:
        """Publish the sample this side sends after `step` (`TeleopController.sample1`: the
        master's (x, v), the slave's (f_env, x, v); TDPA's energy; a wave port's wave)."""
        assert self._sent is not None, "a direction with a codec sends through its CodecSender"
        self._sent.publish(stamp_ns, self._own_wire.values(self.ctrl.sample1(x, v, f_env)))

    def applied(self, force: Sequence[float]) -> None:
        """The force the plant applied over the period that follows `step`: the reservoir
        accounts with it (docs/eba_actuator_limits.md, "Actuator limits inside the bound")."""
        self.ctrl.bound.applied1(force[0])

    def publish_internals(self) -> None:
        self._eba_out.publish(self.ctrl.bound.energy_j[0], self.ctrl.force_desired[0])

    def bound_ms(self) -> float:
        """The watchdog bound: zero force at most this long after the last arrival."""
        return self.watchdog.bound_s(self.period_s) * 1e3

    def diagnostic_values(self) -> dict[str, float | int | str]:
        wd = self.watchdog
        return {
            "watchdog_gain": round(wd.gain, 3),
            "watchdog_trips": wd.trips,
            "remote_samples": self.remote_samples,
            "rejected_samples": self.ctrl.rejected_samples,
        }

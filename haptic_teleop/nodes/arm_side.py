"""What master_eba and slave_eba run for an arm scene (docs/live_arms.md, "Arm scenes").

The node hosts its side's MuJoCo arm in-process (the master device; the slave arm as a ros2_control
hardware interface would) and runs the engine's per-side tick on it: with numba, the side's part of
the engine's compiled tick (`compiled_side.CompiledSideTick`, `side_kernel.side_tick`), else
`side.SideTick` (the same results, in the interpreter): the task-space law, the task force's
saturation, each motor's room left by gravity compensation, the pooled joint energy bound, on the
parts `assembly.build_arm_parts` builds. No arithmetic of the tick is written here: the node only
takes the newest released remote sample (through the side's `SampleGuard`), feeds the remote-data
watchdog, whose gain scales the task force's limit before the bound (as `ForceFade` does for one
axis), and publishes what the bag records, in the bag's layouts (`record.layouts.topic_specs` of
the scene's `TickSchema`: JointState with the joint names, PoseStamped, WrenchStamped, the EBA
arrays).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from haptic_teleop.nodes.base import LiveNode
from haptic_teleop.nodes.cdr import JointStateReader
from haptic_teleop.nodes.eba_side import declare_watchdog
from haptic_teleop.nodes.messages import JointStateOut, SpecOut, take_all, take_latest
from haptic_teleop.nodes.topics import (
    SCENE_START_TOPIC,
    latched_qos,
    received_topic,
    sample_topic,
    scene_start_ns,
    sent_topic,
    stream_qos,
)
from haptic_teleop.nodes.wire import scene_law, wire_of
from haptic_teleop.record.columns import measured_topic


class ArmEbaSide:
    """One side of an arm scene in a node: its plant, its SideTick, the watchdog, the remote input
    and the bag-layout publishers of the side's topics."""

    def __init__(self, node: LiveNode, role: str, config: Any) -> None:
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Header

        from haptic_teleop.assembly import compiled_side
        from haptic_teleop.assembly.parts import build_arm_parts
        from haptic_teleop.assembly.side import side_ticks
        from haptic_teleop.record.layouts import topic_specs
        from haptic_teleop.scene.load import side_period_ticks
        from haptic_teleop.scene.sides import side_period_s

        self.role = role
        self.parts = parts = build_arm_parts(config)  # both arms: the mapping's offset needs both starts
        mt, st = side_ticks(parts)
        self.side = parts.master if role == "master" else parts.slave
        # A side with its own period (<side>.period_s = `every` scene periods: docs/arms.md, "A side's
        # own period") runs the node's loop at that period; its bound, watchdog and ledger restart
        # count in it, and a simulated arm is stepped `every` scene periods per tick with the torque
        # held, as the engine's loop does (engine/loop.py).
        self.every = side_period_ticks(config, role, f"parameters of node {node.get_name()}")
        # The engine's compiled tick of this side (numba), else the Python SideTick (same results).
        fallback = mt if role == "master" else st
        if self.every > 1:  # the compiled side tick steps its arm once per tick (as the engine's compiled loop)
            self.tick, why = fallback, f"its own period {side_period_s(config, role):g} s"
        else:
            self.tick, why = compiled_side.side_tick(self.side, parts, role == "master", fallback)
        self.compiled = why is None
        if why is not None:
            node.get_logger().warning(f"{role} arm tick runs in Python, not compiled: {why}")
        other = parts.slave if role == "master" else parts.master
        other.plant.close()  # the other side's plant only gave its start point (a device's: never started)
        self.plant = self.side.plant
        # A real arm (plants/hardware_arm.py): its driver starts at the first tick's read, the tick reads
        # and writes it once, the safety guards act on the desired torque before the bound (SideTick),
        # a guard's fault or a device's HardwareError ends the node (exit 1, one line), and `close` on
        # every way out turns its torque off (docs/live_arms.md, "A real arm on a side").
        self.hardware = isinstance(self.plant, _hardware_arm())
        self.maps = parts.maps
        self.schema = parts.schema
        self.period_s = side_period_s(config, role)  # the side's own period (its loop's)
        self.watchdog = declare_watchdog(node, round(self.period_s * 1e9))
        self.limit_n = self.tick.limit
        axes = self.schema.task_axes
        remote = "backward" if role == "master" else "forward"
        own = "forward" if role == "master" else "backward"
        # The samples' layouts (nodes/wire.py): with TDPA the sender's pooled input energy rides
        # last, on a joint of its own (core/tdpa_coupled.py), as in the engine's packets.
        law = scene_law(config, axes)
        self.tdpa = law == "tdpa"
        # wave variables: the side's waves ride where the velocities were (core/wave_coupled.py)
        self.wave = config.controllers.master.eba.law == "wave"
        self._in_wire = rw = wire_of(remote, axes, law)
        self._read = JointStateReader(rw.want, [(rw.names, rw.fields)], rw.width)
        self._own_wire = ow = wire_of(own, axes, law)
        self._wire_out: JointStateOut | None = None  # TDPA, wave: /<own>/sent in the wire's layout (`send`)
        if (self.tdpa or self.wave) and getattr(config.network, own).codec is None:
            self._wire_out = JointStateOut(node, sent_topic(own), ow.names, ow.fields)
        self._sub = node.create_polled_subscription(JointState, received_topic(remote), stream_qos(), raw=True)
        specs = topic_specs(self.schema)
        self.out = {t: SpecOut(node, s) for t, s in specs.items() if t in side_topics(role, self.schema)}
        self.node = node
        self._sample_out: SpecOut | None = None
        # Scene time 0 (announced by the operator source ahead of time, latched): the bound's ledger
        # restarts there with min(reservoir, initial energy), so energy the side took in while the
        # graph settled is not spent inside the recorded run, whose analysis starts each side at
        # its initial energy (its true margin from the bag is then >= the ledger's, >= 0).
        self._start_sub = node.create_polled_subscription(Header, SCENE_START_TOPIC, latched_qos())
        self._scene_period_ns = round(config.scene.period_s * 1e9)  # scene time 0 is on the scene's grid
        self.restart_ns: int | None = None
        self.restarted_j: float | None = None  # the energy the ledger discarded at scene time 0
        self.remote: tuple[float, ...] | None = None
        self.measured: np.ndarray | None = None  # a real arm's reported port torque of the last hold
        self._last_write_s: float | None = None
        self.long_holds = 0  # a real arm's writes held longer than two periods (wall time)
        self.max_hold_s = 0.0
        self.remote_samples = 0
        self.malformed_samples = 0

    def torque(self, x: np.ndarray, v: np.ndarray, stamp_ns: int) -> np.ndarray:
        """The side's torque for this tick (SideTick.torque) on the newest accepted remote sample."""
        if self.restarted_j is None:
            self._restart(stamp_ns)
        raw = take_latest(self._sub)
        if raw is not None:
            try:
                sent_ns, values = self._read(raw)
            except IndexError:  # not an arm payload (fewer values than the task has axes): ignored
                self.malformed_samples += 1
            else:
                payload = self._in_wire.payload(values) if self._in_wire.maps else values
                self.remote_samples += 1
                if self.side.guard.accept(payload):
                    self.remote = payload
                    if self.tdpa and self._counts(sent_ns):
                        self.tick.bound.receive(payload[-1])
                    elif self.wave and self._counts(sent_ns):  # its waves, used once
                        self.tick.bound.receive(payload)
                self.watchdog.feed(stamp_ns)
        self.tick.limit = self.limit_n * self.watchdog.update(stamp_ns)
        return self.tick.torque(x, v, self.remote)

    def _counts(self, sent_ns: int) -> bool:
        """TDPA, wave variables: whether a remote sample's energy (its count, its waves) is of this
        side's ledger. After the restart at scene time 0 only samples stamped at or after it: the
        remote side restarted its ledger at its first tick there, so an earlier sample carries energy from before
        (docs/stabilizers_arms.md, "TDPA live on arms: the restart"). Before the restart every
        sample counts (it is discarded)."""
        return self.restarted_j is None or self.restart_ns is None or sent_ns >= self.restart_ns

    def send(self, direction: str, stamp_ns: int, payload: tuple[float, ...]) -> None:
        """This tick's sample on /<direction>/sent (a direction without a codec): the bag's layout;
        with TDPA the wire's, the side's pooled input energy last (`sent_j`, as the engine's
        ArmSideStage), with wave variables its waves in the velocities' place (`sent`), and the bag's
        layout on /<direction>/sample for the recorder."""
        if self._wire_out is None:
            self.publish(sent_topic(direction), stamp_ns, payload)
            return
        self.publish_sample(direction, stamp_ns, payload)
        bound = self.tick.bound
        if self.wave:
            wire = (*payload[:3], *bound.sent.tolist(), *payload[6:])
        else:
            wire = (*payload, bound.sent_j)
        self._wire_out.publish(stamp_ns, self._own_wire.values(wire))

    def _restart(self, stamp_ns: int) -> None:
        if self.restart_ns is None:
            told = take_all(self._start_sub)
            if not told:
                return
            self.restart_ns = scene_start_ns(told[-1], self._scene_period_ns)
        if stamp_ns >= self.restart_ns:  # the side's first tick at or after scene time 0 (on it: operator_source)
            bound = self.tick.bound
            e = min(bound.energy_j, bound.params.initial_energy_j)
            self.restarted_j = bound.energy_j - e
            bound.restart(e)

    def read_point(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The tick's start: q, qd and the point's x, v (world frame), the plant's `read` and
        `point` (compiled with the tick when it is)."""
        if self.compiled:
            return self.tick.read_point()  # type: ignore[no-any-return]
        q, qd = self.plant.read()
        if self.hardware:
            # A real arm lives in wall time: the motion since the last read took this long (the
            # driver's read times; one period on a lockstep clock), and the ledger credits its damping
            # over that time (CoupledEnergyBound.stretch), as the engine's loop does. The plant's
            # guard stops the side when a hold exceeds the bound's budget (docs/eba_many_joints.md).
            self.tick.bound.stretch(self.plant.read_interval_s)
            # The ledger books the port torque the device reported over the hold that just ended,
            # not the command (docs/hardware_plant.md, "Applied, not commanded"), as the engine's loop does.
            self.measured = self.plant.port_torque_nm
            self.tick.bound.held[:] = self.measured
        x, v = self.plant.point()
        return q, qd, x, v

    def step(self, torque: np.ndarray, hand_force_n: np.ndarray | None = None) -> np.ndarray:
        """The plant's `step` (compiled with the tick when it is); returns the torques applied. A
        simulated arm with its own period is stepped `every` scene periods with the torque held (the
        ledger takes the first step's applied torques, as the engine's loop); a real arm holds it."""
        if self.compiled:
            return self.tick.step(torque, hand_force_n)  # type: ignore[no-any-return]
        applied = self.plant.step(torque, hand_force_n)
        if self.hardware:
            self._hold()
        else:
            for _ in range(self.every - 1):
                self.plant.step(torque, hand_force_n)
        return applied  # type: ignore[no-any-return]

    def _hold(self) -> None:
        """A real arm holds each write until the next one, in wall time: count the holds longer than
        two periods (the energy bound budgets max_hold_s; docs/live_arms.md, "Late ticks on a real arm")."""
        now = time.monotonic()
        last = self._last_write_s
        self._last_write_s = now
        if last is None:
            return
        hold = now - last
        self.max_hold_s = max(self.max_hold_s, hold)
        if hold > 2.0 * self.period_s:
            self.long_holds += 1

    def applied(self, torque: np.ndarray) -> None:
        """The ledger takes the torques the plant applied (as the engine's loop; a real arm's are
        replaced by the torque it reports at the next read, `read_point`)."""
        self.tick.bound.held[:] = torque

    def publish_measured(self, stamp_ns: int) -> None:
        """A real arm's /<side>/measured_effort: the port torque it reported at this tick's read
        (the hold that ended there); nothing on a simulated arm (its schema has no such topic)."""
        if self.measured is not None:
            self.out[measured_topic(self.role)].publish(stamp_ns, self.measured)

    def publish(self, topic: str, stamp_ns: int | None, values: Any) -> None:
        self.out[topic].publish(stamp_ns, values)

    def publish_sample(self, direction: str, stamp_ns: int, values: Any) -> None:
        """The tick's sample on /<direction>/sample (a codec sends it as packets on /<direction>/sent):
        the recorder's source of the columns only /<direction>/sent fills (the velocities)."""
        out = self._sample_out
        if out is None:
            import dataclasses

            spec = self.out[sent_topic(direction)].spec
            out = self._sample_out = SpecOut(self.node, dataclasses.replace(spec, name=sample_topic(direction)))
        out.publish(stamp_ns, values)

    def publish_internals(self, stamp_ns: int) -> None:
        """The task force the applied torques realise, the desired one and the reservoir."""
        t = self.tick
        p = self.role
        self.out[f"/{p}/{'rendered' if p == 'master' else 'applied'}_wrench"].publish(stamp_ns, t.rendered)
        self.out[f"/{p}/eba"].publish(None, (t.bound.energy_j, *t.force.tolist()))

    def bound_ms(self) -> float:
        return self.watchdog.bound_s(self.period_s) * 1e3

    def diagnostic_values(self) -> dict[str, float | int | str]:
        wd = self.watchdog
        holds: dict[str, float | int] = {
            "long_holds": self.long_holds,
            "max_hold_ms": round(self.max_hold_s * 1e3, 3),
        }
        if self.hardware:
            p = self.plant
            holds.update(
                {
                    "read_long_holds": p.long_holds,
                    "read_longest_hold_ms": round(p.longest_hold_s * 1e3, 3),
                    "over_budget_holds": p.over_budget_holds,
                    "hold_budget_ms": round(p.hold_budget_s * 1e3, 3),
                }
            )
        return {
            "watchdog_gain": round(wd.gain, 3),
            "watchdog_trips": wd.trips,
            "remote_samples": self.remote_samples,
            "rejected_samples": self.side.rejected_samples,
            "malformed_samples": self.malformed_samples,
            "joint_limited_ticks": self.tick.limited_ticks,
            "arm_tick": "compiled" if self.compiled else "python",
            "side_period_ticks": self.every,
            "ledger_restarted_discarding_j": self.restarted_j if self.restarted_j is not None else -1.0,
            **(holds if self.hardware else {}),
        }

    def hold_report(self) -> str | None:
        """One line on a real arm's holds longer than two periods, or None (none, or not a real arm)."""
        if not self.hardware or not self.long_holds:
            return None
        return (
            f"{self.role} arm: {self.long_holds} torque holds longer than two periods (the longest "
            f"{self.max_hold_s * 1e3:.1f} ms, the period {self.period_s * 1e3:g} ms): the energy bound budgets one "
            f"hold of {self.plant.hold_budget_s * 1e3:g} ms ({self.role}.hardware.max_hold_s; a longer one stops the "
            "side: docs/eba_many_joints.md, 'Late ticks on a real clock')"
        )

    def close(self, log: Any = None) -> None:
        """Release the plant (a real arm: torque off), then report its long holds, if any."""
        self.plant.close()
        line = self.hold_report()
        if line is not None and log is not None:
            log(line)


def _hardware_arm() -> type:
    from haptic_teleop.plants.hardware_arm import HardwareArm

    return HardwareArm


HARDWARE_SCHEDULING = (
    "the arm's vendor SDK busy-waits on the serial port for each reply, which at SCHED_FIFO starves the "
    "kernel's serial path on its CPU"
)


def side_topics(role: str, schema: Any) -> tuple[str, ...]:
    """The per-tick topics one side's node publishes (record.columns.tick_topics); a side on
    hardware also its /<side>/measured_effort."""
    measured = (measured_topic(role),) if schema.measured(role) else ()
    if role == "master":
        return (
            "/master/joint_states", "/master/handle_pose", "/master/rendered_wrench", "/master/eba", "/forward/sent",
            *measured,
        )  # fmt: skip
    return (
        "/slave/joint_states", "/slave/tool_pose", "/slave/applied_wrench", "/slave/contact_wrench", "/slave/eba",
        "/backward/sent", *measured,
    )  # fmt: skip

"""The stages of one tick (docs/architecture.md, "One tick"): each side (`AxisSide` for one-axis
scenes, `ArmSideStage` for arms), the operator (`AxisOperator`, `ArmOperator`), a direction's channel
(`PlainChannel`: link and playout buffer; the codec stage's `CodecChannel`, assembly/channel.py,
has the same `step`) and the row of the run's tick schema (`AxisRow`, `ArmRow`).

The engine's Python loop (engine/loop.py) runs them in the one order every loop has:

    master tick (sense, control, its sample) -> forward channel -> the slave takes what it
    releases -> slave tick -> backward channel -> the master takes what it releases
    -> the operator's hand -> both sides actuate -> the operator finishes -> the row

Each stage holds its part of the tick's state and calls the core objects the assembly built (the
controllers and bounds, the arm's side tick, the links and buffers, the codecs); none spells a rule.
"""

from __future__ import annotations

import bisect
import struct
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop.core.link import Link, Packet
from haptic_teleop.core.operator import imposed_force1
from haptic_teleop.core.playout import PlayoutBuffer
from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
from haptic_teleop.core.wave_coupled import CoupledWaveBound

if TYPE_CHECKING:
    from haptic_teleop.assembly.parts import ArmParts, ArmSide
    from haptic_teleop.core.controller import TeleopController
    from haptic_teleop.core.operator import Operator
    from haptic_teleop.record.columns import TickSchema

Payload = tuple[float, ...]


# --------------------------------------------------------------------------------------------
# A direction's channel.


def _seq(p: Packet) -> int:
    return p.seq


def settled_records(link: Link, buf: PlayoutBuffer, sent: int, final: bool) -> np.ndarray | None:
    """Records (bag rows) of the packets at the head of `link.log` whose fate is final, taken
    out of the log; None if there are none. `sent`: the packets of ticks before it were sent.

    A packet's record is final once the packet is neither in flight nor held by the buffer (lost,
    played, skipped, late or a duplicate): every packet older than the oldest one still in the
    link or the buffer. The log is in send order, so those are a prefix of it. `final` (the run
    ended): every packet of the ticks before `sent`, in flight or not."""
    mark = sent
    if not final:
        for s in (link.oldest_in_flight_seq(), buf.oldest_held_seq()):
            if s is not None and s < mark:
                mark = s
    log = link.log
    k = bisect.bisect_left(log, mark, key=_seq)
    if k == 0:
        return None
    from haptic_teleop.record.layouts import packet_rows

    rows = packet_rows(log[:k])
    del log[:k]
    return rows


class PlainChannel:
    """A direction without a codec: each tick's sample is one packet into the link; what has
    arrived goes into the playout buffer, which releases the sample for this tick."""

    def __init__(self, link: Link, buffer: PlayoutBuffer, size_bytes: int) -> None:
        self.link, self.buffer, self.size_bytes = link, buffer, size_bytes
        self._send, self._deliver = link.send, link.deliver
        self._push, self._release = buffer.push, buffer.release
        self.occupancy: float = buffer.occupancy  # the buffer's after this tick's release

    def step(self, n: int, now_ns: int, sample: Payload) -> tuple[Payload | None, int]:
        """Send tick n's sample, deliver, release: (the released payload or None, its seq or -1)."""
        self._send(Packet(n, now_ns, sample, self.size_bytes))
        push = self._push
        for p in self._deliver(now_ns):
            push(p, now_ns)
        rel = self._release(now_ns)
        self.occupancy = self.buffer.occupancy
        return (None, -1) if rel is None else (rel.payload, rel.seq)

    def settled(self, sent: int, final: bool) -> np.ndarray | None:
        return settled_records(self.link, self.buffer, sent, final)


class CodecStage:
    """A direction with a codec (assembly/channel.py's `CodecChannel`) as a stage: its `step`, no
    buffer (occupancy 0), its packets' records once final."""

    occupancy = 0.0

    def __init__(self, channel: Any, period_ns: int) -> None:
        self.channel, self.period_ns = channel, period_ns
        self.step = channel.step

    def settled(self, sent: int, final: bool) -> np.ndarray | None:
        return self.channel.settled(sent, final, self.period_ns)  # type: ignore[no-any-return]


def channel_stage(codec: Any, link: Link, buffer: PlayoutBuffer, size_bytes: int, period_ns: int) -> Any:
    """A direction's stage: its codec's, or its link and buffer's."""
    return PlainChannel(link, buffer, size_bytes) if codec is None else CodecStage(codec, period_ns)


# --------------------------------------------------------------------------------------------
# One-axis scenes.


class AxisSide:
    """One side of a one-axis scene: its plant and its controller (law, saturation, bound)."""

    def __init__(self, plant: Any, ctrl: TeleopController, master: bool) -> None:
        self.plant, self.ctrl, self.master = plant, ctrl, master
        self._read, self._step, self._contact = plant.read, plant.step, plant.contact_force
        self._control, self._set_remote = ctrl.step1, ctrl.set_remote  # one axis: the scalar path
        self._applied = ctrl.bound.applied1  # the reservoir books the force the plant applied
        self.desired, self.energy = ctrl.force_desired, ctrl.bound.energy_j  # updated in place
        self._sample = ctrl.sample1  # what it sends: (x, v) or (f_env, x, v), TDPA's energy, or its wave
        self.xs: list[float] = [0.0]
        self.vs: list[float] = [0.0]
        self.x = self.v = self.f_env = self.force = self.applied = 0.0

    def tick(self, n: int) -> Payload:
        """Sense (the plant's state at t_n; the slave's wall force over the last period), control
        (the law on the newest remote sample, saturation, the bound), and the sample to send:
        the master's (x, v), the slave's (f_env, x, v); with TDPA, its input energy last; with wave
        variables, (its wave, x)."""
        self.xs, self.vs = xs, vs = self._read()
        self.x, self.v = x, v = xs[0], vs[0]
        self.force = self._control(x, v)
        if self.master:
            return self._sample(x, v)
        self.f_env = f = self._contact()[0]
        return self._sample(x, v, f)

    def take(self, payload: Payload) -> None:
        self._set_remote(payload)

    def actuate(self, n: int, hand: list[float] | None) -> None:
        self.applied = self._step([self.force], hand)[0] if self.master else self._step([self.force])[0]
        self._applied(self.applied)


class AxisOperator:
    """The operator of a one-axis scene: a hand (a spring and damper toward the intended position)
    on the master's handle, or with `operator.profile: imposed` a position source that puts the
    handle on its trajectory after the step (the force it took is the op_force_n column)."""

    def __init__(self, operator: Operator, master: AxisSide, period_s: float) -> None:
        self.period_s = period_s
        self._hand = operator.hand_force_and_intended
        self.xd = self.vd = self.force = 0.0
        self._drive: Any = None
        if operator.imposed:
            plant = master.plant
            intended, set_state = operator.intended, plant.set_state
            mass, damping = plant.inertia_kg(), plant.joint_damping()[0]

            def drive(n1: int, v: float, applied: float) -> float:
                x1, v1 = intended(n1 * period_s)
                set_state(x1, v1)
                return imposed_force1(mass, damping, period_s, v, v1, applied)

            self._drive = drive
        else:
            self.finish = None  # type: ignore[assignment]  # nothing after the step: the loop skips it

    def hand(self, n: int, master: AxisSide) -> list[float]:
        fh, self.xd, self.vd = self._hand(n * self.period_s, master.xs, master.vs)
        self.force = fh[0]
        return fh  # type: ignore[no-any-return]

    def finish(self, n: int, master: AxisSide) -> None:
        """After the master's step: an imposed trajectory puts the handle on it at tick n + 1."""
        self.force = self._drive(n + 1, master.v, master.applied)


class AxisRow:
    """A one-axis tick's row (record/columns.py's ONE_DOF), packed straight into the block's
    memory: one C call, no tuple, no numpy scalar conversions."""

    def __init__(self, schema: TickSchema) -> None:
        self._pack = struct.Struct(f"<{schema.width}d").pack_into
        self.row_bytes = 8 * schema.width

    def write(
        self, block: Any, i: int, op: AxisOperator, m: AxisSide, s: AxisSide,
        frx: int, brx: int, focc: float, bocc: float,
    ) -> None:  # fmt: skip
        self._pack(
            block, i * self.row_bytes,
            op.xd, op.vd, op.force,
            m.x, m.v, m.applied, m.desired[0], m.energy[0],
            s.x, s.v, s.applied, s.desired[0], s.energy[0], s.f_env,
            frx, brx, focc, bocc,
        )  # fmt: skip


# --------------------------------------------------------------------------------------------
# Arm scenes.


class ArmSideStage:
    """One side of an arm scene: its plant, its side tick (`side.SideTick` or the compiled one), the
    workspace maps and the guard on the remote samples. A side with its own period (`every` scene
    ticks) reads, controls and writes every `every`-th tick and holds its command in between: a
    simulated arm is stepped with the held torque every scene tick, a real one is left alone. A real
    arm's ledger credits the damping over the time the tick's motion really took, and books the
    port torque the device reported for the hold that just ended (`measured`: its
    `port_torque_nm`), not the command (docs/hardware_plant.md, "Applied, not commanded")."""

    def __init__(self, side: ArmSide, tick: Any, maps: Any, master: bool, every: int, real: bool, hand: bool) -> None:
        self.side, self.side_tick, self.maps, self.master = side, tick, maps, master
        self.plant: Any = side.plant  # a MujocoArm, or a HardwareArm (its read_interval_s)
        self.guard = side.guard
        self.every, self.real, self.hand_on = every, real, hand
        self.due = True
        self.remote: Payload | None = None  # the newest accepted remote sample
        self.tdpa = isinstance(side.bound, CoupledTdpaBound)  # its energy rides on the samples
        self.wave = isinstance(side.bound, CoupledWaveBound)  # its waves ride where the velocities were
        # the tick's arrays (joints, the point in the task frame, the master's handle in the
        # device's frame for the hand, the slave's contact force and torque): set at the first sense
        self.q: Any = None
        self.qd: Any = None
        self.tau: Any = None
        self.applied: Any = None
        self.measured: Any = None  # a real arm's reported port torque over the hold that ended at the read
        self.x: Any = None
        self.v: Any = None
        self.hand_x: Any = None
        self.hand_v: Any = None
        self.f_env: Any = None
        self.t_env: Any = None

    def tick(self, n: int) -> Payload:
        """On a due tick: sense (joints, the point, the master's point mapped into the task frame,
        the slave's contact wrench) and control (the side tick on the newest remote sample); then
        the sample to send: the master's handle x, v, the slave's tool x, v and contact force."""
        self.due = due = n % self.every == 0
        plant = self.plant
        if due:
            self.q, self.qd = plant.read()
            if self.real:
                bound = self.side_tick.bound
                bound.stretch(plant.read_interval_s)  # the motion since the last read took its own time
                # The hold that ended at this read: the ledger books the torque the device reported
                # over it, not the one commanded (set in `actuate`), before the bound books the motion.
                self.measured = plant.port_torque_nm
                bound.held[:] = self.measured
            x, v = plant.point()
            if self.master:
                self.hand_x, self.hand_v = x, v
                self.x, self.v = self.maps.to_task_x(x), self.maps.to_task_v(v)
            else:
                self.x, self.v = x, v
                self.f_env, self.t_env = plant.contact_wrench()
            self.tau = self.side_tick.torque(self.x, self.v, self.remote)
        elif self.master and not self.real:  # the operator's hand meets the simulated handle where it is now
            self.hand_x, self.hand_v = plant.point()
        # TDPA: the side's pooled input energy rides last on its samples (core/tdpa_coupled.py);
        # wave variables: the side's waves in the velocities' place (core/wave_coupled.py).
        e = (self.side_tick.bound.sent_j,) if self.tdpa else ()
        v = self.side_tick.bound.sent if self.wave else self.v
        if self.master:
            return (*self.x.tolist(), *v.tolist(), *e)
        return (*self.x.tolist(), *v.tolist(), *self.f_env.tolist(), *e)

    def take(self, payload: Payload) -> None:
        if self.guard.accept(payload):
            self.remote = payload
            if self.tdpa:
                self.side_tick.bound.receive(payload[-1])
            elif self.wave:
                self.side_tick.bound.receive(payload)

    def actuate(self, n: int, hand: Any) -> None:
        hand = hand if self.hand_on else None
        if self.due:
            self.applied = self.plant.step(self.tau, hand)
            # the ledger: the torques the plant applied (a real arm's: replaced by its report at the next read)
            self.side_tick.bound.held[:] = self.applied
        elif not self.real:
            self.plant.step(self.tau, hand)


class ArmOperator:
    """The operator of an arm scene: a 3-D hand toward the intended point, in the device's frame
    (side.operator_hand); a real master's operator is a real hand, nothing is commanded."""

    finish = None  # a hand, not a position source: nothing after the step

    def __init__(self, parts: ArmParts, period_s: float) -> None:
        from haptic_teleop.assembly.side import operator_hand

        self.parts, self.period_s, self._hand = parts, period_s, operator_hand
        self.xd: Any = None
        self.vd: Any = None
        self.force: Any = None

    def hand(self, n: int, master: ArmSideStage) -> Any:
        self.xd, self.vd, self.force = self._hand(self.parts, n * self.period_s, master.hand_x, master.hand_v)
        return self.force


class ArmRow:
    """An arm tick's row: the scene's tick schema's groups (joint columns per joint, task columns
    per axis, all task columns in the shared frame)."""

    def __init__(self, schema: TickSchema, maps: Any) -> None:
        g = schema.group
        self.c = [g(name) for name in ARM_GROUPS]
        self.maps = maps
        # a real side's measured port torque (only in its schema: simulated rows are unchanged)
        self.cm = g("m_tau_measured_nm") if schema.master_measured else None
        self.cs = g("s_tau_measured_nm") if schema.slave_measured else None

    def write(
        self, block: np.ndarray, i: int, op: ArmOperator, m: ArmSideStage, s: ArmSideStage,
        frx: int, brx: int, focc: float, bocc: float,
    ) -> None:  # fmt: skip
        row = block[i]
        c = iter(self.c)
        mt, st = m.side_tick, s.side_tick
        row[next(c)] = op.xd
        row[next(c)] = op.vd
        row[next(c)] = self.maps.force_to_task(op.force) if m.hand_on else np.nan
        for side, tick in ((m, mt), (s, st)):
            row[next(c)] = side.q
            row[next(c)] = side.qd
            row[next(c)] = side.applied
            row[next(c)] = side.x
            row[next(c)] = side.v
            row[next(c)] = tick.rendered
            row[next(c)] = tick.force
            row[next(c)] = tick.bound.energy_j
        row[next(c)] = s.f_env
        row[next(c)] = s.t_env
        row[next(c)] = frx
        row[next(c)] = brx
        row[next(c)] = focc
        row[next(c)] = bocc
        if self.cm is not None:
            row[self.cm] = m.measured
        if self.cs is not None:
            row[self.cs] = s.measured


# The arm row's groups, in the order ArmRow writes them.
ARM_GROUPS = (
    "op_x_m", "op_v_m_per_s", "op_force_n",
    "m_q", "m_qd", "m_tau_nm", "m_x_m", "m_v_m_per_s", "m_force_n", "m_force_desired_n", "m_energy_j",
    "s_q", "s_qd", "s_tau_nm", "s_x_m", "s_v_m_per_s", "s_force_n", "s_force_desired_n", "s_energy_j",
    "s_contact_n", "s_contact_torque_nm", "fwd_rx_seq", "bwd_rx_seq", "fwd_occupancy", "bwd_occupancy",
)  # fmt: skip

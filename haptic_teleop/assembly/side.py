"""One side of an arm scene's tick, in Python, and what both sides share: the per-side arithmetic
(`SideTick`: law, saturation, motor room, bound), the workspace mapping's maps (`Maps`), the
operator's hand (`operator_hand`) and the wire sizes of the arm packets. The engine's Python arm
loop (engine/loop.py) and the live arm nodes (nodes/arm_side.py, operator_source) run these
same objects; compiled_side.py is the same side compiled (docs/arms.md, "The tick").
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from haptic_teleop.core.eba_coupled import joint_limited
from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound
from haptic_teleop.core.taskspace import dot, matrix_times, rendered_ratio, task_force_of, tick_scratch
from haptic_teleop.core.tdpa import slipped1
from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
from haptic_teleop.core.wave_coupled import CoupledWaveBound

if TYPE_CHECKING:
    from collections.abc import Mapping

    from haptic_teleop.assembly.parts import ArmParts, ArmSide
    from haptic_teleop.core.taskspace import WorkspaceMapping


def wire_payload_bytes(names: int, fields: int) -> int:
    """CDR size of the sensor_msgs/JointState carrying `fields` arrays of `names` values (one per axis)."""
    from haptic_teleop.record.layouts import typestore

    ts = typestore()
    cls = ts.types["sensor_msgs/msg/JointState"]
    hdr = ts.types["std_msgs/msg/Header"]
    stamp = ts.types["builtin_interfaces/msg/Time"]
    vals = np.zeros(names)
    empty = np.zeros(0)
    arrays = [vals if i < fields else empty for i in range(3)]
    msg = cls(
        header=hdr(stamp=stamp(sec=0, nanosec=0), frame_id=""),
        name=[f"axis_{i}" for i in range(names)],
        position=arrays[0],
        velocity=arrays[1],
        effort=arrays[2],
    )
    return len(bytes(ts.serialize_cdr(msg, "sensor_msgs/msg/JointState")))


def arm_message_bytes(floats: int) -> int:
    """Wire message of an arm scene's codec packet carrying `floats` values: the JointState of one
    name per task axis (more names when the payload needs them, three values a name), so the
    plain payloads (6 forward, 9 backward) have the plain arm packet's size (docs/codec_channels.md)."""
    names = max(3, -(-floats // 3))
    return wire_payload_bytes(names, -(-floats // names))


class _SideTick:
    """One side's per-tick arithmetic (law, saturation, motor room, bound) for the Python loop."""

    def __init__(self, side: ArmSide, jac_scale: np.ndarray | None) -> None:
        self.side = side
        self.plant = side.plant
        self.law = side.law
        self.bound = side.bound
        self.limit = side.force_limit_n
        # The master's law acts in the task frame: its Jacobian there is force_scale R J_device
        # (tau = J_device^T f_device with f_device = force_scale R^T F).
        self.jac_scale = jac_scale
        self.limited = np.zeros(self.plant.n)
        self.force = np.zeros(3)  # the desired task force (before saturation)
        self.ratio = 0.0  # applied / desired torque (direction kept): scales the task force
        # TDPA's velocity controller adds a damper along the joints' motion, and the two-condition
        # law cuts each joint alone: the applied torque is then no scaled copy of the desired one,
        # and its task force is solved for (`rendered`).
        bound = side.bound
        velocity = isinstance(bound, CoupledTdpaBound) and bound.controller == "velocity" and bound.params.enabled
        # the two-condition law bounds each joint within the motors' room this tick (its fallback
        # torque is then one the motor applies)
        self.per_joint = isinstance(bound, CoupledTwoConditionBound)
        # wave variables: the ports make the task force (before the torque) and cut their waves to
        # the force the motors' limits let through (after it): core/wave_coupled.py
        self.wave = isinstance(bound, CoupledWaveBound)
        joints = self.per_joint and bound.params.enabled
        self.task_force: np.ndarray | None = np.zeros(3) if velocity or joints else None
        # TDPA's admittance placement: the coupling's reference offset by the bound's slip
        self.admittance = isinstance(bound, CoupledTdpaBound) and bound.admittance
        self._c1 = side.law.constants().stiffness_n_per_m if self.admittance else None
        self.limited_ticks = 0  # ticks a motor's torque limit scaled the torque down
        k = side.kernels
        self.joint_limited = k["joint_limited"] if k is not None else joint_limited
        self.task_force_of = k["task_force_of"] if k is not None else task_force_of
        self._wrench = np.zeros(6 if side.rotational else 3)  # the velocity controller's solved wrench
        self._scratch = tick_scratch(self._wrench.shape[0], self.plant.n)
        self.safe = getattr(self.plant, "safe_torque", None)  # HardwareArm's guards; none on MuJoCo

    def torque(self, x: np.ndarray, v: np.ndarray, remote: tuple[float, ...] | None) -> np.ndarray:
        plant = self.plant
        q, qd = plant.read()
        jac = plant.jacobian(rotational=self.side.rotational)
        if self.jac_scale is not None:
            matrix_times(jac[:3], self.jac_scale, jac[:3].copy())  # summed in order: the compiled loop's bits
        if remote is None:
            rx = rv = None
        else:
            rx = np.asarray(remote[0:3])
            rv = np.asarray(remote[3:6])
            if self.admittance:
                rx = rx + self.bound.slip_m
        r_tool = plant.orientation() if self.side.rotational else None
        port = self.bound.begin(x, v) if self.wave else None
        tau = self.law.torque(jac, qd, x, v, rx, rv, None, r_tool, port)
        f = self.law.wrench[:3]
        self.force[:] = f
        norm = float(np.sqrt(dot(f, f)))
        if norm > self.limit:
            tau = tau * (self.limit / norm)
        lo, hi = plant.torque_room()
        self.joint_limited(self.limited, tau, lo, hi, True)
        if not np.array_equal(self.limited, tau):
            self.limited_ticks += 1
        # A real arm's safety guards (core/safety.py) shrink the torque before the bound.
        into = self.limited if self.safe is None else self.safe(self.limited)
        out = self.bound.step(q, into, lo, hi) if self.per_joint else self.bound.step(q, into)
        self.ratio = rendered_ratio(out, tau, self.limit, norm)
        if self.wave:
            self.bound.end(self.ratio)
        if self.task_force is not None:  # not a scaled copy of tau (TDPA's velocity controller, two conditions)
            self.task_force_of(self._wrench, jac, out, self._scratch)
            self.task_force[:] = self._wrench[:3]
            return out
        if self.admittance:  # the task force into the bound against the one out of it (the controller's cut)
            before = rendered_ratio(into, tau, self.limit, norm)
            slip, c1, recover = self.bound.slip_m, self._c1, self.bound.recover
            for i in range(3):
                slip[i] = slipped1(slip[i], before * f[i], self.ratio * f[i], c1[i], recover)
        return out

    @property
    def rendered(self) -> np.ndarray:
        """The task force the applied torque renders: the desired task force times the ratio of
        the applied to the desired torque (the bound scales the torque vector by one factor), or,
        where a controller adds torque of its own or cuts joints alone (TDPA's velocity controller,
        the two-condition law), the force whose
        J^T is the applied torque (least squares, the task frame; docs/stabilizers_arms.md, "Pooled joints")."""
        return self.ratio * self.force if self.task_force is None else self.task_force


class _Maps:
    """The workspace mapping's five maps for the tick: `WorkspaceMapping`'s own methods, or the same
    functions compiled (the kernels) when the scene has them."""

    def __init__(self, mapping: WorkspaceMapping, kernels: Mapping[str, Callable[..., Any]] | None) -> None:
        self.to_task_x = mapping.position_to_task
        self.to_task_v = mapping.velocity_to_task
        self.to_master_x = mapping.position_to_master
        self.to_master_v = mapping.velocity_to_master
        self.force_to_task = mapping.force_to_task
        self.force_to_master = mapping.force_to_master
        if kernels is None:
            return
        r, s, o, fs = mapping.matrix, mapping.scale, mapping.offset, mapping.force_scale
        mp, ump, mv, mvb = (kernels[k] for k in ("map_point", "unmap_point", "map_vector", "map_vector_back"))

        def to_task_x(x: np.ndarray) -> np.ndarray:
            out = np.empty(3)
            mp(out, r, s, o, x)
            return out

        def to_task_v(v: np.ndarray) -> np.ndarray:
            out = np.empty(3)
            mv(out, r, s, v)
            return out

        def to_master_x(x: np.ndarray) -> np.ndarray:
            out = np.empty(3)
            ump(out, r, s, o, x)
            return out

        def to_master_v(v: np.ndarray) -> np.ndarray:
            out = np.empty(3)
            mvb(out, r, 1.0 / s, v)
            return out

        def force_to_task(f: np.ndarray) -> np.ndarray:
            out = np.empty(3)
            mv(out, r, 1.0 / fs, f)
            return out

        def force_to_master(f: np.ndarray) -> np.ndarray:
            out = np.empty(3)
            mvb(out, r, fs, f)
            return out

        self.to_task_x, self.to_task_v, self.to_master_x = to_task_x, to_task_v, to_master_x
        self.to_master_v, self.force_to_task, self.force_to_master = to_master_v, force_to_task, force_to_master
        z = np.zeros(3)  # compile (or load) them now, not in the timed loop
        for fn in (to_task_x, to_task_v, to_master_x, to_master_v, force_to_task, force_to_master):
            fn(z)


# The per-side tick and the maps by their public names: the live nodes (master_eba, slave_eba,
# operator_source) run the very same arithmetic per tick as this loop (docs/live_arms.md, "Arm scenes").
SideTick = _SideTick
Maps = _Maps


def operator_hand(
    parts: ArmParts, t_s: float, x_dev: np.ndarray, v_dev: np.ndarray
) -> tuple[tuple[float, ...], tuple[float, ...], np.ndarray]:
    """The operator at scene time `t_s` on a handle at `x_dev`, `v_dev` (device frame): the intended
    point and velocity (task frame) and the hand's force on the handle (device frame), a 3-D
    spring-damper toward the intended point mapped into the device frame (docs/arms.md, step 6)."""
    maps = parts.maps
    op = parts.operator
    xd_t, vd_t = op.intended_along(t_s, parts.operator_origin_m, parts.operator_direction)
    xd = maps.to_master_x(np.asarray(xd_t))
    vd = maps.to_master_v(np.asarray(vd_t))
    f_hand = op.params.stiffness_n_per_m * (xd - x_dev) + op.params.damping_n_s_per_m * (vd - v_dev)
    return xd_t, vd_t, f_hand


def side_ticks(parts: ArmParts) -> tuple[_SideTick, _SideTick]:
    """The per-side tick state of an arm scene (built, and the law compiled, before the loop)."""
    mapping = parts.mapping
    parts.maps = _Maps(mapping, parts.master.kernels)
    return _SideTick(parts.master, mapping.force_scale * mapping.matrix), _SideTick(parts.slave, None)

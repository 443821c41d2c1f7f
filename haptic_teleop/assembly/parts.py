"""Assembly: the one place a scene's core objects and plants are built.

The engine's loops (Python and compiled) and the live nodes all take their controllers, energy
bounds, operator, links, playout buffers and plants from here, so a scene means the same parts
wherever it runs (docs/architecture.md). One-axis scenes: `assemble_axis` (every part of a run:
`build_operator`, the plants, `side_controller`, `build_network`, the codec channels). Arm scenes
(docs/arms.md): `build_arm_parts`, every part of both sides in task space.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from haptic_teleop.assembly.plants import build_master_plant, build_slave_plant
from haptic_teleop.core.controller import ControllerParams, RemoteLimits, TeleopController
from haptic_teleop.core.eba_state import EnergyBoundParams
from haptic_teleop.core.link import Link
from haptic_teleop.core.netconfig import min_one_way_delay_s
from haptic_teleop.core.operator import Operator, OperatorParams
from haptic_teleop.core.playout import PlayoutBuffer, contact_force_slope
from haptic_teleop.core.playout_config import build_buffer
from haptic_teleop.core.playout_seed import NetworkAdaptiveBuffer, TransparencyBuffer
from haptic_teleop.core.transparency import ContactStart
from haptic_teleop.scene.contact import contact_start_of, transparency_budget_of
from haptic_teleop.scene.controllers import ControllerConfig
from haptic_teleop.scene.schema import OperatorConfig, SaturationConfig, Scene
from haptic_teleop.scene.traces import (
    build_scene_link,  # the link with its trace files' rows
    read_operator_trace,
)

if TYPE_CHECKING:
    import numpy as np

    from haptic_teleop.core.controller import SampleGuard
    from haptic_teleop.core.eba_coupled import CoupledEnergyBound, CoupledEnergyBoundParams
    from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound
    from haptic_teleop.core.taskspace import TaskSpaceLaw, WorkspaceMapping
    from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
    from haptic_teleop.core.wave_coupled import CoupledWaveBound

    # An arm side's stabilizer (arm_bound): the interface SideTick and the stages use.
    ArmBound = CoupledEnergyBound | CoupledTdpaBound | CoupledTwoConditionBound | CoupledWaveBound
    from haptic_teleop.plants.arm import MujocoArm
    from haptic_teleop.plants.hardware_arm import HardwareArm
    from haptic_teleop.record.columns import TickSchema

__all__ = [
    "REMOTE_LIMIT_MARGIN",
    "AxisParts",
    "assemble_axis",
    "build_arm_parts",
    "build_controller",
    "build_master_plant",
    "build_network",
    "build_operator",
    "build_slave_plant",
    "read_operator_trace",
    "remote_limits",
    "side_controller",
]


REMOTE_LIMIT_MARGIN = 10.0  # remote values beyond 10x what the scene can produce are faults


def operator_reach(
    op: OperatorConfig, trace: tuple[tuple[float, ...], tuple[float, ...]] | None
) -> tuple[float, float]:
    """How far (m) and how fast (m/s) the operator's profile moves the hand at most (0 for hold)."""
    if op.profile == "push":
        return abs(op.distance_m), abs(op.speed_m_per_s)
    if op.profile == "imposed":
        return abs(op.speed_m_per_s) * (op.duration_s or 0.0), abs(op.speed_m_per_s)
    if op.profile == "sinusoid":
        return abs(op.amplitude_m), 2.0 * math.pi * op.frequency_hz * abs(op.amplitude_m)
    if op.profile == "trace" and trace is not None:
        ts, xs = trace
        slopes = [abs((xs[i + 1] - xs[i]) / (ts[i + 1] - ts[i])) for i in range(len(ts) - 1)]
        return max(abs(x) for x in xs), max(slopes, default=0.0)
    return 0.0, 0.0


def remote_limits(config: Scene, trace: tuple[tuple[float, ...], tuple[float, ...]] | None = None) -> RemoteLimits:
    """Largest plausible remote values for a scene (docs/eba.md, "Bad values in packets").

    REMOTE_LIMIT_MARGIN times: the workspace (wall position, the operator's reach, the robot's
    start; at least 0.1 m), the operator's speed (at least 0.1 m/s), and the strongest force
    limit of the actuators and controllers (a wall force far beyond what any actuator in the loop
    can push is a sensor fault).
    """
    reach, speed = operator_reach(config.operator, trace)
    start = contact_start_of(config)
    x0 = abs(start.master_x_m) if start is not None else 0.0
    workspace = max(0.1, abs(config.slave.wall.position_m), reach + x0, abs(config.slave.start_position_m))
    forces = (
        config.master.force_limit_n,
        config.slave.force_limit_n,
        config.controllers.master.force_limit_n,
        config.controllers.slave.force_limit_n,
    )
    k = REMOTE_LIMIT_MARGIN
    return RemoteLimits(position_m=k * workspace, velocity_m_per_s=k * max(0.1, speed), force_n=k * max(forces))


def build_controller(
    cfg: ControllerConfig,
    role: str,
    period_s: float,
    damping: float,
    limits: RemoteLimits | None = None,
    saturation: SaturationConfig | None = None,
) -> TeleopController:
    """One side's controller. `saturation`: the side's actuator effect (clip and slew limit), which
    the energy bound then models (docs/eba_actuator_limits.md, "Actuator limits inside the bound"). The plant's own
    clip (`<side>.force_limit_n`) is never reached: the scene keeps the controller's saturation
    within it."""
    params = ControllerParams(
        role=role,
        law=cfg.law,
        stiffness_n_per_m=cfg.stiffness_n_per_m,
        damping_n_s_per_m=cfg.damping_n_s_per_m,
        force_gain=cfg.force_gain,
        force_limit_n=cfg.force_limit_n,
        remote_limits=limits,
    )
    bound = EnergyBoundParams(
        period_s=period_s,
        damping_n_s_per_m=(damping,),
        initial_energy_j=cfg.eba.initial_energy_j,
        enabled=cfg.eba.enabled,
        force_limit_n=saturation.force_limit_n if saturation is not None else None,
        slew_rate_n_per_s=saturation.slew_rate_n_per_s if saturation is not None else None,
        law=cfg.eba.law,
        tdpa_controller=cfg.eba.tdpa_controller,
        tdpa_reflection=cfg.eba.tdpa_reflection,
        tdpa_placement=cfg.eba.tdpa_placement,
        tdpa_drift_gain_per_s=cfg.eba.tdpa_drift_gain_per_s,
    )
    wave = None
    if cfg.eba.law == "wave":
        from haptic_teleop.core.wave import WaveParams

        e = cfg.eba
        wave = WaveParams(e.wave_impedance_n_s_per_m, e.wave_filter_hz, e.wave_drift_gain_per_s, e.wave_matched)
    return TeleopController(params, bound, wave)


def build_operator(
    op: OperatorConfig, trace: tuple[tuple[float, ...], tuple[float, ...]] | None, start: ContactStart | None = None
) -> Operator:
    """The core operator model a scene's `operator` section names (engine and operator_source).
    `start`: an in-contact start (`contact_start_of`): the profile starts where the master rests,
    a hand's intended position as far beyond it as its spring needs to hold the master's force."""
    x0 = 0.0
    if start is not None:
        x0 = start.master_x_m + (0.0 if op.profile == "imposed" else start.hand_offset_m)
    return Operator(
        OperatorParams(
            profile=op.profile,
            start_position_m=x0,
            duration_s=op.duration_s if op.duration_s is not None else 1.0,
            mass_kg=op.mass_kg,
            stiffness_n_per_m=op.stiffness_n_per_m,
            damping_n_s_per_m=op.damping_n_s_per_m,
            start_s=op.start_s,
            speed_m_per_s=op.speed_m_per_s,
            distance_m=op.distance_m,
            amplitude_m=op.amplitude_m,
            frequency_hz=op.frequency_hz,
            trace_time_s=trace[0] if trace else (),
            trace_position_m=trace[1] if trace else (),
        )
    )


def configure_network_adaptive(buf: PlayoutBuffer, c: Scene, direction: str) -> None:
    """Give a `network_adaptive` buffer (core/playout.py) what it cannot observe: the link's
    minimum one-way delay (`core.netconfig.min_one_way_delay_s` of the direction's effects, unless
    the scene sets `min_one_way_delay_s`) and the allowable delay and loss time of the scene's
    transparency analysis (`transparency_budget_of`, unless the scene sets them). Any other buffer
    is left alone. The engine and the live sync_buffer node both call it."""
    if not isinstance(buf, NetworkAdaptiveBuffer):
        return
    ch = getattr(c.network, direction)
    bcfg = ch.buffer
    d0 = bcfg.min_one_way_delay_s
    buf.set_min_one_way_delay(round((min_one_way_delay_s(ch.effects) if d0 is None else d0) * 1e9))
    d_a, l_a = bcfg.allowable_delay_s, bcfg.allowable_loss_time_s
    if d_a is None or l_a is None:
        budget = transparency_budget_of(c)
        if budget is None:  # the scene's validation refuses this already (scene/schema.py)
            raise ValueError(
                f"network.{direction}.buffer: policy network_adaptive needs allowable_delay_s and "
                "allowable_loss_time_s, or a one-axis scene whose operator profile is push or imposed"
            )
        d_a = budget[0] if d_a is None else d_a
        l_a = budget[1] if l_a is None else l_a
    never = 1 << 62
    buf.set_allowable(
        None if math.isinf(d_a) else min(round(d_a * 1e9), never),
        min(round(l_a * 1e9), never) if math.isfinite(l_a) else never,
    )


def build_network(c: Scene, period_ns: int) -> tuple[Link, Link, PlayoutBuffer, PlayoutBuffer]:
    """Fresh links and playout buffers for both directions, as the scene names them."""
    op = c.operator
    seed = c.scene.seed
    forward = build_scene_link(c.network.forward.effects, seed, "forward")
    backward = build_scene_link(c.network.backward.effects, seed, "backward")
    forward_buffer = build_buffer(c.network.forward.buffer, period_ns)
    backward_buffer = build_buffer(c.network.backward.buffer, period_ns)
    # The transparency-driven buffers need the contact force slope (docs/eba.md): the bounded
    # coupling stiffness min(c1, 2b/T) times the operator's speed (`operator_reach`), unless the
    # scene gives it.
    speed = operator_reach(op, None)[1]
    for buf, bcfg, ctrl, b in (
        (backward_buffer, c.network.backward.buffer, c.controllers.master, c.master.damping_n_s_per_m),
        (forward_buffer, c.network.forward.buffer, c.controllers.slave, c.slave.damping_n_s_per_m),
    ):
        if isinstance(buf, TransparencyBuffer) and bcfg.force_slope_n_per_s is None:
            buf.set_force_slope(contact_force_slope(min(ctrl.stiffness_n_per_m, 2 * b / c.scene.period_s), speed))
    # The network-adaptive buffers (seed 000) need the link's minimum delay, which a buffer cannot
    # observe, and the allowable delay and loss time of the scene's transparency analysis.
    configure_network_adaptive(forward_buffer, c, "forward")
    configure_network_adaptive(backward_buffer, c, "backward")
    return forward, backward, forward_buffer, backward_buffer


def apply_contact_start(
    start: ContactStart, master: TeleopController, slave: TeleopController, slave_plant: Any
) -> dict[str, float]:
    """Put both controllers and the robot's wall force into the in-contact equilibrium: each
    controller already holds the remote sample of the resting other side (so the delay's first
    period is the rest state, as if it had lasted forever), each reservoir its holding energy on
    top of the scene's `eba.initial_energy_j`, and the robot's last wall force is -F0. Returns
    the reservoirs' start values (the run facts `master_initial_energy_j`, `slave_initial_energy_j`)."""
    from haptic_teleop.core.eba_state import AxisBoundState

    master.remote = (start.wall_force_n, start.slave_x_m, 0.0)
    slave.remote = (start.master_x_m, 0.0)
    out = {}
    for name, ctrl, hold in (("master", master, start.master_energy_j), ("slave", slave, start.slave_energy_j)):
        energy = ctrl.bound.params.initial_energy_j + hold
        ctrl.bound.set_axis_state(AxisBoundState(energy, 0.0, 0.0, False))
        out[f"{name}_initial_energy_j"] = energy
    slave_plant.set_contact_force(start.wall_force_n)
    return out


def side_controller(
    c: Scene, role: str, trace: tuple[tuple[float, ...], tuple[float, ...]] | None = None
) -> TeleopController:
    """One side's controller of a one-axis scene (`build_controller` with the side's joint damping,
    its actuator saturation and the scene's remote limits): the engine's and the live node's."""
    plant = getattr(c, role)
    return build_controller(
        getattr(c.controllers, role),
        role,
        c.scene.period_s,
        plant.damping_n_s_per_m,
        remote_limits(c, trace),
        plant.effects.saturation,
    )


@dataclass
class AxisParts:
    """Every part of a one-axis scene's run, built once (`assemble_axis`): the operator, both plants
    and controllers (after an in-contact start, `initial_energy` holds each reservoir's start), the
    links and playout buffers of both directions, and the codec channel of each direction that
    names one (assembly/channel.py)."""

    operator: Operator
    master: Any
    slave: Any
    master_ctrl: TeleopController
    slave_ctrl: TeleopController
    contact_start: ContactStart | None
    initial_energy: dict[str, float]
    forward: Link
    backward: Link
    forward_buffer: PlayoutBuffer
    backward_buffer: PlayoutBuffer
    codecs: tuple[Any, Any]

    def close(self) -> None:
        """Stop both plants (torque off on a real device; idempotent)."""
        self.master.close()
        self.slave.close()


def assemble_axis(c: Scene, trace: tuple[tuple[float, ...], tuple[float, ...]] | None, period_ns: int) -> AxisParts:
    """A one-axis scene's parts (`trace`: the operator trace's rows, if the scene names one)."""
    from haptic_teleop.assembly.channel import build_codec_channels

    # An in-contact start (slave.start: in_contact): both sides at rest in the equilibrium.
    start = contact_start_of(c)
    operator = build_operator(c.operator, trace, start)
    master = build_master_plant(c, start.master_x_m if start is not None else 0.0)
    slave = build_slave_plant(c, start.slave_x_m if start is not None else None)
    master_ctrl = side_controller(c, "master", trace)
    slave_ctrl = side_controller(c, "slave", trace)
    initial_energy: dict[str, float] = {}
    if start is not None:
        initial_energy = apply_contact_start(start, master_ctrl, slave_ctrl, slave)
    forward, backward, forward_buffer, backward_buffer = build_network(c, period_ns)
    codecs = build_codec_channels(c, period_ns, forward, backward)
    return AxisParts(
        operator, master, slave, master_ctrl, slave_ctrl, start, initial_energy,
        forward, backward, forward_buffer, backward_buffer, codecs,
    )  # fmt: skip


# --------------------------------------------------------------------------------------------
# Arm scenes (docs/arms.md).


@dataclass
class ArmSide:
    """One side of an arm scene: the plant, its task-space law, its pooled joint bound and the guard
    on the remote samples it receives; `force_limit_n` saturates the task force's norm."""

    plant: MujocoArm | HardwareArm
    law: TaskSpaceLaw
    bound: ArmBound
    guard: SampleGuard
    force_limit_n: float
    rotational: bool  # the law needs the 6-row Jacobian (orientation held)
    kernels: Mapping[str, Callable[..., Any]] | None = None  # the compiled array functions, if any

    @property
    def rejected_samples(self) -> int:
        """Remote samples the guard rejected so far (as TeleopController.rejected_samples)."""
        return self.guard.rejected


@dataclass
class ArmParts:
    """Everything an arm scene's tick uses besides the network."""

    master: ArmSide
    slave: ArmSide
    mapping: WorkspaceMapping
    operator: Operator
    operator_origin_m: np.ndarray  # the intended point at rest (task frame): the start handle
    operator_direction: np.ndarray  # unit, task frame
    schema: TickSchema
    maps: Any = None  # the tick's mapping functions (side.side_ticks builds them)


def arm_remote_limits(config: Scene, points: list[np.ndarray]) -> RemoteLimits:
    """`remote_limits` for arms: REMOTE_LIMIT_MARGIN times the workspace (the largest coordinate of
    the start handle and tool and the wall point, the operator's reach; at least 0.1 m), the
    operator's speed (at least 0.1 m/s) and the controllers' force limits."""
    reach, speed = operator_reach(config.operator, None)
    workspace = max([0.1, reach] + [float(abs(p).max()) for p in points])
    forces = (config.controllers.master.force_limit_n, config.controllers.slave.force_limit_n)
    k = REMOTE_LIMIT_MARGIN
    return RemoteLimits(position_m=k * workspace, velocity_m_per_s=k * max(0.1, speed), force_n=k * max(forces))


@functools.cache
def arm_kernels() -> Mapping[str, Callable[..., Any]] | None:
    """core.taskspace's and core.eba's per-tick array functions compiled by numba (its on-disk
    cache after the first time), or None without numba: the laws and bounds then run interpreted.
    Each is compiled once per process and warmed up on the scene's array types by `build_arm_parts`,
    so no compiling happens inside the timed loop."""
    try:
        import numba  # noqa: F401 - only whether it is here
    except Exception:  # noqa: BLE001 - no numba here: the interpreted functions run
        return None
    from haptic_teleop.compiling import compile_tree
    from haptic_teleop.core.eba_two_condition_coupled import coupled_two_condition, room_within
    from haptic_teleop.core.taskspace import KERNEL_FUNCTIONS
    from haptic_teleop.core.tdpa_coupled import coupled_tdpa
    from haptic_teleop.core.wave_coupled import wave_ports_begin, wave_ports_end

    # Each compiled from its one definition with its callees, as the compiled arm loop's
    # side_kernel.py compiles them (the same compiled functions in one process: the same bits)
    laws = (coupled_tdpa, coupled_two_condition, room_within, wave_ports_begin, wave_ports_end)
    return {fn.__name__: compile_tree(fn) for fn in (*KERNEL_FUNCTIONS, *laws)}


def _warm_up(side: ArmSide, config: Scene) -> None:
    """One tick of a throwaway copy of the side's law and bound on its arrays: compiles (or loads)
    every kernel for these array types now, leaving the real objects untouched."""
    import numpy as np

    from haptic_teleop.core.taskspace import TaskSpaceLaw

    plant, n = side.plant, side.plant.n
    law = TaskSpaceLaw(side.law.params, n, side.kernels)
    from haptic_teleop.core.eba_coupled import CoupledEnergyBound
    from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound
    from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound
    from haptic_teleop.core.wave_coupled import CoupledWaveBound

    b = side.bound
    bound: ArmBound
    if isinstance(b, CoupledTdpaBound):
        bound = CoupledTdpaBound(b.params, b.controller, side.kernels, b.reflection)
    elif isinstance(b, CoupledWaveBound):
        bound = CoupledWaveBound(b.params, b.wave, b.master, b.k, b.c, side.kernels)
    elif isinstance(b, CoupledTwoConditionBound):
        bound = CoupledTwoConditionBound(b.params, side.kernels)
    else:
        bound = CoupledEnergyBound(b.params, side.kernels)
    z3 = np.zeros(3)
    jac = plant.jacobian(rotational=side.rotational)
    tau = law.torque(jac, np.zeros(n), z3, z3, z3, z3, None, plant.orientation() if side.rotational else None)
    if isinstance(bound, CoupledWaveBound):  # its two halves around the torque
        bound.begin(z3, z3)
        bound.end(1.0)
    bound.step(np.zeros(n), tau)
    bound.step(np.zeros(n), tau)
    if isinstance(bound, CoupledTwoConditionBound):  # its other signature: the room given
        bound.step(np.zeros(n), tau, np.zeros(n), np.zeros(n))
    if side.kernels is not None:
        lo, hi = plant.torque_room()
        side.kernels["joint_limited"](np.zeros(n), tau, lo, hi, True)


def arm_bound(
    params: CoupledEnergyBoundParams, config: Scene, role: str, kernels: Mapping[str, Callable[..., Any]] | None
) -> ArmBound:
    """The side's joint stabilizer the scene names (`controllers.<side>.eba.law`): EBA's pooled
    reservoir bound, the two conditions joint by joint (core/eba_two_condition_coupled.py), or TDPA
    with its controller (core/tdpa_coupled.py)."""
    eba = getattr(config.controllers, role).eba
    if eba.law == "two_condition":
        from haptic_teleop.core.eba_two_condition_coupled import CoupledTwoConditionBound

        return CoupledTwoConditionBound(params, kernels)
    if eba.law == "wave":
        import numpy as np

        from haptic_teleop.core.wave import WaveParams
        from haptic_teleop.core.wave_coupled import CoupledWaveBound

        ctrl = getattr(config.controllers, role)
        wave = WaveParams(eba.wave_impedance_n_s_per_m, eba.wave_filter_hz, eba.wave_drift_gain_per_s, eba.wave_matched)
        # the slave's local spring and damper: the task coupling's gains (the master's port has none)
        k = np.array(ctrl.stiffness_axes_n_per_m or (ctrl.stiffness_n_per_m,) * 3, dtype=float)
        c = np.array(ctrl.damping_axes_n_s_per_m or (ctrl.damping_n_s_per_m,) * 3, dtype=float)
        return CoupledWaveBound(params, wave, role == "master", k, c, kernels)
    if eba.law == "tdpa":
        from haptic_teleop.core.tdpa_coupled import CoupledTdpaBound

        admittance = eba.tdpa_placement == "admittance"
        recover = eba.tdpa_drift_gain_per_s * params.period_s
        return CoupledTdpaBound(params, eba.tdpa_controller, kernels, eba.tdpa_reflection, admittance, recover)
    from haptic_teleop.core.eba_coupled import CoupledEnergyBound

    return CoupledEnergyBound(params, kernels)


def check_gravity_hold(config: Scene, role: str, plant: MujocoArm | HardwareArm) -> None:
    """A side whose motors compensate gravity must be able to hold the arm at its start pose:
    a joint whose torque limit is below the gravity torque there would let the arm fall (the
    bound then limits only the port torque beyond what the motors cannot give: a UR5e with 5 N m
    limits fell into the table at 142 N). Refused before anything moves, one line naming the
    side's key, the joint and both torques. Called with the plant at its start pose."""
    import numpy as np

    g = np.asarray(plant.gravity_torque(), dtype=float)  # zero when the side does not compensate
    lo, hi = np.asarray(plant.torque_lo, dtype=float), np.asarray(plant.torque_hi, dtype=float)
    short = np.flatnonzero((g > hi + 1e-9) | (g < lo - 1e-9))
    if short.size:
        from haptic_teleop.errors import ConfigError

        k = int(short[0])
        limit = float(hi[k] if g[k] > 0 else -lo[k])
        raise ConfigError(
            f"scene {config.scene.name}",
            f"{role}.torque_limit_nm",
            [round(float(x), 4) for x in hi],
            f"joint {plant.joints[k]} needs {abs(float(g[k])):.2f} N m to hold the arm against gravity at "
            f"{role}.start_q_rad, above its limit {limit:.2f} N m: raise that joint's limit, or start where "
            f"gravity needs less",
        )


def arm_schema(master: MujocoArm | HardwareArm, slave: MujocoArm | HardwareArm) -> TickSchema:
    """The tick schema of an arm scene with these plants: their joints, 3 task axes, and the
    measured torque columns of each side on a real device (record/columns.py; docs/hardware_plant.md,
    "Applied, not commanded"). A simulated side adds nothing: its bag keeps its bytes."""
    from haptic_teleop.plants.hardware_arm import HardwareArm
    from haptic_teleop.record.columns import TickSchema

    return TickSchema(master.joints, slave.joints, 3, isinstance(master, HardwareArm), isinstance(slave, HardwareArm))


def build_arm_parts(config: Scene, compiled: bool = True) -> ArmParts:
    """Both sides of an arm scene: plants, mapping, task-space laws, pooled joint bounds, guards,
    operator (docs/arms.md). `compiled`: the laws and bounds call numba-compiled kernels
    (`arm_kernels`, when numba is there); False: interpreted (the same results, slower)."""
    import numpy as np

    from haptic_teleop.assembly.plants import build_arm
    from haptic_teleop.core.controller import SampleGuard
    from haptic_teleop.core.eba_coupled import CoupledEnergyBoundParams
    from haptic_teleop.core.taskspace import TaskCouplingParams, TaskSpaceLaw, WorkspaceMapping, rotation_from_rpy
    from haptic_teleop.core.tdpa import ENERGY_LIMIT_J
    from haptic_teleop.scene.sides import side_period_s

    # A hardware side's plant starts its driver at its first read, not here (plants/hardware_arm.py).
    master = build_arm(config, "master")
    slave = build_arm(config, "slave")
    for role, plant in (("master", master), ("slave", slave)):
        check_gravity_hold(config, role, plant)
    kernels = arm_kernels() if compiled else None
    xm0 = master.point()[0]
    xs0 = slave.point()[0]
    mc = config.mapping
    if mc is None:
        from haptic_teleop.scene.controllers import MappingConfig

        mc = MappingConfig()
    rot = rotation_from_rpy(*(math.radians(a) for a in mc.rotation_rpy_deg))
    if mc.offset_m is not None:
        offset = tuple(mc.offset_m)
    else:  # the start handle maps onto the start tool
        r = np.array(rot)
        offset = tuple(float(c) for c in xs0 - mc.scale * r @ xm0)
    mapping = WorkspaceMapping(scale=mc.scale, rotation=rot, offset_m=offset, force_scale=mc.force_scale)
    handle0 = mapping.position_to_task(xm0)
    limits = arm_remote_limits(config, [handle0, xs0, np.array(config.slave.wall.point_m)])

    def side(role: str, plant: MujocoArm | HardwareArm) -> ArmSide:
        cfg: ControllerConfig = getattr(config.controllers, role)
        slew = getattr(config, role).slew_nm_per_s
        c1 = cfg.stiffness_axes_n_per_m or (cfg.stiffness_n_per_m,) * 3
        c2 = cfg.damping_axes_n_s_per_m or (cfg.damping_n_s_per_m,) * 3
        ori = cfg.orientation
        hold = ori is not None and ori.mode == "fixed"
        params = TaskCouplingParams(
            law="position",
            stiffness_n_per_m=tuple(c1),
            damping_n_s_per_m=tuple(c2),
            orientation="hold" if hold else "free",
            rot_stiffness_nm_per_rad=(ori.stiffness_nm_per_rad,) * 3 if hold and ori is not None else (0.0,) * 3,
            rot_damping_nm_s_per_rad=(ori.damping_nm_s_per_rad,) * 3 if hold and ori is not None else (0.0,) * 3,
            null_damping_nm_s_per_rad=(
                (cfg.null_space_damping_nm_s_per_rad,) * plant.n if cfg.null_space_damping_nm_s_per_rad else ()
            ),
        )
        bound = arm_bound(
            CoupledEnergyBoundParams(
                period_s=side_period_s(config, role),  # the side's own period: its ledger's T
                damping_nm_s_per_rad=tuple(plant.joint_damping()),
                initial_energy_j=cfg.eba.initial_energy_j,
                enabled=cfg.eba.enabled,
                slew_nm_per_s=tuple(slew) if slew is not None else (),
                joint_names=plant.joints,
                # A real arm's torque may be held longer than a period (late ticks): the bound budgets it.
                max_hold_s=getattr(plant, "hold_budget_s", None),
            ),
            config,
            role,
            kernels,
        )
        # Remote payloads (task frame): master receives (x, v, f_contact), slave (x, v); with
        # TDPA, the sender's pooled input energy last (core/tdpa_coupled.py).
        kinds = (limits.position_m, limits.velocity_m_per_s, limits.force_n)
        if cfg.eba.law == "wave":  # (x, waves[, f_env]): the waves where the velocities were
            from haptic_teleop.core.wave import wave_limit

            wave = wave_limit(cfg.eba.wave_impedance_n_s_per_m, limits.velocity_m_per_s, limits.force_n)
            kinds = (limits.position_m, wave, limits.force_n)
        per = kinds if role == "master" else kinds[:2]
        energy = (ENERGY_LIMIT_J,) if cfg.eba.law == "tdpa" else ()
        guard = SampleGuard([*(k for k in per for _ in range(3)), *energy])
        out = ArmSide(plant, TaskSpaceLaw(params, plant.n, kernels), bound, guard, cfg.force_limit_n, hold, kernels)
        if kernels is not None:
            _warm_up(out, config)
        return out

    op = config.operator
    direction = np.array(op.direction if op.direction is not None else [-c for c in config.slave.wall.normal or ()])
    return ArmParts(
        master=side("master", master),
        slave=side("slave", slave),
        mapping=mapping,
        operator=build_operator(op, None),
        operator_origin_m=handle0,
        operator_direction=direction,
        schema=arm_schema(master, slave),
    )

"""The plants of a scene, built from its config: the one place plants are built from a scene (the
engine and the live nodes both call these). Only the effects the scene names are built; with none
named the bare MuJoCo plant is returned, so an effect-free scene pays nothing per tick for the
effects machinery. A backend's SDK (mujoco, dynamixel_sdk, rtde) is imported inside its module."""

from __future__ import annotations

import math
import typing
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from haptic_teleop.errors import PlantError
from haptic_teleop.plants.base import Plant, backend, backend_class
from haptic_teleop.scene.schema import PlantEffectsConfig, Scene
from haptic_teleop.scene.sides import arm_settings, side_period_s, sim_settings, wall_spec

if TYPE_CHECKING:
    from haptic_teleop.plants.arm import MujocoArm
    from haptic_teleop.plants.hardware_arm import HardwareArm


def build_master_plant(config: Scene, start_position_m: float = 0.0) -> Plant:
    """The operator's device of `config` (its `master` section), with `master.effects`, its handle
    at `start_position_m` (an in-contact start moves it)."""
    m = config.master
    plant = backend_class("mujoco", "master")(
        sim_settings(config),
        mass_kg=m.mass_kg,
        damping_n_s_per_m=m.damping_n_s_per_m,
        force_limit_n=m.force_limit_n,
        hand_mass_kg=config.operator.mass_kg,
        model=m.model,
        start_position_m=start_position_m,
    )
    return _with_effects(plant, config, "master", m.effects)


def build_slave_plant(config: Scene, start_position_m: float | None = None) -> Plant:
    """The robot and wall of `config` (its `slave` section), with `slave.effects`; the robot at
    `start_position_m` (default the scene's `slave.start_position_m`; an in-contact start gives it)."""
    s = config.slave
    plant = backend_class("mujoco", "slave")(
        sim_settings(config),
        mass_kg=s.mass_kg,
        damping_n_s_per_m=s.damping_n_s_per_m,
        force_limit_n=s.force_limit_n,
        wall_position_m=s.wall.position_m,
        wall_stiffness_n_per_m=s.wall.stiffness_n_per_m,
        wall_damping_n_s_per_m=s.wall.damping_n_s_per_m,
        contact_impedance=s.contact_impedance,
        model=s.model,
        start_position_m=s.start_position_m if start_position_m is None else start_position_m,
    )
    return _with_effects(plant, config, "slave", s.effects)


def build_master_arm(config: Scene) -> MujocoArm:
    """An arm scene's master device (docs/arms.md): the `master` section's model, joints and
    overrides, the operator's hand mass at the handle."""
    from haptic_teleop.plants.arm import MujocoArm

    return MujocoArm(**arm_settings(config, "master"))


def build_slave_arm(config: Scene) -> MujocoArm:
    """An arm scene's slave arm and its wall (docs/arms.md)."""
    from haptic_teleop.plants.arm import MujocoArm

    return MujocoArm(**arm_settings(config, "slave"))


def build_arm(config: Scene, role: str) -> MujocoArm | HardwareArm:
    """An arm scene's `role` side ("master" or "slave") on its backend: the MuJoCo arm
    (`build_master_arm`, `build_slave_arm`), or a real arm (`build_hardware_arm`)."""
    if getattr(config, role).backend == "mujoco":
        return build_master_arm(config) if role == "master" else build_slave_arm(config)
    return build_hardware_arm(config, role)


def build_hardware_arm(config: Scene, role: str) -> HardwareArm:
    """A real arm (docs/hardware.md): the side's driver, made by its backend from its hardware
    section (plants/base.py; not started: the plant starts it at its first read), and the
    kinematics of the same MJCF. `config` is validated (scene/load.py): the hardware section names
    the device, the side its start pose and the damping EBA may assume."""
    from haptic_teleop.plants.hardware import ArmDriver
    from haptic_teleop.plants.hardware_arm import HardwareArm
    from haptic_teleop.plants.kinematics import ArmKinematics

    cfg = getattr(config, role)
    hw = cfg.hardware
    if hw is None or cfg.damping_nm_s_per_rad is None or cfg.start_q_rad is None:
        raise PlantError(f"{role}.backend {cfg.backend}: needs {role}.hardware, damping_nm_s_per_rad, start_q_rad")
    kin = ArmKinematics(cfg.model, cfg.joints, "handle" if role == "master" else "tool")
    arm = backend(cfg.backend).make_arm_driver(hw, kin, cfg.torque_limit_nm, side_period_s(config, role))
    assert isinstance(arm, ArmDriver)
    return HardwareArm(
        arm.driver,
        kin,
        cfg.damping_nm_s_per_rad,
        cfg.start_q_rad,
        side_period_s(config, role),
        role,
        torque_limit_nm=cfg.torque_limit_nm,
        gravity_compensation=cfg.gravity_compensation is not False and not arm.gravity_by_device,
        wall=wall_spec(config) if role == "slave" else None,
        start_tolerance_rad=hw.start_tolerance_rad,
        ramp_in_s=hw.ramp_in_s,
        source=f"{role} ({cfg.backend} on {arm.where})",
        wrench_source=arm.wrench,
        lockstep_clock=hw.device_clock == "lockstep",
        max_hold_s=hw.max_hold_s,
    )


def _with_effects(plant: Any, config: Scene, side: str, effects: PlantEffectsConfig) -> Plant:
    """Write the physical effects into the MuJoCo model, wrap the sensor/actuator ones."""
    if effects.gravity is not None:
        _set_gravity(plant, effects.gravity.incline_deg, effects.gravity.acceleration_m_per_s2)
    contact_source = None
    fr = effects.friction
    if fr is not None:
        model = plant.model
        model.dof_frictionloss[:] = fr.coulomb_n
        # MuJoCo's dry friction is a soft constraint: with its default softness a device held by
        # half the Coulomb force creeps at about 2.6 mm/s. A time constant of two steps and an
        # impedance of 0.9999 make sticking stick (creep about 0.5 um/s per N, docs/effects.md).
        model.dof_solref[:] = (2.0 * model.opt.timestep, 1.0)
        model.dof_solimp[:] = (0.9999, 0.9999, 0.001, 0.5, 2.0)
        model.dof_damping[:] += fr.viscous_n_s_per_m
        if fr.coulomb_n > 0.0 and side == "slave":
            contact_source = _contact_without_dof_friction(plant)
    physical = tuple(n for n in ("gravity", "friction") if getattr(effects, n) is not None)

    from haptic_teleop.core import sensing

    seed = config.scene.seed
    period_s = config.scene.period_s
    position: list[Any] = []
    velocity: list[Any] = []
    force: list[Any] = []
    actuator: list[Any] = []
    nz = effects.noise
    # Order on each signal: noise on the analog value, then the encoder's quantization or the
    # force filter (the filter smooths the noisy reading), as a real sensor chain does.
    if nz is not None:
        for std, name, chain in (
            (nz.position_std_m, "position_noise", position),
            (nz.velocity_std_m_per_s, "velocity_noise", velocity),
            (nz.force_std_n, "force_noise", force),
        ):
            if std > 0.0:
                chain.append(sensing.GaussianNoise(std, sensing.sensing_rng(seed, side, name), name))
    if effects.encoder is not None:
        position.append(sensing.Quantizer(effects.encoder.resolution_m))
    ff = effects.force_filter
    if ff is not None:
        if ff.type == "lowpass":
            assert ff.cutoff_hz is not None
            force.append(sensing.LowPassFilter(ff.cutoff_hz, period_s))
        else:
            assert ff.window_samples is not None
            force.append(sensing.MovingAverage(ff.window_samples))
    sat = effects.saturation
    if sat is not None:
        actuator.append(sensing.ActuatorLimit(period_s, plant.axes, sat.force_limit_n, sat.slew_rate_n_per_s))
    if not (position or velocity or force or actuator or contact_source is not None):
        return typing.cast(Plant, plant)  # nothing per tick to add: the bare plant, no pass-through
    from haptic_teleop.plants.effects import EffectsPlant

    return EffectsPlant(plant, position, velocity, force, actuator, contact_source, physical)


def _set_gravity(plant: Any, incline_deg: float, g_m_per_s2: float) -> None:
    """World gravity with a component -g sin(incline) along the (single) slide axis."""
    import mujoco
    import numpy as np

    model, data = plant.model, plant.data
    if model.njnt != 1 or model.jnt_type[0] != mujoco.mjtJoint.mjJNT_SLIDE:
        raise PlantError("gravity needs a model with one slide joint (the device axis)")
    mujoco.mj_kinematics(model, data)
    axis = np.array(data.xaxis[0], dtype=float)
    axis /= np.linalg.norm(axis)
    # A unit vector across the axis carries the rest of g; on a single slide joint it does nothing.
    across = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    across -= axis * float(across @ axis)
    across /= np.linalg.norm(across)
    th = math.radians(incline_deg)
    model.opt.gravity[:] = -g_m_per_s2 * (math.sin(th) * axis + math.cos(th) * across)
    mujoco.mj_forward(model, data)


def _contact_without_dof_friction(plant: Any) -> Callable[[], list[float]]:
    """The plant's constraint force on the joint minus MuJoCo's dry-friction rows: the wall force.

    The plant reports `qfrc_constraint`, which holds the joint's friction (dof_frictionloss)
    as well as the contact; the friction rows' forces of the last step are taken out. Exact for
    one MuJoCo step per period (the scene requires substeps 1 with slave Coulomb friction)."""
    import mujoco

    model, data = plant.model, plant.data
    # MuJoCo orders constraint rows equality, dry friction, limits, contacts, and a dof with
    # frictionloss > 0 always has its friction row: on this one-dof model it is row 0, every step.
    mujoco.mj_forward(model, data)
    if model.nv != 1 or data.nefc < 1 or data.efc_type[0] != mujoco.mjtConstraint.mjCNSTR_FRICTION_DOF:
        raise PlantError("slave Coulomb friction needs a one-dof model whose first constraint row is its friction")
    plant_contact = plant.contact_force

    def contact() -> list[float]:
        return [plant_contact()[0] - float(data.efc_force[0])]

    return contact

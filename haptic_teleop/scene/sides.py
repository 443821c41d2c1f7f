"""A scene's sides in the plants' own terms: the MuJoCo settings (`sim_settings`), an arm's
arguments and its wall (`arm_settings`, `wall_spec`), a side's own period (`side_period_s`). The
assembly builds the plants from these; the scene's checks (load.py) build a model from them too,
so both read a scene the same way."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from haptic_teleop.scene.schema import Scene

if TYPE_CHECKING:
    from haptic_teleop.plants.arm import WallSpec
    from haptic_teleop.plants.mujoco_plant import SimSettings


def sim_settings(config: Scene) -> SimSettings:
    """The MuJoCo settings of a scene."""
    from haptic_teleop.plants.mujoco_plant import SimSettings

    s = config.simulation
    return SimSettings(
        period_s=config.scene.period_s,
        substeps=s.substeps,
        integrator=s.integrator,
        solver_iterations=s.solver_iterations,
        solver_tolerance=s.solver_tolerance,
    )


def side_period_s(config: Scene, role: str) -> float:
    """A side's own control period: `<role>.period_s`, else the scene's (docs/arms.md)."""
    p = getattr(config, role).period_s
    return float(p) if p is not None else config.scene.period_s


def arm_settings(config: Scene, role: str) -> dict[str, Any]:
    """The keyword arguments of the MuJoCo arm (`plants.arm.MujocoArm`) of an arm scene's `role`
    side ("master": the device, the operator's hand mass at the handle; "slave": the arm and its
    wall), from the side's model, joints and overrides (docs/arms.md)."""
    cfg = getattr(config, role)
    master = role == "master"
    return {
        "sim": sim_settings(config),
        "model": cfg.model,
        "point_site": "handle" if master else "tool",
        "joints": cfg.joints,
        "start_q_rad": cfg.start_q_rad,
        "damping_nm_s_per_rad": cfg.damping_nm_s_per_rad,
        "torque_limit_nm": cfg.torque_limit_nm,
        "gravity_compensation": cfg.gravity_compensation is not False,
        **({"hand_mass_kg": config.operator.mass_kg} if master else {"wall": wall_spec(config)}),
    }


def wall_spec(config: Scene) -> WallSpec:
    """The wall of an arm scene's slave (a plane with its contact), in the arm plant's terms."""
    from haptic_teleop.plants.arm import WallSpec

    s = config.slave
    w = s.wall
    assert w.point_m is not None and w.normal is not None  # an arm scene (Scene.is_arm)
    return WallSpec(
        (w.point_m[0], w.point_m[1], w.point_m[2]),
        (w.normal[0], w.normal[1], w.normal[2]),
        w.stiffness_n_per_m,
        w.damping_n_s_per_m,
        s.contact_impedance,
    )

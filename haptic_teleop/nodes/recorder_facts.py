"""What the live recorder knows of a run before it records (nodes/recorder.py): its tick schema and the
run facts the engine writes for the same scene (`schema_and_facts`), and how many scene ticks apart
each topic's samples come (`side_every`)."""

from __future__ import annotations

from typing import Any


def schema_and_facts(cfg: Any) -> tuple[Any, dict[str, Any]]:
    """The run's tick schema and the run facts the engine writes for it (engine.record_run): for an
    arm scene the joint names and the damping each joint has in the simulator (the compiled
    MjModel's dof_damping, which the analysis' true energy margin uses) from the scene's models,
    and the wall's point and normal (the analysis' penetration). A one-axis scene: ONE_DOF."""
    from haptic_teleop.record.columns import ONE_DOF

    if cfg.is_nve:  # an NVE run: its record schema (the run facts' nve_schema is the recorder's own)
        from haptic_teleop.record.nve_columns import NveSchema

        return NveSchema(tuple(c.name for c in cfg.nve.clients), cfg.nve.axes), {}
    if not cfg.is_arm:
        return ONE_DOF, {}
    from haptic_teleop.assembly.parts import arm_schema
    from haptic_teleop.assembly.plants import build_arm

    # A real arm's plant (built, its driver never started here): the damping the scene lets EBA
    # assume, as the engine records it for a hardware side (docs/hardware.md).
    master, slave = build_arm(cfg, "master"), build_arm(cfg, "slave")
    facts = {
        "master_joint_damping": master.joint_damping(),
        "slave_joint_damping": slave.joint_damping(),
        "wall_point_m": list(cfg.slave.wall.point_m or ()),
        "wall_normal": list(cfg.slave.wall.normal or ()),
        "master_backend": cfg.master.backend,
        "slave_backend": cfg.slave.backend,
    }
    return arm_schema(master, slave), facts  # a hardware side's measured effort among its columns


def side_every(cfg: Any, topic: str) -> int:
    """How many scene ticks apart `topic`'s samples come: its side's own period over the scene's
    (<side>.period_s, arm scenes) for /master/* and /slave/*, else 1."""
    role = topic.split("/")[1] if topic.count("/") >= 2 else ""
    role = {"forward": "master", "backward": "slave"}.get(role, role)  # /<dir>/sent: its sender's
    if not cfg.is_arm or role not in ("master", "slave"):
        return 1
    from haptic_teleop.scene.load import side_period_ticks

    return side_period_ticks(cfg, role)

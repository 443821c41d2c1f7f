"""What seed 000's scenario makes of a one-axis scene (docs/transparency.md), from the scene alone:
the in-contact start (where both sides rest against the wall and what the reservoirs hold), the
transparency analysis' contact model and budget (allowable delay and loss time), and whether the
analysis and its undisturbed reference run apply. For the assembly (which puts the start into the
controllers and plant), the playout buffers, the engine's reference run, the analysis of a bag and
the experiments."""

from __future__ import annotations

from haptic_teleop.core.transparency import (
    ContactModel,
    ContactStart,
    allowable_delay,
    allowable_loss_time,
    contact_start,
    transparent_loss_time,
)
from haptic_teleop.scene.schema import Scene


def contact_start_of(c: Scene) -> ContactStart | None:
    """The equilibrium a one-axis scene with `slave.start: in_contact` starts in (core/transparency.py),
    or None for a free start."""
    s = c.slave
    if not s.in_contact or s.initial_contact_force_n is None:
        return None
    m, sl = c.controllers.master, c.controllers.slave
    return contact_start(
        wall_position_m=s.wall.position_m,
        wall_stiffness_n_per_m=s.wall.stiffness_n_per_m,
        contact_force_n=s.initial_contact_force_n,
        slave_stiffness_n_per_m=sl.stiffness_n_per_m,
        master_law=m.law,
        master_stiffness_n_per_m=m.stiffness_n_per_m,
        master_force_gain=m.force_gain,
        master_damping_n_s_per_m=c.master.damping_n_s_per_m,
        slave_damping_n_s_per_m=s.damping_n_s_per_m,
        period_s=c.scene.period_s,
        hand_stiffness_n_per_m=c.operator.stiffness_n_per_m,
    )


def contact_model_of(c: Scene) -> ContactModel | None:
    """The transparency analysis' contact model of a one-axis scene whose operator moves toward the
    wall at a set speed (`push` or `imposed`), from the scene alone (core/transparency.py; the
    analysis of a bag uses the measured speed instead): None for any other scene."""
    op = c.operator
    if c.is_arm or op.profile not in ("push", "imposed") or op.speed_m_per_s == 0.0:
        return None
    m, sl, s = c.controllers.master, c.controllers.slave, c.slave
    return ContactModel(
        period_s=c.scene.period_s,
        speed_m_per_s=abs(op.speed_m_per_s),
        master_law=m.law,
        master_stiffness_n_per_m=m.stiffness_n_per_m,
        master_damping_n_s_per_m=m.damping_n_s_per_m,
        master_force_gain=m.force_gain,
        master_physical_damping_n_s_per_m=c.master.damping_n_s_per_m,
        master_force_limit_n=m.force_limit_n,
        slave_stiffness_n_per_m=sl.stiffness_n_per_m,
        wall_stiffness_n_per_m=s.wall.stiffness_n_per_m,
        contact_force_n=s.initial_contact_force_n or 0.0,
        master_eba=m.eba.enabled,
        slave_damping_n_s_per_m=sl.damping_n_s_per_m,
        slave_physical_damping_n_s_per_m=s.damping_n_s_per_m,
        wall_damping_n_s_per_m=s.wall.damping_n_s_per_m,
    )


def transparency_budget_of(c: Scene) -> tuple[float, float] | None:
    """(allowable one-way delay D_a, allowable loss time L_a) in s for the scene's required force
    distortion E (`analysis.allowed_force_error_n`, 0.1 N without an `analysis` section), from its
    contact model and the master's EBA law (core/transparency.py): L_a = T_tr + E / s with T_tr the
    transparent loss time at the ramp's start (the felt force at the start, desired = felt: the
    least T_tr over a ramp whose gap only grows). None when the scene has no contact model."""
    m = contact_model_of(c)
    if m is None:
        return None
    law = c.controllers.master.eba.law
    error = c.analysis.allowed_force_error_n if c.analysis is not None else 0.1
    t_tr = transparent_loss_time(m, 0.0, m.master_start_force_n, law)
    return allowable_delay(m, error, law), allowable_loss_time(m, error, t_tr, law)


def transparency_applies(c: Scene) -> bool:
    """Whether seed 000's transparency analysis applies to a scene: a one-axis teleoperation scene
    whose operator moves toward the wall (push or imposed) and that asks for it, by the seed's
    premise (`operator.profile: imposed` or `slave.start: in_contact`) or by an `analysis:` section
    (a push from free space opts in). The analysis reads the run whole (its memory grows with the
    run, unlike the streaming summary), so the other scenes, long runs among them, are left alone.
    Its predictions are of the EBA laws: not for TDPA or wave-variable scenes."""
    op = c.operator
    if c.is_nve or c.is_arm or op.profile not in ("push", "imposed") or not op.speed_m_per_s > 0.0:
        return False
    if c.controllers.master.eba.law in ("tdpa", "wave"):  # the analysis models the EBA laws only
        return False
    return op.profile == "imposed" or c.slave.in_contact or c.analysis is not None


def reference_wanted(c: Scene) -> bool:
    """Whether a run of the scene is compared with its undisturbed reference run (the same scene
    without network effects): `analysis.reference`, by default for in-contact starts only. The
    reference runs when the run does and is recorded in its bag (engine/reference.py)."""
    if not transparency_applies(c):
        return False
    asked = c.analysis.reference if c.analysis is not None else None
    return asked if asked is not None else c.slave.in_contact

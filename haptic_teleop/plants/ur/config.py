"""A Universal Robots side's `hardware` section (`URConfig`: the controller's address, how the side's
command reaches the robot, the force-mode and admittance settings) and the driver the arm plant
runs on it (`arm_driver`): the backend's registry entry names both (plants/base.py)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from haptic_teleop.plants.hardware import ArmDriver, HardwareConfig, Problem
from haptic_teleop.plants.ur.driver import APPLIED_MISMATCH_READS, APPLIED_TOLERANCE_NM, JOINTS

CONTROL_MODES = ("force_mode", "admittance", "torque")


@dataclass(frozen=True)
class URConfig(HardwareConfig):
    """A side on a Universal Robots arm (docs/hardware.md, docs/ur.md): where its controller is, the
    control mode, and the settings of force mode and of the admittance; the start-up checks and the
    clock of every real side."""

    required: ClassVar[tuple[str, ...]] = ("host", "control_mode")

    host: str | None = field(default=None, metadata={"help": "the robot controller's address"})
    control_mode: str | None = field(
        default=None,
        metadata={"choices": CONTROL_MODES, "help": "how the side's command reaches the robot (docs/hardware.md)"},
    )
    rtde_watchdog_s: float = field(
        default=0.1,
        metadata={
            "gt": 0.0,
            "max": 10.0,
            "help": "the controller stops the control script when no command arrives for this long (ur_rtde "
            "setWatchdog at 1 / this; the default 0.1 s is ur_rtde's 10 Hz)",
        },
    )
    force_mode_damping: float = field(
        default=0.025,
        metadata={
            "min": 0.0,
            "max": 1.0,
            "help": "force_mode: URScript force_mode_set_damping (0 none .. 1 full; ur_rtde's default 0.025)",
        },
    )
    force_mode_speed_limits: tuple[float, ...] = field(
        default=(0.1, 0.1, 0.1, 0.5, 0.5, 0.5),
        metadata={
            "gt": 0.0,
            "max": 10.0,
            "help": "force_mode: the largest TCP speed along each compliant axis (m/s x3, rad/s x3)",
        },
    )
    admittance_mass_kg: float = field(
        default=2.0, metadata={"gt": 0.0, "max": 1000.0, "help": "admittance: the virtual mass per axis"}
    )
    admittance_damping_n_s_per_m: float = field(
        default=400.0,
        metadata={"gt": 0.0, "max": 1e6, "help": "admittance: the virtual damping (passive for > 0; > K T / 2)"},
    )
    admittance_inertia_kg_m2: float = field(
        default=0.05, metadata={"gt": 0.0, "max": 100.0, "help": "admittance: the virtual inertia per axis"}
    )
    admittance_damping_nm_s_per_rad: float = field(
        default=5.0, metadata={"gt": 0.0, "max": 1e5, "help": "admittance: the virtual rotational damping"}
    )
    applied_tolerance_nm: tuple[float, ...] = field(
        default=APPLIED_TOLERANCE_NM,
        metadata={
            "min": 0.0,
            "max": 150.0,
            "help": "torque: per joint, how far the torque the joint reports it applies (RTDE "
            "actual_current_as_torque) may be from the command, plus a fifth of the command (default 2 % of the "
            "rated torque; docs/ur.md, 'Applied, not commanded')",
        },
    )
    applied_mismatch_reads: int = field(
        default=APPLIED_MISMATCH_READS,
        metadata={
            "min": 1,
            "max": 5000,
            "help": "torque: fresh reads in a row a joint may be off its command before the side stops (default "
            "25, 50 ms at the controller's 500 Hz)",
        },
    )

    def __post_init__(self) -> None:
        if len(self.force_mode_speed_limits) != 6:
            raise ValueError(
                f"force_mode_speed_limits needs 6 values (m/s x3, rad/s x3), got {list(self.force_mode_speed_limits)}"
            )
        if len(self.applied_tolerance_nm) != 6:
            raise ValueError(
                f"applied_tolerance_nm needs 6 values (N m, one per joint), got {list(self.applied_tolerance_nm)}"
            )

    def problem(self, role: str, joints: tuple[str, ...], emulate: bool) -> Problem | None:
        """The controller's address, a control mode the side can run, the UR's joints in order."""
        if self.host is None and not emulate:
            return Problem(
                "hardware.host",
                None,
                "required for backend ur: the controller's address (e.g. 192.168.1.10), or run with --emulate",
            )
        if self.control_mode is None:
            return Problem(
                "hardware.control_mode",
                None,
                "required for backend ur; allowed: force_mode (UR's force control), admittance (speedL through "
                "core/admittance.py), torque (direct torque, PolyScope 5.23 / 10.10 or later; docs/ur.md)",
            )
        if role == "master" and self.control_mode != "torque":
            return Problem(
                "hardware.control_mode",
                self.control_mode,
                "allowed for a UR master: torque (force_mode and admittance render the slave's task force on a tool)",
            )
        if tuple(joints) != JOINTS:
            return Problem("joints", list(joints), f"backend ur drives the UR's joints in order: {', '.join(JOINTS)}")
        return None


def arm_driver(hw: URConfig, kin: Any, torque_limit_nm: Sequence[float] | None, period_s: float) -> ArmDriver:
    """The robot as the arm plant drives it. The UR controller compensates gravity itself in every
    mode, so the plant adds none; its contact is the controller's TCP wrench (the e-Series' F/T
    sensor). Direct torque mode is a `JointDriver` as it is; force mode and the admittance turn the
    bounded torque into a tool wrench (docs/ur_control_modes.md)."""
    from haptic_teleop.plants.ur.driver import URTaskDriver, URTorqueDriver

    assert hw.host is not None
    if hw.control_mode == "torque":
        ur = URTorqueDriver(
            hw.host,
            watchdog_hz=1.0 / hw.rtde_watchdog_s,
            applied_tolerance_nm=hw.applied_tolerance_nm,
            applied_mismatch_reads=hw.applied_mismatch_reads,
        )
        return ArmDriver(ur, True, lambda: ur.ur.state().tcp_wrench, hw.host)
    lin, rot = hw.admittance_mass_kg, hw.admittance_inertia_kg_m2
    dl, dr = hw.admittance_damping_n_s_per_m, hw.admittance_damping_nm_s_per_rad
    task = URTaskDriver(
        hw.host,
        str(hw.control_mode),
        lambda: kin.jacobian(rotational=True),
        period_s,
        watchdog_hz=1.0 / hw.rtde_watchdog_s,
        force_mode_damping=hw.force_mode_damping,
        speed_limits=hw.force_mode_speed_limits,
        admittance_mass=(lin, lin, lin, rot, rot, rot),
        admittance_damping=(dl, dl, dl, dr, dr, dr),
    )
    return ArmDriver(task, True, task.tcp_wrench, hw.host)  # the TCP wrench of the tick's one read

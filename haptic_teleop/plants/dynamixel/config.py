"""A Dynamixel side's `hardware` section (`DynamixelConfig`: the bus and, per joint, the servo) and the
driver the arm plant runs on it (`arm_driver`): the backend's registry entry names both
(plants/base.py)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

from haptic_teleop.plants.dynamixel import tables
from haptic_teleop.plants.hardware import ArmDriver, HardwareConfig, JointDriver, Problem

BAUDS_BPS = (9600, 57600, 115200, 1000000, 2000000, 3000000, 4000000)


@dataclass(frozen=True)
class DynamixelConfig(HardwareConfig):
    """A side on Dynamixel servos (docs/hardware.md): the bus (port, baud), per joint the servo's id,
    model, sign and zero offset; the start-up checks and the clock of every real side."""

    required: ClassVar[tuple[str, ...]] = ("port", "ids", "models")

    port: str | None = field(default=None, metadata={"help": "the serial port, e.g. /dev/ttyUSB0"})
    baud_bps: int = field(default=1000000, metadata={"choices": BAUDS_BPS, "help": "the bus's baud rate"})
    ids: tuple[int, ...] | None = field(
        default=None, metadata={"min": 0, "max": 252, "help": "the servo id of each joint, in joint order"}
    )
    models: tuple[str, ...] | None = field(
        default=None, metadata={"help": "each joint's servo model, e.g. XM430-W350, XM540-W270"}
    )
    signs: tuple[int, ...] | None = field(
        default=None, metadata={"min": -1, "max": 1, "help": "+1 or -1 per joint (servo direction vs joint)"}
    )
    zero_offsets_rad: tuple[float, ...] | None = field(
        default=None, metadata={"min": -6.3, "max": 6.3, "help": "servo angle at the joint's zero, per joint"}
    )
    torque_constants_nm_per_a: tuple[float, ...] | None = field(
        default=None, metadata={"gt": 0.0, "max": 100.0, "help": "identified N m/A (default: datasheet)"}
    )
    bus_watchdog_s: float = field(
        default=0.1, metadata={"min": 0.02, "max": 2.54, "help": "servos stop when the host is silent this long"}
    )
    read_timeout_s: float | None = field(
        default=None,
        metadata={"gt": 0.0, "max": 10.0, "help": "how long a read waits for replies (default: the SDK's)"},
    )

    def __post_init__(self) -> None:
        if self.signs is not None and any(s not in (-1, 1) for s in self.signs):
            raise ValueError(f"signs must each be +1 or -1, got {list(self.signs)}")
        if self.ids is not None and len(set(self.ids)) != len(self.ids):
            raise ValueError(f"ids must be distinct (one servo per joint), got {list(self.ids)}")

    def problem(self, role: str, joints: tuple[str, ...], emulate: bool) -> Problem | None:
        """The bus's port (unless `--emulate` fills it in), one servo per joint of a known model."""
        if self.port is None and not emulate:
            allowed = "required: the serial port of the bus (e.g. /dev/ttyUSB0), or run with --emulate"
            return Problem("hardware.port", None, allowed)
        names = ", ".join(joints)
        for key in ("ids", "models"):
            if getattr(self, key) is None:
                return Problem(f"hardware.{key}", None, f"required: one per joint ({names})")
        for key in ("ids", "models", "signs", "zero_offsets_rad", "torque_constants_nm_per_a"):
            v = getattr(self, key)
            if v is not None and len(v) != len(joints):
                return Problem(f"hardware.{key}", list(v), f"allowed: {len(joints)} values, one per joint ({names})")
        assert self.models is not None
        for i, name in enumerate(self.models):
            if name not in tables.MODELS:
                return Problem(f"hardware.models[{i}]", name, f"allowed: one of {', '.join(sorted(tables.MODELS))}")
        return None

    def absent(self) -> Problem | None:
        import os

        if self.port is None or os.path.exists(self.port):
            return None
        return Problem(
            "hardware.port",
            self.port,
            "does not exist: is the USB adapter (U2D2) plugged in? `ls /dev/ttyUSB* /dev/serial/by-id/` lists the "
            "serial ports; allowed: one of them, or --emulate",
        )

    def unopenable(self) -> Problem | None:
        """The port exists but the SDK cannot open it at `baud_bps` (not a serial port, taken, no
        permission): said before a run builds anything (the driver's own message, `probe_port`)."""
        from haptic_teleop.plants.dynamixel.port import probe_port
        from haptic_teleop.plants.hardware import HardwareError

        if self.port is None:
            return None
        try:
            probe_port(self.port, self.baud_bps)
        except HardwareError as exc:
            reason = str(exc).removeprefix(f"{self.port}").lstrip(": ")
            return Problem("hardware.port", self.port, f"{reason}; or --emulate")
        return None


def joint_driver(hw: DynamixelConfig, joints: tuple[str, ...], torque_limit_nm: Sequence[float] | None) -> JointDriver:
    """The Dynamixel chain of a side's hardware section (plants/dynamixel/driver.py). Each servo's
    Current Limit(38) is set to the joint's torque limit (`torque_limit_nm`, the scene's or the
    model's ctrlrange), so the servo itself clips where the plant and the energy bound do."""
    from haptic_teleop.plants.dynamixel.chain import DynamixelChainConfig, DynamixelJoint
    from haptic_teleop.plants.dynamixel.driver import DynamixelDriver

    n = len(joints)
    assert hw.ids is not None and hw.models is not None and hw.port is not None
    signs = hw.signs if hw.signs is not None else (1,) * n
    offsets = hw.zero_offsets_rad if hw.zero_offsets_rad is not None else (0.0,) * n
    kts = hw.torque_constants_nm_per_a
    chain = []
    for k, name in enumerate(joints):
        model = tables.model(hw.models[k])
        kt = kts[k] if kts is not None else model.torque_constant_nm_per_a
        top_a = model.current_limit_max * tables.CURRENT_UNIT_A
        limit_a = top_a if torque_limit_nm is None else min(top_a, torque_limit_nm[k] / kt)
        chain.append(
            DynamixelJoint(
                name=name,
                id=hw.ids[k],
                model=hw.models[k],
                sign=signs[k],
                zero_offset_rad=offsets[k],
                torque_constant_nm_per_a=kt,
                current_limit_a=limit_a,
            )
        )
    config = DynamixelChainConfig(
        port=hw.port,
        joints=tuple(chain),
        baud_bps=hw.baud_bps,
        bus_watchdog_s=hw.bus_watchdog_s,
        read_timeout_s=hw.read_timeout_s,
    )
    return DynamixelDriver(config)


def arm_driver(hw: DynamixelConfig, kin: Any, torque_limit_nm: Sequence[float] | None, period_s: float) -> ArmDriver:
    """The side's servos as the arm plant drives them: torque through each servo's current, gravity
    compensated by the plant, the contact estimated from the joint torques."""
    limit = torque_limit_nm if torque_limit_nm is not None else tuple(kin.torque_limit_nm())
    assert hw.port is not None
    return ArmDriver(joint_driver(hw, kin.joints, limit), False, None, hw.port)

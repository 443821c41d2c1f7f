"""The bus emulator's configuration: `BusConfig` and its sections, from and to JSON-ready dicts.

Every bad value is one `ConfigError` naming the key path, the value and what is allowed
(docs/dynamixel.md, "Configuration" lists every key).
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.dynamixel import tables
from haptic_teleop.typedconfig import build

SOURCE = "bus config"

FAULT_KINDS = ("hardware_error", "drop_replies", "corrupt_crc", "slow_replies", "vanish", "watchdog_trip", "torque_off")
"""watchdog_trip: the servo's Bus Watchdog trips now (-1), as when its instructions came too far
apart; torque_off: its Torque Enable(64) goes to 0, as another program on the bus would set it."""


@dataclass(frozen=True)
class WallConfig:
    """A plane wall for the MuJoCo arm's tool (plants.arm.WallSpec)."""

    point_m: tuple[float, ...] = field(metadata={"help": "a point on the wall surface, world frame (3 values)"})
    normal: tuple[float, ...] = field(metadata={"help": "unit normal into free space (3 values)"})
    stiffness_n_per_m: float = field(default=2000.0, metadata={"gt": 0.0})
    damping_n_s_per_m: float = field(default=10.0, metadata={"min": 0.0})
    contact_impedance: float = field(default=0.1, metadata={"gt": 0.0, "lt": 1.0})

    def __post_init__(self) -> None:
        if len(self.point_m) != 3 or len(self.normal) != 3:
            raise ValueError("point_m and normal need 3 values each")
        if abs(math.sqrt(sum(c * c for c in self.normal)) - 1.0) > 1e-6:
            raise ValueError(f"normal {self.normal} must be a unit vector")


@dataclass(frozen=True)
class HandConfig:
    """The operator's hand on a leader arm: a 3-D spring-damper at the `handle` site (the `tool`
    site if the model has none) pulled toward a point that moves from `origin_m` along
    `direction` with the project's push profile (core.operator)."""

    start_s: float = field(default=0.0, metadata={"min": 0.0})
    speed_m_per_s: float = 0.05
    distance_m: float = field(default=0.05, metadata={"min": 0.0})
    stiffness_n_per_m: float = field(default=300.0, metadata={"min": 0.0})
    damping_n_s_per_m: float = field(default=10.0, metadata={"min": 0.0})
    origin_m: tuple[float, ...] | None = field(
        default=None, metadata={"help": "start of the intended point (3 values); default: the site's start position"}
    )
    direction: tuple[float, ...] = (1.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if self.origin_m is not None and len(self.origin_m) != 3:
            raise ValueError("origin_m needs 3 values")
        if len(self.direction) != 3 or abs(math.sqrt(sum(c * c for c in self.direction)) - 1.0) > 1e-6:
            raise ValueError(f"direction {self.direction} must be a unit vector of 3 values")


@dataclass(frozen=True)
class InertiaJointConfig:
    """One joint of the "inertia" physics: I qdd = tau - b qd - c sign(qd) (sticking at rest)."""

    name: str
    inertia_kg_m2: float = field(metadata={"gt": 0.0})
    viscous_nm_s_per_rad: float = field(default=0.0, metadata={"min": 0.0})
    coulomb_nm: float = field(default=0.0, metadata={"min": 0.0})
    start_q_rad: float = 0.0


@dataclass(frozen=True)
class PhysicsConfig:
    """What the servos drive: "mujoco" (an MJCF arm, plants.arm.MujocoArm) or "inertia" (one
    inertia with viscous and Coulomb friction per joint)."""

    kind: str = field(default="mujoco", metadata={"choices": ("mujoco", "inertia")})
    dt_s: float = field(default=0.0005, metadata={"gt": 0.0, "max": 0.01, "help": "physics time step"})
    model: str = field(default="dxl_arm.xml", metadata={"help": "mujoco: a bundled model's name or a path"})
    start_q_rad: tuple[float, ...] | None = field(default=None, metadata={"help": "mujoco: per model joint"})
    damping_nm_s_per_rad: tuple[float, ...] | None = field(
        default=None, metadata={"min": 0.0, "help": "mujoco: true viscous friction per model joint (dof_damping)"}
    )
    frictionloss_nm: tuple[float, ...] | None = field(
        default=None, metadata={"min": 0.0, "help": "mujoco: true Coulomb friction per model joint (dof_frictionloss)"}
    )
    wall: WallConfig | None = None
    hand: HandConfig | None = None
    joints: tuple[InertiaJointConfig, ...] = ()


@dataclass(frozen=True)
class TimeConfig:
    """How emulator time runs: "realtime" (physics follows the wall clock, as a real servo) or
    "lockstep" (physics advances `lockstep_dt_s` at each write of Goal Current: deterministic)."""

    mode: str = field(default="realtime", metadata={"choices": ("realtime", "lockstep")})
    lockstep_dt_s: float = field(default=0.001, metadata={"gt": 0.0, "max": 1.0})


@dataclass(frozen=True)
class ServoConfig:
    """One servo on the bus and the joint it drives:
    position register = 2048 + sign (q - offset_rad) 4096 / (2 pi) + Homing Offset."""

    id: int = field(metadata={"min": 0, "max": tables.MAX_ID})
    model: str = field(metadata={"choices": tuple(tables.MODELS)})
    joint: str = field(metadata={"help": "the joint it drives (a model joint, or an inertia joint's name)"})
    sign: int = field(default=1, metadata={"min": -1, "max": 1, "help": "+1 or -1"})
    offset_rad: float = 0.0
    torque_constant_nm_per_a: float | None = field(
        default=None, metadata={"gt": 0.0, "help": "the TRUE k_t of this servo; default: the model's"}
    )
    firmware_version: int = field(default=46, metadata={"min": 0, "max": 255})
    registers: tuple[tuple[str, int], ...] = ()
    """EEPROM values other than the factory defaults, as configured earlier and kept over power
    cycles, e.g. {"return_delay_time": 0, "operating_mode": 0}; RAM starts at its factory values."""

    def __post_init__(self) -> None:
        if self.sign not in (-1, 1):
            raise ValueError(f"sign must be +1 or -1, got {self.sign}")

    @property
    def servo_model(self) -> tables.ServoModel:
        return tables.model(self.model)

    @property
    def k_t_nm_per_a(self) -> float:
        k = self.torque_constant_nm_per_a
        return self.servo_model.torque_constant_nm_per_a if k is None else k


@dataclass(frozen=True)
class FaultConfig:
    """A scheduled fault: at the `at_transaction`-th instruction packet from start (1 = the first)
    or once emulator time reaches `at_time_s`; exactly one of the two."""

    servo_id: int = field(metadata={"min": 0, "max": tables.MAX_ID})
    kind: str = field(metadata={"choices": FAULT_KINDS})
    at_transaction: int | None = field(default=None, metadata={"min": 0})
    at_time_s: float | None = field(default=None, metadata={"min": 0.0})
    bits: int = field(default=0, metadata={"min": 0, "max": 255, "help": "hardware_error: Hardware Error Status bits"})
    count: int = field(default=1, metadata={"min": 1, "help": "drop_replies, corrupt_crc, slow_replies: how many"})
    extra_delay_s: float = field(default=0.0, metadata={"min": 0.0, "help": "slow_replies: added before each reply"})

    def __post_init__(self) -> None:
        if (self.at_transaction is None) == (self.at_time_s is None):
            raise ValueError("give exactly one of at_transaction and at_time_s")
        if self.kind == "hardware_error" and self.bits == 0:
            raise ValueError("a hardware_error fault needs bits (Hardware Error Status bits, e.g. 32 = overload)")


@dataclass(frozen=True)
class BusConfig:
    """One emulated bus: its baud, the USB adapter's latency, time, physics, servos and faults."""

    servos: tuple[ServoConfig, ...] = ()
    baud_bps: int = field(default=1_000_000, metadata={"help": "a rate of Baud Rate(8): 9600 .. 4500000"})
    usb_latency_s: float = field(
        default=0.0, metadata={"min": 0.0, "max": 0.1, "help": "added to each reply burst (FTDI latency timer)"}
    )
    time: TimeConfig = field(default_factory=TimeConfig)
    physics: PhysicsConfig = field(default_factory=PhysicsConfig)
    faults: tuple[FaultConfig, ...] = ()
    control_socket: str | None = field(default=None, metadata={"help": "a UNIX socket path for run-time faults"})

    # ------------------------------------------------------------------------ (de)serialising

    @classmethod
    def from_dict(cls, data: Any, source: str = SOURCE) -> BusConfig:
        if not isinstance(data, Mapping):
            raise ConfigError(source, "", data, "allowed: a mapping of keys to values")
        data = dict(data)
        servos_raw = data.pop("servos", None)
        faults_raw = data.pop("faults", [])
        physics_raw = data.pop("physics", {})
        if not isinstance(physics_raw, Mapping):
            raise ConfigError(source, "physics", physics_raw, "allowed: a mapping")
        physics_raw = dict(physics_raw)
        joints_raw = physics_raw.pop("joints", [])
        base = build(cls, data, "", source)
        physics = build(PhysicsConfig, physics_raw, "physics", source)
        joints = tuple(
            build(InertiaJointConfig, j, f"physics.joints[{i}]", source)
            for i, j in enumerate(_list(joints_raw, "physics.joints", source))
        )
        physics = dataclasses.replace(physics, joints=joints)
        if servos_raw is None:
            raise ConfigError(source, "servos", None, "required key is missing (a list of servos)")
        servos = tuple(_servo(s, f"servos[{i}]", source) for i, s in enumerate(_list(servos_raw, "servos", source)))
        faults = tuple(
            build(FaultConfig, f, f"faults[{i}]", source) for i, f in enumerate(_list(faults_raw, "faults", source))
        )
        cfg = dataclasses.replace(base, physics=physics, servos=servos, faults=faults)
        cfg.check(source)
        return cfg

    @classmethod
    def from_json(cls, text: str, source: str = SOURCE) -> BusConfig:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(source, "", text[:60], f"not JSON ({exc})") from None
        return cls.from_dict(data, source)

    def to_dict(self) -> dict[str, Any]:
        def plain(obj: Any) -> Any:
            if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
                out = {}
                for f in dataclasses.fields(obj):
                    v = getattr(obj, f.name)
                    out[f.name] = dict(v) if f.name == "registers" else plain(v)
                return out
            if isinstance(obj, tuple):
                return [plain(v) for v in obj]
            return obj

        result: dict[str, Any] = plain(self)
        return result

    def to_json(self) -> str:
        return json.dumps(self.to_dict())

    # ------------------------------------------------------------------------ checks across keys

    def check(self, source: str = SOURCE) -> None:
        rates = sorted(tables.BAUD_RATES_BPS.values())
        if self.baud_bps not in rates:
            raise ConfigError(source, "baud_bps", self.baud_bps, f"allowed: one of {rates} (Baud Rate(8) codes 0..7)")
        if not self.servos:
            raise ConfigError(source, "servos", [], "allowed: at least one servo")
        ids = [s.id for s in self.servos]
        for i, s in enumerate(self.servos):
            if s.id in ids[:i]:
                raise ConfigError(source, f"servos[{i}].id", s.id, "allowed: an id no other servo has")
        p = self.physics
        if p.kind == "inertia":
            names = [j.name for j in p.joints]
            if not names:
                raise ConfigError(source, "physics.joints", [], "allowed: at least one joint for the inertia physics")
            for i, n in enumerate(names):
                if n in names[:i]:
                    raise ConfigError(source, f"physics.joints[{i}].name", n, "allowed: a name no other joint has")
            for i, s in enumerate(self.servos):
                if s.joint not in names:
                    raise ConfigError(source, f"servos[{i}].joint", s.joint, f"allowed: one of {names}")
            for key in ("wall", "hand", "start_q_rad", "damping_nm_s_per_rad", "frictionloss_nm"):
                if getattr(p, key) is not None:
                    raise ConfigError(source, f"physics.{key}", getattr(p, key), 'allowed only with kind "mujoco"')
        elif p.joints:
            raise ConfigError(source, "physics.joints", "...", 'allowed only with kind "inertia"')
        for i, f in enumerate(self.faults):
            if f.servo_id not in ids:
                raise ConfigError(source, f"faults[{i}].servo_id", f.servo_id, f"allowed: a configured servo id {ids}")


def _list(value: Any, where: str, source: str) -> list[Any]:
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
        raise ConfigError(source, where, value, "allowed: a list")
    return list(value)


def _servo(data: Any, where: str, source: str) -> ServoConfig:
    if not isinstance(data, Mapping):
        raise ConfigError(source, where, data, "allowed: a mapping of keys to values")
    data = dict(data)
    regs_raw = data.pop("registers", {})
    servo = build(ServoConfig, data, where, source)
    if not isinstance(regs_raw, Mapping):
        raise ConfigError(source, f"{where}.registers", regs_raw, "allowed: a mapping of field name to value")
    m = servo.servo_model
    regs: list[tuple[str, int]] = []
    for name, value in regs_raw.items():
        path = f"{where}.registers.{name}"
        try:
            fld = m.field(str(name))
        except KeyError:
            raise ConfigError(
                source, path, value, f"unknown field; fields: {', '.join(f.name for f in m.fields)}"
            ) from None
        if fld.access != "RW" or fld.area != "EEPROM":
            raise ConfigError(
                source, path, value, "allowed: a writable EEPROM field (RAM holds its factory values at power-on)"
            )
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(source, path, value, "allowed: an integer")
        if fld.low is not None and fld.high is not None and not fld.low <= value <= fld.high:
            raise ConfigError(source, path, value, f"allowed: {fld.low} .. {fld.high}")
        if fld.name in ("id", "baud_rate"):
            raise ConfigError(source, path, value, "allowed: set the id with servos[].id and the rate with baud_bps")
        regs.append((fld.name, int(value)))
    return dataclasses.replace(servo, registers=tuple(regs))

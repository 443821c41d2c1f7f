"""The UR emulator's configuration: frozen dataclasses built from plain data (JSON) with errors
that name the key, the value and what is allowed (docs/ur_emulator.md, "Emulator configuration")."""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from haptic_teleop import typedconfig
from haptic_teleop.errors import ConfigError

UR5E_HOME_Q_RAD = (0.0, -1.5708, 1.5708, -1.5708, -1.5708, 0.0)  # tool pointing down, 0.44 m up


@dataclass(frozen=True)
class WallConfig:
    """A plane wall the tool can touch (plants/arm.py WallSpec)."""

    point_m: tuple[float, ...] = field(metadata={"help": "a point on the wall surface (x, y, z), base frame"})
    normal: tuple[float, ...] = field(metadata={"help": "unit normal into free space"})
    stiffness_n_per_m: float = field(default=1e4, metadata={"gt": 0.0})
    damping_n_s_per_m: float = field(default=50.0, metadata={"min": 0.0})

    def __post_init__(self) -> None:
        if len(self.point_m) != 3 or len(self.normal) != 3:
            raise ValueError("point_m and normal need 3 values each")
        n = sum(c * c for c in self.normal) ** 0.5
        if abs(n - 1.0) > 1e-6:
            raise ValueError(f"normal must be a unit vector (length {n:.6g})")


@dataclass(frozen=True)
class URConfig:
    """Everything the emulator needs. Ports are those ur_rtde 1.6.5 connects to (fixed there: the
    RTDE port 30004, the dashboard 29999, the script port 30003); `control_port` 0 picks a free port
    for the emulator's own test channel (fault injection, ground truth)."""

    host: str = field(default="127.0.0.1", metadata={"choices": ("127.0.0.1",), "help": "loopback only"})
    rtde_port: int = field(default=30004, metadata={"min": 0, "max": 65535})
    dashboard_port: int = field(default=29999, metadata={"min": 0, "max": 65535})
    script_ports: tuple[float, ...] = field(default=(30002.0, 30003.0), metadata={"help": "secondary and real-time"})
    control_port: int = field(default=0, metadata={"min": 0, "max": 65535})
    controller_version: tuple[float, ...] = field(
        default=(5.0, 11.0, 1.0, 108318.0), metadata={"help": "major, minor, bugfix, build"}
    )
    serial_number: str = "20205500001"
    frequency_hz: float = field(default=500.0, metadata={"help": "125 (CB3) or 500 (e-Series)"})
    model: str = "ur5e.xml"
    start_q_rad: tuple[float, ...] = UR5E_HOME_Q_RAD
    wall: WallConfig | None = None
    substeps: int = field(default=4, metadata={"min": 1, "max": 50, "help": "MuJoCo steps per controller cycle"})
    protective_stop_force_n: float = field(default=150.0, metadata={"gt": 0.0, "help": "TCP force norm"})
    protective_stop_torque_nm: float = field(
        default=1e9, metadata={"gt": 0.0, "help": "joint torque beyond gravity, any joint"}
    )
    robot_mode: int = field(default=7, metadata={"min": -1, "max": 8, "help": "UR robot mode at start (7 RUNNING)"})
    safety_mode: int = field(default=1, metadata={"min": 1, "max": 13, "help": "UR safety mode at start (1 NORMAL)"})
    servo_gain_scale: float = field(default=1.0, metadata={"gt": 0.0})
    force_mode_damping_n_s_per_m: float = field(default=400.0, metadata={"gt": 0.0})
    force_mode_damping_nm_s_per_rad: float = field(default=20.0, metadata={"gt": 0.0})

    def __post_init__(self) -> None:
        if self.frequency_hz not in (125.0, 500.0):
            raise ValueError(f"frequency_hz = {self.frequency_hz}: allowed 125 (CB3) or 500 (e-Series)")
        if len(self.start_q_rad) != 6:
            raise ValueError(f"start_q_rad needs 6 values, got {len(self.start_q_rad)}")
        if len(self.controller_version) != 4 or any(v < 0 or v != int(v) for v in self.controller_version):
            raise ValueError("controller_version needs 4 non-negative integers (major, minor, bugfix, build)")
        if not self.script_ports or any(p != int(p) or not 0 <= p <= 65535 for p in self.script_ports):
            raise ValueError("script_ports needs one or more port numbers")

    @property
    def version(self) -> tuple[int, int, int, int]:
        v = [int(x) for x in self.controller_version]
        return (v[0], v[1], v[2], v[3])

    @classmethod
    def from_dict(cls, data: Any, source: str = "<ur emulator config>") -> URConfig:
        return typedconfig.build(cls, data, source=source)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_file(cls, path: str | Path) -> URConfig:
        p = Path(path)
        try:
            data = json.loads(p.read_text())
        except OSError as exc:
            raise ConfigError(str(p), "", str(p), f"a readable JSON file ({exc.strerror})") from None
        except json.JSONDecodeError as exc:
            raise ConfigError(str(p), "", str(p), f"valid JSON ({exc.msg} at line {exc.lineno})") from None
        return cls.from_dict(data, source=str(p))

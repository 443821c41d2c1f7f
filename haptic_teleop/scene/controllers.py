"""The controllers' part of the scene schema (`controllers.master`, `controllers.slave`): the control
law, its gains and limits, the stabilizer (`eba`: EBA's laws, TDPA, wave variables) and, for arms,
the workspace mapping and the tool's orientation (docs/scenes.md)."""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class EBAConfig:
    enabled: bool = field(default=True, metadata={"help": "false runs the unprotected control law"})
    initial_energy_j: float = field(default=0.0, metadata={"min": 0.0, "max": 1e3, "help": "per-axis budget E0"})
    law: str = field(
        default="reservoir",
        metadata={
            "choices": ("reservoir", "two_condition", "tdpa", "wave"),
            "help": "reservoir: one pooled reservoir; two_condition: the ZOH and controller energy conditions "
            "(docs/eba.md; on arms joint by joint); tdpa: the time-domain passivity approach; wave: wave variables "
            "(both on both sides, docs/stabilizers.md)",
        },
    )
    wave_impedance_n_s_per_m: float = field(
        default=20.0,
        metadata={"gt": 0.0, "max": 1e5, "help": "law wave: the wave impedance b (the same on both sides)"},
    )
    wave_filter_hz: float | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e5, "help": "law wave: low-pass cutoff on the received wave"}
    )
    wave_drift_gain_per_s: float = field(
        default=0.0,
        metadata={"min": 0.0, "max": 1e4, "help": "law wave (slave): the drift correction's rate; 0: none"},
    )
    wave_matched: bool = field(
        default=False,
        metadata={
            "help": "law wave (slave): terminate the slave's port in the wave impedance, so free motion "
            'reflects no wave back (docs/stabilizers.md, "Impedance matching")'
        },
    )
    tdpa_controller: str = field(
        default="velocity",
        metadata={
            "choices": ("velocity", "zoh"),
            "help": "law tdpa's passivity controller: velocity (the field's, a predicted hold) or zoh "
            "(the hold's worst case with the device's damping; docs/stabilizers.md)",
        },
    )
    tdpa_reflection: float = field(
        default=0.0,
        metadata={
            "min": 0.0,
            "max": 1.0,
            "help": "law tdpa: the fraction of its observed input energy a side keeps for its own output "
            "(energy reflection) instead of sending it; 0: the network-aware standard (docs/stabilizers.md)",
        },
    )
    tdpa_placement: str = field(
        default="impedance",
        metadata={
            "choices": ("impedance", "admittance"),
            "help": "law tdpa: where the passivity controller acts: impedance (on the force) or admittance (on "
            "the coupling's reference position, which slips and returns at tdpa_drift_gain_per_s; "
            "docs/stabilizers.md)",
        },
    )
    tdpa_drift_gain_per_s: float = field(
        default=0.0,
        metadata={
            "min": 0.0,
            "max": 1e3,
            "help": "law tdpa, admittance placement: the rate its reference returns toward the received position",
        },
    )


@dataclass(frozen=True)
class OrientationConfig:
    """A 6-DoF slave's tool orientation: held at its start orientation by a rotational spring-damper
    ("fixed"), or left free ("free": the joints it needs see null-space damping only)."""

    mode: str = field(default="fixed", metadata={"choices": ("fixed", "free")})
    stiffness_nm_per_rad: float = field(default=20.0, metadata={"min": 0.0, "max": 1e5})
    damping_nm_s_per_rad: float = field(default=1.0, metadata={"min": 0.0, "max": 1e4})


@dataclass(frozen=True)
class MappingConfig:
    """Arms: the workspace mapping master -> slave, x_s = scale R x_m + offset, f_m = force_scale R^T f_s."""

    scale: float = field(default=1.0, metadata={"gt": 0.0, "max": 1e3, "help": "position scale"})
    rotation_rpy_deg: tuple[float, ...] = field(
        default=(0.0, 0.0, 0.0), metadata={"min": -360.0, "max": 360.0, "help": "R as roll, pitch, yaw about x, y, z"}
    )
    offset_m: tuple[float, ...] | None = field(
        default=None,
        metadata={"min": -10.0, "max": 10.0, "help": "default: the one mapping the start handle onto the start tool"},
    )
    force_scale: float = field(default=1.0, metadata={"gt": 0.0, "max": 1e3, "help": "force scale back to the master"})

    def __post_init__(self) -> None:
        if len(self.rotation_rpy_deg) != 3:
            raise ValueError(f"rotation_rpy_deg needs 3 values (roll, pitch, yaw), got {len(self.rotation_rpy_deg)}")
        if self.offset_m is not None and len(self.offset_m) != 3:
            raise ValueError(f"offset_m needs 3 values (x, y, z), got {len(self.offset_m)}")


@dataclass(frozen=True)
class ControllerConfig:
    law: str = field(default="position", metadata={"choices": ("position", "force")})
    stiffness_n_per_m: float = field(default=500.0, metadata={"min": 0.0, "max": 1e7, "help": "c1"})
    damping_n_s_per_m: float = field(default=20.0, metadata={"min": 0.0, "max": 1e5, "help": "c2"})
    force_gain: float = field(default=1.0, metadata={"min": 0.0, "max": 100.0, "help": "force reflection gain"})
    force_limit_n: float = field(default=20.0, metadata={"gt": 0.0, "max": 1e5, "help": "saturation"})
    eba: EBAConfig = field(default_factory=EBAConfig)
    stiffness_axes_n_per_m: tuple[float, ...] | None = field(
        default=None, metadata={"min": 0.0, "max": 1e7, "help": "arms: c1 per task axis x, y, z (default: c1 on each)"}
    )
    damping_axes_n_s_per_m: tuple[float, ...] | None = field(
        default=None, metadata={"min": 0.0, "max": 1e5, "help": "arms: c2 per task axis x, y, z (default: c2 on each)"}
    )
    null_space_damping_nm_s_per_rad: float | None = field(
        default=None, metadata={"min": 0.0, "max": 1e4, "help": "arms: damping of joint motion the task does not see"}
    )
    orientation: OrientationConfig | None = None

    def __post_init__(self) -> None:
        for name in ("stiffness_axes_n_per_m", "damping_axes_n_s_per_m"):
            v = getattr(self, name)
            if v is not None and len(v) != 3:
                raise ValueError(f"{name} needs 3 values (x, y, z), got {len(v)}")


def _slave_default() -> ControllerConfig:
    return ControllerConfig(force_limit_n=40.0, eba=EBAConfig(initial_energy_j=0.5))


@dataclass(frozen=True)
class ControllersConfig:
    master: ControllerConfig = field(default_factory=ControllerConfig)
    slave: ControllerConfig = field(default_factory=_slave_default)

    def __post_init__(self) -> None:
        if self.slave.law != "position":
            raise ValueError("controllers.slave.law must be 'position': force reflection is a master law")

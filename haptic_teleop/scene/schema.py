"""The scene schema: every key of a scene, its unit, default and range, as frozen dataclasses.

A scene names the effects it wants; absent effects are not built. Nothing runs until the whole
scene is valid (docs/scenes.md, "Scenes").
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import yaml

from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.base import BACKENDS as PLANT_BACKENDS
from haptic_teleop.plants.base import hardware_classes
from haptic_teleop.plants.hardware import HardwareConfig
from haptic_teleop.scene.controllers import (
    ControllersConfig,
    MappingConfig,
)
from haptic_teleop.scene.direction import ChannelDirectionConfig
from haptic_teleop.scene.nve_schema import NveConfig


@dataclass(frozen=True)
class RunConfig:
    name: str = field(default="scene", metadata={"help": "scene name, used in reports"})
    description: str = field(default="", metadata={"help": "one line: what the scene shows (`haptic-teleop scenes`)"})
    period_s: float = field(default=0.001, metadata={"gt": 0.0, "max": 0.01, "help": "control period T"})
    duration_s: float = field(default=10.0, metadata={"gt": 0.0, "max": 86400.0})
    seed: int = field(default=0, metadata={"min": 0, "max": 2**63 - 1, "help": "seed of every random stream"})

    def __post_init__(self) -> None:
        if self.duration_s < self.period_s:
            raise ValueError("duration_s must be at least one period_s")


@dataclass(frozen=True)
class OperatorConfig:
    profile: str = field(
        default="push",
        metadata={
            "choices": ("push", "sinusoid", "hold", "trace", "imposed"),
            "help": "imposed: the device is driven along the push (a position source), one-axis scenes only",
        },
    )
    mass_kg: float = field(default=0.5, metadata={"min": 0.0, "max": 20.0, "help": "arm mass moving with the handle"})
    stiffness_n_per_m: float = field(default=200.0, metadata={"min": 0.0, "max": 1e5})
    damping_n_s_per_m: float = field(default=10.0, metadata={"min": 0.0, "max": 1e4})
    start_s: float = field(default=0.5, metadata={"min": 0.0, "help": "when the intended motion starts"})
    speed_m_per_s: float = field(default=0.02, metadata={"min": -5.0, "max": 5.0, "help": "push speed"})
    distance_m: float = field(default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "push length, then hold"})
    amplitude_m: float = field(default=0.02, metadata={"min": 0.0, "max": 10.0})
    frequency_hz: float = field(default=0.5, metadata={"gt": 0.0, "max": 100.0})
    trace_file: str | None = field(default=None, metadata={"help": "CSV time_s,position_m (profile trace)"})
    duration_s: float | None = field(
        default=None,
        metadata={"min": 0.0, "max": 86400.0, "help": "imposed: how long it moves at speed_m_per_s, then holds"},
    )
    direction: tuple[float, ...] | None = field(
        default=None,
        metadata={
            "help": "arms: the profile's direction in the task frame (3 values, normalised; default: into the wall)"
        },
    )

    def __post_init__(self) -> None:
        if self.direction is not None:
            object.__setattr__(self, "direction", _unit(self.direction, "direction"))
        if self.profile == "trace" and not self.trace_file:
            raise ValueError("profile 'trace' needs trace_file")
        if self.profile != "trace" and self.trace_file:
            raise ValueError(f"trace_file is only used with profile 'trace', not {self.profile!r}")
        if self.profile == "imposed" and self.duration_s is None:
            raise ValueError("profile 'imposed' needs duration_s (s at speed_m_per_s, then hold)")
        if self.profile != "imposed" and self.duration_s is not None:
            raise ValueError(f"duration_s is only used with profile 'imposed', not {self.profile!r}")


@dataclass(frozen=True)
class GravityConfig:
    """Gravity along the device axis, simulated by MuJoCo (model.opt.gravity)."""

    incline_deg: float = field(
        metadata={
            "min": -90.0,
            "max": 90.0,
            "help": "angle of the +x axis above the horizontal: > 0 means +x is uphill, gravity pulls toward -x",
        }
    )
    acceleration_m_per_s2: float = field(default=9.81, metadata={"gt": 0.0, "max": 100.0, "help": "g"})


@dataclass(frozen=True)
class FrictionConfig:
    """Joint friction simulated by MuJoCo: Coulomb (dof_frictionloss) and viscous (dof_damping)."""

    coulomb_n: float = field(default=0.0, metadata={"min": 0.0, "max": 1e4, "help": "dry friction force level"})
    viscous_n_s_per_m: float = field(
        default=0.0,
        metadata={"min": 0.0, "max": 1e5, "help": "added to the side's damping_n_s_per_m; EBA does not count it"},
    )

    def __post_init__(self) -> None:
        if self.coulomb_n == 0.0 and self.viscous_n_s_per_m == 0.0:
            raise ValueError("friction needs coulomb_n > 0 or viscous_n_s_per_m > 0 (leave the section out for none)")


@dataclass(frozen=True)
class NoiseConfig:
    """Zero-mean Gaussian sensor noise per signal; a zero std builds nothing for that signal."""

    position_std_m: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0, "help": "position sensor noise"})
    velocity_std_m_per_s: float = field(
        default=0.0, metadata={"min": 0.0, "max": 100.0, "help": "velocity sensor noise"}
    )
    force_std_n: float = field(default=0.0, metadata={"min": 0.0, "max": 1e4, "help": "force sensor noise"})

    def __post_init__(self) -> None:
        if self.position_std_m == 0.0 and self.velocity_std_m_per_s == 0.0 and self.force_std_n == 0.0:
            raise ValueError(
                "noise needs at least one of position_std_m, velocity_std_m_per_s, force_std_n > 0 "
                "(leave the section out for none)"
            )


@dataclass(frozen=True)
class EncoderConfig:
    """Position encoder quantization."""

    resolution_m: float = field(metadata={"gt": 0.0, "max": 1.0, "help": "one encoder count"})


FILTER_TYPES = ("lowpass", "moving_average")


@dataclass(frozen=True)
class ForceFilterConfig:
    """Filtering of the force sensor reading (the wall force the slave measures)."""

    type: str = field(default="lowpass", metadata={"choices": FILTER_TYPES, "help": "filter kind"})
    cutoff_hz: float | None = field(default=None, metadata={"gt": 0.0, "help": "lowpass: first-order cutoff"})
    window_samples: int | None = field(
        default=None, metadata={"min": 1, "max": 100000, "help": "moving_average: samples averaged"}
    )

    def __post_init__(self) -> None:
        if self.type == "lowpass" and (self.cutoff_hz is None or self.window_samples is not None):
            raise ValueError("force_filter type 'lowpass' needs cutoff_hz and no window_samples")
        if self.type == "moving_average" and (self.window_samples is None or self.cutoff_hz is not None):
            raise ValueError("force_filter type 'moving_average' needs window_samples and no cutoff_hz")


@dataclass(frozen=True)
class SaturationConfig:
    """Actuator saturation: a force limit and/or a slew rate limit on the force applied."""

    force_limit_n: float | None = field(default=None, metadata={"gt": 0.0, "max": 1e5, "help": "clip |F| to this"})
    slew_rate_n_per_s: float | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e9, "help": "largest change of the applied force per second"}
    )

    def __post_init__(self) -> None:
        if self.force_limit_n is None and self.slew_rate_n_per_s is None:
            raise ValueError("saturation needs force_limit_n, slew_rate_n_per_s or both")


@dataclass(frozen=True)
class PlantEffectsConfig:
    """Physical, sensor and actuator effects of one side; absent (None) effects are not built."""

    gravity: GravityConfig | None = None
    friction: FrictionConfig | None = None
    noise: NoiseConfig | None = None
    encoder: EncoderConfig | None = None
    force_filter: ForceFilterConfig | None = None
    saturation: SaturationConfig | None = None

    def named(self) -> tuple[str, ...]:
        """The effects this config names, in declaration order."""
        return tuple(f.name for f in dataclasses.fields(self) if getattr(self, f.name) is not None)


def _check_saturation(side: str, effects: PlantEffectsConfig, plant_limit_n: float) -> None:
    sat = effects.saturation
    if sat is not None and sat.force_limit_n is not None and sat.force_limit_n >= plant_limit_n:
        raise ValueError(
            f"{side}.effects.saturation.force_limit_n ({sat.force_limit_n}) must be below {side}.force_limit_n "
            f"({plant_limit_n}), where the plant already clips: lower it or leave force_limit_n out"
        )


BACKENDS = tuple(PLANT_BACKENDS)  # plants/base.py: the registry (mujoco, dynamixel, ur)


def hardware_variants() -> tuple[type, ...]:
    """Every real backend's hardware section class (plants/base.py's registry, in its order)."""
    return tuple(hardware_classes().values())


def hardware_section(backend: str, data: Any, where: str, source: str) -> type:
    """The config class that reads a side's `hardware` section: its backend's (plants/base.py), or
    for a simulated side, whose section waits for `--set <side>.backend=...`, the real backend
    whose keys it uses (checked the same, unused)."""
    classes = hardware_classes()
    keys = set(data) if isinstance(data, Mapping) else set()

    def own(cls: type) -> list[str]:
        return [f.name for f in dataclasses.fields(cls)]

    if backend in classes:
        cls = classes[backend]
        stray = sorted(keys - set(own(cls)))
        if stray:
            others = [name for name, c in classes.items() if name != backend and stray[0] in own(c)]
            side = where.rpartition(".")[0]
            why = f"a key of backend {others[0]}, and" if others else "unknown key, and"
            raise ConfigError(
                source,
                f"{where}.{stray[0]}",
                data[stray[0]],
                f"{why} {side}.backend is {backend}; allowed for backend {backend}: {', '.join(own(cls))}",
            )
        return cls
    for cls in classes.values():
        if keys <= set(own(cls)):
            return cls
    allowed = "; ".join(f"for backend {name}: {', '.join(own(c))}" for name, c in classes.items())
    raise ConfigError(source, where, dict(data), f"keys of no one backend's hardware section; allowed {allowed}")


@dataclass(frozen=True)
class MasterConfig:
    backend: str = field(
        default="mujoco", metadata={"choices": BACKENDS, "help": "mujoco (simulated), or a real arm: docs/hardware.md"}
    )
    model: str = "master_device.xml"
    mass_kg: float = field(default=0.2, metadata={"gt": 0.0, "max": 100.0})
    damping_n_s_per_m: float = field(default=1.0, metadata={"gt": 0.0, "max": 1e4, "help": "physical damping b_m"})
    force_limit_n: float = field(default=30.0, metadata={"gt": 0.0, "max": 1e4, "help": "actuator limit"})
    effects: PlantEffectsConfig = field(default_factory=PlantEffectsConfig)
    joints: tuple[str, ...] | None = field(
        default=None, metadata={"help": "arms: joint names, checked against the model (default: its motors' joints)"}
    )
    start_q_rad: tuple[float, ...] | None = field(
        default=None, metadata={"help": "arms: start joint configuration, one value per joint"}
    )
    damping_nm_s_per_rad: tuple[float, ...] | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e4, "help": "arms: joint damping override (default: the MJCF's)"}
    )
    torque_limit_nm: tuple[float, ...] | None = field(
        default=None,
        metadata={"gt": 0.0, "max": 1e4, "help": "arms: motor torque limits (default: the MJCF's ctrlrange)"},
    )
    gravity_compensation: bool | None = field(
        default=None, metadata={"help": "arms: compensate gravity through the motors (default true)"}
    )
    slew_nm_per_s: tuple[float, ...] | None = field(
        default=None,
        metadata={"gt": 0.0, "max": 1e9, "help": "arms: each motor's torque slew limit, inside the energy bound"},
    )
    hardware: HardwareConfig | None = field(
        default=None,
        metadata={
            "help": "a real backend's device (docs/hardware.md); its keys are the backend's",
            "by": "backend",
            "classes": hardware_section,
            "variants": hardware_variants,
        },
    )
    period_s: float | None = field(
        default=None,
        metadata={
            "gt": 0.0,
            "max": 1.0,
            "help": "arms: the side's own control period, an integer multiple of scene.period_s (default: it)",
        },
    )

    def __post_init__(self) -> None:
        e = self.effects
        if (e.noise is not None and e.noise.force_std_n > 0.0) or e.force_filter is not None:
            raise ValueError(
                "master.effects: the master device has no force sensor, so noise.force_std_n and force_filter "
                "are not allowed here (they belong under slave.effects)"
            )
        _check_saturation("master", e, self.force_limit_n)


@dataclass(frozen=True)
class WallConfig:
    position_m: float = field(default=0.02, metadata={"min": -10.0, "max": 10.0, "help": "tip position at contact"})
    stiffness_n_per_m: float = field(default=1e4, metadata={"gt": 0.0, "max": 1e7})
    damping_n_s_per_m: float = field(default=10.0, metadata={"min": 0.0, "max": 1e5})
    point_m: tuple[float, ...] | None = field(
        default=None, metadata={"min": -10.0, "max": 10.0, "help": "arms: a point of the wall surface (task frame)"}
    )
    normal: tuple[float, ...] | None = field(
        default=None, metadata={"help": "arms: the wall's normal into free space (3 values, normalised)"}
    )

    def __post_init__(self) -> None:
        if (self.point_m is None) != (self.normal is None):
            raise ValueError("an arm's wall needs both point_m and normal (a one-axis wall neither)")
        if self.point_m is not None and len(self.point_m) != 3:
            raise ValueError(f"point_m needs 3 values (x, y, z), got {len(self.point_m)}")
        if self.normal is not None:
            object.__setattr__(self, "normal", _unit(self.normal, "normal"))


def _unit(v: tuple[float, ...], name: str) -> tuple[float, ...]:
    """`v` normalised; a ValueError unless it has 3 values and a nonzero length."""
    if len(v) != 3:
        raise ValueError(f"{name} needs 3 values (x, y, z), got {len(v)}")
    n = math.sqrt(sum(c * c for c in v))
    if not n > 0.0:
        raise ValueError(f"{name} must be a nonzero vector, got {tuple(v)}")
    return tuple(c / n for c in v)


@dataclass(frozen=True)
class SlaveConfig:
    backend: str = field(
        default="mujoco", metadata={"choices": BACKENDS, "help": "mujoco (simulated), or a real arm: docs/hardware.md"}
    )
    model: str = "wall_scene.xml"
    mass_kg: float = field(default=1.0, metadata={"gt": 0.0, "max": 1000.0})
    damping_n_s_per_m: float = field(default=5.0, metadata={"gt": 0.0, "max": 1e5, "help": "physical damping b_s"})
    force_limit_n: float = field(default=50.0, metadata={"gt": 0.0, "max": 1e5, "help": "actuator limit"})
    start_position_m: float = field(default=0.0, metadata={"min": -10.0, "max": 10.0})
    start: str | None = field(
        default=None,
        metadata={
            "choices": ("free", "in_contact"),
            "help": "in_contact: start pressed against the wall at equilibrium (one-axis; docs/transparency.md)",
        },
    )
    initial_contact_force_n: float | None = field(
        default=None,
        metadata={"gt": 0.0, "max": 1e4, "help": "start in_contact: the wall force at the start"},
    )
    contact_impedance: float = field(
        default=0.1, metadata={"gt": 0.0, "max": 0.5, "help": "MuJoCo solimp d of the wall contact"}
    )
    wall: WallConfig = field(default_factory=WallConfig)
    effects: PlantEffectsConfig = field(default_factory=PlantEffectsConfig)
    joints: tuple[str, ...] | None = field(
        default=None, metadata={"help": "arms: joint names, checked against the model (default: its motors' joints)"}
    )
    start_q_rad: tuple[float, ...] | None = field(
        default=None, metadata={"help": "arms: start joint configuration, one value per joint"}
    )
    damping_nm_s_per_rad: tuple[float, ...] | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e4, "help": "arms: joint damping override (default: the MJCF's)"}
    )
    torque_limit_nm: tuple[float, ...] | None = field(
        default=None,
        metadata={"gt": 0.0, "max": 1e4, "help": "arms: motor torque limits (default: the MJCF's ctrlrange)"},
    )
    gravity_compensation: bool | None = field(
        default=None, metadata={"help": "arms: compensate gravity through the motors (default true)"}
    )
    slew_nm_per_s: tuple[float, ...] | None = field(
        default=None,
        metadata={"gt": 0.0, "max": 1e9, "help": "arms: each motor's torque slew limit, inside the energy bound"},
    )
    hardware: HardwareConfig | None = field(
        default=None,
        metadata={
            "help": "a real backend's device (docs/hardware.md); its keys are the backend's",
            "by": "backend",
            "classes": hardware_section,
            "variants": hardware_variants,
        },
    )
    period_s: float | None = field(
        default=None,
        metadata={
            "gt": 0.0,
            "max": 1.0,
            "help": "arms: the side's own control period, an integer multiple of scene.period_s (default: it)",
        },
    )

    @property
    def in_contact(self) -> bool:
        """The robot starts pressed against the wall (`start: in_contact`)."""
        return self.start == "in_contact"

    def __post_init__(self) -> None:
        _check_saturation("slave", self.effects, self.force_limit_n)
        if self.in_contact != (self.initial_contact_force_n is not None):
            raise ValueError(
                "start: in_contact and initial_contact_force_n go together (the wall force at the start, > 0); "
                "a free start has no initial_contact_force_n"
            )
        if self.in_contact:
            if self.start_position_m != 0.0:
                raise ValueError(
                    "start: in_contact sets the start position from the contact force; leave start_position_m out"
                )
            return
        if self.wall.position_m <= self.start_position_m:
            raise ValueError(
                f"wall.position_m ({self.wall.position_m}) must be beyond start_position_m "
                f"({self.start_position_m}): the robot starts in free space"
            )


@dataclass(frozen=True)
class SimulationConfig:
    substeps: int = field(default=1, metadata={"min": 1, "max": 64, "help": "MuJoCo steps per control period"})
    integrator: str = field(default="implicitfast", metadata={"choices": ("Euler", "implicitfast", "implicit", "RK4")})
    solver_iterations: int = field(default=100, metadata={"min": 1, "max": 10000})
    solver_tolerance: float = field(default=1e-8, metadata={"gt": 0.0, "max": 1.0})


@dataclass(frozen=True)
class NetworkConfig:
    forward: ChannelDirectionConfig = field(default_factory=ChannelDirectionConfig)
    backward: ChannelDirectionConfig = field(default_factory=ChannelDirectionConfig)


@dataclass(frozen=True)
class RecordingConfig:
    eba_internals: bool = field(default=True, metadata={"help": "record reservoirs and desired forces"})
    packets: bool = field(default=True, metadata={"help": "record every packet's fate"})
    compression: str = field(
        default="none", metadata={"choices": ("none", "zstd", "lz4"), "help": "MCAP chunk compression of the bag"}
    )


@dataclass(frozen=True)
class AnalysisConfig:
    """What the transparency analysis of a contact run takes from the scene (docs/transparency.md)."""

    allowed_force_error_n: float = field(
        default=0.1,
        metadata={"gt": 0.0, "max": 1e3, "help": "the force distortion E the allowable delay and loss time are for"},
    )
    reference: bool | None = field(
        default=None,
        metadata={
            "help": "compare with an undisturbed reference run (no network effects); default: in-contact starts only"
        },
    )


WALL_STEP_LIMIT = math.sqrt(2.0)  # largest stable omega * h of the wall contact (docs/robustness.md)


@dataclass(frozen=True)
class Scene:
    """A whole scene. Every default here is the default scene (config/scenes/wall_contact.yaml)."""

    scene: RunConfig = field(default_factory=RunConfig)
    operator: OperatorConfig = field(default_factory=OperatorConfig)
    master: MasterConfig = field(default_factory=MasterConfig)
    slave: SlaveConfig = field(default_factory=SlaveConfig)
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    controllers: ControllersConfig = field(default_factory=ControllersConfig)
    network: NetworkConfig = field(default_factory=NetworkConfig)
    recording: RecordingConfig = field(default_factory=RecordingConfig)
    mapping: MappingConfig | None = field(default=None, metadata={"help": "arms: workspace mapping master -> slave"})
    nve: NveConfig | None = field(
        default=None, metadata={"help": "an NVE scene: a server's virtual object and its clients (docs/nve.md)"}
    )
    analysis: AnalysisConfig | None = field(
        default=None, metadata={"help": "the transparency analysis of contact runs (docs/transparency.md)"}
    )

    @property
    def is_nve(self) -> bool:
        """A client-server haptic NVE scene (no master, slave or controllers)."""
        return self.nve is not None

    @property
    def is_arm(self) -> bool:
        """An arm scene (its wall has a pose): the task is 3-D, the plants are MJCF arms."""
        return self.slave.wall.point_m is not None

    def __post_init__(self) -> None:
        for name in ("forward", "backward"):
            buf = getattr(self.network, name).buffer
            if buf.policy != "network_adaptive" or None not in (buf.allowable_delay_s, buf.allowable_loss_time_s):
                continue
            if self.is_arm or self.operator.profile not in ("push", "imposed") or self.operator.speed_m_per_s == 0.0:
                raise ValueError(
                    f"network.{name}.buffer: policy network_adaptive takes its allowable delay and loss time from "
                    "the transparency analysis of a one-axis scene whose operator profile is push or imposed; "
                    "allowed here: set allowable_delay_s and allowable_loss_time_s (docs/playout.md)"
                )
        for side, ctrl, plant in (
            ("master", self.controllers.master, self.master),
            ("slave", self.controllers.slave, self.slave),
        ):
            sat = plant.effects.saturation
            slew = sat is not None and sat.slew_rate_n_per_s is not None
            if ctrl.eba.law in ("two_condition", "tdpa", "wave") and slew:
                raise ValueError(
                    f"controllers.{side}.eba.law {ctrl.eba.law} does not model {side}.effects.saturation."
                    "slew_rate_n_per_s; allowed with a slew limit: law reservoir (docs/eba.md)"
                )
            if ctrl.force_limit_n > plant.force_limit_n:
                raise ValueError(
                    f"controllers.{side}.force_limit_n ({ctrl.force_limit_n}) exceeds {side}.force_limit_n "
                    f"({plant.force_limit_n}): the actuator would clip forces the energy bound accounted for"
                )
        self._check_tdpa()
        nyquist_hz = 0.5 / self.scene.period_s
        for side, effects in (("master", self.master.effects), ("slave", self.slave.effects)):
            filt = effects.force_filter
            if filt is not None and filt.cutoff_hz is not None and filt.cutoff_hz >= nyquist_hz:
                raise ValueError(
                    f"{side}.effects.force_filter.cutoff_hz ({filt.cutoff_hz}) must be below the Nyquist "
                    f"frequency 1 / (2 scene.period_s) = {nyquist_hz:g} Hz"
                )
        # A wall too stiff for the MuJoCo step makes energy in the plant (below the controllers,
        # where EBA cannot see it). Measured limit: omega * h <= sqrt(2), omega = sqrt(K (1 - d) / m)
        # (docs/robustness.md, "The naive integrator").
        h = self.scene.period_s / self.simulation.substeps
        omega = math.sqrt(self.slave.wall.stiffness_n_per_m * (1.0 - self.slave.contact_impedance) / self.slave.mass_kg)
        if omega * h > WALL_STEP_LIMIT and not self.is_arm:  # an arm's wall: _check_arm_scene, with the model
            need = math.ceil(omega * self.scene.period_s / WALL_STEP_LIMIT)
            raise ValueError(
                f"slave.wall.stiffness_n_per_m ({self.slave.wall.stiffness_n_per_m:g}) is too stiff for a MuJoCo "
                f"step of {h * 1e3:g} ms: omega * h = {omega * h:.2f} > {WALL_STEP_LIMIT:.2f} makes the simulated wall "
                f"active; allowed: simulation.substeps >= {need} for this wall, or a softer wall or heavier robot"
            )
        self._check_seed_premise()
        friction = self.slave.effects.friction
        if friction is not None and friction.coulomb_n > 0.0 and self.simulation.substeps != 1:
            raise ValueError(
                "slave.effects.friction.coulomb_n needs simulation.substeps: 1 (the wall force is told "
                "apart from the joint friction force per MuJoCo step, docs/effects.md)"
            )

    def _check_tdpa(self) -> None:
        """TDPA and wave variables (docs/stabilizers.md) stabilize the two-port: both sides run the
        same one, each sending what the other needs (its observed energy, its wave). Runs so far:
        one-axis scenes in the engine, plain channels (no codec stage, which carries its own
        payloads)."""
        laws = (self.controllers.master.eba.law, self.controllers.slave.eba.law)
        law = next((x for x in laws if x in ("tdpa", "wave")), None)
        if law is None:
            return
        if laws != (law, law):
            raise ValueError(
                f"controllers.<side>.eba.law: {law} on one side only (master {laws[0]}, slave {laws[1]}); allowed: "
                f"{law} on both sides (each side spends what the other side sends)"
            )
        if self.is_nve:
            raise ValueError(f"controllers.<side>.eba.law {law}: not for NVE scenes; allowed there: reservoir")
        for side in ("master", "slave"):
            c = getattr(self.controllers, side)
            if law != "tdpa" or c.eba.tdpa_placement != "admittance":
                continue
            if c.law == "force":
                raise ValueError(
                    f"controllers.{side}.eba.tdpa_placement admittance moves the coupling's reference; "
                    f"controllers.{side}.law force has none; allowed: position, or tdpa_placement impedance"
                )
            if c.eba.tdpa_drift_gain_per_s * self.scene.period_s > 1.0:
                raise ValueError(
                    f"controllers.{side}.eba.tdpa_drift_gain_per_s ({c.eba.tdpa_drift_gain_per_s:g}) returns more "
                    f"than the whole slip in one period; allowed: at most 1 / scene.period_s = "
                    f"{1.0 / self.scene.period_s:g}"
                )
        for name in ("forward", "backward"):
            if getattr(self.network, name).codec is not None:
                raise ValueError(
                    f"network.{name}.codec with controllers.<side>.eba.law {law}: the codecs do not carry its "
                    f"samples yet; allowed with {law}: no codec (plain samples)"
                )
            buf = getattr(self.network, name).buffer
            if buf.policy == "network_adaptive" and None in (buf.allowable_delay_s, buf.allowable_loss_time_s):
                raise ValueError(
                    f"network.{name}.buffer: policy network_adaptive takes its budget from the EBA transparency "
                    f"analysis, which does not model {law}; allowed: set allowable_delay_s and allowable_loss_time_s"
                )
        m, s = self.controllers.master.eba, self.controllers.slave.eba
        if law == "wave" and m.wave_impedance_n_s_per_m != s.wave_impedance_n_s_per_m:
            raise ValueError(
                f"controllers.slave.eba.wave_impedance_n_s_per_m ({s.wave_impedance_n_s_per_m:g}) differs from the "
                f"master's ({m.wave_impedance_n_s_per_m:g}); allowed: one wave impedance for the channel"
            )
        if m.wave_matched:
            raise ValueError(
                "controllers.master.eba.wave_matched: the master's port is not matched (a series damper would halve "
                'the force the hand feels; docs/stabilizers.md, "Impedance matching"); allowed: '
                "controllers.slave.eba.wave_matched"
            )
        nyquist = 0.5 / self.scene.period_s
        for side, e in (("master", m), ("slave", s)):
            if law == "wave" and e.wave_filter_hz is not None and e.wave_filter_hz >= nyquist:
                raise ValueError(
                    f"controllers.{side}.eba.wave_filter_hz ({e.wave_filter_hz:g}) must be below the Nyquist "
                    f"frequency 1 / (2 scene.period_s) = {nyquist:g} Hz"
                )

    def _check_seed_premise(self) -> None:
        """The seed scenario's keys (docs/transparency.md): one axis; an in-contact start that can
        be held (each side's equilibrium force within its saturation)."""
        op, s = self.operator, self.slave
        if self.is_arm and (op.profile == "imposed" or s.in_contact):
            key = "operator.profile imposed" if op.profile == "imposed" else "slave.start in_contact"
            raise ValueError(
                f"{key} is for one-axis scenes; an arm scene starts free with a hand (push, sinusoid, hold)"
            )
        if not s.in_contact:
            return
        if op.profile == "trace":
            raise ValueError(
                "slave.start in_contact moves the start positions; operator.profile trace gives absolute ones "
                "(allowed: push, sinusoid, hold, imposed)"
            )
        f0 = s.initial_contact_force_n or 0.0
        ms, cs = self.controllers.master, self.controllers.slave
        if cs.stiffness_n_per_m <= 0.0:
            raise ValueError("slave.start in_contact needs controllers.slave.stiffness_n_per_m > 0 to hold the contact")
        fm = ms.force_gain * f0 if ms.law == "force" else ms.stiffness_n_per_m * f0 / cs.stiffness_n_per_m
        for side, need, lim in (("slave", f0, cs.force_limit_n), ("master", fm, ms.force_limit_n)):
            if need > lim:
                raise ValueError(
                    f"slave.initial_contact_force_n ({f0:g}) needs {need:g} N from the {side} controller, beyond "
                    f"controllers.{side}.force_limit_n ({lim:g}); allowed: a contact force the controllers can hold"
                )
        if op.profile in ("push", "hold", "sinusoid") and fm > 0.0 and op.stiffness_n_per_m <= 0.0:
            raise ValueError(
                "slave.start in_contact with a hand needs operator.stiffness_n_per_m > 0 to hold the master"
            )


@dataclass(frozen=True)
class LoadedScene:
    """A validated scene with where it came from and the data files it names, already read."""

    config: Scene
    source: str
    raw: Mapping[str, Any]
    operator_trace: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def to_yaml(self) -> str:
        d = dataclasses.asdict(self.config)
        if self.config.nve is not None:  # an NVE scene: the sections it uses only
            d = {k: d[k] for k in NVE_SECTIONS}
        return yaml.safe_dump(_without_absent_arm_keys(d), sort_keys=False)


# The sections of an NVE scene; the others (master, slave, ...) are teleoperation's.
NVE_SECTIONS = ("scene", "nve", "recording")


# Keys only arm scenes use: left out of a scene's YAML when absent, so a one-axis scene's resolved
# YAML (and its bag) stay as they were before arms.
ARM_KEYS = frozenset(
    {
        "joints", "start_q_rad", "damping_nm_s_per_rad", "torque_limit_nm", "gravity_compensation", "point_m",
        "normal", "mapping", "stiffness_axes_n_per_m", "damping_axes_n_s_per_m", "null_space_damping_nm_s_per_rad",
        "orientation", "direction", "slew_nm_per_s", "hardware", "nve",
    }
)  # fmt: skip
# Keys of the seed scenario (docs/transparency.md), left out the same way when absent.
SEED_KEYS = frozenset({"duration_s", "start", "initial_contact_force_n", "analysis"})


def _without_absent_arm_keys(d: Any) -> Any:
    if isinstance(d, dict):
        return {
            k: (_given_codec_keys(v) if k == "codec" else _without_absent_arm_keys(v))
            for k, v in d.items()
            if not ((k in ARM_KEYS or k in SEED_KEYS or k == "codec") and v is None)
        }
    return d


def _given_codec_keys(d: Any) -> Any:
    """A channel's codec section with only the keys its kind has that were given (the rest are
    None: another codec's keys, or defaults the codec's own config fills in)."""
    return {k: v for k, v in d.items() if v is not None} if isinstance(d, dict) else d

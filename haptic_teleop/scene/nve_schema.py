"""The `nve:` section of a scene: a client-server haptic networked virtual environment (seed 000).

A scene with an `nve` section is an NVE scene: a consistency server integrates one virtual object
and each client, over its own link pair (`up`: client -> server, `down`: server -> client, the
same effects and playout buffers as teleoperation), feels a spring-damper toward the object it
last received. Its HIP is driven by an operator profile. docs/nve.md has the model, docs/nve_scenes.md the keys.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field

from haptic_teleop.core.nve import SCHEMES
from haptic_teleop.core.nve_transparency import RULES
from haptic_teleop.scene.direction import DirectionConfig

NVE_AXES = (1, 3)
NVE_PROFILES = ("push", "sinusoid", "hold", "trace")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")


@dataclass(frozen=True)
class NveObjectConfig:
    mass_kg: float = field(default=0.25, metadata={"gt": 0.0, "max": 1e4, "help": "the virtual object's mass m"})
    damping_n_s_per_m: float = field(
        default=0.0025, metadata={"min": 0.0, "max": 1e5, "help": "the virtual object's damping b (to the world)"}
    )
    start_position_m: tuple[float, ...] | None = field(
        default=None, metadata={"min": -100.0, "max": 100.0, "help": "one value per axis (default: the origin)"}
    )


@dataclass(frozen=True)
class NveOperatorConfig:
    """What drives a client's HIP (position-driven: the HIP follows the profile exactly)."""

    profile: str = field(default="push", metadata={"choices": NVE_PROFILES})
    start_s: float = field(default=0.5, metadata={"min": 0.0, "help": "when the motion starts"})
    speed_m_per_s: float = field(default=0.1, metadata={"min": -5.0, "max": 5.0, "help": "push speed"})
    distance_m: float = field(default=1.0, metadata={"min": 0.0, "max": 100.0, "help": "push length, then hold"})
    amplitude_m: float = field(default=0.05, metadata={"min": 0.0, "max": 10.0})
    frequency_hz: float = field(default=0.5, metadata={"gt": 0.0, "max": 100.0})
    trace_file: str | None = field(default=None, metadata={"help": "CSV time_s,position_m (profile trace)"})
    direction: tuple[float, ...] | None = field(
        default=None, metadata={"help": "3 axes: the profile's direction (3 values, normalised; default +x)"}
    )

    def __post_init__(self) -> None:
        if self.profile == "trace" and not self.trace_file:
            raise ValueError("profile 'trace' needs trace_file")
        if self.profile != "trace" and self.trace_file:
            raise ValueError(f"trace_file is only used with profile 'trace', not {self.profile!r}")
        if self.direction is not None:
            if len(self.direction) != 3:
                raise ValueError(f"direction needs 3 values, got {len(self.direction)}")
            n = math.sqrt(sum(x * x for x in self.direction))
            if n == 0.0:
                raise ValueError("direction must not be the zero vector")
            object.__setattr__(self, "direction", tuple(x / n for x in self.direction))


@dataclass(frozen=True)
class CouplingConfig:
    client_stiffness_n_per_m: float = field(
        default=0.5, metadata={"min": 0.0, "max": 1e6, "help": "k_h: the client's spring toward the received object"}
    )
    client_damping_n_s_per_m: float = field(default=0.0, metadata={"min": 0.0, "max": 1e5, "help": "d_h"})
    server_stiffness_n_per_m: float = field(
        default=0.5,
        metadata={
            "min": 0.0,
            "max": 1e6,
            "help": "k_e: the server's spring pulling the object to the received HIP (0: observer)",
        },
    )
    server_damping_n_s_per_m: float = field(default=0.0, metadata={"min": 0.0, "max": 1e5, "help": "d_e"})


_TRANSPARENCY_KEYS = ("allowable_mass_kg", "allowable_damping_n_s_per_m")
_FUJIMOTO_KEYS = ("initial_spring_n_per_m", "reduction_n_per_m_per_s", "threshold_rtt_s")


@dataclass(frozen=True)
class CompensationConfig:
    """A client's delay compensation: its spring coefficient k_h against the measured round trip."""

    scheme: str = field(default="none", metadata={"choices": SCHEMES})
    # transparency (seed 000)
    rule: str = field(
        default="auto",
        metadata={"choices": RULES, "help": "which spring distortion: auto = mass-based iff m w >= b"},
    )
    interaction_rad_per_s: float = field(
        default=1.0, metadata={"gt": 0.0, "max": 1e3, "help": "w of the rule: the user's interaction frequency"}
    )
    allowable_mass_kg: float | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e5, "help": "m_allowable: the largest perceived mass accepted"}
    )
    allowable_damping_n_s_per_m: float | None = field(
        default=None, metadata={"min": 0.0, "max": 1e6, "help": "b_allowable: the largest perceived damping accepted"}
    )
    # fujimoto04
    initial_spring_n_per_m: float | None = field(
        default=None, metadata={"min": 0.0, "max": 1e6, "help": "K0 (default: the client stiffness)"}
    )
    reduction_n_per_m_per_s: float | None = field(
        default=None, metadata={"min": 0.0, "max": 1e8, "help": "alpha: spring removed per second of round trip"}
    )
    threshold_rtt_s: float | None = field(
        default=None, metadata={"min": 0.0, "max": 100.0, "help": "R0: round trip below which K stays K0"}
    )
    # both
    min_spring_n_per_m: float = field(
        default=0.0, metadata={"min": 0.0, "max": 1e6, "help": "the spring is never set below this"}
    )

    def __post_init__(self) -> None:
        given = [k for k in (*_TRANSPARENCY_KEYS, *_FUJIMOTO_KEYS) if getattr(self, k) is not None]
        own = {"none": (), "transparency": _TRANSPARENCY_KEYS, "fujimoto04": _FUJIMOTO_KEYS}[self.scheme]
        stray = [k for k in given if k not in own]
        if stray:
            raise ValueError(f"{stray[0]} is not used by scheme {self.scheme!r}")
        if self.scheme == "transparency":
            need = {
                "auto": _TRANSPARENCY_KEYS,
                "mass": ("allowable_mass_kg",),
                "damping": ("allowable_damping_n_s_per_m",),
            }[self.rule]
            missing = [k for k in need if getattr(self, k) is None]
            if missing:
                raise ValueError(f"scheme 'transparency' with rule {self.rule!r} needs {' and '.join(missing)}")
        if self.scheme == "fujimoto04" and self.reduction_n_per_m_per_s is None:
            raise ValueError("scheme 'fujimoto04' needs reduction_n_per_m_per_s (alpha)")


@dataclass(frozen=True)
class NveClientConfig:
    name: str = field(default="client", metadata={"help": "letters, digits and _; distinct per client"})
    operator: NveOperatorConfig = field(default_factory=NveOperatorConfig)
    hip_start_m: tuple[float, ...] | None = field(
        default=None,
        metadata={"min": -100.0, "max": 100.0, "help": "the HIP's rest position (default: the object's start)"},
    )
    coupling: CouplingConfig = field(default_factory=CouplingConfig)
    compensation: CompensationConfig = field(default_factory=CompensationConfig)
    up: DirectionConfig = field(default_factory=DirectionConfig, metadata={"help": "client -> server"})
    down: DirectionConfig = field(default_factory=DirectionConfig, metadata={"help": "server -> client"})

    def __post_init__(self) -> None:
        if not _NAME.match(self.name):
            raise ValueError(f"name {self.name!r}: letters, digits and _ only, not starting with a digit")


@dataclass(frozen=True)
class NveConfig:
    axes: int = field(default=1, metadata={"choices": NVE_AXES, "help": "1 (a line) or 3 (x, y, z)"})
    object: NveObjectConfig = field(default_factory=NveObjectConfig)
    clients: tuple[NveClientConfig, ...] = field(
        default=(NveClientConfig(),), metadata={"help": "one or more clients, each with its own link pair"}
    )

    def __post_init__(self) -> None:
        if not self.clients:
            raise ValueError("clients: at least one client is needed")
        names = [c.name for c in self.clients]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ValueError(f"client names must be distinct; {', '.join(dup)} repeats")
        start = self.object.start_position_m
        if start is not None and len(start) != self.axes:
            raise ValueError(f"object.start_position_m needs {self.axes} value(s) (axes), got {len(start)}")
        for c in self.clients:
            if c.hip_start_m is not None and len(c.hip_start_m) != self.axes:
                raise ValueError(
                    f"client {c.name}: hip_start_m needs {self.axes} value(s) (axes), got {len(c.hip_start_m)}"
                )
            if c.operator.direction is not None and self.axes != 3:
                raise ValueError(f"client {c.name}: operator.direction is for 3 axes only")
            comp = c.compensation
            if comp.scheme == "transparency":
                rule = comp.rule
                if rule == "auto":
                    rule = (
                        "mass"
                        if self.object.mass_kg * comp.interaction_rad_per_s >= self.object.damping_n_s_per_m
                        else "damping"
                    )
                if rule == "damping" and self.object.damping_n_s_per_m <= 0.0:
                    raise ValueError(
                        f"client {c.name}: the damping-based spring distortion needs object.damping_n_s_per_m > 0"
                    )

    @property
    def object_start(self) -> tuple[float, ...]:
        return self.object.start_position_m if self.object.start_position_m is not None else (0.0,) * self.axes

"""Scene files (YAML) -> validated, frozen config. Nothing runs until the whole scene is valid.

Every key, its unit, default and range is declared here (docs/scenes.md lists them). A scene
names the effects it wants; absent effects are not built.
"""

from __future__ import annotations

import copy
import csv
import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from haptic_teleop.core.network import NetworkEffectsConfig, resolve_trace_paths
from haptic_teleop.core.playout import BufferConfig
from haptic_teleop.errors import ConfigError
from haptic_teleop.schema import build


@dataclass(frozen=True)
class RunConfig:
    name: str = field(default="scene", metadata={"help": "scene name, used in reports"})
    period_s: float = field(default=0.001, metadata={"gt": 0.0, "max": 0.01, "help": "control period T"})
    duration_s: float = field(default=10.0, metadata={"gt": 0.0, "max": 86400.0})
    seed: int = field(default=0, metadata={"min": 0, "max": 2**63 - 1, "help": "seed of every random stream"})

    def __post_init__(self) -> None:
        if self.duration_s < self.period_s:
            raise ValueError("duration_s must be at least one period_s")


@dataclass(frozen=True)
class OperatorConfig:
    profile: str = field(default="push", metadata={"choices": ("push", "sinusoid", "hold", "trace")})
    mass_kg: float = field(default=0.5, metadata={"min": 0.0, "max": 20.0, "help": "arm mass moving with the handle"})
    stiffness_n_per_m: float = field(default=200.0, metadata={"min": 0.0, "max": 1e5})
    damping_n_s_per_m: float = field(default=10.0, metadata={"min": 0.0, "max": 1e4})
    start_s: float = field(default=0.5, metadata={"min": 0.0, "help": "when the intended motion starts"})
    speed_m_per_s: float = field(default=0.02, metadata={"min": -5.0, "max": 5.0, "help": "push speed"})
    distance_m: float = field(default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "push length, then hold"})
    amplitude_m: float = field(default=0.02, metadata={"min": 0.0, "max": 10.0})
    frequency_hz: float = field(default=0.5, metadata={"gt": 0.0, "max": 100.0})
    trace_file: str | None = field(default=None, metadata={"help": "CSV time_s,position_m (profile trace)"})

    def __post_init__(self) -> None:
        if self.profile == "trace" and not self.trace_file:
            raise ValueError("profile 'trace' needs trace_file")
        if self.profile != "trace" and self.trace_file:
            raise ValueError(f"trace_file is only used with profile 'trace', not {self.profile!r}")


@dataclass(frozen=True)
class MasterConfig:
    backend: str = field(default="mujoco", metadata={"choices": ("mujoco",)})
    model: str = "master_device.xml"
    mass_kg: float = field(default=0.2, metadata={"gt": 0.0, "max": 100.0})
    damping_n_s_per_m: float = field(default=1.0, metadata={"gt": 0.0, "max": 1e4, "help": "physical damping b_m"})
    force_limit_n: float = field(default=30.0, metadata={"gt": 0.0, "max": 1e4, "help": "actuator limit"})


@dataclass(frozen=True)
class WallConfig:
    position_m: float = field(default=0.02, metadata={"min": -10.0, "max": 10.0, "help": "tip position at contact"})
    stiffness_n_per_m: float = field(default=1e4, metadata={"gt": 0.0, "max": 1e7})
    damping_n_s_per_m: float = field(default=10.0, metadata={"min": 0.0, "max": 1e5})


@dataclass(frozen=True)
class SlaveConfig:
    backend: str = field(default="mujoco", metadata={"choices": ("mujoco",)})
    model: str = "wall_scene.xml"
    mass_kg: float = field(default=1.0, metadata={"gt": 0.0, "max": 1000.0})
    damping_n_s_per_m: float = field(default=5.0, metadata={"gt": 0.0, "max": 1e5, "help": "physical damping b_s"})
    force_limit_n: float = field(default=50.0, metadata={"gt": 0.0, "max": 1e5, "help": "actuator limit"})
    start_position_m: float = field(default=0.0, metadata={"min": -10.0, "max": 10.0})
    contact_impedance: float = field(
        default=0.1, metadata={"gt": 0.0, "max": 0.5, "help": "MuJoCo solimp d of the wall contact"}
    )
    wall: WallConfig = field(default_factory=WallConfig)

    def __post_init__(self) -> None:
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
class EBAConfig:
    enabled: bool = field(default=True, metadata={"help": "false runs the unprotected control law"})
    initial_energy_j: float = field(default=0.0, metadata={"min": 0.0, "max": 1e3, "help": "per-axis budget E0"})


@dataclass(frozen=True)
class ControllerConfig:
    law: str = field(default="position", metadata={"choices": ("position", "force")})
    stiffness_n_per_m: float = field(default=500.0, metadata={"min": 0.0, "max": 1e7, "help": "c1"})
    damping_n_s_per_m: float = field(default=20.0, metadata={"min": 0.0, "max": 1e5, "help": "c2"})
    force_gain: float = field(default=1.0, metadata={"min": 0.0, "max": 100.0, "help": "force reflection gain"})
    force_limit_n: float = field(default=20.0, metadata={"gt": 0.0, "max": 1e5, "help": "saturation"})
    eba: EBAConfig = field(default_factory=EBAConfig)


def _slave_default() -> ControllerConfig:
    return ControllerConfig(force_limit_n=40.0, eba=EBAConfig(initial_energy_j=0.5))


@dataclass(frozen=True)
class ControllersConfig:
    master: ControllerConfig = field(default_factory=ControllerConfig)
    slave: ControllerConfig = field(default_factory=_slave_default)

    def __post_init__(self) -> None:
        if self.slave.law != "position":
            raise ValueError("controllers.slave.law must be 'position': force reflection is a master law")


@dataclass(frozen=True)
class DirectionConfig:
    effects: NetworkEffectsConfig = field(default_factory=NetworkEffectsConfig)
    buffer: BufferConfig = field(default_factory=BufferConfig)


@dataclass(frozen=True)
class NetworkConfig:
    forward: DirectionConfig = field(default_factory=DirectionConfig)
    backward: DirectionConfig = field(default_factory=DirectionConfig)


@dataclass(frozen=True)
class RecordingConfig:
    eba_internals: bool = field(default=True, metadata={"help": "record reservoirs and desired forces"})
    packets: bool = field(default=True, metadata={"help": "record every packet's fate"})


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

    def __post_init__(self) -> None:
        for side, ctrl, plant in (
            ("master", self.controllers.master, self.master),
            ("slave", self.controllers.slave, self.slave),
        ):
            if ctrl.force_limit_n > plant.force_limit_n:
                raise ValueError(
                    f"controllers.{side}.force_limit_n ({ctrl.force_limit_n}) exceeds {side}.force_limit_n "
                    f"({plant.force_limit_n}): the actuator would clip forces the energy bound accounted for"
                )


@dataclass(frozen=True)
class LoadedScene:
    """A validated scene with where it came from and the data files it names, already read."""

    config: Scene
    source: str
    raw: Mapping[str, Any]
    operator_trace: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def to_yaml(self) -> str:
        return yaml.safe_dump(dataclasses.asdict(self.config), sort_keys=False)


def parse_override(text: str) -> tuple[list[str], Any]:
    """`a.b.c=value` -> (["a","b","c"], value parsed as YAML)."""
    if "=" not in text:
        raise ConfigError("--set", text, text, "allowed: KEY.PATH=VALUE, e.g. slave.wall.stiffness_n_per_m=1e5")
    key, _, value = text.partition("=")
    parts = [p for p in key.strip().split(".")]
    if not key.strip() or any(not p for p in parts):
        raise ConfigError("--set", key, text, "allowed: a dotted key path like network.forward.effects.delay.delay_s")
    try:
        parsed = yaml.safe_load(value) if value.strip() else None
    except yaml.YAMLError:
        parsed = value
    return parts, parsed


def apply_overrides(raw: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    data = copy.deepcopy(raw)
    for text in overrides:
        parts, value = parse_override(text)
        node: Any = data
        for i, p in enumerate(parts[:-1]):
            nxt = node.get(p)
            if nxt is None:
                nxt = node[p] = {}
            if not isinstance(nxt, dict):
                where = ".".join(parts[: i + 1])
                raise ConfigError("--set", where, nxt, f"is a value, not a section; cannot set {'.'.join(parts)}")
            node = nxt
        node[parts[-1]] = value
    return data


def _read_trace(path: Path, source: str, key: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    if not path.is_file():
        raise ConfigError(source, key, str(path), "allowed: an existing CSV file with columns time_s,position_m")
    ts: list[float] = []
    xs: list[float] = []
    with path.open(newline="") as fh:
        for lineno, row in enumerate(csv.reader(fh), start=1):
            if not row or row[0].lstrip().startswith("#"):
                continue
            try:
                t, x = float(row[0]), float(row[1])
            except (ValueError, IndexError):
                if lineno == 1:
                    continue  # header
                raise ConfigError(f"{path}:{lineno}", key, row, "allowed: two numbers time_s,position_m") from None
            if ts and t <= ts[-1]:
                raise ConfigError(f"{path}:{lineno}", key, row, "allowed: strictly increasing time_s")
            ts.append(t)
            xs.append(x)
    if len(ts) < 2:
        raise ConfigError(source, key, str(path), "allowed: a CSV with at least two rows time_s,position_m")
    return tuple(ts), tuple(xs)


def _resolve_traces(config: Scene, base: Path, source: str) -> Scene:
    """Network trace files: relative to the scene's folder, read once now so a bad file stops the run."""
    net = config.network
    dirs = {}
    for name in ("forward", "backward"):
        d = getattr(net, name)
        try:
            effects = resolve_trace_paths(d.effects, base)
        except (OSError, ValueError) as exc:
            raise ConfigError(
                source, f"network.{name}.effects", "trace", f"allowed: a readable trace file ({exc})"
            ) from None
        dirs[name] = dataclasses.replace(d, effects=effects)
    return dataclasses.replace(config, network=dataclasses.replace(net, **dirs))


def load_scene(path: str | Path, overrides: Sequence[str] = (), seed: int | None = None) -> LoadedScene:
    """Read, override and validate a scene file. Raises ConfigError naming file, key, value, allowed."""
    p = Path(path)
    source = str(path)
    if not p.is_file():
        raise ConfigError(source, "", source, "allowed: the path of an existing scene YAML file")
    try:
        raw = yaml.safe_load(p.read_text()) or {}
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else ""
        raise ConfigError(source, where, "", f"not valid YAML ({getattr(exc, 'problem', exc)})") from None
    if not isinstance(raw, dict):
        raise ConfigError(source, "", raw, "allowed: a mapping of sections (scene, operator, master, ...)")
    raw = apply_overrides(raw, overrides)
    if seed is not None:
        raw.setdefault("scene", {})
        if not isinstance(raw["scene"], dict):
            raise ConfigError(source, "scene", raw["scene"], "allowed: a mapping")
        raw["scene"]["seed"] = seed
    config = build(Scene, raw, "", source)
    config = _resolve_traces(config, p.parent, source)
    trace = None
    if config.operator.trace_file:
        tp = Path(config.operator.trace_file)
        if not tp.is_absolute():
            tp = p.parent / tp
        trace = _read_trace(tp, source, "operator.trace_file")
    return LoadedScene(config=config, source=source, raw=raw, operator_trace=trace)


def scenes_dir() -> Path:
    here = Path(__file__).resolve()
    cand = here.parents[1] / "config" / "scenes"
    if cand.is_dir():
        return cand
    try:
        from ament_index_python.packages import get_package_share_directory

        return Path(get_package_share_directory("haptic_teleop")) / "config" / "scenes"
    except Exception:  # noqa: BLE001
        return cand


def find_scene(name: str) -> Path:
    """A path, or the name of a bundled scene (`wall_contact` or `wall_contact.yaml`)."""
    p = Path(name)
    if p.exists():
        return p
    stem = p.name if p.suffix else p.name + ".yaml"
    cand = scenes_dir() / stem
    return cand if cand.exists() else p

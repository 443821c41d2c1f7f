"""Scene files (YAML) -> a validated `LoadedScene`: duplicate keys refused, overrides applied,
the models and the arm geometry checked, data files read; bundled scenes found by name.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from haptic_teleop.errors import ConfigError
from haptic_teleop.plants.base import backend
from haptic_teleop.scene.overrides import Override, apply_overrides, blame_override, parse_override
from haptic_teleop.scene.schema import NVE_SECTIONS, LoadedScene, Scene
from haptic_teleop.scene.traces import read_operator_trace, resolve_scene_traces, resolve_trace_paths
from haptic_teleop.scene.yaml_text import parse_yaml, read_scene_text
from haptic_teleop.typedconfig import build


def _check_models(config: Scene, source: str) -> None:
    """The plants' model files exist (a path, or a bundled model's name): found now, not when a
    plant is built after the outputs were opened."""
    from haptic_teleop.errors import PlantError
    from haptic_teleop.plants.mujoco_plant import models_dir, resolve_model

    for side in ("master", "slave"):
        name = getattr(config, side).model
        try:
            resolve_model(name)
        except (PlantError, OSError, ValueError):  # ValueError: a NUL in the name
            allowed = f"no such model file; allowed: a MuJoCo XML path, or a bundled model's name (in {models_dir()})"
            raise ConfigError(source, f"{side}.model", name, allowed) from None


ARM_SITES = {"master": "handle", "slave": "tool"}  # the point each side's coupling acts on (NDOF names)
ARM_WALL_STEP_LIMIT = 1.0  # omega * h of an arm's wall contact (docs/arms.md: 1.28 chattered on a light arm)


def _check_hardware(
    source: str, side: str, cfg: Any, joints: Sequence[str], emulate: bool, identify: bool = False
) -> None:
    """A side's `backend` and `hardware` section agree (docs/hardware.md): a real device names where
    it is and what it is (its backend's config class says, `problem`), where it stands at start and
    the joint damping EBA may assume (it cannot be read from a simulator), and its SDK is
    installed. A simulated side may carry a hardware section (a bundled scene's, for `--set
    <side>.backend=dynamixel`): checked the same by the backend whose keys it uses, its address
    aside, unused. `emulate`: the addresses are filled in later (`haptic-teleop run --emulate`
    starts an emulator per device)."""
    b = backend(cfg.backend)
    hw = cfg.hardware
    if b.real:
        _check_sdk(source, side, cfg.backend, b.sdk)
        if cfg.damping_nm_s_per_rad is None and not identify:
            raise ConfigError(
                source,
                f"{side}.damping_nm_s_per_rad",
                None,
                f"required for backend {cfg.backend}: the joint damping the energy bound may assume, at most what "
                "the hardware dissipates (measure it: haptic-teleop identify; docs/hardware.md)",
            )
        if cfg.start_q_rad is None:
            raise ConfigError(
                source,
                f"{side}.start_q_rad",
                None,
                f"required for backend {cfg.backend}: where the arm stands at start (the start-up check compares "
                "the measured pose with it)",
            )
        if hw is None:
            keys = ", ".join(b.config_class().required)
            raise ConfigError(
                source, f"{side}.hardware", None, f"required for backend {cfg.backend}: {keys} (docs/hardware.md)"
            )
    if hw is None:
        return
    problem = hw.problem(side, tuple(joints), emulate or not b.real)
    if problem is not None:
        raise ConfigError(source, f"{side}.{problem.key}", problem.value, problem.allowed)


def _check_sdk(source: str, side: str, name: str, modules: Sequence[str]) -> None:
    """A hardware backend whose SDK is not installed is refused before anything runs."""
    import importlib.util

    from haptic_teleop.plants.hardware import SDKS

    for module in modules:
        if importlib.util.find_spec(module) is None:
            raise ConfigError(
                source,
                f"{side}.backend",
                name,
                f"backend {name} needs the Python module {module!r}, which is not installed: "
                f"pip install '{SDKS[module]}' (or install haptic_teleop with its 'hardware' extra)",
            )


def side_period_ticks(config: Scene, side: str, source: str = "scene") -> int:
    """How many scene ticks one of `side`'s ticks spans: `<side>.period_s` / scene.period_s, which
    must be a whole number (docs/arms.md, "A side's own period"); 1 without the key."""
    p = getattr(config, side).period_s
    if p is None:
        return 1
    t = config.scene.period_s
    k = round(p / t)
    if k < 1 or abs(k * t - p) > 1e-9 * max(p, t):
        raise ConfigError(
            source,
            f"{side}.period_s",
            p,
            f"allowed: a whole multiple of scene.period_s ({t:g} s), e.g. {t:g} or {2 * t:g}",
        )
    return int(k)


def _check_arm_scene(config: Scene, source: str, emulate: bool = False, identify: bool = False) -> None:
    """An arm scene's models, joints and per-joint lists agree; the tool starts in free space and
    the wall is not too stiff for the MuJoCo step. A one-axis scene names no arm model."""
    from haptic_teleop.errors import PlantError
    from haptic_teleop.plants.arm import inspect_model

    infos = {side: inspect_model(getattr(config, side).model) for side in ("master", "slave")}
    arm_models = {side: ARM_SITES[side] in infos[side].sites for side in infos}
    if not config.is_arm:
        for side in ("master", "slave"):
            if arm_models[side]:
                raise ConfigError(
                    source,
                    "slave.wall.point_m",
                    None,
                    f"{side}.model {getattr(config, side).model!r} is an arm: its scene needs the wall's pose "
                    "(slave.wall.point_m and normal); allowed: an arm scene, or a one-axis model",
                )
            if getattr(config, side).backend != "mujoco":
                raise ConfigError(
                    source,
                    f"{side}.backend",
                    getattr(config, side).backend,
                    "a real device drives an arm: allowed in a one-axis scene: mujoco",
                )
            for key in (
                "joints",
                "start_q_rad",
                "damping_nm_s_per_rad",
                "torque_limit_nm",
                "gravity_compensation",
                "slew_nm_per_s",
                "hardware",
                "period_s",
            ):
                if getattr(getattr(config, side), key) is not None:
                    raise ConfigError(
                        source, f"{side}.{key}", getattr(getattr(config, side), key), "only for arm models"
                    )
        return
    for side in ("master", "slave"):
        cfg = getattr(config, side)
        info = infos[side]
        if not arm_models[side]:
            raise ConfigError(
                source,
                f"{side}.model",
                cfg.model,
                f"an arm scene needs an arm MJCF with a site {ARM_SITES[side]!r}; this model's sites: "
                f"{', '.join(info.sites) or 'none'}",
            )
        if cfg.effects.named():
            raise ConfigError(
                source, f"{side}.effects", ", ".join(cfg.effects.named()), "not built for arms yet; allowed: none"
            )
        joints = cfg.joints if cfg.joints is not None else tuple(m for m in info.motors if m in info.joints)
        for i, name in enumerate(joints):
            if name not in info.joints:
                raise ConfigError(
                    source,
                    f"{side}.joints[{i}]",
                    name,
                    f"no such joint in {cfg.model}; its joints: {', '.join(info.joints)}",
                )
            if name not in info.motors:
                raise ConfigError(
                    source, f"{side}.joints[{i}]", name, f"{cfg.model} has no motor named {name!r} (one per joint)"
                )
        for key in ("start_q_rad", "damping_nm_s_per_rad", "torque_limit_nm", "slew_nm_per_s"):
            v = getattr(cfg, key)
            if v is not None and len(v) != len(joints):
                raise ConfigError(
                    source,
                    f"{side}.{key}",
                    list(v),
                    f"allowed: {len(joints)} values, one per joint ({', '.join(joints)})",
                )
        _check_hardware(source, side, cfg, joints, emulate, identify)
        side_t = side_period_ticks(config, side, source) * config.scene.period_s
        hold = cfg.hardware.max_hold_s if cfg.hardware is not None else None
        if hold is not None and not hold >= side_t * (1.0 - 1e-9):
            raise ConfigError(
                source,
                f"{side}.hardware.max_hold_s",
                hold,
                f"allowed: at least the side's period ({side_t:g} s): a torque is held a period at least",
            )
    op = config.operator
    if op.profile == "trace":
        raise ConfigError(source, "operator.profile", op.profile, "allowed for arms: push, sinusoid, hold")
    for side in ("master", "slave"):
        if getattr(config.controllers, side).law != "position":
            raise ConfigError(source, f"controllers.{side}.law", "force", "allowed for arms: position")
        law = getattr(config.controllers, side).eba.law
        if law in ("two_condition", "wave") and backend(getattr(config, side).backend).real:
            raise ConfigError(source, f"controllers.{side}.eba.law", law,
                              f"allowed on a real arm: reservoir, tdpa ({law} counts one period per tick; a real "
                              "clock's late ticks need the hold budget those two keep)")  # fmt: skip
        eba = getattr(config.controllers, side).eba
        if law == "tdpa" and eba.tdpa_placement == "admittance" and eba.tdpa_controller != "zoh":
            raise ConfigError(source, f"controllers.{side}.eba.tdpa_placement", "admittance",
                              "allowed for arms with tdpa_controller velocity: impedance (the admittance "
                              "placement on arms moves the reference by the zoh controller's scale)")  # fmt: skip
        if law in ("tdpa", "two_condition", "wave") and getattr(config, side).slew_nm_per_s is not None:
            raise ConfigError(source, f"{side}.slew_nm_per_s", getattr(config, side).slew_nm_per_s,
                              f"allowed with {law}: none (its bound is not slew-aware)")  # fmt: skip
    from haptic_teleop.plants.arm import MujocoArm
    from haptic_teleop.scene.sides import arm_settings

    try:
        slave = MujocoArm(**arm_settings(config, "slave"))
    except PlantError as exc:
        raise ConfigError(source, "slave", config.slave.model, str(exc)) from None
    h = config.scene.period_s / config.simulation.substeps
    omega = slave.wall_omega_rad_per_s()
    if omega * h > ARM_WALL_STEP_LIMIT:
        need = math.ceil(omega * config.scene.period_s / ARM_WALL_STEP_LIMIT)
        raise ConfigError(
            source,
            "slave.wall.stiffness_n_per_m",
            config.slave.wall.stiffness_n_per_m,
            f"too stiff for a MuJoCo step of {h * 1e3:g} ms on this arm: omega * h = {omega * h:.2f} > "
            f"{ARM_WALL_STEP_LIMIT:g}; allowed: simulation.substeps >= {need}, or a softer wall",
        )


def load_scene(
    path: str | Path,
    overrides: Sequence[str] = (),
    seed: int | None = None,
    emulate: bool = False,
    identify: bool = False,
) -> LoadedScene:
    """Read, override and validate a scene file. Raises ConfigError naming file, key, value, allowed.
    `emulate`: a Dynamixel side's port may be missing (`run --emulate` fills it in); `identify`: a
    real side's damping may be missing (`haptic-teleop identify` measures it).

    Errors about a key an override set name the override (`--set KEY=VALUE`, `--seed N`), not the file."""
    p = Path(path)
    source = str(path)
    raw = parse_yaml(read_scene_text(p, source), source)
    if raw is None:
        raise ConfigError(
            source,
            "",
            None,
            "the file is empty; allowed: a mapping of sections (scene, operator, ...), {} for all defaults",
        )
    if not isinstance(raw, dict):
        raise ConfigError(source, "", raw, "allowed: a mapping of sections (scene, operator, master, ...)")
    ovs: list[Override] = []
    for text in overrides:
        parts, value = parse_override(text)
        ovs.append(Override(f"--set {text}", tuple(parts), value))
    if seed is not None:
        ovs.append(Override(f"--seed {seed}", ("scene", "seed"), seed))
    raw = apply_overrides(raw, ovs)
    if "nve" in raw:
        return _load_nve(raw, ovs, p, source)
    try:
        config = build(Scene, raw, "", source)
        _check_models(config, source)
        _check_arm_scene(config, source, emulate, identify)
    except ConfigError as exc:
        raise blame_override(exc, ovs) from None
    config = resolve_scene_traces(config, p.parent, source)
    trace = None
    if config.operator.trace_file:
        tp = Path(config.operator.trace_file)
        if not tp.is_absolute():
            tp = (p.parent / tp).resolve()
        trace = read_operator_trace(tp, source, "operator.trace_file")
        # Absolute, as the network traces: the resolved scene (DIR/scene.yaml) runs from anywhere.
        config = dataclasses.replace(config, operator=dataclasses.replace(config.operator, trace_file=str(tp)))
    return LoadedScene(config=config, source=source, raw=raw, operator_trace=trace)


def _load_nve(raw: dict[str, Any], ovs: list[Override], p: Path, source: str) -> LoadedScene:
    """An NVE scene: its own sections only; trace files resolved from the scene's folder and read once."""
    stray = [k for k in raw if k not in NVE_SECTIONS]
    if stray:
        raise ConfigError(
            source,
            stray[0],
            raw[stray[0]],
            f"an NVE scene (it has an nve section) has no {stray[0]} section; allowed: {', '.join(NVE_SECTIONS)}",
        )
    try:
        config = build(Scene, raw, "", source)
    except ConfigError as exc:
        raise blame_override(exc, ovs) from None
    assert config.nve is not None
    clients = []
    for i, c in enumerate(config.nve.clients):
        where = f"nve.clients[{i}]"
        links = {}
        for name in ("up", "down"):
            d = getattr(c, name)
            try:
                links[name] = dataclasses.replace(d, effects=resolve_trace_paths(d.effects, p.parent))
            except (OSError, ValueError) as exc:
                raise ConfigError(
                    source, f"{where}.{name}.effects", "trace", f"allowed: a readable trace file ({exc})"
                ) from None
        op = c.operator
        if op.trace_file:
            tp = Path(op.trace_file)
            if not tp.is_absolute():
                tp = (p.parent / tp).resolve()
            read_operator_trace(tp, source, f"{where}.operator.trace_file")
            op = dataclasses.replace(op, trace_file=str(tp))
        clients.append(dataclasses.replace(c, operator=op, **links))
    config = dataclasses.replace(config, nve=dataclasses.replace(config.nve, clients=tuple(clients)))
    return LoadedScene(config=config, source=source, raw=raw)


def scenes_dir() -> Path:
    """The bundled scenes' folder, wherever the package is installed (haptic_teleop.resources)."""
    from haptic_teleop.resources import scenes_dir as bundled

    return bundled()


def find_scene(name: str) -> Path:
    """A path, or the name of a bundled scene (`wall_contact` or `wall_contact.yaml`)."""
    p = Path(name)
    if p.is_file():
        return p
    stem = p.name if p.suffix else p.name + ".yaml"
    cand = scenes_dir() / stem
    return cand if cand.exists() else p


def bundled_scenes() -> list[tuple[str, str]]:
    """(name, description) of every bundled scene, by name; `find_scene(name)` finds each."""
    rows = []
    for p in sorted(scenes_dir().glob("*.yaml")):
        try:
            raw = parse_yaml(read_scene_text(p, str(p)), str(p))
            desc = raw.get("scene", {}).get("description", "") if isinstance(raw, dict) else ""
        except ConfigError as exc:
            desc = f"(invalid: {exc})"
        rows.append((p.stem, str(desc)))
    return rows

"""Node parameters declared from the scene schema (haptic_teleop.scene): the one source of names,
types, ranges and help text."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Sequence
from typing import Any, Union, get_args, get_origin

from haptic_teleop.errors import ConfigError

# ---------------------------------------------------------------------------------------------
# Parameters: the scene schema (haptic_teleop.scene) is the one source of names, types, ranges.

LOOP_PRIORITY_PARAM = "loop.realtime_priority"
LOOP_CATCH_UP_PARAM = "loop.max_catch_up_periods"
DEFAULT_REALTIME_PRIORITY = 40
_INT64_MIN = -(2**63)
_INT64_MAX = 2**63 - 1


@dataclasses.dataclass(frozen=True)
class ParamSpec:
    """One scene leaf as a ROS parameter."""

    name: str  # dotted key path, e.g. controllers.master.stiffness_n_per_m
    kind: type  # bool, int, float, str, or tuple (array)
    inner: type | None  # element type of an array
    metadata: typing.Mapping[str, Any]
    default: Any


def _unwrap_optional(tp: Any) -> Any:
    if get_origin(tp) in (Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        return args[0]
    return tp


# An NVE scene's clients are a list of sections (`nve.clients`); as parameters each is a section
# named by the client (`nve.clients.<name>.coupling....`) and this parameter lists the names in
# scene order (the server's client index).
NVE_CLIENT_NAMES_PARAM = "nve.client_names"
_CLIENTS = "clients"


def _section_list(tp: Any) -> Any:
    """The element dataclass of a `tuple[Section, ...]` field (the NVE clients), or None."""
    if get_origin(tp) is tuple:
        inner = get_args(tp)[0]
        if dataclasses.is_dataclass(inner):
            return inner
    return None


def section_type(path: str) -> type:
    """The config dataclass at a dotted path of the scene (`""` is the whole scene); an element of
    a list of sections is named by its `name` (`nve.clients.client1.up`)."""
    from haptic_teleop.scene.schema import Scene

    cls: Any = Scene
    parts = [p for p in path.split(".") if p]
    i = 0
    while i < len(parts):
        part = parts[i]
        hints = typing.get_type_hints(cls)
        if part not in hints:
            raise KeyError(f"{path}: no section {part!r} in {cls.__name__}")
        tp = _unwrap_optional(hints[part])
        element = _section_list(tp)
        if element is not None:
            if i + 1 >= len(parts):
                raise KeyError(f"{path}: {part!r} is a list of sections: name one ({part}.NAME)")
            cls = element
            i += 2
            continue
        cls = tp
        if not dataclasses.is_dataclass(cls):
            raise KeyError(f"{path}: {part!r} is a value, not a section")
        i += 1
    return typing.cast(type, cls)


def scene_section(config: Any, path: str) -> Any:
    """The section object at a dotted path of a validated scene (`section_type`'s paths), or None
    for an optional section the scene leaves out."""
    obj = config
    parts = [p for p in path.split(".") if p]
    i = 0
    while i < len(parts):
        obj = getattr(obj, parts[i])
        if isinstance(obj, tuple) and obj and dataclasses.is_dataclass(obj[0]):
            name = parts[i + 1]
            obj = next((x for x in obj if getattr(x, "name", None) == name), None)
            if obj is None:
                raise KeyError(f"{path}: no element named {name!r}")
            i += 2
            continue
        if obj is None:
            return None
        i += 1
    return obj


def expand_sections(sections: Sequence[str], client_names: Sequence[str]) -> list[str]:
    """`sections` with `nve` (the whole NVE section) spelled out: its own leaves plus one section
    per client (`nve.clients.<name>`)."""
    out: list[str] = []
    for s in sections:
        out.append(s)
        if s in ("", "nve"):
            out += [f"nve.{_CLIENTS}.{n}" for n in client_names]
    return out


def scene_param_specs(path: str) -> list[ParamSpec]:
    """Every leaf below the scene section at `path`, as parameter specs."""
    out: list[ParamSpec] = []

    def walk(cls: Any, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            name = f"{prefix}.{f.name}" if prefix else f.name
            tp = _unwrap_optional(hints[f.name])
            if _section_list(tp) is not None:  # a list of sections: one section per element (expand_sections)
                continue
            if name.count(".") >= 3 and name.split(".")[-3] == _CLIENTS and f.name == "name":
                continue  # an element's name is its key (nve.clients.<name>)
            variants = f.metadata.get("variants")
            if variants is not None:  # a section read by its backend's class: every class's keys, once
                before = len(out)
                for variant in variants():
                    walk(variant, name)
                known: set[str] = set()
                unique = []
                for spec in out[before:]:
                    if spec.name not in known:
                        known.add(spec.name)
                        unique.append(spec)
                out[before:] = unique
                continue
            if dataclasses.is_dataclass(tp):
                walk(tp, name)
                continue
            inner = None
            kind = tp
            if get_origin(tp) is tuple:
                kind, inner = tuple, get_args(tp)[0]
            default = f.default if f.default is not dataclasses.MISSING else None
            out.append(ParamSpec(name, kind, inner, f.metadata, default))

    walk(section_type(path), path)
    return out


def _descriptor(spec: ParamSpec) -> Any:
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    meta = spec.metadata
    lo = meta.get("min", meta.get("gt"))
    hi = meta.get("max", meta.get("lt"))
    parts = [str(meta.get("help", ""))]
    if meta.get("gt") is not None:
        parts.append(f"> {meta['gt']}")
    if meta.get("lt") is not None:
        parts.append(f"< {meta['lt']}")
    d = ParameterDescriptor(description="; ".join(p for p in parts if p))
    if meta.get("choices"):
        d.additional_constraints = "one of: " + ", ".join(map(str, meta["choices"]))
    element = spec.inner if spec.kind is tuple else spec.kind
    if element is float and (lo is not None or hi is not None):
        d.floating_point_range = [
            FloatingPointRange(
                from_value=float(lo) if lo is not None else -math.inf,
                to_value=float(hi) if hi is not None else math.inf,
                step=0.0,
            )
        ]
    elif element is int and spec.kind is int and (lo is not None or hi is not None):
        d.integer_range = [
            IntegerRange(
                from_value=int(lo) if lo is not None else _INT64_MIN,
                to_value=int(hi) if hi is not None else _INT64_MAX,
                step=0,
            )
        ]
    return d


def _param_type(spec: ParamSpec) -> Any:
    from rclpy.parameter import Parameter

    element = spec.inner if spec.kind is tuple else spec.kind
    if spec.kind is tuple:
        return {
            float: Parameter.Type.DOUBLE_ARRAY,
            int: Parameter.Type.INTEGER_ARRAY,
            str: Parameter.Type.STRING_ARRAY,
        }[typing.cast(type, element)]
    return {
        bool: Parameter.Type.BOOL,
        int: Parameter.Type.INTEGER,
        float: Parameter.Type.DOUBLE,
        str: Parameter.Type.STRING,
    }[typing.cast(type, element)]


def declare_scene(node: Any, sections: Sequence[str], extra_names: Sequence[str] = ()) -> Any:
    """Declare every leaf of `sections` (dotted scene paths) as a typed parameter with its range,
    read those that are set, and validate them as a scene.

    Returns the validated `haptic_teleop.scene.schema.Scene` (sections not declared keep their defaults).
    ROS rejects a wrong type or an out-of-range value at declaration; the schema then checks what
    ROS cannot (exclusive bounds, choices, cross-field contradictions). Every error names the
    parameter. Parameters in the file that no section or `extra_names` declares are errors too.
    """
    from haptic_teleop.scene.schema import Scene
    from haptic_teleop.typedconfig import build

    raw: dict[str, Any] = {}
    declared: set[str] = set(extra_names) | {LOOP_PRIORITY_PARAM, LOOP_CATCH_UP_PARAM}
    names: list[str] = []
    if any(s in {"", "nve"} or s.startswith("nve.") for s in sections):
        names = _declare_client_names(node)
        declared.add(NVE_CLIENT_NAMES_PARAM)
        for s in sections:
            parts = s.split(".")
            if len(parts) >= 3 and parts[:2] == ["nve", _CLIENTS] and parts[2] not in names:
                raise ConfigError(
                    f"parameters of node {node.get_name()}",
                    NVE_CLIENT_NAMES_PARAM,
                    names,
                    f"must name client {parts[2]!r} (this node reads {s})",
                )
        sections = expand_sections(sections, names)
    for section in sections:
        for spec in scene_param_specs(section):
            declared.add(spec.name)
            p = node.declare_parameter(spec.name, _param_type(spec), _descriptor(spec))
            if int(p.type_) == 0:  # NOT_SET: not in the parameter file, the schema default applies
                continue
            value = p.value
            if spec.kind is tuple:
                value = list(value)
            cur = raw
            parts = spec.name.split(".")
            for part in parts[:-1]:
                cur = cur.setdefault(part, {})
            cur[parts[-1]] = value
    overrides = getattr(node, "_parameter_overrides", {})  # rclpy keeps the file's values here
    unknown = sorted(
        n for n in overrides if n not in declared and n != "use_sim_time" and not n.startswith("qos_overrides.")
    )
    if unknown:
        raise ConfigError(
            f"parameters of node {node.get_name()}",
            unknown[0],
            overrides[unknown[0]].value,
            "unknown parameter for this node; it reads " + ", ".join(sections),
        )
    if names:
        nve = raw.setdefault("nve", {})
        given = nve.get(_CLIENTS, {})
        nve[_CLIENTS] = [{**given.get(n, {}), "name": n} for n in names]
    return build(Scene, raw, "", f"parameters of node {node.get_name()}")


def _declare_client_names(node: Any) -> list[str]:
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.parameter import Parameter

    d = ParameterDescriptor(description="an NVE scene's clients, in scene order (their sections: nve.clients.<name>)")
    p = node.declare_parameter(NVE_CLIENT_NAMES_PARAM, Parameter.Type.STRING_ARRAY, d)
    return [] if int(p.type_) == 0 else [str(n) for n in p.value]


def declare_value(
    node: Any,
    name: str,
    default: Any,
    description: str,
    lo: float | None = None,
    hi: float | None = None,
    choices: Sequence[str] | None = None,
) -> Any:
    """Declare one node-specific parameter with a descriptor (range or choices) and return its value."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    d = ParameterDescriptor(description=description)
    if isinstance(default, float) and (lo is not None or hi is not None):
        d.floating_point_range = [
            FloatingPointRange(
                from_value=-math.inf if lo is None else float(lo),
                to_value=math.inf if hi is None else float(hi),
                step=0.0,
            )
        ]
    elif isinstance(default, int) and not isinstance(default, bool) and (lo is not None or hi is not None):
        d.integer_range = [
            IntegerRange(
                from_value=_INT64_MIN if lo is None else int(lo), to_value=_INT64_MAX if hi is None else int(hi), step=0
            )
        ]
    if choices:
        d.additional_constraints = "one of: " + ", ".join(choices)
    value = node.declare_parameter(name, default, d).value
    if choices and value not in choices:
        raise ConfigError(f"parameters of node {node.get_name()}", name, value, "allowed: one of " + ", ".join(choices))
    return value

"""Build frozen config dataclasses from plain YAML data, with errors that name the key path.

A config class is a frozen dataclass whose fields carry optional metadata:

    stiffness_n_per_m: float = field(default=1e4, metadata={"min": 0.0, "help": "wall spring"})

Recognised metadata: "min", "max" (inclusive), "gt", "lt" (exclusive), "choices" (sequence),
"help" (one line, shown in errors and docs), and for a section whose class depends on another key
of the same section, "by" (that key's name) with "classes" (a function of that key's value, the
section's data, its key path and the source, returning the config class to build, or raising
ConfigError). Field types may be bool, int, float, str, a nested
config dataclass, `X | None` (absent when the key is missing or null), and `tuple[float, ...]`
/ `tuple[str, ...]`. Cross-field contradictions are raised as ValueError from `__post_init__`;
they are reported with the path of that section.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from collections.abc import Mapping
from typing import Any, TypeVar, Union, get_args, get_origin

from haptic_teleop.errors import ConfigError

T = TypeVar("T")
_NUMBER = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$")


def _type_name(tp: Any) -> str:
    if tp is float:
        return "a number"
    if tp is int:
        return "an integer"
    if tp is bool:
        return "true or false"
    if tp is str:
        return "a string"
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    return str(tp)


def _check_range(value: float, meta: Mapping[str, Any], where: str, source: str) -> None:
    lo, hi = meta.get("min"), meta.get("max")
    gt, lt = meta.get("gt"), meta.get("lt")
    parts = []
    if lo is not None:
        parts.append(f">= {lo}")
    if gt is not None:
        parts.append(f"> {gt}")
    if hi is not None:
        parts.append(f"<= {hi}")
    if lt is not None:
        parts.append(f"< {lt}")
    ok = (
        (lo is None or value >= lo)
        and (gt is None or value > gt)
        and (hi is None or value <= hi)
        and (lt is None or value < lt)
    )
    if not ok:
        raise ConfigError(source, where, value, "allowed: a value " + " and ".join(parts) + _help(meta))


def _help(meta: Mapping[str, Any]) -> str:
    h = meta.get("help")
    return f" ({h})" if h else ""


def convert(tp: Any, value: Any, where: str, source: str, meta: Mapping[str, Any] | None = None) -> Any:
    """Convert one YAML value to `tp`, or raise ConfigError naming `where`."""
    meta = meta or {}
    origin = get_origin(tp)
    if origin in (Union, types.UnionType):
        args = [a for a in get_args(tp) if a is not type(None)]
        if value is None:
            return None
        return convert(args[0], value, where, source, meta)
    if origin is tuple:
        inner = get_args(tp)[0]
        if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)):
            raise ConfigError(source, where, value, f"allowed: a list of {_type_name(inner)}s{_help(meta)}")
        items = tuple(convert(inner, v, f"{where}[{i}]", source) for i, v in enumerate(value))
        if inner in (int, float):
            for i, v in enumerate(items):
                _check_range(v, meta, f"{where}[{i}]", source)
        return items
    if dataclasses.is_dataclass(tp):
        return build(typing.cast(type, tp), value, where, source)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(source, where, value, f"allowed: true or false{_help(meta)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(source, where, value, f"allowed: an integer{_help(meta)}")
        _check_range(value, meta, where, source)
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            raise ConfigError(source, where, value, f"allowed: one of {', '.join(map(str, choices))}")
        return value
    if tp is float:
        if isinstance(value, str) and _NUMBER.match(value.strip()):
            value = float(value)  # YAML 1.1 reads 1e5 (no dot) as a string; users mean the number
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(source, where, value, f"allowed: a number{_help(meta)}")
        try:
            value = float(value)
        except OverflowError:
            value = math.inf  # an integer beyond any float
        if not math.isfinite(value):
            raise ConfigError(source, where, value, f"allowed: a finite number{_help(meta)}")
        _check_range(value, meta, where, source)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(source, where, value, f"allowed: a string{_help(meta)}")
        choices = meta.get("choices")
        if choices is not None and value not in choices:
            raise ConfigError(source, where, value, f"allowed: one of {', '.join(map(str, choices))}")
        return value
    raise TypeError(f"unsupported config field type {tp!r} at {where}")


def _default_section(f: dataclasses.Field[Any]) -> dict[str, Any] | None:
    """The default of a section-valued field as a plain mapping, or None."""
    if f.default_factory is not dataclasses.MISSING:
        obj = f.default_factory()
    elif f.default is not dataclasses.MISSING:
        obj = f.default
    else:
        return None
    return dataclasses.asdict(obj) if dataclasses.is_dataclass(obj) and not isinstance(obj, type) else None


def _merged(base: Mapping[str, Any], given: Mapping[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in given.items():
        out[k] = _merged(out[k], v) if isinstance(v, Mapping) and isinstance(out.get(k), Mapping) else v
    return out


def build(cls: type[T], data: Any, where: str = "", source: str = "<config>") -> T:
    """Build config dataclass `cls` from a mapping; unknown keys, bad types and ranges are errors."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(source, where, data, "allowed: a mapping of keys to values")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}  # type: ignore[arg-type]
    unknown = [k for k in data if k not in fields]
    if unknown:
        key = unknown[0]
        path = f"{where}.{key}" if where else str(key)
        raise ConfigError(source, path, data[key], f"unknown key; allowed keys here: {', '.join(sorted(fields))}")
    kwargs: dict[str, Any] = {}
    for name, f in fields.items():
        path = f"{where}.{name}" if where else name
        if name in data:
            value = data[name]
            base = _default_section(f)
            if base is not None and isinstance(value, Mapping):
                # A section given in part keeps its field's own defaults for the rest (the slave
                # controller's default differs from ControllerConfig's: E0 0.5 J, limit 40 N).
                value = _merged(base, value)
            chooser = f.metadata.get("classes")
            if chooser is not None and value is not None:  # the class depends on a sibling key
                by = f.metadata["by"]
                key = kwargs[by] if by in kwargs else fields[by].default
                kwargs[name] = build(chooser(key, value, path, source), value, path, source)
            else:
                kwargs[name] = convert(hints[name], value, path, source, f.metadata)
        elif f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            if dataclasses.is_dataclass(hints[name]):
                kwargs[name] = build(hints[name], {}, path, source)
            else:
                raise ConfigError(source, path, None, f"required key is missing{_help(f.metadata)}")
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise ConfigError(source, where, {k: data[k] for k in data}, f"contradiction: {exc}") from None
    except ArithmeticError as exc:  # values each in range whose combination overflows a check
        raise ConfigError(source, where, {k: data[k] for k in data}, f"values out of range together ({exc})") from None


def describe(cls: type, prefix: str = "") -> list[tuple[str, str, str]]:
    """(key path, default, help) for every leaf of a config class: used to generate docs."""
    rows: list[tuple[str, str, str]] = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        path = f"{prefix}.{f.name}" if prefix else f.name
        tp = hints[f.name]
        inner = [a for a in get_args(tp) if a is not type(None)] if get_origin(tp) in (Union, types.UnionType) else [tp]
        variants = f.metadata.get("variants")
        if variants is not None:  # a section whose class depends on a sibling key: every class's keys
            known: set[str] = set()
            for variant in variants():
                for row in describe(variant, path):
                    if row[0] not in known:
                        known.add(row[0])
                        rows.append(row)
        elif inner and dataclasses.is_dataclass(inner[0]):
            rows.extend(describe(typing.cast(type, inner[0]), path))
        else:
            default = f.default if f.default is not dataclasses.MISSING else ""
            rows.append((path, repr(default), f.metadata.get("help", "")))
    return rows

"""`--set a.b.c=value` overrides of a scene's keys, and whose error a bad key is (the file's or the flag's)."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import yaml

from haptic_teleop.errors import ConfigError
from haptic_teleop.scene.yaml_text import DuplicateKeyError, SceneLoader


@dataclass(frozen=True)
class Override:
    """One `--set KEY.PATH=VALUE` (or `--seed N`): where it came from, the key path and the value."""

    label: str
    parts: tuple[str, ...]
    value: Any

    @property
    def path(self) -> str:
        return ".".join(self.parts)


def parse_override(text: str) -> tuple[list[str], Any]:
    """`a.b.c=value` -> (["a","b","c"], value parsed as YAML)."""
    label = f"--set {text}"
    if "=" not in text:
        raise ConfigError(label, "", text, "allowed: KEY.PATH=VALUE, e.g. slave.wall.stiffness_n_per_m=1e5")
    key, _, value = text.partition("=")
    parts = [p.strip() for p in key.strip().split(".")]
    if not key.strip() or any(not p for p in parts):
        raise ConfigError(label, key, text, "allowed: a dotted key path like network.forward.effects.delay.delay_s")
    try:
        parsed = yaml.load(value, Loader=SceneLoader) if value.strip() else None
    except DuplicateKeyError as exc:
        raise ConfigError(label, key, value, f"{exc.problem}; allowed: each key once") from None
    except (yaml.YAMLError, RecursionError):
        parsed = value  # not YAML: the text itself (a string value)
    return parts, parsed


def apply_overrides(raw: dict[str, Any], overrides: Sequence[str | Override]) -> dict[str, Any]:
    data = copy.deepcopy(raw)
    for ov in overrides:
        if isinstance(ov, str):
            parts, value = parse_override(ov)
            ov = Override(f"--set {ov}", tuple(parts), value)  # noqa: PLW2901
        node: Any = data
        for i, p in enumerate(ov.parts[:-1]):
            if isinstance(node, list):  # a list of sections (an NVE scene's clients): by index
                node = node[_index(node, p, ov, i)]
                continue
            nxt = node.get(p)
            if nxt is None:
                nxt = node[p] = {}
            if not isinstance(nxt, (dict, list)) or (
                isinstance(nxt, list) and not all(isinstance(e, dict) for e in nxt)
            ):
                where = ".".join(ov.parts[: i + 1])
                raise ConfigError(ov.label, where, nxt, f"is a value, not a section; cannot set {ov.path}")
            node = nxt
        if isinstance(node, list):
            node[_index(node, ov.parts[-1], ov, len(ov.parts) - 1)] = ov.value
        else:
            node[ov.parts[-1]] = ov.value
    return data


def _index(items: list[Any], part: str, ov: Override, i: int) -> int:
    """`part` as an index of the list of sections at ov.parts[:i] (`nve.clients.0.name=a`)."""
    if not part.isdigit() or int(part) >= len(items):
        where = ".".join(ov.parts[:i])
        raise ConfigError(
            ov.label, where, part, f"is a list of {len(items)} section(s); allowed: an index 0..{len(items) - 1}"
        )
    return int(part)


def blame_override(exc: ConfigError, overrides: Sequence[Override]) -> ConfigError:
    """An error about a key an override set is the override's, not the scene file's."""
    key = exc.key_path
    for ov in reversed(overrides):
        if key == ov.path or key.startswith((ov.path + ".", ov.path + "[")):
            return ConfigError(ov.label, key, exc.value, exc.allowed)
    for ov in reversed(overrides):
        if ov.path.startswith(key + ".") or not key:
            if not exc.allowed.startswith("contradiction"):  # e.g. an unknown section the override named
                return ConfigError(ov.label, key, exc.value, exc.allowed)
            # a contradiction in a section an override changed: the file and the override together
            return ConfigError(f"{exc.source} with {ov.label}", key, exc.value, exc.allowed)
    return exc

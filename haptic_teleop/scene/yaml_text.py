"""Scene YAML text: the safe loader that refuses a key given twice, and reading a scene file with
errors that name the file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from haptic_teleop.errors import ConfigError


class SceneLoader(yaml.SafeLoader):
    """YAML's safe loader, except that a key given twice in one mapping is an error (naming both lines)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        self.flatten_mapping(node)
        seen: dict[Any, int] = {}
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                first = seen.get(key)
            except TypeError:
                continue  # unhashable: the base class says so
            line = key_node.start_mark.line + 1
            if first is not None:
                raise DuplicateKeyError(key, first, line, key_node.start_mark)
            seen[key] = line
        return super().construct_mapping(node, deep=deep)


class DuplicateKeyError(yaml.constructor.ConstructorError):
    def __init__(self, key: Any, first_line: int, line: int, mark: yaml.Mark) -> None:
        super().__init__(None, None, f"key {key!r} given twice (lines {first_line} and {line})", mark)
        self.key = key


def parse_yaml(text: str, source: str) -> Any:
    """One YAML document with SceneLoader; a YAML error becomes a ConfigError naming the line."""
    try:
        return yaml.load(text, Loader=SceneLoader)  # SceneLoader is a SafeLoader
    except DuplicateKeyError as exc:
        where = f"line {exc.problem_mark.line + 1}" if exc.problem_mark is not None else ""
        raise ConfigError(source, where, exc.key, f"{exc.problem}; allowed: each key once") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise ConfigError(source, where, "", f"not valid YAML ({problem})") from None
    except RecursionError:
        raise ConfigError(source, "", "", "not valid YAML (nested too deeply)") from None


def read_scene_text(p: Path, source: str) -> str:
    """The text of a scene file, or a ConfigError: not a file, unreadable, not UTF-8, empty."""
    if p.is_dir():
        raise ConfigError(source, "", source, "is a directory; allowed: the path of a scene YAML file")
    if not p.is_file():
        raise ConfigError(source, "", source, "allowed: the path of an existing scene YAML file")
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise ConfigError(
            source, "", source, f"cannot be read ({exc.strerror}); allowed: a readable scene YAML file"
        ) from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise ConfigError(
            source,
            f"line {line}",
            data[exc.start : exc.start + 1],
            "not UTF-8 text; allowed: a scene YAML file in UTF-8",
        ) from None

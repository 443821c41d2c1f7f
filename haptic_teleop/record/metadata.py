"""metadata.yaml emitter."""

from __future__ import annotations

import re
from functools import lru_cache
from typing import Any

# --------------------------------------------------------------------------------------------
# Block-style YAML for plain data, as ruamel's YAML(typ="safe") with default_flow_style=False
# writes it (the way rosbags writes metadata): keys sorted, two-space indentation, sequences at
# their key's indentation, a scalar that would end past column 80 moved to a line of its own
# (after a space). Only words ruamel writes unquoted, integers, booleans, None, "" and empty
# containers are written; for anything else `yaml_block` returns None and the caller uses
# ruamel. A test compares it with ruamel on generated data.

_YAML_WIDTH = 80
_YAML_PLAIN = re.compile(r"[A-Za-z_/][A-Za-z0-9_./-]*\Z")
# Words a YAML reader could take for something other than a string (ruamel would quote them).
_YAML_WORDS = frozenset({"y", "yes", "n", "no", "on", "off", "true", "false", "null", "inf", "nan"})


class _NotPlain(Exception):
    """Data outside what `yaml_block` writes."""


def _yaml_scalar(value: Any) -> tuple[str, bool]:
    """(text, whether it is a plain scalar, which ruamel may move to the next line)."""
    if value is None:
        return "null", True
    if value is True or value is False:
        return ("true" if value else "false"), True
    if type(value) is int:
        return str(value), True
    if type(value) is str:
        if not value:
            return "''", False
        if _yaml_word(value, True):
            return value, True
    if type(value) is dict and not value:
        return "{}", False
    if type(value) is list and not value:
        return "[]", False
    raise _NotPlain


@lru_cache(maxsize=1024)
def _yaml_word(text: str, value: bool) -> bool:
    """Whether `text` is written unquoted as a key (value=False: only plain-looking words) or a value."""
    if _YAML_PLAIN.match(text) and text.lower() not in _YAML_WORDS:
        return True
    return value and text.isascii() and text.isprintable() and " " not in text and _ruamel_writes_plain(text)


@lru_cache(maxsize=256)
def _ruamel_writes_plain(word: str) -> bool:
    """Whether ruamel writes `word` (no spaces) unquoted, as it decides it: a one-key dump, once per word.

    For words that could read as something else (a number, a date, a boolean) or start with an
    indicator character; the bag's own strings (topics, types, hashes, "bag.mcap") never get here."""
    from io import StringIO

    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump({"k": word}, out)
    return out.getvalue() in (f"k: {word}\n", f"k: \n  {word}\n")


def _yaml_mapping(m: dict[Any, Any], indent: int, out: list[str], seen: set[int], inline: bool = False) -> None:
    """Keys at `indent`; with `inline`, the first key continues a "- " already written."""
    keys = list(m)
    for k in keys:
        if type(k) is not str or not _yaml_word(k, False):
            raise _NotPlain
    for i, key in enumerate(sorted(keys)):
        lead = "" if inline and i == 0 else " " * indent
        value = m[key]
        if type(value) in (dict, list) and value:
            if id(value) in seen:  # ruamel writes a shared object once, with an anchor
                raise _NotPlain
            seen.add(id(value))
            out.append(f"{lead}{key}:\n")
            if type(value) is dict:
                _yaml_mapping(value, indent + 2, out, seen)
            else:
                _yaml_sequence(value, indent, out, seen)
            continue
        text, plain = _yaml_scalar(value)
        if type(value) in (dict, list):
            if id(value) in seen:
                raise _NotPlain
            seen.add(id(value))
        column = indent + len(key) + 2
        if column + len(text) <= _YAML_WIDTH:
            out.append(f"{lead}{key}: {text}\n")
        elif plain:
            out.append(f"{lead}{key}: \n{' ' * (indent + 2)}{text}\n")
        else:
            raise _NotPlain


def _yaml_sequence(seq: list[Any], indent: int, out: list[str], seen: set[int]) -> None:
    for item in seq:
        if type(item) in (dict, list):
            if id(item) in seen:
                raise _NotPlain
            seen.add(id(item))
        if type(item) is dict and item:
            out.append(" " * indent + "- ")
            _yaml_mapping(item, indent + 2, out, seen, inline=True)
            continue
        if type(item) is list and item:
            raise _NotPlain
        text, _ = _yaml_scalar(item)
        if indent + 2 + len(text) > _YAML_WIDTH:
            raise _NotPlain
        out.append(f"{' ' * indent}- {text}\n")


def yaml_block(data: dict[str, Any]) -> str | None:
    """`data` as ruamel's safe block-style dump writes it, or None if it is outside the plain subset."""
    if type(data) is not dict or not data:
        return None
    out: list[str] = []
    try:
        _yaml_mapping(data, 0, out, {id(data)})
    except _NotPlain:
        return None
    return "".join(out)

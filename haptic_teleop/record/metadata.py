"""metadata.yaml: the rosbag2 bag information (storage version 9) and its emitter.

The file holds what rosbag2 writes for an MCAP bag: storage id, files, duration, start, message
counts, per topic its type, serialization format, offered QoS profiles (storage version 9: a list of
profiles with names, e.g. `reliability: best_effort`) and type hash. MCAP chunk compression is
inside the storage file (compression_format and compression_mode stay empty, as rosbag2 leaves
them with a storage preset).
"""

from __future__ import annotations

import copy
import re
from functools import lru_cache
from pathlib import Path
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


# -- offered QoS profiles (rosbag2 storage version 9)
_INFINITE = {"sec": 9223372036, "nsec": 854775807}  # RMW_DURATION_INFINITE, as rosbag2 writes it
_QOS_VALUES = {
    "history": ("keep_last", "keep_all", "system_default", "unknown"),
    "reliability": ("reliable", "best_effort", "system_default", "best_available", "unknown"),
    "durability": ("volatile", "transient_local", "system_default", "best_available", "unknown"),
    "liveliness": ("automatic", "manual_by_topic", "system_default", "best_available", "unknown"),
}
_QOS_DURATIONS = ("deadline", "lifespan", "liveliness_lease_duration")


def qos_profile(**fields: Any) -> dict[str, Any]:
    """One offered QoS profile as rosbag2 v9 writes it; unnamed fields take ROS 2's defaults."""
    out: dict[str, Any] = {
        "history": "keep_last",
        "depth": 10,
        "reliability": "reliable",
        "durability": "volatile",
        "deadline": dict(_INFINITE),
        "lifespan": dict(_INFINITE),
        "liveliness": "automatic",
        "liveliness_lease_duration": dict(_INFINITE),
        "avoid_ros_namespace_conventions": False,
    }
    for key, value in fields.items():
        if key not in out:
            raise ValueError(f"QoS field {key!r} is not one of {', '.join(out)}")
        if key in _QOS_VALUES and value not in _QOS_VALUES[key]:
            raise ValueError(f"QoS {key} {value!r} is not one of {', '.join(_QOS_VALUES[key])}")
        if key in _QOS_DURATIONS:
            if not (isinstance(value, dict) and set(value) == {"sec", "nsec"}):
                raise ValueError(f"QoS {key} must be a mapping with sec and nsec")
            out[key] = {"sec": int(value["sec"]), "nsec": int(value["nsec"])}
            continue
        if key == "depth" and (type(value) is not int or value < 0):
            raise ValueError(f"QoS depth must be an integer >= 0; got {value!r}")
        out[key] = value
    return out


STREAM_QOS = [qos_profile(reliability="best_effort", depth=1)]  # the 1 kHz streams
LATCHED_QOS = [qos_profile(durability="transient_local", depth=1)]  # scene and run facts
BATCH_QOS = [qos_profile(depth=10)]  # packet record batches: reliable, volatile
# topic -> offered profiles; "*" for every topic not named.
DEFAULT_QOS: dict[str, list[dict[str, Any]]] = {
    "*": STREAM_QOS,
    "/haptic_teleop/scene": LATCHED_QOS,
    "/haptic_teleop/run_info": LATCHED_QOS,
    "/forward/packets": BATCH_QOS,
    "/backward/packets": BATCH_QOS,
}


def qos_yaml(profiles: list[dict[str, Any]]) -> str:
    """Profiles as the YAML text of MCAP channel metadata `offered_qos_profiles` ("" for none)."""
    if not profiles:
        return ""
    text = yaml_block({"q": profiles})
    if text is None:
        return _ruamel_dump(profiles).strip()
    return text.split("\n", 1)[1].strip()


def bag_info(
    file_name: str, topics: list[tuple[str, str, list[dict[str, Any]], str, int]], start_ns: int, end_ns: int
) -> dict[str, Any]:
    """rosbag2_bagfile_information of a one-file MCAP bag: topics are (name, type, qos, hash, count)."""
    count = sum(t[4] for t in topics)
    start = start_ns if count else 0
    duration = max(0, end_ns - start_ns) if count else 0
    return {
        "version": 9,
        "storage_identifier": "mcap",
        "relative_file_paths": [file_name],
        "duration": {"nanoseconds": duration},
        "starting_time": {"nanoseconds_since_epoch": start},
        "message_count": count,
        "topics_with_message_count": [
            {
                "topic_metadata": {
                    "name": name,
                    "type": msgtype,
                    "serialization_format": "cdr",
                    "offered_qos_profiles": copy.deepcopy(qos),  # each its own (no YAML anchors)
                    "type_description_hash": digest,
                },
                "message_count": n,
            }
            for name, msgtype, qos, digest, n in topics
        ],
        "compression_format": "",
        "compression_mode": "",
        "files": [
            {
                "path": file_name,
                "starting_time": {"nanoseconds_since_epoch": start},
                "duration": {"nanoseconds": duration},
                "message_count": count,
            }
        ],
        "custom_data": None,
        "ros_distro": "",
    }


def _ruamel_dump(data: Any) -> str:
    from io import StringIO

    from ruamel.yaml import YAML

    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    out = StringIO()
    yaml.dump(data, out)
    return out.getvalue()


def metadata_text(info: dict[str, Any]) -> tuple[str, str]:
    """(the information alone, as the MCAP metadata record holds it; the whole metadata.yaml)."""
    inner = yaml_block(info) or _ruamel_dump(info)
    whole = yaml_block({"rosbag2_bagfile_information": info}) or _ruamel_dump({"rosbag2_bagfile_information": info})
    return inner, whole


def write_metadata(bag_dir: Path, whole: str) -> None:
    """metadata.yaml, written whole or not at all (a temporary file renamed into place): a process
    killed at any moment leaves the old state or the whole file. Not fsynced, as the MCAP file is
    not: both survive the end of any process in the page cache, and an fsync cost about 1 ms of
    every run's close (docs/recording_costs.md)."""
    path = Path(bag_dir) / "metadata.yaml"
    tmp = path.with_suffix(".yaml.tmp")
    with open(tmp, "w", encoding="utf8") as f:
        f.write(whole)
    tmp.replace(path)


def _ruamel_load(text: str) -> Any:
    """YAML text (channel metadata) as data; None when empty or unreadable."""
    if not text.strip():
        return None
    from ruamel.yaml import YAML
    from ruamel.yaml.error import YAMLError

    try:
        return YAML(typ="safe").load(text)
    except YAMLError:
        return None

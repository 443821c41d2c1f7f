"""BagReader."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.layouts import (
    JOINT_STATE,
    MULTIARRAY,
    PACKET_FIELDS,
    STRING,
    WRENCH,
    TopicSpec,
    topic_specs,
    typestore,
)


@dataclass
class TopicData:
    """One topic read back: log times (ns), header stamps (ns, or None) and values (N, k)."""

    log_ns: np.ndarray
    stamp_ns: np.ndarray | None
    values: np.ndarray
    fields: tuple[str, ...]

    def field(self, name: str) -> np.ndarray:
        return self.values[:, self.fields.index(name)]


def _deserialize_values(spec: TopicSpec, msg: Any) -> list[float]:
    if spec.layout.msgtype == JOINT_STATE:
        return [float(getattr(msg, f)[0]) for f in spec.fields]
    if spec.layout.msgtype == WRENCH:
        return [float(msg.wrench.force.x)]
    return [float(v) for v in msg.data[: len(spec.fields)]]


def _stamp_of(msg: Any) -> int | None:
    h = getattr(msg, "header", None)
    return None if h is None else int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


class BagReader:
    """Read what analysis needs from a bag written by `write_run` or by the live recorder."""

    def __init__(self, path: str | Path) -> None:
        from rosbags.rosbag2 import Reader

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (give the rosbag2 directory that holds metadata.yaml)")
        if self.path.is_file() and self.path.name == "metadata.yaml":
            self.path = self.path.parent
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types; all mean unreadable
            raise BagError(f"{self.path}: not a readable rosbag2 directory ({exc})") from None
        self.topics = {c.topic: c for c in self._reader.connections}

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _raw(self, topic: str) -> Iterable[tuple[int, bytes]]:
        if topic not in self.topics:
            raise BagError(f"{self.path}: topic {topic} is missing (topics here: {', '.join(sorted(self.topics))})")
        conns = [c for c in self._reader.connections if c.topic == topic]
        for _, t, raw in self._reader.messages(connections=conns):
            yield t, bytes(raw)

    def has(self, topic: str) -> bool:
        return topic in self.topics

    def string(self, topic: str) -> str:
        ts = typestore()
        for _, raw in self._raw(topic):
            return str(ts.deserialize_cdr(raw, STRING).data)
        raise BagError(f"{self.path}: topic {topic} has no messages")

    def read(self, topic: str) -> TopicData:
        """Decode one fixed-layout topic (bulk where the layout matches, else message by message)."""
        spec = topic_specs().get(topic)
        if spec is None:
            raise BagError(f"{topic} is not a fixed-layout topic of haptic_teleop")
        items = list(self._raw(topic))
        log = np.array([t for t, _ in items], dtype=np.int64)
        if not items:
            return TopicData(log, np.zeros(0, dtype=np.int64), np.zeros((0, len(spec.fields))), spec.fields)
        ts = typestore()
        size = spec.layout.size
        first = ts.deserialize_cdr(items[0][1], spec.layout.msgtype)
        if all(len(r) == size for _, r in items):
            rows = np.frombuffer(b"".join(r for _, r in items), dtype=np.uint8).reshape(len(items), size)
            vals, stamps = spec.layout.decode(rows[:1])
            if vals[0].tolist() == _deserialize_values(spec, first) and (
                stamps is None or int(stamps[0]) == _stamp_of(first)
            ):
                vals, stamps = spec.layout.decode(rows)
                return TopicData(log, stamps, vals, spec.fields)
        values = np.empty((len(items), len(spec.fields)))
        stamps_l = np.empty(len(items), dtype=np.int64)
        for i, (_, raw) in enumerate(items):
            msg = ts.deserialize_cdr(raw, spec.layout.msgtype)
            values[i] = _deserialize_values(spec, msg)
            s = _stamp_of(msg)
            stamps_l[i] = -1 if s is None else s
        return TopicData(log, stamps_l if spec.layout.msgtype != MULTIARRAY else None, values, spec.fields)

    def packets(self, topic: str) -> np.ndarray:
        """All packet rows of /forward/packets or /backward/packets, sorted by seq: (N, 6) per PACKET_FIELDS."""
        ts = typestore()
        chunks = []
        for _, raw in self._raw(topic):
            msg = ts.deserialize_cdr(raw, MULTIARRAY)
            chunks.append(np.asarray(msg.data, dtype=np.float64).reshape(-1, len(PACKET_FIELDS)))
        if not chunks:
            return np.zeros((0, len(PACKET_FIELDS)))
        rows = np.concatenate(chunks)
        # Batches are written as the records come (any order of seq across batches): by seq, stable.
        return rows[np.argsort(rows[:, 0], kind="stable")]

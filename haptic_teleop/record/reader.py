"""BagReader."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.errors import BagError
from haptic_teleop.record.columns import (
    JOINT_STATE,
    MULTIARRAY,
    ONE_DOF,
    POSE,
    SchemaError,
    TickSchema,
    measured_topic,
)
from haptic_teleop.record.layouts import (
    PACKET_FIELDS,
    STRING,
    FixedLayout,
    TopicSpec,
    nve_topic_specs,
    topic_specs,
    typestore,
)
from haptic_teleop.record.nve_columns import TWIST, NveSchema, nve_schema_from_topics


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
    """The values of one message, by the spec's value names (`position`, `position[joint]`,
    `force_x`, `position_z`, `linear_y`, or Float64MultiArray data in order)."""
    msgtype = spec.layout.msgtype
    if msgtype == MULTIARRAY:
        return [float(v) for v in msg.data[: len(spec.fields)]]
    out = []
    if msgtype == JOINT_STATE:
        names = list(msg.name)
        for f in spec.fields:
            field, _, joint = f.partition("[")
            i = names.index(joint[:-1]) if joint else 0
            out.append(float(getattr(msg, field)[i]))
        return out
    for f in spec.fields:
        field, _, axis = f.rpartition("_")
        if msgtype == POSE:
            vec = msg.pose.position
        else:
            vec = getattr(msg.twist if msgtype == TWIST else msg.wrench, field)
        out.append(float(getattr(vec, axis)))
    return out


def _joined(parts: list[TopicData]) -> TopicData:
    """Blocks of one topic (or of rows) as one."""
    stamps = (
        None if parts[0].stamp_ns is None else np.concatenate([p.stamp_ns for p in parts if p.stamp_ns is not None])
    )
    return TopicData(
        np.concatenate([p.log_ns for p in parts]), stamps, np.concatenate([p.values for p in parts]), parts[0].fields
    )


def _stamp_of(msg: Any) -> int | None:
    h = getattr(msg, "header", None)
    return None if h is None else int(h.stamp.sec) * 1_000_000_000 + int(h.stamp.nanosec)


def recover_hint(bag: Path) -> str:
    return f": `haptic-teleop bag recover {bag}` rebuilds it from its complete chunks"


def _describe_damage(bag: Path, mcap: Path, what: str) -> BagError:
    """One line: what is wrong with the bag and what `bag recover` would keep."""
    from haptic_teleop.record.mcapread import scan

    try:
        s = scan(mcap)
    except BagError as exc:
        return exc
    except OSError as exc:
        return BagError(f"{mcap}: cannot read ({exc.strerror or exc})")
    return BagError(
        f"{what}: `haptic-teleop bag recover {bag}` rebuilds it from its {len(s.chunks)} complete chunks, "
        f"{s.seconds:.3f} s of messages"
    )


def _safe_yaml(text: str) -> Any:
    """YAML `text` with PyYAML's safe loader, libyaml's C one where PyYAML has it (a tenth of
    ruamel's pure-Python time on a bag's metadata.yaml: 0.28 s per bag opened before)."""
    import yaml

    return yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))


def _load_metadata(bag: Path) -> dict[str, Any]:
    from yaml import YAMLError

    meta = bag / "metadata.yaml"
    try:
        text = meta.read_text(encoding="utf8")
        data = _safe_yaml(text)
        info = data["rosbag2_bagfile_information"]
        files = [str(f) for f in info["relative_file_paths"]]
        storage = str(info["storage_identifier"])
    except OSError as exc:
        raise BagError(f"{meta}: cannot read ({exc.strerror or exc})") from None
    except (YAMLError, UnicodeDecodeError, TypeError, KeyError) as exc:
        what = f"no {exc} key" if isinstance(exc, KeyError) else type(exc).__name__
        raise BagError(f"{bag}: not a readable rosbag2 directory (metadata.yaml: {what})") from None
    if not isinstance(info, dict):
        raise BagError(f"{bag}: not a readable rosbag2 directory (metadata.yaml holds no bag information)")
    return {"files": files, "storage": storage, "info": info}


class BagReader:
    """Read what analysis needs from a bag written by the recorder or by other tools.

    MCAP bags are read by this package's validating reader (summary CRC on open, each chunk's CRC
    as it is read); other storage (sqlite3) through rosbags. `path` is the rosbag2 directory, its
    metadata.yaml, or an .mcap file."""

    def __init__(self, path: str | Path) -> None:
        from haptic_teleop.record.mcapread import McapFile

        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"{self.path}: no such bag (give the rosbag2 directory that holds metadata.yaml)")
        if self.path.is_file() and self.path.name == "metadata.yaml":
            self.path = self.path.parent
        self._files: list[McapFile] = []
        self._rosbags: Any = None
        if self.path.is_file():
            mcaps = [self.path]
        else:
            if not (self.path / "metadata.yaml").exists():
                found = sorted(self.path.glob("*.mcap"))
                if not found:
                    raise BagError(f"{self.path}: not a rosbag2 directory (no metadata.yaml and no .mcap file)")
                raise _describe_damage(
                    self.path,
                    found[0],
                    f"{self.path}/ has no metadata.yaml (the run was killed before the bag was closed?)",
                )
            meta = _load_metadata(self.path)
            if meta["storage"] != "mcap":
                self._open_rosbags()
                return
            mcaps = [self.path / f for f in meta["files"]]
        for m in mcaps:
            if not m.is_file():
                self.close()
                raise BagError(f"{self.path}: the bag's file {m.name} is missing")
            try:
                self._files.append(McapFile(m, recover_hint(self.path)))
            except BagError as exc:
                self.close()
                if "truncated" in str(exc):
                    raise _describe_damage(self.path, m, str(exc).split(": `haptic-teleop")[0]) from None
                raise
        self.topics: dict[str, str] = {}
        for f in self._files:
            for c in f.channels.values():
                s = f.schemas.get(c.schema_id)
                self.topics[c.topic] = s.name if s is not None else ""

    def _open_rosbags(self) -> None:
        from rosbags.rosbag2 import Reader

        try:
            self._rosbags = Reader(self.path)
            self._rosbags.open()
        except Exception as exc:  # noqa: BLE001 - rosbags raises several types; all mean unreadable
            raise BagError(f"{self.path}: not a readable rosbag2 directory ({exc})") from None
        self.topics = {c.topic: c.msgtype for c in self._rosbags.connections}

    def close(self) -> None:
        for f in self._files:
            f.close()
        if self._rosbags is not None:
            self._rosbags.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _messages(self, topic: str) -> tuple[np.ndarray, list[bytes] | np.ndarray]:
        """Log times and payloads of one topic, in log time order (rows when all have one size)."""
        if topic not in self.topics:
            raise BagError(f"{self.path}: topic {topic} is missing (topics here: {', '.join(sorted(self.topics))})")
        if self._rosbags is not None:
            conns = [c for c in self._rosbags.connections if c.topic == topic]
            items = [(t, bytes(raw)) for _, t, raw in self._rosbags.messages(connections=conns)]
            return np.array([t for t, _ in items], dtype=np.int64), [r for _, r in items]
        logs, parts = [], []
        for f in self._files:
            cids = [c.id for c in f.channels.values() if c.topic == topic]
            log, payloads = f.topic_messages(cids)
            logs.append(log)
            parts.append(payloads)
        if len(parts) == 1:
            return logs[0], parts[0]
        flat = [bytes(p) for ps in parts for p in ps]
        return np.concatenate(logs), flat

    def _message_blocks(self, topic: str) -> Iterator[tuple[np.ndarray, list[bytes] | np.ndarray]]:
        """`_messages` chunk by chunk (each in log time order): memory of one chunk, not of the
        topic. Bags without a chunk index (or not MCAP) come as one block."""
        from haptic_teleop.record.mcapread import fixed_rows, messages_in

        if topic not in self.topics or self._rosbags is not None or any(f.loose for f in self._files):
            yield self._messages(topic)
            return
        for k, f in enumerate(self._files):
            cids = [c.id for c in f.channels.values() if c.topic == topic]
            for i, c in enumerate(f.chunks):
                if not any(cid in c.index_offsets for cid in cids):
                    continue
                raw = self._chunk(k, i)
                for cid in cids:
                    t, o = f.message_offsets(i, cid)
                    if not t.size:
                        continue
                    rows = fixed_rows(raw, o)
                    order = np.argsort(t, kind="stable")
                    if rows is not None:
                        yield t[order], rows[order]
                    else:
                        payloads = [p for _, _, p in messages_in(raw, o)]
                        yield t[order], [payloads[k] for k in order.tolist()]

    def _chunk(self, k: int, i: int) -> bytes:
        """Chunk i of file k, from a cache of the last four: topics read side by side (in step,
        block by block) decompress each chunk once."""
        cache: dict[tuple[int, int], bytes] = self.__dict__.setdefault("_chunk_cache", {})
        raw = cache.pop((k, i), None)
        if raw is None:
            raw = self._files[k].chunk(i)
            while len(cache) >= 4:
                cache.pop(next(iter(cache)))
        cache[(k, i)] = raw
        return raw

    def log_blocks(self, topic: str) -> Iterator[np.ndarray]:
        """The log times (ns) of `topic` chunk by chunk, from the chunks' message indexes alone."""
        if topic not in self.topics or self._rosbags is not None or any(f.loose for f in self._files):
            yield self._messages(topic)[0]
            return
        for f in self._files:
            cids = [c.id for c in f.channels.values() if c.topic == topic]
            for i, c in enumerate(f.chunks):
                for cid in cids:
                    if cid in c.index_offsets:
                        yield np.sort(f.message_offsets(i, cid)[0], kind="stable")

    def blocks(self, topic: str) -> Iterator[TopicData]:
        """`read(topic)` chunk by chunk: the blocks, joined, are what `read` returns when the
        topic's chunks follow one another in log time (a recorded run's do)."""
        if topic not in self.specs():
            raise BagError(f"{topic} is not a fixed-layout topic of haptic_teleop")
        for log, payloads in self._message_blocks(topic):
            yield self._decode(topic, log, payloads)

    def packet_blocks(self, topic: str) -> Iterator[np.ndarray]:
        """The packet rows of `topic` chunk by chunk, in the bag's order (not sorted by seq)."""
        ts = typestore()
        for _, payloads in self._message_blocks(topic):
            parts = [
                np.asarray(ts.deserialize_cdr(bytes(raw), MULTIARRAY).data, dtype=np.float64).reshape(
                    -1, len(PACKET_FIELDS)
                )
                for raw in payloads
            ]
            if parts:
                yield np.concatenate(parts)

    def _raw(self, topic: str) -> Iterable[tuple[int, bytes]]:
        log, payloads = self._messages(topic)
        for t, p in zip(log.tolist(), payloads, strict=True):
            yield t, bytes(p)

    def has(self, topic: str) -> bool:
        return topic in self.topics

    def messages(self, topic: str) -> list[tuple[int, bytes]]:
        """Every message of `topic` as (log time [ns], CDR bytes), in log time order."""
        return list(self._raw(topic))

    def fixed(self, topic: str, layout: FixedLayout) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Log times [ns], values (N, layout.nfloats) and stamps [ns] (None without a header) of a
        topic whose every message has `layout`'s size (a BagError names the topic if one does not)."""
        log, payloads = self._messages(topic)
        if not isinstance(payloads, np.ndarray):
            sizes = {len(p) for p in payloads}
            if sizes - {layout.size}:
                raise BagError(
                    f"{self.path}: {topic}: messages of {sorted(sizes)} bytes; this reader takes {layout.size} "
                    f"({layout.msgtype} with {layout.nfloats} values)"
                )
            payloads = np.frombuffer(b"".join(payloads), dtype=np.uint8).reshape(len(log), layout.size)
        elif payloads.size and payloads.shape[1] != layout.size:
            raise BagError(
                f"{self.path}: {topic}: messages of {payloads.shape[1]} bytes; this reader takes {layout.size} "
                f"({layout.msgtype} with {layout.nfloats} values)"
            )
        if not len(log):
            return log, np.zeros((0, layout.nfloats)), None
        values, stamps = layout.decode(np.asarray(payloads))
        return log, values, stamps

    @property
    def schema(self) -> TickSchema:
        """The run's tick schema (joint names, task axes), read from the bag itself: the joint
        names of the first /master/joint_states and /slave/joint_states messages, the axes of
        /operator/joint_states and which sides have a /<side>/measured_effort topic (a hardware
        side's); without those messages, the run facts' `tick_schema`; else the
        1-DoF schema. A BagError for an NVE run's bag (its schema is `nve_schema`)."""
        cached: TickSchema | None = self.__dict__.get("_schema")
        if cached is not None:
            return cached
        nve = self.nve_schema
        if nve is not None:
            raise BagError(
                f"{self.path} is an NVE run's bag (clients {', '.join(nve.clients)}, {nve.axes} axes), "
                "not a teleoperation run's: it has no tick schema"
            )
        schema = self._schema_from_messages() or self._schema_from_facts() or ONE_DOF
        self.__dict__["_schema"] = schema
        return schema

    def _first(self, topic: str, msgtype: str) -> Any:
        """The first message of `topic` (reading one chunk, not the topic), or None."""
        if topic not in self.topics:
            return None
        for _, payloads in self._message_blocks(topic):
            if len(payloads):
                return typestore().deserialize_cdr(bytes(payloads[0]), msgtype)
        return None

    def _schema_from_messages(self) -> TickSchema | None:
        msgs = [self._first(f"/{s}/joint_states", JOINT_STATE) for s in ("operator", "master", "slave")]
        if any(m is None for m in msgs):
            return None
        op, m, s = (tuple(str(n) for n in msg.name) for msg in msgs)
        # a side on hardware records its measured port torque (/<side>/measured_effort)
        measured = (measured_topic("master") in self.topics, measured_topic("slave") in self.topics)
        try:
            return TickSchema(m, s, len(op), *measured)
        except SchemaError as exc:
            raise BagError(f"{self.path}: the joint states name no usable tick schema ({exc})") from None

    def _schema_from_facts(self) -> TickSchema | None:
        import json

        if "/haptic_teleop/run_info" not in self.topics:
            return None
        try:
            facts = json.loads(self.string("/haptic_teleop/run_info")).get("tick_schema")
        except (BagError, ValueError, AttributeError):
            return None
        if facts is None:
            return None
        try:
            return TickSchema.from_facts(facts)
        except SchemaError as exc:
            raise BagError(f"{self.path}: run facts: {exc}") from None

    @property
    def nve_schema(self) -> NveSchema | None:
        """An NVE run's schema (clients, axes), or None for a teleoperation run's bag: the run
        facts' `nve_schema`; without them (a recovered bag of a killed run), the clients' HIP
        topics in connection order and the names of the first /nve/object/joint_states message."""
        if "_nve_schema" in self.__dict__:
            cached: NveSchema | None = self.__dict__["_nve_schema"]
            return cached
        schema = None
        if "/nve/object/joint_states" in self.topics:
            schema = self._nve_schema_from_facts() or self._nve_schema_from_messages()
        self.__dict__["_nve_schema"] = schema
        return schema

    def _nve_schema_from_facts(self) -> NveSchema | None:
        import json

        if "/haptic_teleop/run_info" not in self.topics:
            return None
        try:
            facts = json.loads(self.string("/haptic_teleop/run_info")).get("nve_schema")
        except (BagError, ValueError, AttributeError):
            return None
        if facts is None:
            return None
        try:
            return NveSchema.from_facts(facts)
        except SchemaError as exc:
            raise BagError(f"{self.path}: run facts: {exc}") from None

    def _nve_schema_from_messages(self) -> NveSchema | None:
        first = self._first("/nve/object/joint_states", JOINT_STATE)
        if first is None:
            raise BagError(
                f"{self.path}: an NVE run's bag without run facts and without object states: its schema is unknown"
            )
        try:
            return nve_schema_from_topics(self._topics_in_channel_order(), len(first.name))
        except SchemaError as exc:
            raise BagError(f"{self.path}: the NVE topics name no usable schema ({exc})") from None

    def _topics_in_channel_order(self) -> list[str]:
        if self._rosbags is not None:
            return [c.topic for c in sorted(self._rosbags.connections, key=lambda c: c.id)]
        return [c.topic for f in self._files for _, c in sorted(f.channels.items())]

    def specs(self) -> dict[str, TopicSpec]:
        """The fixed-layout topics of this bag's schema (tick schema, or an NVE run's)."""
        nve = self.nve_schema
        return nve_topic_specs(nve) if nve is not None else topic_specs(self.schema)

    def string(self, topic: str) -> str:
        ts = typestore()
        for _, raw in self._raw(topic):
            return str(ts.deserialize_cdr(raw, STRING).data)
        raise BagError(f"{self.path}: topic {topic} has no messages")

    def read(self, topic: str) -> TopicData:
        """Decode one fixed-layout topic (bulk where the layout matches, else message by message)."""
        spec = self.specs().get(topic)
        if spec is None:
            raise BagError(f"{topic} is not a fixed-layout topic of haptic_teleop")
        log, payloads = self._messages(topic)
        return self._decode(topic, log, payloads)

    def _decode(self, topic: str, log: np.ndarray, payloads: list[bytes] | np.ndarray) -> TopicData:
        spec = self.specs()[topic]
        if not len(payloads):
            return TopicData(log, np.zeros(0, dtype=np.int64), np.zeros((0, len(spec.fields))), spec.fields)
        ts = typestore()
        size = spec.layout.size
        if isinstance(payloads, np.ndarray) and payloads.shape[1] == size:
            rows = payloads
        elif all(len(r) == size for r in payloads):
            rows = np.frombuffer(b"".join(bytes(r) for r in payloads), dtype=np.uint8).reshape(len(payloads), size)
        else:
            rows = None
        first = ts.deserialize_cdr(bytes(payloads[0]), spec.layout.msgtype)
        if rows is not None:
            vals, stamps = spec.layout.decode(rows[:1])
            if vals[0].tolist() == _deserialize_values(spec, first) and (
                stamps is None or int(stamps[0]) == _stamp_of(first)
            ):
                vals, stamps = spec.layout.decode(rows)
                return TopicData(log, stamps, vals, spec.fields)
        values = np.empty((len(payloads), len(spec.fields)))
        stamps_l = np.empty(len(payloads), dtype=np.int64)
        for i, raw in enumerate(payloads):
            msg = ts.deserialize_cdr(bytes(raw), spec.layout.msgtype)
            values[i] = _deserialize_values(spec, msg)
            s = _stamp_of(msg)
            stamps_l[i] = -1 if s is None else s
        return TopicData(log, stamps_l if spec.layout.msgtype != MULTIARRAY else None, values, spec.fields)

    def read_ticks(self) -> np.ndarray:
        """A teleoperation run's tick rows rebuilt from its per-tick topics: (ticks, schema.width)
        in the engine's columns (record/columns.py). `fwd_rx_seq`/`bwd_rx_seq` come from
        /forward/received and /backward/received (the tick a released sample was sent at, -1
        where none was released); columns no topic holds (the buffers' occupancy, and the EBA
        internals of a run recorded without them) are NaN."""
        from haptic_teleop.record.streams import RECEIVED_TOPICS

        schema = self.schema
        specs = topic_specs(schema)
        period = self._period_ns()
        received = dict(RECEIVED_TOPICS)
        topics = [t for t in specs if self.has(t)]
        # side by side, a block (a chunk) of each topic in turn: each chunk is decompressed once
        sources = {t: self.blocks(t) for t in topics}
        parts: dict[str, list[TopicData]] = {t: [] for t in topics}
        while sources:
            for topic in list(sources):
                block = next(sources[topic], None)
                if block is None:
                    del sources[topic]
                else:
                    parts[topic].append(block)
        data = {t: _joined(p) for t, p in parts.items() if p}
        ref = data.get("/master/joint_states")
        ticks = int(ref.log_ns[-1] // period) + 1 if ref is not None and ref.log_ns.size else 0
        rows = np.full((ticks, schema.width), np.nan)
        for topic, got in data.items():
            if topic not in received:
                rows[np.ix_(got.log_ns // period, np.asarray(specs[topic].columns, dtype=np.int64))] = got.values
        for topic, column in RECEIVED_TOPICS:
            seq = np.full(ticks, -1.0)
            released = data.get(topic)
            if released is not None and released.stamp_ns is not None:
                seq[released.log_ns // period] = released.stamp_ns // period
            rows[:, schema.index(column)] = seq
        return rows

    def _period_ns(self) -> int:
        """The run's tick period, from the scene the bag holds."""
        scene = _safe_yaml(self.string("/haptic_teleop/scene"))
        return round(float(scene["scene"]["period_s"]) * 1e9)

    def nve_blocks(self) -> Iterator[TopicData]:
        """An NVE run's tick rows rebuilt from its per-tick topics, block by block (the topics read
        side by side, chunk by chunk: memory of a chunk, not of the run): values (ticks,
        schema.width) in the columns of `nve_schema` (`fields` = its column names, so
        `.field("client1.rtt_s")`), log times and stamps. Of a bag whose cut fell inside a tick
        (recovered), the ticks every topic holds."""
        schema = self.nve_schema
        if schema is None:
            raise BagError(f"{self.path}: not an NVE run's bag (no /nve/object/joint_states)")
        specs = nve_topic_specs(schema)
        ref_topic = "/nve/object/joint_states"
        sources = {t: self.blocks(t) for t in specs}
        pending: dict[str, list[TopicData]] = {t: [] for t in specs}
        have = dict.fromkeys(specs, 0)
        while True:
            for topic, source in sources.items():
                while not have[topic]:
                    block = next(source, None)
                    if block is None:
                        break
                    pending[topic].append(block)
                    have[topic] += len(block.log_ns)
            n = min(have.values())
            if n == 0:
                return
            values = np.empty((n, schema.width))
            log = stamps = np.zeros(0, dtype=np.int64)
            for topic in specs:
                parts = pending[topic]
                whole = parts[0] if len(parts) == 1 else _joined(parts)
                if topic == ref_topic:
                    log, stamps = whole.log_ns[:n], whole.stamp_ns[:n] if whole.stamp_ns is not None else stamps
                elif not np.array_equal(whole.log_ns[:n], log):
                    raise BagError(f"{self.path}: {topic} is not logged at the ticks of {ref_topic}")
                values[:, list(specs[topic].columns)] = whole.values[:n]
                rest = TopicData(
                    whole.log_ns[n:],
                    None if whole.stamp_ns is None else whole.stamp_ns[n:],
                    whole.values[n:],
                    whole.fields,
                )
                pending[topic] = [rest] if len(rest.log_ns) else []
                have[topic] -= n
            yield TopicData(log, stamps, values, schema.columns)

    def read_nve(self) -> TopicData:
        """`nve_blocks()` joined: the whole run's rows."""
        blocks = list(self.nve_blocks())
        schema = self.nve_schema
        assert schema is not None
        if not blocks:
            return TopicData(
                np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64), np.zeros((0, schema.width)), schema.columns
            )
        return _joined(blocks)

    def packets(self, topic: str) -> np.ndarray:
        """All packet rows of /forward/packets or /backward/packets (an NVE run's
        /nve/<client>/up/packets, /down/packets), sorted by seq: (N, 6) per PACKET_FIELDS."""
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

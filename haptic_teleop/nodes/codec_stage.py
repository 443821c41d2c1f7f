"""The codec stage live (docs/live_network.md, "Codecs live"; docs/codec_live.md): a direction's encoder
in the sending node, its decoder in the receiving side's buffer node, the relay between them
carrying the encoder's packets, and (ARQ) an ack relay carrying the decoder's acknowledgements
back over the reverse direction's effects.

Wire message of a codec packet: the engine's (`assembly.channel.message_bytes`), a
sensor_msgs/JointState with the payload's F values spread over position, velocity and effort,
field by field, `names = ceil(F / 3)` values per field (the last field padded with zeros); the
names are `cFFF_iii` (F the payload's length, i the name's index: 8 characters, the size the
engine's accounting assumes), so a receiver knows F. An arm scene's (`assembly.side.arm_message_bytes`):
one name per task axis, more when the payload needs them (`max(3, ceil(F / 3))` names), names
`cFFFii` (6 characters, as the engine's `axis_i`). header.stamp = the packet's seq (the tick of
the sample it carries) on the node clock's tick grid: the relay takes seq = stamp / period from it,
as for a plain sample. An acknowledgement is the same message with the payload (seq,).

Counters: each side publishes its codec's counters (std_msgs/String, JSON, latched) on
/<direction>/codec/encoder and /<direction>/codec/decoder about every 0.5 s and at close, counted
over the scene's window (from scene time 0, /haptic_teleop/scene_start, to scene.duration_s): the
recorder writes them into the run facts `codec_<direction>` as the engine does.
"""

from __future__ import annotations

import json
import re
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from haptic_teleop.assembly.channel import REVERSE, codec_pair, message_bytes
from haptic_teleop.errors import ConfigError

# The codecs the live nodes run (HLI sizes its packets by class, not by this wire message).
LIVE_CODECS = ("deadband", "prediction", "fec", "arq", "hli")
# network_relay `carries`: the direction's plain samples, its codec's packets, or the
# acknowledgements of its codec (ARQ) over the reverse direction's effects.
RELAY_CARRIES = ("samples", "codec", "ack")
_FIELDS = ("position", "velocity", "effort")
_NAME = re.compile(r"c(\d{3})(?:_\d{3}|\d{2})\Z")
_HLI_NAME = re.compile(r"h(\d{3})_\d{3}\Z")
COUNTERS_EVERY_S = 0.5
SNAPSHOT_TICKS = 5000  # counter snapshots kept while scene time 0 is not known yet


def ack_sent_topic(direction: str) -> str:
    """Decoder -> ack relay: the acknowledgements of `direction`'s codec."""
    return f"/{direction}/ack/sent"


def ack_delivered_topic(direction: str) -> str:
    """Ack relay -> the encoder's node."""
    return f"/{direction}/ack/delivered"


def counters_topic(direction: str, side: str) -> str:
    """The codec's counters of `side` (encoder, decoder) over the scene's window, latched."""
    return f"/{direction}/codec/{side}"


def wire_layout(floats: int, arm: bool = False) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """(names, fields) of the JointState carrying a payload of `floats` values (`arm`: an arm
    scene's, one name per task axis at least)."""
    if not 1 <= floats <= (297 if arm else 999):
        raise ValueError(f"a codec packet carries 1 to {297 if arm else 999} values, got {floats}")
    names = max(3, -(-floats // 3)) if arm else -(-floats // 3)
    fields = _FIELDS[: -(-floats // names)]
    if arm:
        return tuple(f"c{floats:03d}{i:02d}" for i in range(names)), fields
    return tuple(f"c{floats:03d}_{i:03d}" for i in range(names)), fields


class CodecWire:
    """Encodes and decodes the codec packets' JointState (module docstring). `hli_dim`: the
    direction's codec is HLI with samples of that many values; its packets then take the engine's
    HLI message (core/hli_codec.hli_message_bytes): `hli_dim + 1` names `hDDD_iii`, position =
    (x..., class), velocity = (previous x..., offset), and in an HLI1 packet effort = (the HLI2
    event's copy..., 0); the payload in the codec's order is rebuilt from it on decoding."""

    def __init__(self, arm: bool = False, hli_dim: int | None = None) -> None:
        self.arm = arm
        self.hli_dim = hli_dim
        self._codecs: dict[int, Any] = {}
        self._size_of = wire_size_of(arm)

    def _codec(self, floats: int) -> Any:
        c = self._codecs.get(floats)
        if c is None:
            from haptic_teleop.nodes.cdr import JointStateCodec

            names, fields = wire_layout(floats, self.arm)
            c = self._codecs[floats] = JointStateCodec(names, fields)
        return c

    def _hli_codec(self, fields: int) -> Any:
        key = -fields  # apart from the payload lengths of the other layout
        c = self._codecs.get(key)
        if c is None:
            from haptic_teleop.nodes.cdr import JointStateCodec

            d = self.hli_dim
            assert d is not None
            names = tuple(f"h{d:03d}_{i:03d}" for i in range(d + 1))
            c = self._codecs[key] = JointStateCodec(names, _FIELDS[:fields])
        return c

    def size_of(self, payload: Sequence[float]) -> int:
        """The engine's message size of a packet with this payload (what the links count)."""
        d = self.hli_dim
        if d is None:
            return self._size_of(len(payload))
        from haptic_teleop.core.hli_codec import hli_message_bytes

        return hli_message_bytes(d, round(payload[d]))

    def encode(self, stamp_ns: int, payload: Sequence[float]) -> bytes:
        d = self.hli_dim
        if d is not None:
            pl = tuple(payload)
            three = len(pl) == 3 * d + 2
            if len(pl) != 2 * d + 2 and not three:
                want = f"{2 * d + 2} or {3 * d + 2}"
                raise ValueError(f"an HLI packet of {d}-value samples carries {want} values, got {len(pl)}")
            values = (*pl[:d], pl[d], *pl[d + 2 : 2 * d + 2], pl[d + 1])
            if three:
                values = (*values, *pl[2 * d + 2 :], 0.0)
            hli: bytes = self._hli_codec(3 if three else 2).encode(stamp_ns, values)
            return hli
        f = len(payload)
        c = self._codec(f)
        slots = len(c.names) * len(c.fields)
        out: bytes = c.encode(stamp_ns, (*payload, *(0.0,) * (slots - f)))
        return out

    @staticmethod
    def decode(raw: bytes) -> tuple[int, tuple[float, ...]]:
        """(stamp ns, payload) of a codec message; ValueError for a message of another layout."""
        from rclpy.serialization import deserialize_message
        from sensor_msgs.msg import JointState

        m = deserialize_message(raw, JointState)
        st = m.header.stamp
        stamp = int(st.sec) * 1_000_000_000 + int(st.nanosec)
        hli = _HLI_NAME.match(m.name[0]) if len(m.name) else None
        if hli is not None:
            d = int(hli.group(1))
            pos, vel, eff = m.position, m.velocity, m.effort
            if len(m.name) != d + 1 or len(pos) != d + 1 or len(vel) != d + 1 or len(eff) not in (0, d + 1):
                raise ValueError(f"an HLI packet of {d}-value samples has {d + 1} names, positions and velocities")
            out = (*pos[:d], pos[d], vel[d], *vel[:d], *eff[:d])
            return stamp, tuple(float(v) for v in out)
        match = _NAME.match(m.name[0]) if len(m.name) else None
        if match is None:
            raise ValueError("not a codec packet (joint names cFFF_iii, an arm scene's cFFFii, HLI's hDDD_iii)")
        f = int(match.group(1))
        values = (*m.position, *m.velocity, *m.effort)
        if len(values) < f:
            raise ValueError(f"a codec packet of {f} values carries {len(values)}")
        return stamp, tuple(float(v) for v in values[:f])


def direction_wire(cfg: Any, direction: str, arm: bool) -> CodecWire:
    """The wire of `direction`'s codec packets in this scene (HLI's own message, else the engine's
    codec message of the payload's length)."""
    codec = getattr(cfg.network, direction).codec
    if codec is None or codec.kind != "hli":
        return CodecWire(arm)
    from haptic_teleop.assembly.channel import LAYOUT_ARM, LAYOUT_ONE_AXIS

    layout = LAYOUT_ARM if arm else LAYOUT_ONE_AXIS
    return CodecWire(arm, hli_dim=len(layout[direction]) * (3 if arm else 1))


def check_live_codec(where: str, cfg: Any, direction: str) -> str | None:
    """The kind of `direction`'s codec if the live nodes run it (None: no codec); ConfigError for
    one they do not run."""
    codec = getattr(cfg.network, direction).codec
    if codec is None:
        return None
    if cfg.is_arm:
        from haptic_teleop.scene.load import side_period_ticks

        own = [r for r in ("master", "slave") if side_period_ticks(cfg, r) != 1]
        if own:
            raise ConfigError(
                where, f"network.{direction}.codec", codec.kind,
                f"an arm side with its own period ({own[0]}.period_s) runs no codec live yet (the engine's "
                "encoder takes a sample every scene tick); leave one of them out",
            )  # fmt: skip
    if codec.kind not in LIVE_CODECS:
        raise ConfigError(
            where, f"network.{direction}.codec", codec.kind,
            f"codec {codec.kind} runs in `haptic-teleop run` only; live: {', '.join(LIVE_CODECS)}",
        )  # fmt: skip
    every = getattr(codec.settings(), "ack_every_ticks", 1) if codec.kind == "arq" else 1
    if every != 1:
        raise ConfigError(
            where, f"network.{direction}.codec.ack_every_ticks", every,
            "live ARQ sends one ACK per data packet: ack_every_ticks must be 1 (cumulative ACKs run in "
            "`haptic-teleop run` only)",
        )  # fmt: skip
    return str(codec.kind)


class WindowCounters:
    """A codec's counters over the scene's window: a snapshot at scene time 0 (the operator's
    /haptic_teleop/scene_start) and one at scene.duration_s, the difference published (latched)
    every COUNTERS_EVERY_S and at close. The operator source publishes the start at scene time 0
    itself, so it reaches this node a little after: until it does, a snapshot per tick is kept
    (the last SNAPSHOT_TICKS) and the one of scene time 0 is taken from there. Without a scene
    start (a node set without an operator source) the counters since the node started."""

    def __init__(self, node: Any, topic: str, cfg: Any, counters: Callable[[], dict[str, Any]]) -> None:
        from std_msgs.msg import Header, String

        from haptic_teleop.nodes.topics import SCENE_START_TOPIC, latched_qos

        self._string = String
        self._counters = counters
        self.period_ns = round(cfg.scene.period_s * 1e9)
        self.duration_ns = round(cfg.scene.duration_s / cfg.scene.period_s) * self.period_ns
        self._start_sub = node.create_polled_subscription(Header, SCENE_START_TOPIC, latched_qos())
        self._pub = node.create_publisher(String, topic, latched_qos())
        self.start_ns: int | None = None
        self.base: dict[str, Any] | None = None
        self.end: dict[str, Any] | None = None
        self._every = max(1, round(COUNTERS_EVERY_S * 1e9 / self.period_ns))
        self._ticks = 0
        self._early: deque[tuple[int, dict[str, Any]]] = deque(maxlen=SNAPSHOT_TICKS)

    def at_tick(self, stamp_ns: int) -> None:
        """Before the tick's work (so the window is ticks [0, duration))."""
        if self.start_ns is None:
            from haptic_teleop.nodes.messages import take_all
            from haptic_teleop.nodes.topics import scene_start_ns

            told = take_all(self._start_sub)
            if told:
                t0 = scene_start_ns(told[-1], self.period_ns)
                self.start_ns = t0
                # the snapshot before the first tick of scene time >= 0 this node ran, if kept
                self.base = next((c for s, c in self._early if s >= t0), None)
                self._early.clear()
            else:
                self._early.append((stamp_ns, dict(self._counters())))
        start = self.start_ns
        if start is not None:
            if self.base is None and stamp_ns >= start:
                self.base = dict(self._counters())
            if self.end is None and stamp_ns >= start + self.duration_ns:
                self.end = dict(self._counters())
        self._ticks += 1
        if self._ticks % self._every == 0:
            self.publish()

    def window(self) -> dict[str, Any]:
        cur = self.end if self.end is not None else self._counters()
        if self.start_ns is None:
            base: dict[str, Any] = {}
        else:
            base = self.base if self.base is not None else cur  # not started yet: nothing counted
        return {k: v - base.get(k, 0) for k, v in cur.items() if isinstance(v, (int, float))}

    def publish(self, final: bool = False) -> None:
        """`final` (at close): wait until the recorder acknowledged it (at most
        messages.FINAL_ACK_S), so the last counters are not lost with this node's writer."""
        counters = self.window()
        if final:  # the recorder waits for this one at close (nodes/recorder.py)
            counters["final"] = 1
        self._pub.publish(self._string(data=json.dumps(counters, sort_keys=True)))
        if final:
            from haptic_teleop.nodes.messages import wait_acknowledged

            wait_acknowledged(self._pub)


def _pair(cfg: Any, direction: str, period_ns: int, arm: bool) -> tuple[Any, Any]:
    """The encoder and decoder as the engine builds them for this scene (one axis, or an arm's)."""
    if not arm:
        return codec_pair(cfg, direction, period_ns)
    from haptic_teleop.assembly.channel import LAYOUT_ARM
    from haptic_teleop.assembly.side import arm_message_bytes

    return codec_pair(cfg, direction, period_ns, axes=3, size_of=arm_message_bytes, layout=LAYOUT_ARM)


def wire_size_of(arm: bool) -> Callable[[int], int]:
    """The engine's message size of a codec payload of F values (`arm`: in an arm scene)."""
    if not arm:
        return message_bytes
    from haptic_teleop.assembly.side import arm_message_bytes

    return arm_message_bytes


def _prefixed(side: str, obj: Any) -> dict[str, Any]:
    return {f"{side}_{k}": v for k, v in getattr(obj, "counters", {}).items()}


class CodecSender:
    """The encoder of `direction` in its sending node: per tick, the acknowledgements delivered
    (ARQ) into `feedback`, the sample into `send`, each packet it emits onto /<direction>/sent."""

    def __init__(self, node: Any, direction: str, cfg: Any) -> None:
        from sensor_msgs.msg import JointState

        from haptic_teleop.nodes.messages import raw_publish_fn
        from haptic_teleop.nodes.topics import READER_DEPTH, sent_topic, stream_qos

        kind = check_live_codec(f"parameters of node {node.get_name()}", cfg, direction)
        assert kind is not None
        self.kind, self.direction = kind, direction
        self.period_ns = round(cfg.scene.period_s * 1e9)
        self.encoder, _ = _pair(cfg, direction, self.period_ns, cfg.is_arm)
        self.wire = direction_wire(cfg, direction, cfg.is_arm)
        self._send = raw_publish_fn(node.create_publisher(JointState, sent_topic(direction), stream_qos(READER_DEPTH)))
        self._acks = None
        if kind == "arq":
            qos = stream_qos(READER_DEPTH)
            self._acks = node.create_polled_subscription(JointState, ack_delivered_topic(direction), qos, raw=True)
        self.window = WindowCounters(
            node, counters_topic(direction, "encoder"), cfg, lambda: _prefixed("encoder", self.encoder)
        )
        self.packets = 0

    def send(self, stamp_ns: int, sample: tuple[float, ...]) -> None:
        from haptic_teleop.core.link import Packet
        from haptic_teleop.nodes.messages import take_all

        self.window.at_tick(stamp_ns)
        period, enc, wire = self.period_ns, self.encoder, self.wire
        if self._acks is not None:
            for raw in take_all(self._acks):
                try:
                    stamp, payload = wire.decode(raw)
                except ValueError:
                    continue
                enc.feedback(Packet(stamp // period, stamp, payload, 0), stamp_ns)
        for p in enc.send(stamp_ns // period, stamp_ns, sample):
            self._send(wire.encode(p.seq * period, p.payload))
            self.packets += 1

    def close(self) -> None:
        self.window.publish(final=True)


class CodecReceiver:
    """The decoder of `direction` in the receiving side's buffer node: per tick, every packet the
    relay delivered into `receive` (its acknowledgements, ARQ, onto /<direction>/ack/sent), then
    `sample(n)`, the remote sample of this tick."""

    def __init__(self, node: Any, direction: str, cfg: Any, arm: bool = False) -> None:
        """`arm`: an arm scene (the buffer node reads only the scene's network sections: its
        `task_axes` tells)."""
        from sensor_msgs.msg import JointState

        from haptic_teleop.nodes.messages import raw_publish_fn
        from haptic_teleop.nodes.topics import READER_DEPTH, stream_qos

        kind = check_live_codec(f"parameters of node {node.get_name()}", cfg, direction)
        assert kind is not None
        self.kind, self.direction = kind, direction
        self.period_ns = round(cfg.scene.period_s * 1e9)
        _, self.decoder = _pair(cfg, direction, self.period_ns, arm)
        self.wire = direction_wire(cfg, direction, arm)
        self._ack = (
            raw_publish_fn(node.create_publisher(JointState, ack_sent_topic(direction), stream_qos(READER_DEPTH)))
            if kind == "arq"
            else None
        )
        self.ack_packets = 0
        self.ack_bytes = 0
        self.newest_seq = -1
        self.malformed = 0
        self.window = WindowCounters(node, counters_topic(direction, "decoder"), cfg, self._counters)

    def _counters(self) -> dict[str, Any]:
        return {**_prefixed("decoder", self.decoder), "ack_packets": self.ack_packets, "ack_bytes": self.ack_bytes}

    def tick(self, raws: list[bytes], stamp_ns: int, arrived: Callable[[int], None]) -> tuple[Any, int]:
        """(the decoded sample of this tick or None before the first, the newest arrival's seq if
        it is newer than any before, else -1: the engine's `received` column). `arrived(seq)`:
        called for every packet handed to the decoder."""
        from haptic_teleop.core.link import Packet

        self.window.at_tick(stamp_ns)
        period, dec, wire = self.period_ns, self.decoder, self.wire
        rx = -1
        for raw in raws:
            try:
                stamp, payload = wire.decode(raw)
            except ValueError:
                self.malformed += 1
                continue
            seq = stamp // period
            back = dec.receive(Packet(seq, stamp, payload, wire.size_of(payload), stamp_ns), stamp_ns)
            arrived(seq)
            if seq > self.newest_seq:
                self.newest_seq = rx = seq
            if back and self._ack is not None:
                for b in back:
                    self.ack_packets += 1
                    self.ack_bytes += b.size_bytes
                    self._ack(wire.encode(b.seq * period, b.payload))
        return dec.sample(stamp_ns // period, stamp_ns), rx

    def close(self) -> None:
        self.window.publish(final=True)


def codec_run_facts(cfg: Any, encoder: dict[str, Any], decoder: dict[str, Any]) -> dict[str, Any]:
    """The run facts of a live run's codec stage, as the engine writes them (Engine.codec_facts):
    `codec_<direction>` (kind, the encoder's and the decoder's counters, the acknowledgements) for
    each direction naming a codec, `codec_plain_bytes`; `encoder`/`decoder`: direction -> the
    counters its nodes published last ({} if none came)."""
    from haptic_teleop.record.layouts import joint_state_size

    out: dict[str, Any] = {}
    for d in REVERSE:
        codec = getattr(cfg.network, d).codec
        if codec is None:
            continue
        facts: dict[str, Any] = {"kind": codec.kind, **encoder.get(d, {}), **decoder.get(d, {})}
        facts.setdefault("ack_packets", 0)
        facts.setdefault("ack_bytes", 0)
        missing = [s for s, got in (("encoder", encoder), ("decoder", decoder)) if not got.get(d)]
        if missing:
            facts["counters_missing"] = ",".join(missing)
        out[f"codec_{d}"] = facts
    if out and cfg.is_arm:
        from haptic_teleop.assembly.side import wire_payload_bytes

        out["codec_plain_bytes"] = {"forward": wire_payload_bytes(3, 2), "backward": wire_payload_bytes(3, 3)}
    elif out:
        out["codec_plain_bytes"] = {"forward": joint_state_size(2), "backward": joint_state_size(3)}
    return out

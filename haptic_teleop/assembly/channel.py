"""The codec stage in a teleoperation channel's direction (docs/codec_channels.md).

Per direction whose scene names `codec: {kind: ...}`, each tick:

    ACKs due back (ARQ only) --feedback--> Encoder
    sender's sample --Encoder.send--> packets --Link (the direction's effects)--> arrivals
        --Decoder.receive--> (ARQ: ACKs into the ACK link, the reverse direction's effects)
    Decoder.sample(n) --> the remote sample the receiving controller uses this tick

No playout buffer: the decoder takes the link's arrivals directly (a buffer plays in order and
once, so it would drop FEC recoveries and ARQ retransmissions; the scene must say `buffer.policy:
none`, checked in scene/direction.py). The codec codes the whole sample the direction carries:
forward the master's (x, v) and backward the slave's (f_env, x, v), SI units, one vector; a
deadband's threshold applies to the velocity forward and to the force and the velocity backward
(`DEADBAND_TRIGGERS`).

Every packet the encoder sends goes into the `Link`, so the link's log (the bag's packet records)
holds exactly the encoder's packets; ARQ's acknowledgements go into a separate link with the
reverse direction's effects (own random streams, "<direction>:ack") and are counted, not recorded.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_teleop.core.arq import build_arq
from haptic_teleop.core.deadband import (
    DeadbandDecoder,
    GroupedDeadbandEncoder,
)
from haptic_teleop.core.fec import build_fec
from haptic_teleop.core.hli_codec import build_hli_codec, joint_state_bytes
from haptic_teleop.core.link import Link, Packet
from haptic_teleop.core.prediction import build_prediction
from haptic_teleop.scene.direction import ChannelDirectionConfig, hli_gilbert
from haptic_teleop.scene.schema import Scene
from haptic_teleop.scene.traces import build_scene_link

# The quantities of a direction's sample, in payload order (each `axes` values): one axis
# forward (x_m, v_m), backward (f_env, x_s, v_s); an arm scene (x_m, v_m) and (x_s, v_s, f_env).
LAYOUT_ONE_AXIS = {"forward": ("x", "v"), "backward": ("f", "x", "v")}
LAYOUT_ARM = {"forward": ("x", "v"), "backward": ("x", "v", "f")}
# What a deadband's threshold applies to per direction: the velocity forward (seed 001's
# velocity stream), the force and the velocity backward (the force in contact; the velocity keeps
# the slave's position coming in free space, where the force is zero). Never the absolute
# position: a relative deadband on a position is a threshold that grows with the distance from
# the frame's origin. Positions ride along in every packet.
DEADBAND_TRIGGERS = {"forward": ("v",), "backward": ("f", "v")}
REVERSE = {"forward": "backward", "backward": "forward"}


def message_bytes(floats: int) -> int:
    """Wire message of a codec packet carrying `floats` values: the smallest sensor_msgs/JointState
    that holds them (one name per 3 values, position/velocity/effort filled evenly); the same
    size as the plain packet's JointState for the plain payloads (2 forward, 3 backward)."""
    if floats < 1:
        raise ValueError(f"a codec packet carries at least one value, got {floats}")
    names = -(-floats // 3)
    return joint_state_bytes(-(-floats // names), names)


def _seq_send(p: Packet) -> int:
    return p.send_time_ns


@dataclass
class CodecChannel:
    """One direction's codec stage: encoder, link, decoder (and ARQ's ACK link)."""

    direction: str
    kind: str
    encoder: Any
    decoder: Any
    link: Link
    dim: int
    ack_link: Link | None = None
    ack_packets: int = 0
    ack_bytes: int = 0
    newest_seq: int = -1  # the newest seq the decoder has received
    counters_out: dict[str, Any] = field(default_factory=dict)

    def step(self, n: int, now_ns: int, sample: tuple[float, ...]) -> tuple[tuple[float, ...] | None, int]:
        """One tick: encode `sample`, send, deliver, decode. Returns (the remote sample for tick n
        or None before the first, the seq of the newest arrival this tick if it is newer than any
        before (-1 otherwise): the bag's `received` column)."""
        ack = self.ack_link
        enc, dec, link = self.encoder, self.decoder, self.link
        if ack is not None:
            for a in ack.deliver(now_ns):
                enc.feedback(a, now_ns)
        for p in enc.send(n, now_ns, sample):
            link.send(p)
        rx = -1
        for p in link.deliver(now_ns):
            back = dec.receive(p, now_ns)
            if p.seq > self.newest_seq:
                self.newest_seq = rx = p.seq
            if back and ack is not None:
                for b in back:
                    self.ack_packets += 1
                    self.ack_bytes += b.size_bytes
                    ack.send(b)
        if ack is not None and dec.ack_every_ticks > 1:  # ARQ's cumulative ACK of the tick
            for b in dec.acks(n, now_ns):
                self.ack_packets += 1
                self.ack_bytes += b.size_bytes
                ack.send(b)
        out = dec.sample(n, now_ns)
        return (None if out is None else tuple(out[: self.dim])), rx

    def settled(self, sent: int, final: bool, period_ns: int) -> np.ndarray | None:
        """Records (bag rows) of the packets at the head of the link's log whose fate is final:
        sent before tick `sent` and older than the oldest packet still in flight (the log is in
        send order; retransmissions keep their sample's seq, so the order is by send time)."""
        mark = sent * period_ns
        if not final:
            s = self.link.oldest_in_flight_send_ns()
            if s is not None and s < mark:
                mark = s
        log = self.link.log
        k = bisect.bisect_left(log, mark, key=_seq_send)
        if k == 0:
            return None
        from haptic_teleop.record.layouts import packet_rows

        rows = packet_rows(log[:k])
        del log[:k]
        return rows

    def facts(self) -> dict[str, Any]:
        """What the codec decided, for the bag's run facts (metadata): kind, the encoder's and
        decoder's counters, the ACKs sent back."""
        out: dict[str, Any] = {"kind": self.kind}
        for side, obj in (("encoder", self.encoder), ("decoder", self.decoder)):
            for k, v in getattr(obj, "counters", {}).items():
                if isinstance(v, (int, float)) and math.isfinite(v):
                    out[f"{side}_{k}"] = int(v) if isinstance(v, int) else float(v)
        out["ack_packets"] = self.ack_packets
        out["ack_bytes"] = self.ack_bytes
        return out


def _codec_pair(
    d: ChannelDirectionConfig,
    layout: tuple[str, ...],
    direction: str,
    axes: int,
    period_ns: int,
    size_of: Callable[[int], int],
) -> tuple[Any, Any]:
    c = d.codec
    assert c is not None
    dim = len(layout) * axes
    if c.kind == "deadband":
        cfg = c.settings()

        def part(q: str) -> slice:
            i = layout.index(q)
            return slice(i * axes, (i + 1) * axes)

        triggers = tuple(part(q) for q in DEADBAND_TRIGGERS[direction])
        enc = GroupedDeadbandEncoder(cfg, dim, size_of(dim * cfg.floats_per_axis), triggers, part("v"))
        return enc, DeadbandDecoder(cfg, dim, period_ns)
    if c.kind == "hli":
        return build_hli_codec(c.settings(**hli_gilbert(d)), period_ns, dim)
    if c.kind == "prediction":
        return build_prediction(c.settings(), period_ns, size_of=size_of)
    if c.kind == "fec":
        return build_fec(c.settings(), period_ns, size_of=size_of)
    if c.kind == "arq":
        return build_arq(c.settings(), period_ns, size_of=size_of)
    raise ValueError(f"unknown codec kind {c.kind!r}")


def codec_pair(
    c: Scene,
    direction: str,
    period_ns: int,
    axes: int = 1,
    size_of: Callable[[int], int] = message_bytes,
    layout: dict[str, tuple[str, ...]] | None = None,
) -> tuple[Any, Any]:
    """The encoder and the decoder of `direction`'s codec, as `build_codec_channels` builds them
    (the live nodes run them apart: the encoder in the sending node, the decoder in the receiving
    side's buffer node; nodes/codec_stage.py)."""
    d: ChannelDirectionConfig = getattr(c.network, direction)
    if d.codec is None:
        raise ValueError(f"network.{direction} names no codec")
    layout = LAYOUT_ONE_AXIS if layout is None else layout
    return _codec_pair(d, layout[direction], direction, axes, period_ns, size_of)


def arq_round_trip_notes(c: Scene) -> list[str]:
    """One line for each ARQ direction whose timeout is under its round trip (the constant delays
    of its link and of its ACKs' link, the reverse direction's; jitter and time-varying parts
    aside): the sender then sends every sample again before its ACK can come back, loss or not,
    ARQ working as repetition (docs/codec_cost.md)."""
    out = []
    period = c.scene.period_s
    for name in ("forward", "backward"):
        d: ChannelDirectionConfig = getattr(c.network, name)
        if d.codec is None or d.codec.kind != "arq":
            continue
        cfg = d.codec.settings()
        delays = [getattr(c.network, k).effects.delay for k in (name, REVERSE[name])]
        one_way = [0.0 if e is None else e.delay_s for e in delays]
        rtt = sum(one_way)
        if cfg.timeout_s >= rtt:
            continue
        # the sample's ACK is taken ceil(d_f / T) + max(1, ceil(d_b / T)) ticks after it was
        # sent; a copy goes out every m = ceil(mu / T) ticks before that, nu at most
        ticks = math.ceil(one_way[0] / period - 1e-9) + max(1, math.ceil(one_way[1] / period - 1e-9))
        m = math.ceil(cfg.timeout_s / period - 1e-9)
        copies = 1 + min(cfg.max_retransmissions, -(-ticks // m) - 1)
        if copies < 2:
            continue
        out.append(
            f"ARQ on the {name} link retransmits after {cfg.timeout_s * 1e3:g} ms, under its "
            f"{rtt * 1e3:g} ms round trip: every sample goes out {copies} times, lost or not "
            f"(a timeout_s above the round trip resends only what was lost)"
        )
    return out


def build_codec_channels(
    c: Scene,
    period_ns: int,
    forward: Link,
    backward: Link,
    axes: int = 1,
    size_of: Callable[[int], int] = message_bytes,
    layout: dict[str, tuple[str, ...]] | None = None,
) -> tuple[CodecChannel | None, CodecChannel | None]:
    """The codec stage of each direction that names one (None: that direction runs as before).
    `axes`: values per quantity (1, or an arm scene's 3 task axes); `size_of(floats)`: the wire
    message of a codec payload of that many values (`message_bytes`; an arm scene's engine passes
    its JointState of one name per axis); `layout`: the quantities of each direction's sample
    (`LAYOUT_ONE_AXIS` by default, an arm scene's `LAYOUT_ARM`)."""
    layout = LAYOUT_ONE_AXIS if layout is None else layout
    links = {"forward": forward, "backward": backward}
    out: dict[str, CodecChannel | None] = {}
    for name in ("forward", "backward"):
        d: ChannelDirectionConfig = getattr(c.network, name)
        if d.codec is None:
            out[name] = None
            continue
        dim = len(layout[name]) * axes
        enc, dec = _codec_pair(d, layout[name], name, axes, period_ns, size_of)
        ack = None
        if d.codec.kind == "arq":
            rev: ChannelDirectionConfig = getattr(c.network, REVERSE[name])
            ack = build_scene_link(rev.effects, c.scene.seed, f"{name}:ack")
        out[name] = CodecChannel(name, d.codec.kind, enc, dec, links[name], dim, ack)
    return out["forward"], out["backward"]

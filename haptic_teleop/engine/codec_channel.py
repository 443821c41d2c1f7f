"""The codec stage in a teleoperation channel's direction (docs/codec.md, "In the channels").

Per direction whose scene names `codec: {kind: ...}`, each tick:

    ACKs due back (ARQ only) --feedback--> Encoder
    sender's sample --Encoder.send--> packets --Link (the direction's effects)--> arrivals
        --Decoder.receive--> (ARQ: ACKs into the ACK link, the reverse direction's effects)
    Decoder.sample(n) --> the remote sample the receiving controller uses this tick

No playout buffer: the decoder takes the link's arrivals directly (a buffer plays in order and
once, so it would drop FEC recoveries and ARQ retransmissions; the scene must say `buffer.policy:
none`, checked in scene/direction.py). The codec codes the whole sample the direction carries:
forward the master's (x, v) and backward the slave's (f_env, x, v), SI units, one vector.

Every packet the encoder sends goes into the `Link`, so the link's log (the bag's packet records)
holds exactly the encoder's packets; ARQ's acknowledgements go into a separate link with the
reverse direction's effects (own random streams, "<direction>:ack") and are counted, not recorded.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from haptic_teleop.core.arq import build_arq
from haptic_teleop.core.deadband import build_deadband
from haptic_teleop.core.fec import build_fec
from haptic_teleop.core.hli_codec import build_hli_codec, joint_state_bytes
from haptic_teleop.core.link import Link, Packet
from haptic_teleop.core.prediction import build_prediction
from haptic_teleop.scene.direction import ChannelDirectionConfig, hli_gilbert
from haptic_teleop.scene.schema import Scene
from haptic_teleop.traces import build_scene_link

# Values per direction's sample: forward (x_m, v_m), backward (f_env, x_s, v_s).
SAMPLE_FLOATS = {"forward": 2, "backward": 3}
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


def _codec_pair(d: ChannelDirectionConfig, dim: int, period_ns: int) -> tuple[Any, Any]:
    c = d.codec
    assert c is not None
    if c.kind == "deadband":
        cfg = c.settings()
        return tuple(build_deadband(cfg, dim, period_ns, message_bytes(dim * cfg.floats_per_axis)))  # type: ignore[return-value]
    if c.kind == "hli":
        return build_hli_codec(c.settings(**hli_gilbert(d)), period_ns, dim)
    if c.kind == "prediction":
        return build_prediction(c.settings(), period_ns, size_of=message_bytes)
    if c.kind == "fec":
        return build_fec(c.settings(), period_ns, size_of=message_bytes)
    if c.kind == "arq":
        return build_arq(c.settings(), period_ns, size_of=message_bytes)
    raise ValueError(f"unknown codec kind {c.kind!r}")


def build_codec_channels(
    c: Scene, period_ns: int, forward: Link, backward: Link
) -> tuple[CodecChannel | None, CodecChannel | None]:
    """The codec stage of each direction that names one (None: that direction runs as before)."""
    links = {"forward": forward, "backward": backward}
    out: dict[str, CodecChannel | None] = {}
    for name in ("forward", "backward"):
        d: ChannelDirectionConfig = getattr(c.network, name)
        if d.codec is None:
            out[name] = None
            continue
        dim = SAMPLE_FLOATS[name]
        enc, dec = _codec_pair(d, dim, period_ns)
        ack = None
        if d.codec.kind == "arq":
            rev: ChannelDirectionConfig = getattr(c.network, REVERSE[name])
            ack = build_scene_link(rev.effects, c.scene.seed, f"{name}:ack")
        out[name] = CodecChannel(name, d.codec.kind, enc, dec, links[name], dim, ack)
    return out["forward"], out["backward"]

"""Wire accounting of the codec stage, per direction, from a bag (docs/codec_channels.md, "Summary keys").

Data packets are the bag's packet records of the direction (`/<direction>/packets`: every packet
the encoder sent, retransmissions included, the network's duplicate copies left out); ARQ's
acknowledgements travel the other way and are counted from the run facts the recorder wrote
(`codec_<direction>.ack_packets`, `ack_bytes`), in the direction they travel. Bits count the
message and the per-packet headers (the scene's rate_limit.overhead_bytes, else
core/link.DEFAULT_OVERHEAD_BYTES). The reference is the same stream without a codec: one packet of
the plain JointState every tick (its size from the run facts' `codec_plain_bytes`, else one
axis': 2 values forward, 3 backward).

The keys are added to summary.json only when the scene names a codec on either direction.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from haptic_teleop.analysis.metrics import read_run_info
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES
from haptic_teleop.record.layouts import joint_state_size
from haptic_teleop.record.reader import BagReader

DIRECTIONS = ("forward", "backward")
_REVERSE = {"forward": "backward", "backward": "forward"}
# Values of the plain packet of one axis: forward (x, v), backward (f, x, v).
PLAIN_FLOATS = {"forward": 2, "backward": 3}


def codec_named(scene: dict[str, Any]) -> bool:
    net = scene.get("network") or {}
    return any(((net.get(d) or {}).get("codec") or None) is not None for d in DIRECTIONS)


def codec_wire_summary(bag: str | Path, ticks: int) -> dict[str, Any]:
    """The codec keys of summary.json for a bag whose scene names a codec ({} otherwise)."""
    with BagReader(bag) as r:
        sc = yaml.safe_load(r.string("/haptic_teleop/scene"))
        if not codec_named(sc):
            return {}
        run_info = read_run_info(r)
        T = float(sc["scene"]["period_s"])
        net = sc.get("network") or {}
        duration = ticks * T
        out: dict[str, Any] = {}
        for d in DIRECTIONS:
            rl = ((net.get(d) or {}).get("effects") or {}).get("rate_limit") or {}
            overhead = float(rl.get("overhead_bytes", DEFAULT_OVERHEAD_BYTES))
            codec = (net.get(d) or {}).get("codec") or {}
            topic = f"/{d}/packets"
            packets = 0
            message_bytes = 0.0
            if r.has(topic):
                for rows in r.packet_blocks(topic):
                    orig = rows[:, 4] == 0.0  # the network's duplicate copies were not sent by the encoder
                    packets += int(orig.sum())
                    message_bytes += math.fsum(rows[orig, 5].tolist())
            else:
                packets, message_bytes = -1, math.nan  # packet records not kept (recording.packets false)
            back = run_info.get(f"codec_{_REVERSE[d]}") or {}
            acks = int(back.get("ack_packets", 0))
            ack_bytes = float(back.get("ack_bytes", 0))
            plain = (run_info.get("codec_plain_bytes") or {}).get(d, joint_state_size(PLAIN_FLOATS[d]))
            plain_bits = ticks * 8.0 * (float(plain) + overhead)
            on_wire = packets + acks if packets >= 0 else -1
            bits = 8.0 * (message_bytes + ack_bytes + overhead * on_wire) if packets >= 0 else math.nan

            def per_s(x: float) -> float:
                return x / duration if duration > 0 else math.nan

            out.update(
                {
                    f"codec_kind_{d}": codec.get("kind", "none"),
                    f"codec_samples_{d}": ticks,
                    f"codec_packets_{d}": packets,
                    f"codec_ack_packets_{d}": acks,
                    f"codec_wire_packets_per_s_{d}": per_s(on_wire) if on_wire >= 0 else math.nan,
                    f"codec_wire_bits_per_s_{d}": per_s(bits),
                    f"codec_plain_wire_bits_per_s_{d}": per_s(plain_bits),
                    f"codec_packet_reduction_{d}": 1.0 - on_wire / ticks if ticks and on_wire >= 0 else math.nan,
                    f"codec_bit_reduction_{d}": 1.0 - bits / plain_bits if plain_bits > 0 else math.nan,
                }
            )
        return out

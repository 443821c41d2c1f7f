"""The codec experiments' runs as rosbag2 bags (docs/codec_error_control.md, "Bags").

`hli-filtering` and `error-control` simulate the object's stream in memory (studies/replications/
codec.py); each scheme's run is written to a bag of standard messages and the results table is
computed from the bags read back, so anyone can check every figure from data. The topics (table in
the docs): /experiment/facts (std_msgs/String, JSON), /server/object (the true surface every tick),
/forward/sent and /backward/sent (each packet's payload, stamped with its send time),
/forward/packets and /backward/packets (their records: seq, times, fate, size), /client/object
(the played surface and the force fed back, every tick from the first played).

The transparent force (the true object at the tick the decoder plays) and the present one (one
link delay ago) are the server's stream shifted by the facts' ticks: they are not stored twice.
"""

from __future__ import annotations

import json
import math
import re
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.core.link import Packet
from haptic_teleop.errors import BagError
from haptic_teleop.record.columns import JOINT_STATE, MULTIARRAY
from haptic_teleop.record.layouts import (
    PACKET_BATCH,
    PACKET_FIELDS,
    STRING,
    FixedLayout,
    make_joint_state,
    packet_batch_bytes,
    packet_rows,
    string_bytes,
    typestore,
)
from haptic_teleop.record.metadata import LATCHED_QOS, STREAM_QOS
from haptic_teleop.studies.replications.codec_run import PERIOD_NS, Result

JOINT = "object_surface"
FACTS = "/experiment/facts"
TOPICS: tuple[tuple[str, str], ...] = (
    (FACTS, STRING),
    ("/server/object", JOINT_STATE),
    ("/forward/sent", JOINT_STATE),
    ("/forward/packets", MULTIARRAY),
    ("/backward/sent", JOINT_STATE),
    ("/backward/packets", MULTIARRAY),
    ("/client/object", JOINT_STATE),
)
SERVER = FixedLayout(JOINT_STATE, make_joint_state(JOINT, ("position",)), 1)
CLIENT = FixedLayout(JOINT_STATE, make_joint_state(JOINT, ("position", "effort")), 2)


def slug(label: str) -> str:
    """A scheme's label in lower-case words, for its bag's name."""
    return re.sub(r"[^a-z0-9]+", "_", label.lower()).strip("_") or "scheme"


@lru_cache(maxsize=16)
def _payload_layout(n: int) -> FixedLayout:
    """A sent packet's JointState: n values as positions, joints `value_0` to `value_<n-1>`."""
    return FixedLayout(JOINT_STATE, make_joint_state([f"value_{i}" for i in range(n)], ("position",)), n)


def _sent(packets: list[Packet]) -> list[bytes]:
    """Each packet's payload as one JointState stamped with its send time (encoded a length at a time)."""
    out: list[bytes] = [b""] * len(packets)
    by_length: dict[int, list[int]] = {}
    for k, p in enumerate(packets):
        by_length.setdefault(len(p.payload), []).append(k)
    for n, which in by_length.items():
        values = np.array([packets[k].payload for k in which], dtype=np.float64).reshape(len(which), n)
        stamps = np.array([packets[k].send_time_ns for k in which], dtype=np.int64)
        for k, row in zip(which, _payload_layout(n).encode(values, stamps), strict=True):
            out[k] = row.tobytes()
    return out


def _packet_streams(direction: str, packets: list[Packet], end_ns: int) -> list[Any]:
    from haptic_teleop.record.streams import Stream

    if not packets:
        return []
    send = np.array([p.send_time_ns for p in packets], dtype=np.int64)
    rows = packet_rows(packets)
    starts = range(0, rows.shape[0], PACKET_BATCH)
    return [
        Stream(f"/{direction}/sent", JOINT_STATE, send, blobs=_sent(packets)),
        Stream(
            f"/{direction}/packets",
            MULTIARRAY,
            np.full(len(starts), end_ns, dtype=np.int64),
            blobs=[packet_batch_bytes(rows[s : s + PACKET_BATCH]) for s in starts],
        ),
    ]


def write_bag(bag: Path, r: Result, experiment: str, args: dict[str, Any], compression: str = "zstd") -> None:
    """The run `r` as a rosbag2 directory `bag` (MCAP), closed when this returns."""
    from haptic_teleop.record.mcap import BagSink
    from haptic_teleop.record.streams import Stream

    ticks = np.arange(r.t_s.size, dtype=np.int64) * PERIOD_NS
    end_ns = int(ticks[-1]) if ticks.size else 0
    facts = {
        "experiment": experiment,
        "scheme": r.label,
        "period_ns": PERIOD_NS,
        "stiffness_n_per_m": r.stiffness_n_per_m,
        "latency_ticks": r.latency_ticks,
        "link_delay_ticks": r.link_delay_ticks,
        "arguments": args,
    }
    played = np.isfinite(r.played_m)
    first = int(np.argmax(played)) if played.any() else r.t_s.size
    client = np.column_stack((r.played_m[first:], r.force_n[first:]))
    streams = [
        Stream(FACTS, STRING, np.zeros(1, dtype=np.int64), blobs=[string_bytes(json.dumps(facts, sort_keys=True))]),
        Stream("/server/object", JOINT_STATE, ticks, rows=SERVER.encode(r.object_m.reshape(-1, 1), ticks)),
        *_packet_streams("forward", r.forward, end_ns),
        *_packet_streams("backward", r.reverse, end_ns),
        Stream("/client/object", JOINT_STATE, ticks[first:], rows=CLIENT.encode(client, ticks[first:])),
    ]
    sink = BagSink(bag, TOPICS, compression, qos={FACTS: LATCHED_QOS, "/client/object": STREAM_QOS})
    try:
        sink.write(streams)
    finally:
        sink.close()


def _packets(reader: Any, direction: str) -> list[Packet]:
    """The packets of one direction in the order they were sent: records and payloads paired."""
    topic = f"/{direction}/packets"
    if not reader.has(topic) or not reader.has(f"/{direction}/sent"):
        return []
    ts = typestore()
    payloads = [
        tuple(float(v) for v in ts.deserialize_cdr(raw, JOINT_STATE).position)
        for _, raw in reader.messages(f"/{direction}/sent")
    ]
    batches = list(reader.packet_blocks(topic))  # in the bag's order: the order sent
    rows = np.concatenate(batches) if batches else np.zeros((0, len(PACKET_FIELDS)))
    if rows.shape[0] != len(payloads):
        raise BagError(f"{reader.path}: {len(rows)} packet records against {len(payloads)} {direction} messages")
    out = []
    for rec, msg in zip(rows.tolist(), payloads, strict=True):
        arrival = 0 if math.isnan(rec[2]) else round(rec[2] * 1e9)
        out.append(
            Packet(
                int(rec[0]),
                round(rec[1] * 1e9),
                msg,
                int(rec[5]),
                arrival,
                int(rec[3]),
                bool(rec[4]),
            )
        )
    return out


def read_bag(bag: Path) -> tuple[Result, dict[str, Any]]:
    """The run and its facts, from the bag alone."""
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as reader:
        facts = json.loads(reader.string(FACTS))
        period = int(facts["period_ns"])
        log, obj, _ = reader.fixed("/server/object", SERVER)
        t_s = (log // period) * (period * 1e-9)  # as simulate: tick index times the period in s
        played = np.full(log.size, math.nan)
        clog, client, _ = reader.fixed("/client/object", CLIENT)
        played[clog // period] = client[:, 0]
        result = Result(
            str(facts["scheme"]),
            t_s,
            obj[:, 0],
            played,
            float(facts["stiffness_n_per_m"]),
            int(facts["latency_ticks"]),
            int(facts["link_delay_ticks"]),
            _packets(reader, "forward"),
            _packets(reader, "backward"),
        )
    return result, facts

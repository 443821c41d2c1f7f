"""What happened to the packets of one direction, from the bag's packet records alone.

Inputs are the rows of `/forward/packets` or `/backward/packets` (columns per
`haptic_teleop.record.layouts.PACKET_FIELDS`: seq, send_time_s, arrival_time_s, fate, duplicate, size_bytes),
the samples the playout buffer released (`/<direction>/received`: the sequence number of each and
its release time), and the scene recorded in the bag. Fate codes are those of
`haptic_teleop.core.link` (docs/network.md, "Fates").
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from haptic_teleop.core.link import LOST_CORRUPT, LOST_LATE, LOST_NETWORK, LOST_QUEUE

SEQ, SEND, ARRIVAL, FATE, DUPLICATE, SIZE = range(6)

_LOSS_MODEL_KIND = {
    "bernoulli": "random loss",
    "gilbert": "burst loss",
    "gilbert_elliott": "burst loss",
    "four_state": "burst loss",
    "trace": "loss trace",
}


def loss_causes(rows: np.ndarray, effects: Mapping[str, Any] | None) -> dict[str, np.ndarray]:
    """Lost original packets by cause: {label: send times (s)}, causes with no loss left out.

    Fate `network` is split with the scene's effects of this direction (`network.<dir>.effects`):
    a packet sent inside a blackout window ([start, end), compared in integer ns as the link
    does) was lost to the blackout, which comes first in the effects' order; any other to the loss
    model (`random loss (bernoulli)`, `burst loss (gilbert_elliott)`, ...). Fates `queue_overflow`
    and `corruption` are their own causes. Duplicate copies are left out, as in the loss counts
    of summary.json. Late packets are not lost on the network: see `skip_times`.
    """
    eff = effects or {}
    orig = rows[rows[:, DUPLICATE] == 0.0] if rows.size else np.zeros((0, 6))
    fate = orig[:, FATE]
    send = orig[:, SEND]
    net = fate == LOST_NETWORK
    in_blackout = np.zeros(send.size, dtype=bool)
    bo = eff.get("blackout")
    if bo:
        send_ns = np.round(send * 1e9).astype(np.int64)
        for a, b in zip(bo["starts_s"], bo["ends_s"], strict=True):
            in_blackout |= (send_ns >= round(float(a) * 1e9)) & (send_ns < round(float(b) * 1e9))
    loss = eff.get("loss")
    if loss:
        model = str(loss.get("model", "bernoulli"))
        model_label = f"{_LOSS_MODEL_KIND.get(model, 'loss')} ({model})"
    else:
        model_label = "network"
    out = {
        "blackout": send[net & in_blackout],
        model_label: send[net & ~in_blackout],
        "queue overflow (rate limit)": send[fate == LOST_QUEUE],
        "corruption": send[fate == LOST_CORRUPT],
    }
    return {k: v for k, v in out.items() if v.size}


def first_arrivals(rows: np.ndarray, end_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(seq, arrival_s) of the first copy of each sequence number to arrive by `end_s`, by seq.

    Later copies of a sequence number (duplicates) are dropped by the buffer on arrival, so they
    never occupy it.
    """
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0)
    arr = rows[:, ARRIVAL]
    got = rows[~np.isnan(arr) & (arr <= end_s)]
    order = np.lexsort((got[:, ARRIVAL], got[:, SEQ]))  # by seq, then arrival
    got = got[order]
    seq = got[:, SEQ].astype(np.int64)
    keep = np.ones(seq.size, dtype=bool)
    keep[1:] = seq[1:] != seq[:-1]
    return seq[keep], got[keep, ARRIVAL]


def buffer_exits(seq: np.ndarray, arrival_s: np.ndarray, played_seq: np.ndarray, release_s: np.ndarray) -> np.ndarray:
    """When each arrived packet (seq, arrival_s) left the playout buffer (inf: still in it at the end).

    Every policy releases samples in increasing sequence order (a made-up sample of
    `gap: extrapolate` stands for its slot), and a buffer drops a packet once a sample with the
    same or a newer sequence number has been released: played if it is that packet, skipped
    (fate late) if newer. So a packet leaves at the first release, at or after its arrival, of a
    sequence number >= its own; if such a release came before it arrived, it leaves on arrival.
    With policy `none` a waiting packet is skipped the moment a newer one arrives, which is
    within the same tick as this release; at tick resolution the two agree.
    """
    if played_seq.size == 0:
        return np.full(seq.size, np.inf)
    reached = np.maximum.accumulate(played_seq.astype(np.int64))
    j = np.searchsorted(reached, seq, side="left")
    rel = np.concatenate([release_s, [np.inf]])[j]
    exits: np.ndarray = np.maximum(arrival_s, rel)
    return exits


def buffer_occupancy(rows: np.ndarray, played_seq: np.ndarray, release_s: np.ndarray, t_s: np.ndarray) -> np.ndarray:
    """Packets held by the playout buffer just after each tick t in `t_s` (integers).

    occupancy(t) = #(first arrivals with arrival <= t) - #(those with exit <= t), exits from
    `buffer_exits`: a packet counts from its arrival until it is released or skipped. Duplicates,
    lost packets and packets still in flight at t do not count.
    """
    end = float(t_s[-1]) if t_s.size else 0.0
    seq, arr = first_arrivals(rows, end)
    exits = np.sort(buffer_exits(seq, arr, played_seq, release_s))
    arrived = np.searchsorted(np.sort(arr), t_s, side="right")
    left = np.searchsorted(exits, t_s, side="right")
    return (arrived - left).astype(np.int64)


def skip_times(rows: np.ndarray, played_seq: np.ndarray, release_s: np.ndarray) -> np.ndarray:
    """When each late packet (fate `late`: arrived, never played) was skipped, sorted (s).

    The buffer_exits time of the packet's first arrival (see there).
    """
    if rows.size == 0:
        return np.zeros(0)
    late = rows[rows[:, FATE] == LOST_LATE]
    exits = buffer_exits(late[:, SEQ].astype(np.int64), late[:, ARRIVAL], played_seq, release_s)
    return np.sort(exits[np.isfinite(exits)])

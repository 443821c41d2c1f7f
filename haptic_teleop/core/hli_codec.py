"""Seed 000's priority-based filtering as a codec (docs/codec_hli.md; interface: the codec stage).

Sender (`HliEncoder`): classifies each sample against the receiver's track it mirrors (see
`core/hli.classify`), never sends HLI0, always sends HLI2, and sends the N_HLI1 HLI1 followers of
an HLI2 event unless an allowed bandwidth is set and sending would push the rate over it: then it
filters those of the followers that the filtering pattern (sequential: the first j*, alternate:
the 1st, 3rd, ... up to j* of them) allows, j* the largest j with P_N,j <= P_allowable.

Payload: (x..., class, offset, previous x...[, copy...]): the sample, its class code (2.0 or 1.0),
the offset m of an HLI1 event from its HLI2 event (0 for HLI2), the true sample before it (so the
receiver's prediction takes the true slope), and in an HLI1 packet a copy of the HLI2 event's
sample, so that any one received follower rebuilds a lost HLI2 event exactly.

Receiver (`HliDecoder`): runs N_HLI1 ticks behind its newest possible packet, so that the HLI1
followers of a tick's HLI2 event (in the worst case only the N_HLI1-th, seed slide 48) are in
before the tick is played. A tick's sample is the received sample, else the rebuilt HLI2 sample,
else the prediction (the sender's predictor) from the two samples played before it.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from haptic_teleop.core.hli import (
    CLOCKS,
    DEFAULT_ALPHA,
    DEFAULT_THRESHOLD_M,
    FILTERINGS,
    HLI0,
    HLI1,
    HLI2,
    PREDICTORS,
    GilbertChannel,
    filter_count,
    n_hli1,
    p_all_lost_filtered,
    sent_slots,
)
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES, Packet

KIND = "hli"  # the scene's `codec: {kind: hli, ...}`
_P = {"min": 0.0, "max": 1.0}


@dataclass(frozen=True)
class HliConfig:
    """Priority-based filtering of one stream (seed 000). The Gilbert parameters are the scene's
    loss model's (core/loss.py names); the wiring fills them in from the scene when unset."""

    threshold_m: float = field(
        default=DEFAULT_THRESHOLD_M,
        metadata={"gt": 0.0, "max": 1e3, "help": "TH_HLI in the stream's unit (0.4 mm for positions)"},
    )
    predictor: str = field(default="linear", metadata={"choices": PREDICTORS, "help": "x_pred from the last two"})
    alpha: float = field(
        default=DEFAULT_ALPHA, metadata={"gt": 0.0, "lt": 1.0, "help": "N_HLI1: smallest i with P_i < alpha"}
    )
    p: float | None = field(default=None, metadata={**_P, "help": "Gilbert P(good -> bad) per step"})
    r: float | None = field(default=None, metadata={**_P, "help": "Gilbert P(bad -> good) per step"})
    one_minus_h: float = field(default=1.0, metadata={**_P, "help": "loss probability in the bad state"})
    one_minus_k: float = field(default=0.0, metadata={**_P, "help": "loss probability in the good state"})
    clock: str = field(
        default="slot", metadata={"choices": CLOCKS, "help": "the Gilbert chain moves per time slot or per sent packet"}
    )
    filtering: str = field(default="sequential", metadata={"choices": FILTERINGS, "help": "which HLI1 events to drop"})
    allowed_bandwidth_bps: float | None = field(
        default=None, metadata={"gt": 0.0, "max": 1e12, "help": "wire bits/s incl. headers (unset: no HLI1 filtering)"}
    )
    p_allowable: float = field(
        default=1e-3, metadata={"gt": 0.0, "lt": 1.0, "help": "P_N,j may rise to this when HLI1 events are filtered"}
    )
    rate_window_s: float = field(
        default=0.1, metadata={"gt": 0.0, "max": 60.0, "help": "the sent rate is measured over this window"}
    )
    max_n_hli1: int = field(default=200, metadata={"min": 0, "max": 100_000, "help": "refuse channels needing more"})

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_field(f.name, getattr(self, f.name), f.metadata)
        if self.p_allowable < self.alpha:
            raise ValueError(
                f"codec hli: p_allowable ({self.p_allowable}) must be >= alpha ({self.alpha}): "
                "filtering can only raise P_N,j above P_N"
            )

    def channel(self) -> GilbertChannel:
        if self.p is None or self.r is None:
            raise ValueError("codec hli needs the Gilbert loss parameters p and r (set them, or name a gilbert loss)")
        return GilbertChannel(self.p, self.r, self.one_minus_h, self.one_minus_k)


def _check_field(name: str, value: object, m: Mapping[str, Any]) -> None:
    if value is None:
        return
    choices = m.get("choices")
    if choices is not None and value not in choices:
        raise ValueError(f"codec hli: {name} must be one of {', '.join(choices)}, got {value!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return
    if not math.isfinite(value):
        raise ValueError(f"codec hli: {name} must be finite, got {value}")
    lo, hi, gt, lt = m.get("min"), m.get("max"), m.get("gt"), m.get("lt")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ValueError(f"codec hli: {name} must be in [{lo}, {hi}], got {value}")
    if (gt is not None and not value > gt) or (lt is not None and not value < lt):
        raise ValueError(f"codec hli: {name} must be > {gt} and < {lt}, got {value}")


def joint_state_bytes(values_per_name: int, names: int) -> int:
    """CDR size of a sensor_msgs/JointState with `names` 8-character names and `values_per_name`
    of its position/velocity/effort filled (the rest empty): 48 + 12 f + (names - 1)(16 + 8 f).
    Equal to record/layouts.joint_state_size(f, names) for names <= 3 (tested); core cannot import it."""
    if not (1 <= values_per_name <= 3 and names >= 1):
        raise ValueError(f"a JointState has 1 to 3 value fields and >= 1 name, got {values_per_name}, {names}")
    return 48 + 12 * values_per_name + (names - 1) * (16 + 8 * values_per_name)


def hli_message_bytes(dim: int, cls: int) -> int:
    """Wire message of an HLI packet: a JointState with the stream's `dim` axes and one more name
    ("hli"); position = (x..., class), velocity = (previous sample..., offset), and in HLI1
    packets effort = (copy of the HLI2 sample..., 0)."""
    return joint_state_bytes(3 if cls == HLI1 else 2, dim + 1)


def linear1(a: float, b: float) -> float:
    """The linear predictor of one value: a at n-1, b at n-2, to n (the compiled loop compiles it,
    engine/compiled/codec_kernel.py)."""
    return 2.0 * a - b


def _pred(t1: tuple[float, ...] | None, t2: tuple[float, ...] | None, linear: bool) -> tuple[float, ...] | None:
    if t1 is None:
        return None
    if not linear or t2 is None:
        return t1
    return tuple(linear1(a, b) for a, b in zip(t1, t2, strict=True))


def _norm(a: tuple[float, ...], b: tuple[float, ...]) -> float:
    return math.sqrt(sum((x - y) * (x - y) for x, y in zip(a, b, strict=True)))


class HliEncoder:
    """The sender: classify, filter, packetize. One object per stream direction."""

    def __init__(self, cfg: HliConfig, period_ns: int, dim: int) -> None:
        if not period_ns > 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        ch = cfg.channel()
        self.cfg = cfg
        self.dim = dim
        self.period_ns = period_ns
        self.n_hli1 = n_hli1(ch, cfg.alpha, cfg.max_n_hli1)
        if cfg.allowed_bandwidth_bps is None:
            self.j_max = 0
        else:
            self.j_max = filter_count(ch, self.n_hli1, cfg.p_allowable, cfg.filtering, cfg.clock)
        self.p_n = p_all_lost_filtered(ch, self.n_hli1, 0, cfg.filtering, cfg.clock)
        self.p_n_j = p_all_lost_filtered(ch, self.n_hli1, self.j_max, cfg.filtering, cfg.clock)
        kept = set(sent_slots(self.n_hli1, self.j_max, cfg.filtering))
        self._may_filter = frozenset(k for k in range(1, self.n_hli1 + 1) if k not in kept)
        # followers after position k that are sent whatever the rate (not in the pattern)
        self._fixed_after = [sum(1 for q in range(k + 1, self.n_hli1 + 1) if q in kept) for k in range(self.n_hli1 + 1)]
        self._linear = cfg.predictor == "linear"
        self._warmup = 2 if self._linear else 1
        self._t1: tuple[float, ...] | None = None  # mirrored receiver track at n-1
        self._t2: tuple[float, ...] | None = None  # ... at n-2
        self._seen = 0
        self._since = self.n_hli1 + 1  # ticks since the last HLI2 event
        self._hli2_sample: tuple[float, ...] = ()
        self._prev: tuple[float, ...] | None = None  # the true sample at n-1
        self._window_ticks = max(1, round(cfg.rate_window_s * 1e9 / period_ns))
        bw = cfg.allowed_bandwidth_bps
        self._budget_bits = math.inf if bw is None else bw * self._window_ticks * period_ns * 1e-9
        self._window: deque[tuple[int, int]] = deque()  # (tick, wire bits) of sent packets
        self._window_bits = 0
        self.last_class = HLI0
        self.counters: dict[str, int] = {
            "samples": 0,
            "sent": 0,
            "hli0": 0,
            "hli1": 0,
            "hli2": 0,
            "filtered_hli0": 0,
            "filtered_hli1": 0,
            "wire_bits": 0,
            "over_budget": 0,
        }

    def _packet_bits(self, cls: int) -> int:
        return 8 * (DEFAULT_OVERHEAD_BYTES + hli_message_bytes(self.dim, cls))

    def send(self, n: int, now_ns: int, sample: tuple[float, ...]) -> list[Packet]:
        if len(sample) != self.dim:
            raise ValueError(f"codec hli: sample has {len(sample)} values, the stream has {self.dim}")
        c = self.counters
        c["samples"] += 1
        while self._window and self._window[0][0] <= n - self._window_ticks:
            self._window_bits -= self._window.popleft()[1]
        pred = _pred(self._t1, self._t2, self._linear)
        self._since += 1
        if self._seen < self._warmup or pred is None or _norm(sample, pred) >= self.cfg.threshold_m:
            cls = HLI2
            self._since = 0
            self._hli2_sample = sample
        elif self._since <= self.n_hli1:
            cls = HLI1
        else:
            cls = HLI0
        self._seen += 1
        self.last_class = cls
        c[("hli0", "hli1", "hli2")[cls]] += 1
        send = cls != HLI0
        if cls == HLI1 and self._since in self._may_filter:
            # filter it if sending it and the followers that cannot be filtered would overrun the
            # budget of the current window (nothing assumed to leave the window meanwhile)
            need = self._packet_bits(HLI1) * (1 + self._fixed_after[self._since])
            if self._window_bits + need > self._budget_bits:
                send = False
                c["filtered_hli1"] += 1
        elif cls == HLI0:
            c["filtered_hli0"] += 1
        prev = sample if self._prev is None else self._prev
        self._prev = sample
        if send or pred is None:  # a sent sample re-anchors the track with the true slope
            self._t2, self._t1 = prev, sample
        else:
            self._t2, self._t1 = self._t1, pred
        if not send:
            return []
        if cls == HLI2:
            payload = (*sample, float(HLI2), 0.0, *prev)
        else:
            payload = (*sample, float(HLI1), float(self._since), *prev, *self._hli2_sample)
        size = hli_message_bytes(self.dim, cls)
        bits = 8 * (DEFAULT_OVERHEAD_BYTES + size)
        self._window.append((n, bits))
        self._window_bits += bits
        c["sent"] += 1
        c["wire_bits"] += bits
        if self._window_bits > self._budget_bits:
            c["over_budget"] += 1
        return [Packet(seq=n, send_time_ns=now_ns, payload=payload, size_bytes=size)]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path."""


class HliDecoder:
    """The receiver: hold packets N_HLI1 ticks, rebuild lost HLI2 events, predict the rest."""

    def __init__(self, cfg: HliConfig, dim: int, n_followers: int | None = None) -> None:
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        self.dim = dim
        self.delay_ticks = n_hli1(cfg.channel(), cfg.alpha, cfg.max_n_hli1) if n_followers is None else n_followers
        if self.delay_ticks < 0:
            raise ValueError(f"n_followers must be >= 0, got {n_followers}")
        self._linear = cfg.predictor == "linear"
        self._received: dict[int, tuple[tuple[float, ...], tuple[float, ...]]] = {}  # (x, previous x)
        self._rebuilt: dict[int, tuple[float, ...]] = {}
        self._fresh: list[int] = []  # seqs received since the last sample() call
        self._lag: int | None = None  # smallest (tick - seq) seen: the link's delay in ticks
        self._cursor: int | None = None  # the last tick played
        self._t1: tuple[float, ...] | None = None
        self._t2: tuple[float, ...] | None = None
        self.counters: dict[str, int] = {"received": 0, "rebuilt": 0, "predicted": 0, "played_received": 0, "late": 0}

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        d = self.dim
        pl = packet.payload
        if len(pl) < 2 * d + 2:
            raise ValueError(f"codec hli: payload of {len(pl)} values, need at least {2 * d + 2}")
        seq = packet.seq
        self.counters["received"] += 1
        if self._cursor is not None and seq <= self._cursor:
            self.counters["late"] += 1
            return []
        self._received[seq] = (tuple(pl[:d]), tuple(pl[d + 2 : 2 * d + 2]))
        if round(pl[d]) == HLI1:
            m = round(pl[d + 1])
            if len(pl) < 3 * d + 2:
                raise ValueError(f"codec hli: HLI1 payload of {len(pl)} values, need {3 * d + 2}")
            if self._cursor is None or seq - m > self._cursor:
                self._rebuilt.setdefault(seq - m, tuple(pl[2 * d + 2 : 3 * d + 2]))
        self._fresh.append(seq)
        return []

    def _play(self, t: int) -> tuple[float, ...] | None:
        got = self._received.pop(t, None)
        rb = self._rebuilt.pop(t, None)
        if got is not None:
            self.counters["played_received"] += 1
            x, prev = got
            self._t2, self._t1 = prev, x  # the true slope, as the sender's mirror has it
            return x
        if rb is not None:
            self.counters["rebuilt"] += 1
            x = rb
        else:
            pred = _pred(self._t1, self._t2, self._linear)
            if pred is None:
                return None
            self.counters["predicted"] += 1
            x = pred
        self._t2, self._t1 = self._t1, x
        return x

    def sample(self, n: int, now_ns: int) -> tuple[float, ...] | None:
        """The sample for tick n: that of tick n - lag - N_HLI1 (lag = the link's smallest delay in
        ticks, learnt from the packets: tick received - seq)."""
        for s in self._fresh:
            lag = n - s
            if self._lag is None or lag < self._lag:
                self._lag = lag
        self._fresh.clear()
        if self._lag is None:
            return None
        target = n - self._lag - self.delay_ticks
        if self._cursor is None:
            first = min(self._received, default=target)
            self._cursor = min(first, target + 1) - 1
        while self._cursor < target:
            self._cursor += 1
            self._play(self._cursor)
        return self._t1


def build_hli_codec(cfg: HliConfig, period_ns: int, dim: int) -> tuple[HliEncoder, HliDecoder]:
    """The sender and receiver of one stream direction (`codec: {kind: hli, ...}`)."""
    enc = HliEncoder(cfg, period_ns, dim)
    return enc, HliDecoder(cfg, dim, enc.n_hli1)

"""Prediction-based filtering with an error control layer behind it: seed 000's error-control
experiment (docs/codec_error_control.md, "Seed 000's experiment"; interface: the codec stage).

Seed 000 (slide 42, Kanbara04, Clarke08): the sender transmits a sample (an *event*) only when the
receiver's prediction would miss it by at least a threshold; such filtering "makes the haptic
application very sensitive to packet losses" and "should be used together with an error control
scheme". Here the filter's events, and only they, go through one of:

- `none`: each event in one packet, nothing else.
- `fec`: each event's packet also carries copies of the previous k *events* (each with its own
  seq: events are not consecutive ticks), so a lost event comes back with the next event that
  arrives.
- `arq`: positive ACKs over the reverse link; an event not acknowledged mu after its last
  transmission is retransmitted, at most nu times, then given up. `send` is called every tick, with
  or without a new event, and is where the timeouts are checked.

Sender (`EventEncoder`): the filter is the HLI encoder's (core/hli_codec.py) with no HLI1
followers: it predicts (linear: x_pred(n) = 2 x(n-1) - x(n-2) on the receiver's track, or hold)
from the track it mirrors, sends when |x(n) - x_pred(n)| >= threshold (and the first two samples
of a linear predictor, one of hold), and every event carries the true sample before it, so that a
received event sets the receiver's track to (x(n-1), x(n)), the true slope. A filtered sample
leaves the mirrored track on the prediction.

Payload (d = floats per sample), the sample first:
- `none`: (x..., x(n-1)...)                                     2 d floats
- `fec`:  (x..., x(n-1)..., then k times, newest first: offset, x_e..., x_e(n-1)...)
          with offset = n - seq of that earlier event (0 = no such event yet: the slot repeats
          the current event and the receiver skips it; the size stays fixed)   2 d + k (1 + 2 d)
- `arq`:  (x..., x(n-1)..., attempt)  attempt 0 = original, 1..nu = retransmission      2 d + 1
- ACK (arq, reverse link): (seq,), `Packet.seq` the acknowledged event.                  1
Size: `size_of(floats)` (default: a std_msgs/Float64MultiArray, 20 + 8 floats bytes).

Receiver (`EventDecoder`): plays tick n - lag - wait_ticks (lag = the link's smallest delay in
ticks, learnt from the original packets; wait_ticks 0 by default). Each tick plays the event of
that tick if it has arrived (and sets the track to (x(n-1), x(n)) as the sender's mirror has it),
else the prediction from the two values played before. An event that arrives for a tick already
played (an FEC copy of a lost event, a retransmission, a delayed original) is not dropped: if it
is newer than the event the current track starts from (its `base`), the receiver RE-BASES: it sets
the track to that event's (x(n-1), x(n)) and runs the predictor forward from the event's tick to
the last played tick, so that the next tick plays what the sender's mirror predicted after that
event (exactly, if no other event was lost after it). Nothing already played is changed. An event
no newer than the base is stale (the track already starts from a later event) and only counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from haptic_teleop.core.hli import DEFAULT_THRESHOLD_M, PREDICTORS
from haptic_teleop.core.hli_codec import _norm, _pred
from haptic_teleop.core.link import Packet
from haptic_teleop.core.prediction import Sample, SizeOf, check_fields, float64_multiarray_size

KIND = "event"  # the scene's `codec: {kind: event, ...}`
ERROR_CONTROLS = ("none", "fec", "arq")
# The receiver remembers the newest _DONE_KEEP to 2 _DONE_KEEP events it has played or seen late
# (to tell duplicates); a copy or retransmission of an older one counts as late and stale.
_DONE_KEEP = 4096


@dataclass(frozen=True)
class EventCodecConfig:
    """Codec `event`: prediction-based filtering, its events protected by FEC, ARQ or nothing."""

    threshold_m: float = field(
        default=DEFAULT_THRESHOLD_M,
        metadata={"gt": 0.0, "max": 1e3, "help": "send when the receiver's prediction misses by this much"},
    )
    predictor: str = field(default="linear", metadata={"choices": PREDICTORS, "help": "x_pred from the last two"})
    error_control: str = field(default="none", metadata={"choices": ERROR_CONTROLS, "help": "what protects the events"})
    fec_k: int = field(default=1, metadata={"min": 1, "max": 64, "help": "fec: previous events each packet copies"})
    timeout_s: float = field(
        default=0.025, metadata={"gt": 0.0, "max": 10.0, "help": "arq: mu, retransmit an event not acknowledged"}
    )
    max_retransmissions: int = field(
        default=4, metadata={"min": 0, "max": 100, "help": "arq: nu, retransmissions per event, then give it up"}
    )
    wait_ticks: int = field(
        default=0, metadata={"min": 0, "max": 10000, "help": "the receiver plays this many ticks later"}
    )

    def __post_init__(self) -> None:
        check_fields(self)


def payload_floats(cfg: EventCodecConfig, dim: int) -> int:
    """Floats in an event packet's payload for a sample of `dim` floats."""
    if cfg.error_control == "fec":
        return 2 * dim + cfg.fec_k * (1 + 2 * dim)
    if cfg.error_control == "arq":
        return 2 * dim + 1
    return 2 * dim


class EventEncoder:
    """The sender: filter by prediction, protect the events (module docstring).

    Counters: `samples`, `events`, `filtered`, `sent` (data packets, retransmissions included),
    `retransmitted`, `acked`, `acks_stale`, `gave_up`, `bytes`.
    """

    def __init__(self, cfg: EventCodecConfig, period_ns: int, dim: int, size_of: SizeOf = float64_multiarray_size):
        if not period_ns > 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        self.cfg, self.dim = cfg, dim
        self._linear = cfg.predictor == "linear"
        self._warmup = 2 if self._linear else 1
        self._seen = 0
        self._t1: Sample | None = None  # the mirrored receiver track at n-1
        self._t2: Sample | None = None  # ... at n-2
        self._prev: Sample | None = None  # the true sample at n-1
        self._fec: list[tuple[int, Sample, Sample]] = []  # the last k events (seq, x, x(n-1)), newest first
        self._timeout_ns = round(cfg.timeout_s * 1e9)
        # arq: seq -> (x, x(n-1), retransmissions so far, time of the last transmission)
        self._pending: dict[int, tuple[Sample, Sample, int, int]] = {}
        self._size = size_of(payload_floats(cfg, dim))
        self.counters: dict[str, int] = {
            "samples": 0,
            "events": 0,
            "filtered": 0,
            "sent": 0,
            "retransmitted": 0,
            "acked": 0,
            "acks_stale": 0,
            "gave_up": 0,
            "bytes": 0,
        }

    @property
    def pending(self) -> int:
        """Events awaiting an ACK (arq)."""
        return len(self._pending)

    def _packet(self, seq: int, now_ns: int, payload: tuple[float, ...]) -> Packet:
        self.counters["sent"] += 1
        self.counters["bytes"] += self._size
        return Packet(seq, now_ns, payload, self._size)

    def _is_event(self, x: Sample, prev: Sample) -> bool:
        """Classify x against the mirrored track and move the track (sent: re-anchored on the true
        slope; filtered: left on the prediction)."""
        pred = _pred(self._t1, self._t2, self._linear)
        event = self._seen < self._warmup or pred is None or _norm(x, pred) >= self.cfg.threshold_m
        self._seen += 1
        if event or pred is None:
            self._t2, self._t1 = prev, x
        else:
            self._t2, self._t1 = self._t1, pred
        return event

    def send(self, n: int, now_ns: int, sample: Sample) -> list[Packet]:
        """The packets for tick n: the event (if x(n) is one) and due retransmissions (arq)."""
        x = tuple(float(v) for v in sample)
        if len(x) != self.dim:
            raise ValueError(f"codec event: sample has {len(x)} values, the stream has {self.dim}")
        c = self.counters
        c["samples"] += 1
        prev = x if self._prev is None else self._prev
        event = self._is_event(x, prev)
        self._prev = x
        out: list[Packet] = []
        ec = self.cfg.error_control
        if event:
            c["events"] += 1
            if ec == "fec":
                copies: list[float] = []
                for i in range(self.cfg.fec_k):
                    if i < len(self._fec):
                        s, xe, pe = self._fec[i]
                        copies += [float(n - s), *xe, *pe]
                    else:
                        copies += [0.0, *x, *prev]
                out.append(self._packet(n, now_ns, (*x, *prev, *copies)))
                self._fec.insert(0, (n, x, prev))
                del self._fec[self.cfg.fec_k :]
            elif ec == "arq":
                out.append(self._packet(n, now_ns, (*x, *prev, 0.0)))
            else:
                out.append(self._packet(n, now_ns, (*x, *prev)))
        else:
            c["filtered"] += 1
        if ec == "arq":
            for seq, (xe, pe, tries, last_ns) in list(self._pending.items()):
                if now_ns - last_ns < self._timeout_ns:
                    continue
                if tries >= self.cfg.max_retransmissions:
                    del self._pending[seq]
                    c["gave_up"] += 1
                    continue
                self._pending[seq] = (xe, pe, tries + 1, now_ns)
                c["retransmitted"] += 1
                out.append(self._packet(seq, now_ns, (*xe, *pe, float(tries + 1))))
            if event:
                self._pending[n] = (x, prev, 0, now_ns)
        return out

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """An ACK (arq): `packet.seq` is the acknowledged event."""
        if self._pending.pop(packet.seq, None) is None:
            self.counters["acks_stale"] += 1
        else:
            self.counters["acked"] += 1


class EventDecoder:
    """The receiver: predicts between events, re-bases on late ones (module docstring).

    Counters: `received` packets, `duplicates` (an event already held or played), `played_event`
    (ticks played from an event that came in time), `predicted`, `recovered` (events first
    obtained from an FEC copy or a retransmission), `late` (events that arrived after their tick
    was played), `rebased` (late events the track was re-based on), `stale` (late events no newer
    than the track's base), `acks_sent`.
    """

    def __init__(self, cfg: EventCodecConfig, dim: int, size_of: SizeOf = float64_multiarray_size) -> None:
        if dim < 1:
            raise ValueError(f"dim must be >= 1, got {dim}")
        self.cfg, self.dim = cfg, dim
        self.delay_ticks = cfg.wait_ticks
        self._linear = cfg.predictor == "linear"
        self._floats = payload_floats(cfg, dim)
        self._ack_size = size_of(1)
        self._events: dict[int, tuple[Sample, Sample]] = {}  # arrived, not yet played: seq -> (x, x(n-1))
        self._fresh: list[int] = []  # seqs of originals received since the last sample() call
        self._lag: int | None = None
        self._cursor: int | None = None  # the last tick played
        self._base: int | None = None  # the event the track starts from
        self._done: set[int] = set()  # events played or seen late (to tell duplicates)
        self._t1: Sample | None = None
        self._t2: Sample | None = None
        self.counters: dict[str, int] = {
            "received": 0,
            "duplicates": 0,
            "played_event": 0,
            "predicted": 0,
            "recovered": 0,
            "late": 0,
            "rebased": 0,
            "stale": 0,
            "acks_sent": 0,
        }

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        d, pl = self.dim, packet.payload
        if len(pl) != self._floats:
            raise ValueError(f"codec event: payload of {len(pl)} values, the layout has {self._floats}")
        c = self.counters
        c["received"] += 1
        ec = self.cfg.error_control
        carried: list[tuple[int, Sample, Sample, bool]] = []  # (seq, x, x(n-1), came by redundancy)
        if ec == "fec":
            at = 2 * d
            for _ in range(self.cfg.fec_k):
                off = round(pl[at])
                if off > 0:
                    carried.append(
                        (packet.seq - off, tuple(pl[at + 1 : at + 1 + d]), tuple(pl[at + 1 + d : at + 1 + 2 * d]), True)
                    )
                at += 1 + 2 * d
            carried.reverse()  # oldest first
        retransmitted = ec == "arq" and round(pl[2 * d]) > 0
        carried.append((packet.seq, tuple(pl[:d]), tuple(pl[d : 2 * d]), retransmitted))
        if not retransmitted:
            self._fresh.append(packet.seq)
        late: list[tuple[int, Sample, Sample]] = []
        for seq, x, prev, redundant in carried:
            if seq in self._events or seq in self._done:
                if not redundant or ec == "arq":
                    c["duplicates"] += 1  # an event already held (a copy of one is skipped silently)
                continue
            if redundant:
                c["recovered"] += 1
            if self._cursor is not None and seq <= self._cursor:
                c["late"] += 1
                late.append((seq, x, prev))
                self._done.add(seq)
            else:
                self._events[seq] = (x, prev)
        if late:
            newest = max(late, key=lambda e: e[0])
            self.counters["stale"] += len(late) - 1
            self._rebase(*newest)
        if ec == "arq":
            c["acks_sent"] += 1
            return [Packet(packet.seq, now_ns, (float(packet.seq),), self._ack_size)]
        return []

    def _rebase(self, seq: int, x: Sample, prev: Sample) -> None:
        """Start the track again from the late event `seq` and predict it forward to the cursor."""
        assert self._cursor is not None
        if self._base is not None and seq <= self._base:
            self.counters["stale"] += 1
            return
        self.counters["rebased"] += 1
        self._base = seq
        self._t2, self._t1 = prev, x
        for _ in range(seq + 1, self._cursor + 1):
            pred = _pred(self._t1, self._t2, self._linear)
            self._t2, self._t1 = self._t1, pred

    def _play(self, t: int) -> None:
        got = self._events.pop(t, None)
        if got is not None:
            self.counters["played_event"] += 1
            x, prev = got
            self._t2, self._t1 = prev, x
            self._base = t
            self._done.add(t)
            return
        pred = _pred(self._t1, self._t2, self._linear)
        if pred is None:
            return
        self.counters["predicted"] += 1
        self._t2, self._t1 = self._t1, pred

    def sample(self, n: int, now_ns: int) -> Sample | None:
        """The sample for tick n: that of tick n - lag - wait_ticks."""
        for s in self._fresh:
            if self._lag is None or n - s < self._lag:
                self._lag = n - s
        self._fresh.clear()
        if self._lag is None:
            return None
        target = n - self._lag - self.delay_ticks
        if self._cursor is None:
            first = min(self._events, default=target)
            self._cursor = min(first, target + 1) - 1
        while self._cursor < target:
            self._cursor += 1
            self._play(self._cursor)
        if len(self._done) > 2 * _DONE_KEEP:  # forget what no packet can still duplicate
            self._done = set(sorted(self._done)[-_DONE_KEEP:])
        return self._t1


def build_event_codec(
    cfg: EventCodecConfig, period_ns: int, dim: int, *, size_of: SizeOf = float64_multiarray_size
) -> tuple[EventEncoder, EventDecoder]:
    """The sender and receiver of one stream direction (`codec: {kind: event, ...}`)."""
    return EventEncoder(cfg, period_ns, dim, size_of), EventDecoder(cfg, dim, size_of)

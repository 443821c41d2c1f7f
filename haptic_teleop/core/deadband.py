"""Perceptual deadband codec (seed 001, Hinterseer & Steinbach, Sec. 3.5): send a vector sample
only when it leaves a sphere of radius p |v_i| around the last sent vector v_i.

Pure core: no I/O, no clock (time is passed in as integer ns, the tick index as `n`). One
`DeadbandEncoder` per stream on the sending side, one `DeadbandDecoder` on the receiving side,
to the interface of the codec stage (docs/codec_deadband.md, the codec section of the docs).

Rule (sender), for a stream of vectors of any length (1-D or 3-D):

    send v_c  iff  this is the first sample, or  |v_i - v_c| > max(p(v) |v_i|, min_threshold)

with v_i the last SENT sample. p(v) = p0 without the velocity-adaptive option, else our
parametrisation p(v) = min(p0 (1 + adaptive_gain |v|), max_deadband) of Kammerl et al.'s
velocity-adaptive deadband. With v_i = 0 and min_threshold = 0 the deadzone has radius 0: any
change sends. Geometry: any direction change larger than arcsin(p) sends whatever the
magnitude; at constant magnitude a direction change sends from 2 arcsin(p / 2) on (just below
arcsin(p)); both are derived in the docs.

Payload: the sample, then (reconstruction `extrapolate` with `extrapolate_from: sent_rate`) its
rate (time derivative, unit per s). Receiver: `hold` the last received sample, or `extrapolate`
linearly from the last received sample and its rate (sent, or the slope of the last two
received samples), for at most `max_extrapolation_s`, then hold the value reached.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from haptic_teleop.core import codec_layout as L
from haptic_teleop.core.link import Packet

KIND = "deadband"  # the scene's `codec: {kind: deadband, ...}`
RECONSTRUCTIONS = ("hold", "extrapolate")
RATE_SOURCES = ("sent_rate", "last_two")

_NS_PER_S = 1e9


@dataclass(frozen=True)
class DeadbandConfig:
    """One stream's perceptual deadband (sender rule and receiver reconstruction)."""

    deadband: float = field(
        default=0.1,
        metadata={"min": 0.0, "max": 1.0, "help": "p: send when |v_i - v_c| > p |v_i| (fraction, 0.05 = 5 %)"},
    )
    min_threshold: float = field(
        default=0.0,
        metadata={
            "min": 0.0,
            "max": 1e9,
            "help": "absolute floor of the deadzone radius, in the stream's unit (0: the pure rule)",
        },
    )
    adaptive_gain: float = field(
        default=0.0,
        metadata={
            "min": 0.0,
            "max": 1e6,
            "help": "velocity-adaptive: alpha in p(v) = p0 (1 + alpha |v|), per unit of |v| (0: off)",
        },
    )
    max_deadband: float = field(
        default=0.4,
        metadata={"min": 0.0, "max": 1.0, "help": "velocity-adaptive: upper clip of p(v)"},
    )
    reconstruction: str = field(
        default="hold",
        metadata={"choices": RECONSTRUCTIONS, "help": "receiver: hold the last sample or extrapolate it"},
    )
    extrapolate_from: str = field(
        default="sent_rate",
        metadata={
            "choices": RATE_SOURCES,
            "help": "extrapolate: the rate sent after the sample, or the slope of the last two received",
        },
    )
    max_extrapolation_s: float | None = field(
        default=0.1,
        metadata={
            "gt": 0.0,
            "max": 3600.0,
            "help": "extrapolate at most this long, then hold (unset: no cap)",
        },
    )

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_field(f.name, getattr(self, f.name), f.metadata)
        if self.adaptive_gain > 0.0 and self.max_deadband < self.deadband:
            raise ValueError(
                f"max_deadband ({self.max_deadband}) must be >= deadband ({self.deadband}) when adaptive_gain > 0"
            )

    @property
    def sends_rate(self) -> bool:
        """Whether the payload carries the sample's rate after the sample."""
        return self.reconstruction == "extrapolate" and self.extrapolate_from == "sent_rate"

    @property
    def floats_per_axis(self) -> int:
        """Payload values per vector component: 1 (sample) or 2 (sample, rate)."""
        return 2 if self.sends_rate else 1


def _check_field(name: str, value: object, meta: Mapping[str, Any]) -> None:
    """The schema's metadata checks, for configs built in code rather than from YAML."""
    if value is None:
        return
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ValueError(f"deadband codec: {name} must be one of {', '.join(choices)}, got {value!r}")
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        if choices is None:
            raise ValueError(f"deadband codec: {name} must be a number, got {value!r}")
        return
    if not math.isfinite(value):
        raise ValueError(f"deadband codec: {name} must be finite, got {value}")
    lo, hi, gt = meta.get("min"), meta.get("max"), meta.get("gt")
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        raise ValueError(f"deadband codec: {name} must be in [{lo}, {hi}], got {value}")
    if gt is not None and not value > gt:
        raise ValueError(f"deadband codec: {name} must be > {gt}, got {value}")


def vector_norm(v: Sequence[float]) -> float:
    """|v|: |v_0| for one value, else the square root of the squares summed in order (not
    math.hypot, whose extended-precision sum the compiled loop cannot reproduce bit for bit:
    engine/compiled/arm_codec_kernel.py sums the same squares in the same order)."""
    if len(v) == 1:
        return abs(v[0])
    s = 0.0
    for x in v:
        s += x * x
    return math.sqrt(s)


def vector_distance(a: Sequence[float], b: Sequence[float]) -> float:
    """|a - b|, as `vector_norm` (the differences a_i - b_i)."""
    if len(a) == 1:
        return abs(a[0] - b[0])
    s = 0.0
    for x, y in zip(a, b, strict=True):
        d = x - y
        s += d * d
    return math.sqrt(s)


_norm = vector_norm
_dist = vector_distance


# The per-sample formulas as scalar functions of floats: the one definition the classes below use
# and that the compiled loop compiles (engine/compiled/codec_kernel.py), as core/eba.py's scalar functions.


def deadband_p(p0: float, adaptive_gain: float, max_deadband: float, speed: float) -> float:
    """p(v) = min(p0 (1 + alpha |v|), max_deadband), the velocity-adaptive deadband (alpha > 0)."""
    return min(p0 * (1.0 + adaptive_gain * abs(speed)), max_deadband)


def outside(distance: float, norm_last: float, p: float, min_threshold: float) -> bool:
    """The deadzone test from |v_i - v_c| and |v_i|: |v_i - v_c| > max(p |v_i|, min_threshold)."""
    return distance > max(p * norm_last, min_threshold)


def extrapolated(x: float, rate_per_tick: float, ahead_ticks: float) -> float:
    """The receiver's linear extrapolation of one value `ahead_ticks` past its sample."""
    return x + rate_per_tick * ahead_ticks


def effective_deadband(cfg: DeadbandConfig, speed: float) -> float:
    """p(v): p0 without the adaptive option, else min(p0 (1 + alpha |v|), max_deadband)."""
    if cfg.adaptive_gain == 0.0:
        return cfg.deadband
    return deadband_p(cfg.deadband, cfg.adaptive_gain, cfg.max_deadband, speed)


def violates(last_sent: Sequence[float], current: Sequence[float], p: float, min_threshold: float = 0.0) -> bool:
    """The deadzone test: |v_i - v_c| > max(p |v_i|, min_threshold)."""
    return outside(_dist(last_sent, current), _norm(last_sent), p, min_threshold)


class DeadbandEncoder:
    """Sender side of one stream: decides per tick whether the sample leaves the deadzone.

    `send(n, now_ns, sample, rate=None, velocity=None)`:
    - `rate`: the sample's time derivative (a position stream's velocity), sent after the sample
      when the payload carries a rate; unset, the backward difference of the last two samples
      offered (zero for the first one).
    - `velocity`: the velocity of the velocity-adaptive threshold (a force stream: the operator's
      velocity); unset, the sample's rate is used (right for a position stream only).
    """

    kind = KIND

    def __init__(self, cfg: DeadbandConfig, dim: int, size_bytes: int) -> None:
        if dim < 1:
            raise ValueError(f"deadband codec: dim must be >= 1, got {dim}")
        if size_bytes < 0:
            raise ValueError(f"deadband codec: size_bytes must be >= 0, got {size_bytes}")
        self.cfg = cfg
        self.dim = dim
        self.size_bytes = size_bytes
        self.counters: dict[str, int] = {"offered": 0, "sent": 0, "filtered": 0}
        self.last_deadband = cfg.deadband  # p(v) of the last decision
        self._last_sent: tuple[float, ...] | None = None
        self._prev: tuple[float, ...] | None = None
        self._prev_ns = 0

    @property
    def reduction(self) -> float:
        """1 - sent / offered (0 before any sample)."""
        offered = self.counters["offered"]
        return 1.0 - self.counters["sent"] / offered if offered else 0.0

    def _rate(self, now_ns: int, sample: tuple[float, ...]) -> tuple[float, ...]:
        prev = self._prev
        if prev is None or now_ns <= self._prev_ns:
            return (0.0,) * self.dim
        dt = (now_ns - self._prev_ns) / _NS_PER_S
        return tuple((c - p) / dt for c, p in zip(sample, prev, strict=True))

    def send(
        self,
        n: int,
        now_ns: int,
        sample: tuple[float, ...],
        rate: Sequence[float] | None = None,
        velocity: Sequence[float] | None = None,
    ) -> list[Packet]:
        if len(sample) != self.dim:
            raise ValueError(f"deadband codec: sample has {len(sample)} values, the stream has {self.dim}")
        cfg = self.cfg
        need_rate = cfg.sends_rate or (cfg.adaptive_gain > 0.0 and velocity is None)
        r: tuple[float, ...] = ()
        if need_rate:
            if rate is None:
                r = self._rate(now_ns, sample)
            elif len(rate) != self.dim:
                raise ValueError(f"deadband codec: rate has {len(rate)} values, the stream has {self.dim}")
            else:
                r = tuple(float(x) for x in rate)
        self._prev, self._prev_ns = sample, now_ns
        self.counters["offered"] += 1
        last = self._last_sent
        if last is not None:
            p = cfg.deadband
            if cfg.adaptive_gain > 0.0:
                p = effective_deadband(cfg, _norm(velocity if velocity is not None else r))
            self.last_deadband = p
            if not violates(last, sample, p, cfg.min_threshold):
                self.counters["filtered"] += 1
                return []
        self._last_sent = sample
        self.counters["sent"] += 1
        payload = sample + r if cfg.sends_rate else sample
        return [Packet(seq=n, send_time_ns=now_ns, payload=payload, size_bytes=self.size_bytes)]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path: nothing to do."""


def decoder_receive(
    C: np.ndarray, S: np.ndarray, seq: int, ring: Any, j: int, last0: int, old0: int, rate0: int
) -> None:
    """The decoder takes packet `seq`, its payload in `ring[j, 2:]` (the sample, then its rate if
    the payload carries one): a packet not newer than the last one taken is counted stale and
    dropped; otherwise it becomes the last sample (the one before it the old one) and, when the
    decoder extrapolates, the rate per tick is the rate sent (times the period) or the slope of the
    last two samples. C and S: codec_layout's places (C_DIM, C_EXTRAP, C_SENDS_RATE,
    C_PERIOD_NS; S_HAS_LAST, S_LAST_SEQ, S_HAS_OLD, S_OLD_SEQ, S_HAS_RATE, S_RECEIVED, S_STALE);
    the vectors of `C_DIM` values from `last0`, `old0`, `rate0` in S (their places differ between
    layouts). One definition: `DeadbandDecoder` calls it, the compiled loops inline it."""
    dim = int(C[L.C_DIM])
    if S[L.S_HAS_LAST] != 0.0 and seq <= S[L.S_LAST_SEQ]:
        S[L.S_STALE] += 1.0
        return
    S[L.S_RECEIVED] += 1.0
    S[L.S_HAS_OLD] = S[L.S_HAS_LAST]
    S[L.S_OLD_SEQ] = S[L.S_LAST_SEQ]
    for i in range(dim):
        S[old0 + i] = S[last0 + i]
        S[last0 + i] = ring[j, 2 + i]
    S[L.S_HAS_LAST] = 1.0
    S[L.S_LAST_SEQ] = seq
    if C[L.C_EXTRAP] != 0.0:
        if C[L.C_SENDS_RATE] != 0.0:
            dt_tick = C[L.C_PERIOD_NS] / 1e9
            for i in range(dim):
                S[rate0 + i] = ring[j, 2 + dim + i] * dt_tick
            S[L.S_HAS_RATE] = 1.0
        elif S[L.S_HAS_OLD] != 0.0:
            span = int(S[L.S_LAST_SEQ]) - int(S[L.S_OLD_SEQ])
            for i in range(dim):
                S[rate0 + i] = (S[last0 + i] - S[old0 + i]) / span
            S[L.S_HAS_RATE] = 1.0


def decoder_sample(C: np.ndarray, S: np.ndarray, n: int, out: np.ndarray, last0: int, rate0: int) -> bool:
    """The decoder's sample at tick `n` into `out` (False before the first packet): the last sample
    held, or (with a rate, after its seq) extrapolated n - seq ticks ahead, at most C_MAX_AHEAD
    (past it: the value reached there, held; each tick within it counted `extrapolated`). Places
    as `decoder_receive`'s."""
    if S[L.S_HAS_LAST] == 0.0:
        return False
    dim = int(C[L.C_DIM])
    seq = int(S[L.S_LAST_SEQ])
    if S[L.S_HAS_RATE] == 0.0 or n <= seq:
        for i in range(dim):
            out[i] = S[last0 + i]
        return True
    ahead = float(n - seq)
    if ahead > C[L.C_MAX_AHEAD]:
        ahead = C[L.C_MAX_AHEAD]
    else:
        S[L.S_EXTRAPOLATED] += 1.0
    for i in range(dim):
        out[i] = extrapolated(S[last0 + i], S[rate0 + i], ahead)
    return True


def triggered(C: np.ndarray, S: np.ndarray, smp: Any, sent0: int, trig0: int, group: int) -> bool:
    """The grouped deadband's test (a sample was sent before): whether any trigger group of `smp`
    (`group` values from each i with C[trig0 + i] set) left its sphere |v_i - v_c| > max(p |v_i|,
    min_threshold) around its value in the last sent sample (S from `sent0`); p(|v|) of the
    velocity-adaptive option from the group at C_VEL. Norms and distances of a group as
    `vector_norm`: |x| for one value, else the squares summed in order."""
    p = C[L.C_P0]
    if C[L.C_GAIN] > 0.0:
        vel = int(C[L.C_VEL])
        if group == 1:
            speed = abs(smp[vel])
        else:
            s2 = 0.0
            for i in range(vel, vel + group):
                s2 += smp[i] * smp[i]
            speed = math.sqrt(s2)
        p = deadband_p(C[L.C_P0], C[L.C_GAIN], C[L.C_PMAX], speed)
    for g in range(0, int(C[L.C_DIM]), group):
        if C[trig0 + g] == 0.0:
            continue
        if group == 1:
            last = S[sent0 + g]
            distance, norm_last = abs(last - smp[g]), abs(last)
        else:
            d2 = 0.0
            l2 = 0.0
            for i in range(g, g + group):
                last = S[sent0 + i]
                d = last - smp[i]
                d2 += d * d
                l2 += last * last
            distance, norm_last = math.sqrt(d2), math.sqrt(l2)
        if outside(distance, norm_last, p, C[L.C_MIN]):
            return True
    return False


def encoder_send(
    C: np.ndarray, S: np.ndarray, smp: Any, rate: np.ndarray, now: int, sent0: int, prev0: int, trig0: int,
    group: int,
) -> bool:  # fmt: skip
    """The grouped deadband encoder offered `smp` at `now` (ns): with a sent rate (C_SENDS_RATE),
    its backward difference over the sample offered before into `rate` (zeros for the first or an
    equal time); counted offered, then sent (the last sent sample becomes `smp`: True) or
    filtered (False) by `triggered`. The previous sample (from `prev0`) and the last sent (from
    `sent0`) in S; places of its other state: codec_layout's (S_HAS_PREV, S_PREV_NS, S_HAS_SENT,
    S_OFFERED, S_SENT, S_FILTERED). One definition: `GroupedDeadbandEncoder` calls it, the
    compiled loops inline it."""
    dim = int(C[L.C_DIM])
    if C[L.C_SENDS_RATE] != 0.0:
        if S[L.S_HAS_PREV] == 0.0 or now <= S[L.S_PREV_NS]:
            for i in range(dim):
                rate[i] = 0.0
        else:
            dt = (now - int(S[L.S_PREV_NS])) * 1e-9
            for i in range(dim):
                rate[i] = (smp[i] - S[prev0 + i]) / dt
    for i in range(dim):
        S[prev0 + i] = smp[i]
    S[L.S_HAS_PREV] = 1.0
    S[L.S_PREV_NS] = now
    S[L.S_OFFERED] += 1.0
    if S[L.S_HAS_SENT] != 0.0 and not triggered(C, S, smp, sent0, trig0, group):
        S[L.S_FILTERED] += 1.0
        return False
    for i in range(dim):
        S[sent0 + i] = smp[i]
    S[L.S_HAS_SENT] = 1.0
    S[L.S_SENT] += 1.0
    return True


# The encoder's counters and where S keeps them.
ENCODER_COUNTERS = {"offered": L.S_OFFERED, "sent": L.S_SENT, "filtered": L.S_FILTERED}


class GroupedDeadbandEncoder:
    """Seed 001's deadband on the quantities of a sample (the rule above on each of them): the
    whole sample is sent when any trigger quantity leaves its sphere |v_i - v_c| > max(p |v_i|,
    min_threshold) around its value in the last sent sample; p(v) of the velocity-adaptive option
    from the sample's velocity. `triggers`: the quantities' slices, each `group` values (the
    velocity's `velocity` too). Payload: the sample, then (with `extrapolate` from `sent_rate`) its
    backward-difference rate, so `DeadbandDecoder` rebuilds it. Its state is a codec_layout state
    vector `S` (the previous and last sent samples after the scalars; a list), its constants `C`:
    `encoder_send` acts on them, as it does in the compiled loops. Counters: offered, sent,
    filtered."""

    kind = KIND

    def __init__(
        self, cfg: DeadbandConfig, dim: int, size_bytes: int, triggers: tuple[slice, ...], velocity: slice
    ) -> None:
        group = velocity.stop - velocity.start
        if group < 1 or dim % group or any(t.stop - t.start != group or t.start % group for t in triggers):
            raise ValueError(f"deadband codec: trigger groups must be {group}-value groups of the {dim} values")
        self.cfg, self.dim, self.size_bytes = cfg, dim, size_bytes
        self.triggers, self.velocity, self.group = triggers, velocity, group
        # C and S as Python lists: the functions do the same float64 arithmetic on them as on the
        # compiled loops' arrays, and a list is a few times faster to index from Python
        C = [0.0] * (L.C_SIZE_X + dim)
        C[L.C_DIM] = dim
        C[L.C_SIZE] = size_bytes
        C[L.C_P0], C[L.C_MIN] = cfg.deadband, cfg.min_threshold
        C[L.C_GAIN], C[L.C_PMAX] = cfg.adaptive_gain, cfg.max_deadband
        C[L.C_SENDS_RATE] = 1.0 if cfg.sends_rate else 0.0
        C[L.C_VEL] = velocity.start
        self.trig0 = L.C_SIZE_X  # the trigger flags after the constants
        for t in triggers:
            C[self.trig0 + t.start : self.trig0 + t.stop] = [1.0] * group
        self.C: Any = C
        self.sent0, self.prev0 = L.S_SIZE_X, L.S_SIZE_X + dim
        self.S: Any = [0.0] * (L.S_SIZE_X + 2 * dim)
        self._rate: Any = [0.0] * dim

    @property
    def counters(self) -> dict[str, int]:
        """offered, sent, filtered."""
        return {name: int(self.S[k]) for name, k in ENCODER_COUNTERS.items()}

    def load(self, S: np.ndarray, sent0: int, prev0: int) -> None:
        """Take the state of an encoder kept elsewhere (a compiled loop's state vector `S`, its
        vectors from `sent0` and `prev0`)."""
        d = self.dim
        self.S[: L.S_SIZE_X] = S[: L.S_SIZE_X].tolist()
        self.S[self.sent0 : self.sent0 + d] = S[sent0 : sent0 + d].tolist()
        self.S[self.prev0 : self.prev0 + d] = S[prev0 : prev0 + d].tolist()

    def send(self, n: int, now_ns: int, sample: tuple[float, ...]) -> list[Packet]:
        rate = self._rate
        if not encoder_send(self.C, self.S, sample, rate, now_ns, self.sent0, self.prev0, self.trig0, self.group):
            return []
        payload = sample + tuple(rate) if self.cfg.sends_rate else sample
        return [Packet(n, now_ns, payload, self.size_bytes)]

    def feedback(self, packet: Packet, now_ns: int) -> None:
        """No return path."""


class _Row:
    """A packet's payload as row 0 of an in-flight ring (`ring[0, 2 + i]`), for the Python decoder."""

    __slots__ = ("payload",)

    def __init__(self, payload: Sequence[float]) -> None:
        self.payload = payload

    def __getitem__(self, at: tuple[int, int]) -> float:
        return float(self.payload[at[1] - 2])


# The decoder's counters and where S keeps them.
DECODER_COUNTERS = {"received": L.S_RECEIVED, "stale": L.S_STALE, "extrapolated": L.S_EXTRAPOLATED}


class DeadbandDecoder:
    """Receiver side: hold or extrapolate the newest received sample (by seq; older and
    duplicate arrivals are counted `stale` and ignored). Its state is a codec_layout state
    vector `S` (its samples after the scalars; a list), its constants `C`: `decoder_receive` and
    `decoder_sample` act on them, as they do in the compiled loops."""

    kind = KIND

    def __init__(self, cfg: DeadbandConfig, dim: int, period_ns: int) -> None:
        if dim < 1:
            raise ValueError(f"deadband codec: dim must be >= 1, got {dim}")
        if not period_ns > 0:
            raise ValueError(f"deadband codec: period_ns must be > 0, got {period_ns}")
        self.cfg = cfg
        self.dim = dim
        self.period_ns = period_ns
        cap = cfg.max_extrapolation_s
        C = [0.0] * L.C_SIZE_X  # lists: as the encoder's
        C[L.C_DIM] = dim
        C[L.C_PERIOD_NS] = period_ns
        C[L.C_EXTRAP] = 1.0 if cfg.reconstruction == "extrapolate" else 0.0
        C[L.C_SENDS_RATE] = 1.0 if cfg.sends_rate else 0.0
        C[L.C_MAX_AHEAD] = math.inf if cap is None else cap * _NS_PER_S / period_ns
        self.C: Any = C
        # the last, old and rate vectors after the scalars
        self.last0, self.old0, self.rate0 = L.S_SIZE_X, L.S_SIZE_X + dim, L.S_SIZE_X + 2 * dim
        self.S: Any = [0.0] * (L.S_SIZE_X + 3 * dim)
        self._out: Any = [0.0] * dim

    @property
    def counters(self) -> dict[str, int]:
        """received, stale, extrapolated."""
        return {name: int(self.S[k]) for name, k in DECODER_COUNTERS.items()}

    def load(self, S: np.ndarray, last0: int, old0: int, rate0: int) -> None:
        """Take the state of a decoder kept elsewhere (a compiled loop's state vector `S`, its
        vectors from `last0`, `old0`, `rate0`)."""
        d = self.dim
        self.S[: L.S_SIZE_X] = S[: L.S_SIZE_X].tolist()
        self.S[self.last0 : self.last0 + d] = S[last0 : last0 + d].tolist()
        self.S[self.old0 : self.old0 + d] = S[old0 : old0 + d].tolist()
        self.S[self.rate0 : self.rate0 + d] = S[rate0 : rate0 + d].tolist()

    def receive(self, packet: Packet, now_ns: int) -> list[Packet]:
        want = self.dim * self.cfg.floats_per_axis
        if len(packet.payload) != want:
            raise ValueError(f"deadband codec: payload has {len(packet.payload)} values, expected {want}")
        ring = _Row(packet.payload)
        decoder_receive(self.C, self.S, packet.seq, ring, 0, self.last0, self.old0, self.rate0)
        return []

    def sample(self, n: int, now_ns: int) -> tuple[float, ...] | None:
        out = self._out
        if not decoder_sample(self.C, self.S, n, out, self.last0, self.rate0):
            return None
        return tuple(out)


class DeadbandCodec(NamedTuple):
    encoder: DeadbandEncoder
    decoder: DeadbandDecoder


def build_deadband(cfg: DeadbandConfig, dim: int, period_ns: int, size_bytes: int) -> DeadbandCodec:
    """The encoder and decoder of one stream of `dim`-vectors sampled every `period_ns`.

    `size_bytes` is the serialized size of the message carrying one payload of
    `cfg.floats_per_axis` values per component (the engine passes
    record.layouts.joint_state_size(cfg.floats_per_axis, dim); core cannot import record).
    """
    return DeadbandCodec(DeadbandEncoder(cfg, dim, size_bytes), DeadbandDecoder(cfg, dim, period_ns))


def synthetic_contact_signal(
    rng: np.random.Generator, ticks: int, period_s: float = 0.001
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A seeded haptic-like 3-D test signal (position m, velocity m/s, force N), shape (ticks, 3).

    The operator's hand: per axis a sum of three sinusoids (0.2 to 2 Hz, 2 to 4 cm, random
    phases) around the centre of a sphere of radius 5 cm, stiffness 500 N/m; force is seed 001's
    sphere force F = k (r - |x - s|) (x - s)/|x - s| while inside it, zero outside, plus
    N(0, 0.002 N) sensor noise on each component while in contact. Synthetic: for the codec's
    tests and the docs' illustration table, not a measurement.
    """
    if ticks < 1 or not period_s > 0.0:
        raise ValueError(f"synthetic_contact_signal: need ticks >= 1 and period_s > 0, got {ticks}, {period_s}")
    t = np.arange(ticks) * period_s
    freqs = rng.uniform(0.2, 2.0, size=(3, 3))
    amps = rng.uniform(0.02, 0.04, size=(3, 3))
    phases = rng.uniform(0.0, 2.0 * np.pi, size=(3, 3))
    arg = 2.0 * np.pi * freqs[None, :, :] * t[:, None, None] + phases[None, :, :]
    pos = (amps[None, :, :] * np.sin(arg)).sum(axis=2)
    vel = (amps[None, :, :] * 2.0 * np.pi * freqs[None, :, :] * np.cos(arg)).sum(axis=2)
    radius_m, stiffness_n_per_m = 0.05, 500.0
    dist = np.linalg.norm(pos, axis=1)
    inside = dist < radius_m
    unit = pos / np.maximum(dist, 1e-12)[:, None]
    force = np.where(inside[:, None], stiffness_n_per_m * (radius_m - dist)[:, None] * unit, 0.0)
    force = force + np.where(inside[:, None], rng.normal(0.0, 0.002, size=force.shape), 0.0)
    return pos, vel, force


def reduction_on(signal: np.ndarray, cfg: DeadbandConfig, velocity: np.ndarray | None = None) -> float:
    """The deadband's packet-rate reduction (1 - sent/offered) on a (ticks, dim) signal at 1 kHz."""
    enc = DeadbandEncoder(cfg, signal.shape[1], 0)
    period_ns = 1_000_000
    for n, row in enumerate(signal.tolist()):
        v = None if velocity is None else velocity[n].tolist()
        enc.send(n, n * period_ns, tuple(row), velocity=v)
    return enc.reduction

"""Network effects on haptic packets: the pure, seeded model of one direction of a link.

Times are integer nanoseconds so that arrival-versus-tick comparisons are exact and a run is
reproducible bit for bit. Each effect draws from its own `numpy.random.Generator`, derived from
the scene seed, the direction and the effect's name (`effect_rng`), so adding one effect never
changes another's draws.

A `Link` applies its effects in order when a packet is sent (as netem does: every impairment is
decided at enqueue time) and then holds delivered packets in a time-ordered queue until
`deliver(now_ns)` releases those that have arrived. The order, the models and their formulas
are in docs/network.md; `build_link` builds only the effects a scene names, in
`CANONICAL_ORDER`.

Rules that keep runs comparable across scenes (common random numbers):
- every random decision of an effect is drawn once per original packet sent, whether or not an
  earlier effect already lost that packet, so the n-th packet's draws depend only on the seed,
  the direction, the effect's parameters and n;
- duplicate copies draw from a separate stream per effect (`"<effect>:copy"`), so duplication
  never shifts the draws of the originals;
- only the deterministic queue state (token bucket, `keep_order`) sees just the packets that
  actually pass.
"""

from __future__ import annotations

import bisect
import csv
import heapq
import itertools
import math
import os
import zlib
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from functools import cache
from pathlib import Path
from statistics import NormalDist
from typing import Protocol

import numpy as np

# Fate codes, recorded per packet (see docs/network.md).
DELIVERED = 0
LOST_NETWORK = 1
LOST_QUEUE = 2
LOST_CORRUPT = 3
LOST_LATE = 4  # set by the playout buffer: arrived, but too late to be played
FATE_NAMES = {
    DELIVERED: "delivered",
    LOST_NETWORK: "network",
    LOST_QUEUE: "queue_overflow",
    LOST_CORRUPT: "corruption",
    LOST_LATE: "late",
}

# The order a packet meets the effects on its way (config field names). "reorder" is decided in
# the delay stage: it chooses whether a packet keeps the delay just computed.
CANONICAL_ORDER = ("blackout", "rate_limit", "loss", "duplicate", "corrupt", "delay", "reorder")

# Per-packet bytes on the wire besides the serialized message: IPv4 header 20, UDP header 8,
# RTPS message header 20, RTPS DATA submessage header (with its submessage header) 24.
IPV4_HEADER_BYTES = 20
UDP_HEADER_BYTES = 8
RTPS_HEADER_BYTES = 20
RTPS_DATA_SUBMESSAGE_BYTES = 24
DEFAULT_OVERHEAD_BYTES = IPV4_HEADER_BYTES + UDP_HEADER_BYTES + RTPS_HEADER_BYTES + RTPS_DATA_SUBMESSAGE_BYTES

DISTRIBUTIONS = ("uniform", "normal", "pareto", "paretonormal")
CORRELATION_MODELS = ("netem", "gaussian_copula")

_BLOCK = 4096  # random numbers drawn per numpy call
_TABLE_SIZE = 4096  # entries of a jitter quantile table, as netem's tables
_TABLE_MIN = -32768 / 8192  # netem stores table values as int16 scaled by NETEM_DIST_SCALE=8192
_TABLE_MAX = 32767 / 8192
_NS_PER_S = 1_000_000_000


@dataclass(slots=True)
class Packet:
    """One haptic sample on the wire."""

    seq: int
    send_time_ns: int
    payload: tuple[float, ...]
    size_bytes: int = 0
    arrival_time_ns: int = 0
    fate: int = DELIVERED
    duplicate: bool = False


def effect_rng(seed: int, direction: str, effect: str) -> np.random.Generator:
    """An independent random stream for one effect of one direction of one run."""
    key = (zlib.crc32(direction.encode()), zlib.crc32(effect.encode()))
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


# --------------------------------------------------------------------------------------------
# Random sources: numbers are drawn from numpy in blocks and handed out one at a time, because a
# numpy call per packet costs about a microsecond.


class UniformSource:
    """Uniform numbers in [0, 1) from `rng`, drawn in blocks. Call `next()` for one."""

    __slots__ = ("_it", "_rng")

    def __init__(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._it = iter(()).__next__

    def next(self) -> float:
        try:
            return self._it()
        except StopIteration:
            self._it = iter(self._rng.random(_BLOCK).tolist()).__next__
            return self._it()


class NetemCorrelatedUniform:
    """netem's correlated random: u_n = (1 - rho) v_n + rho u_(n-1), v_n fresh uniform.

    The mean stays 1/2 but the variance shrinks to (1 - rho) / (1 + rho) of a uniform's, so the
    marginal is no longer uniform (docs/network.md, "Correlation")."""

    __slots__ = ("_fresh", "_last", "_rho")

    def __init__(self, rng: np.random.Generator, rho: float) -> None:
        self._fresh = UniformSource(rng).next
        self._rho = rho
        self._last = self._fresh()  # netem seeds `last` with a fresh random number

    def next(self) -> float:
        u = (1.0 - self._rho) * self._fresh() + self._rho * self._last
        self._last = u
        return u


class GaussianCopulaUniform:
    """Correlated uniforms with an exactly uniform marginal: u_n = Phi(z_n) for a stationary
    Gaussian AR(1) z_n = rho z_(n-1) + sqrt(1 - rho^2) e_n."""

    __slots__ = ("_it", "_rho", "_rng", "_s", "_z")

    def __init__(self, rng: np.random.Generator, rho: float) -> None:
        self._rng = rng
        self._it = iter(()).__next__
        self._rho = rho
        self._s = math.sqrt(1.0 - rho * rho)
        self._z = self._normal()

    def _normal(self) -> float:
        try:
            return self._it()
        except StopIteration:
            self._it = iter(self._rng.standard_normal(_BLOCK).tolist()).__next__
            return self._it()

    def next(self) -> float:
        z = self._rho * self._z + self._s * self._normal()
        self._z = z
        u = 0.5 * math.erfc(-z * 0.7071067811865476)
        return u if u < 1.0 else 0.9999999999999999


def uniform_source(rng: np.random.Generator, correlation: float = 0.0, model: str = "netem") -> Callable[[], float]:
    """A function returning the next uniform number of an (optionally correlated) stream."""
    if not 0.0 <= correlation < 1.0:
        raise ValueError(f"correlation must be in [0, 1), got {correlation}")
    if model not in CORRELATION_MODELS:
        raise ValueError(f"correlation model must be one of {', '.join(CORRELATION_MODELS)}, got {model!r}")
    if correlation == 0.0:
        return UniformSource(rng).next
    if model == "netem":
        return NetemCorrelatedUniform(rng, correlation).next
    return GaussianCopulaUniform(rng, correlation).next


# --------------------------------------------------------------------------------------------
# Jitter distributions: quantile tables of netem's shapes (docs/network.md, "Jitter").


def _pareto_quantile(q: float) -> float:
    # netem's pareto table: Pareto(shape 3, scale 1) X = (1 - q)^(-1/3), mean 1.5, shifted to
    # mean 0 and scaled by 4/3.
    x: float = (1.0 - q) ** (-1.0 / 3.0)
    return (x - 1.5) * (4.0 / 3.0)


@cache
def jitter_table(distribution: str) -> tuple[float, ...]:
    """The 4096 quantiles (at cell midpoints) of a unit jitter distribution, clipped to netem's
    int16 table range [-4, 32767/8192]. Delay = base + jitter_s * table[int(u * 4096)]."""
    if distribution not in ("normal", "pareto", "paretonormal"):
        raise ValueError(f"no table for distribution {distribution!r}")
    inv = NormalDist().inv_cdf
    out = []
    for j in range(_TABLE_SIZE):
        q = (j + 0.5) / _TABLE_SIZE
        if distribution == "normal":
            v = inv(q)
        elif distribution == "pareto":
            v = _pareto_quantile(q)
        else:
            # netem pairs the normal and pareto quantiles of the same q (a comonotone mix).
            v = (inv(q) + 3.0 * _pareto_quantile(q)) / 4.0
        out.append(min(max(v, _TABLE_MIN), _TABLE_MAX))
    return tuple(out)


def jitter_quantile(distribution: str) -> Callable[[float], float]:
    """Map a uniform u in [0, 1) to a unit jitter value of `distribution`."""
    if distribution == "uniform":
        return lambda u: 2.0 * u - 1.0  # netem without a table: uniform on [-jitter, +jitter)
    table = jitter_table(distribution)
    n = len(table)

    def lookup(u: float) -> float:
        return table[int(u * n)]

    return lookup


# --------------------------------------------------------------------------------------------
# Effects. `apply` mutates the packet (arrival time, fate) and returns a new copy it made
# (duplication) or None.


class Effect(Protocol):
    """One impairment. `apply` may change the packet's arrival time or fate, and returns a copy
    it made (duplication) or None."""

    name: str

    def apply(self, packet: Packet) -> Packet | None: ...


class Blackout:
    """The link is down in [start, end) windows: every packet sent inside one is lost."""

    name = "blackout"

    def __init__(self, windows_ns: Sequence[tuple[int, int]]) -> None:
        ws = sorted((int(a), int(b)) for a, b in windows_ns)
        for (a, b), nxt in zip(ws, [*ws[1:], None], strict=True):
            if not b > a:
                raise ValueError(f"blackout window must end after it starts, got [{a}, {b}) ns")
            if nxt is not None and nxt[0] < b:
                raise ValueError(f"blackout windows overlap: [{a}, {b}) and [{nxt[0]}, {nxt[1]}) ns")
        self._starts = [a for a, _ in ws]
        self._ends = [b for _, b in ws]
        self.dropped = 0

    vectorized = True

    def apply_all(self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray) -> None:
        """`apply` on every original packet of a run at once (see `Link.schedule_all`)."""
        starts = np.asarray(self._starts, dtype=np.int64)
        ends = np.asarray(self._ends, dtype=np.int64)
        i = np.searchsorted(starts, send_ns, side="right") - 1
        hit = (i >= 0) & (send_ns < ends[np.maximum(i, 0)]) & (fate == DELIVERED)
        fate[hit] = LOST_NETWORK
        self.dropped += int(hit.sum())

    def apply(self, packet: Packet) -> Packet | None:
        t = packet.send_time_ns
        i = bisect.bisect_right(self._starts, t) - 1
        if i >= 0 and t < self._ends[i] and packet.fate == DELIVERED:
            packet.fate = LOST_NETWORK
            self.dropped += 1
        return None


class TokenBucket:
    """Rate limit: a FIFO queue served by a token bucket (tbf), with tail drop.

    Tokens are bits; they accrue at `rate_bps` up to the bucket depth `burst_bytes`. A packet
    needs (size_bytes + overhead_bytes) * 8 tokens and leaves as soon as the packet ahead of it has
    left and the bucket holds enough. A packet that would have to wait while
    `queue_limit_packets` packets are already waiting is dropped (LOST_QUEUE); with a limit of 0
    the bucket polices instead of shaping. The departure time follows from the queue state at
    send time, so it is computed then. Integer arithmetic in nano-bits keeps it exact.
    """

    name = "rate_limit"

    def __init__(
        self,
        rate_bps: float,
        burst_bytes: int,
        queue_limit_packets: int,
        overhead_bytes: int = DEFAULT_OVERHEAD_BYTES,
    ) -> None:
        rate = round(rate_bps)
        if rate < 1:
            raise ValueError(f"rate_bps must be >= 1, got {rate_bps}")
        if burst_bytes < 1 or queue_limit_packets < 0 or overhead_bytes < 0:
            raise ValueError(
                f"need burst_bytes >= 1, queue_limit_packets >= 0, overhead_bytes >= 0; got "
                f"{burst_bytes}, {queue_limit_packets}, {overhead_bytes}"
            )
        self.rate_bps = rate  # whole bits per second; also nano-bits per nanosecond
        self.burst_bytes = burst_bytes
        self.queue_limit_packets = queue_limit_packets
        self.overhead_bytes = overhead_bytes
        self._depth = burst_bytes * 8 * _NS_PER_S  # nano-bits
        self._tokens = self._depth  # the bucket starts full
        self._t_tokens = 0  # time _tokens refers to (unused while the bucket is full)
        self._full = True
        self._last_departure = -(1 << 62)
        self._waiting: deque[int] = deque()  # departure times of packets still waiting
        self.dropped = 0

    def transmit_time_ns(self, size_bytes: int) -> float:
        """Time one packet of `size_bytes` message bytes takes at the token rate."""
        return (size_bytes + self.overhead_bytes) * 8 * 1e9 / self.rate_bps

    def apply(self, packet: Packet) -> Packet | None:
        if packet.fate != DELIVERED:
            return None
        t = packet.arrival_time_ns
        waiting = self._waiting
        while waiting and waiting[0] <= t:
            waiting.popleft()
        need = (packet.size_bytes + self.overhead_bytes) * 8 * _NS_PER_S
        depth = self._depth
        if need > depth:
            raise ValueError(
                f"rate_limit: a packet of {packet.size_bytes} + {self.overhead_bytes} overhead bytes "
                f"exceeds burst_bytes={self.burst_bytes}; it could never be sent"
            )
        start = t if t > self._last_departure else self._last_departure
        if self._full:
            tokens = depth
        else:
            tokens = min(depth, self._tokens + (start - self._t_tokens) * self.rate_bps)
        if tokens >= need:
            departure = start
            tokens -= need
        else:
            wait = -((tokens - need) // self.rate_bps)  # ceil((need - tokens) / rate)
            departure = start + wait
            tokens = min(depth, tokens + wait * self.rate_bps) - need
        if departure > t:
            if len(waiting) >= self.queue_limit_packets:
                packet.fate = LOST_QUEUE
                self.dropped += 1
                return None
            waiting.append(departure)
        self._tokens = tokens
        self._t_tokens = departure
        self._full = False
        self._last_departure = departure
        packet.arrival_time_ns = departure
        return None

    @property
    def queue_length(self) -> int:
        """Packets waiting after the last send (before time moves on)."""
        return len(self._waiting)


class BernoulliLoss:
    """Independent loss with probability p per packet (netem `loss random p [corr]`)."""

    name = "loss"

    def __init__(
        self,
        probability: float,
        rng: np.random.Generator,
        correlation: float = 0.0,
        correlation_model: str = "netem",
    ) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self.probability = probability
        self._rng = rng
        self._u = uniform_source(rng, correlation, correlation_model)
        self.dropped = 0
        # Uncorrelated draws are plain uniforms: a whole run's can be drawn in one call.
        self.vectorized = correlation == 0.0

    def apply_all(self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray) -> None:
        """`apply` on every original packet of a run at once, before any `apply` (`Link.schedule_all`).

        `rng.random(n)` gives the numbers `UniformSource` hands out one at a time (it draws the
        same stream in blocks), so the same packets are lost."""
        if not self.vectorized:
            raise ValueError("correlated loss draws depend on the previous draw; it has no vectorized form")
        hit = (self._rng.random(len(send_ns)) < self.probability) & (fate == DELIVERED)
        fate[hit] = LOST_NETWORK
        self.dropped += int(hit.sum())

    def apply(self, packet: Packet) -> Packet | None:
        if self._u() < self.probability and packet.fate == DELIVERED:
            packet.fate = LOST_NETWORK
            self.dropped += 1
        return None


class GilbertElliottLoss:
    """2-state Markov loss (netem `loss gemodel p r 1-h 1-k`).

    Per packet, as netem does: draw the transition (good->bad with p, bad->good with r), then
    draw the loss with the loss probability of the state the packet met (1-k in good, 1-h in
    bad). Starts in the good state. Gilbert is the case 1-k = 0, simple Gilbert 1-h = 1 too.
    """

    name = "loss"

    def __init__(self, p: float, r: float, one_minus_h: float, one_minus_k: float, rng: np.random.Generator) -> None:
        for key, v in (("p", p), ("r", r), ("one_minus_h", one_minus_h), ("one_minus_k", one_minus_k)):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{key} must be in [0, 1], got {v}")
        self.p, self.r = p, r
        self.loss_bad, self.loss_good = one_minus_h, one_minus_k
        self._u = UniformSource(rng).next
        self.bad = False
        self.dropped = 0

    def apply(self, packet: Packet) -> Packet | None:
        u = self._u
        move = u()
        if self.bad:
            lost = u() < self.loss_bad
            if move < self.r:
                self.bad = False
        else:
            lost = u() < self.loss_good
            if move < self.p:
                self.bad = True
        if lost and packet.fate == DELIVERED:
            packet.fate = LOST_NETWORK
            self.dropped += 1
        return None


class FourStateLoss:
    """netem's 4-state Markov loss (`loss state p13 p31 p32 p23 p14`, the GI model).

    States: 1 received in a gap, 2 received in a burst, 3 lost in a burst, 4 isolated loss in a
    gap. One draw per packet moves the chain; the packet is lost if the new state is 3 or 4.
    1 -> 4 (p14), 1 -> 3 (p13); 2 -> 3 (p23); 3 -> 2 (p32), 3 -> 1 (p31); 4 -> 1 always.
    """

    name = "loss"

    def __init__(self, p13: float, p31: float, p32: float, p23: float, p14: float, *, rng: np.random.Generator) -> None:
        for key, v in (("p13", p13), ("p31", p31), ("p32", p32), ("p23", p23), ("p14", p14)):
            if not 0.0 <= v <= 1.0:
                raise ValueError(f"{key} must be in [0, 1], got {v}")
        if p13 + p14 > 1.0 or p31 + p32 > 1.0:
            raise ValueError("need p13 + p14 <= 1 and p31 + p32 <= 1")
        self.p13, self.p31, self.p32, self.p23, self.p14 = p13, p31, p32, p23, p14
        self._u = UniformSource(rng).next
        self.state = 1
        self.dropped = 0

    def apply(self, packet: Packet) -> Packet | None:
        u = self._u()
        s = self.state
        if s == 1:
            if u < self.p14:
                s = 4
            elif u < self.p14 + self.p13:
                s = 3
        elif s == 2:
            if u < self.p23:
                s = 3
        elif s == 3:
            if u < self.p32:
                s = 2
            elif u < self.p32 + self.p31:
                s = 1
        else:
            s = 1
        self.state = s
        if s >= 3 and packet.fate == DELIVERED:
            packet.fate = LOST_NETWORK
            self.dropped += 1
        return None


class TraceLoss:
    """Replay a recorded loss pattern: the n-th packet is lost if pattern[n] is true."""

    name = "loss"

    def __init__(self, pattern: Sequence[bool] | np.ndarray, repeat: bool = True) -> None:
        self._pattern = [bool(x) for x in pattern]
        if not self._pattern:
            raise ValueError("a loss trace needs at least one entry")
        self._repeat = repeat
        self._n = 0
        self.dropped = 0

    def apply(self, packet: Packet) -> Packet | None:
        n = self._n
        self._n = n + 1
        pat = self._pattern
        if n >= len(pat):
            if not self._repeat:
                return None
            n %= len(pat)
        if pat[n] and packet.fate == DELIVERED:
            packet.fate = LOST_NETWORK
            self.dropped += 1
        return None


class Duplicate:
    """netem `duplicate p [corr]`: a delivered packet gets a copy (`duplicate=True`) that then
    meets the remaining effects on its own."""

    name = "duplicate"

    def __init__(
        self,
        probability: float,
        rng: np.random.Generator,
        correlation: float = 0.0,
        correlation_model: str = "netem",
    ) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self.probability = probability
        self._u = uniform_source(rng, correlation, correlation_model)
        self.copies = 0

    def apply(self, packet: Packet) -> Packet | None:
        if packet.duplicate:
            return None  # a copy is never copied again (netem: tc_depth)
        if self._u() < self.probability and packet.fate == DELIVERED:
            self.copies += 1
            return Packet(
                packet.seq, packet.send_time_ns, packet.payload, packet.size_bytes,
                packet.arrival_time_ns, DELIVERED, True,
            )  # fmt: skip
        return None


class Corrupt:
    """netem `corrupt p [corr]`: a bit error; the receiver's UDP checksum fails and the stack
    discards the packet (LOST_CORRUPT)."""

    name = "corrupt"

    def __init__(
        self,
        probability: float,
        rng: np.random.Generator,
        correlation: float = 0.0,
        correlation_model: str = "netem",
        copy_rng: np.random.Generator | None = None,
    ) -> None:
        if not 0.0 <= probability <= 1.0:
            raise ValueError(f"probability must be in [0, 1], got {probability}")
        self.probability = probability
        self._u = uniform_source(rng, correlation, correlation_model)
        # Copies draw from their own stream so they never shift the originals' draws.
        self._copy_rng = copy_rng if copy_rng is not None else rng.spawn(1)[0]
        self._copy_u: Callable[[], float] | None = None
        self.dropped = 0

    def apply(self, packet: Packet) -> Packet | None:
        if packet.duplicate:
            if self._copy_u is None:
                self._copy_u = UniformSource(self._copy_rng).next
            u = self._copy_u()
        else:
            u = self._u()
        if u < self.probability and packet.fate == DELIVERED:
            packet.fate = LOST_CORRUPT
            if not packet.duplicate:
                self.dropped += 1
        return None


class ConstantDelay:
    """Fixed one-way delay."""

    name = "delay"

    def __init__(self, delay_s: float) -> None:
        if not delay_s >= 0.0:
            raise ValueError(f"delay_s must be >= 0, got {delay_s}")
        self.delay_ns = round(delay_s * 1e9)

    vectorized = True

    def apply_all(self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray) -> None:
        """`apply` on every original packet of a run at once (see `Link.schedule_all`)."""
        arrival_ns += self.delay_ns

    def apply(self, packet: Packet) -> Packet | None:
        packet.arrival_time_ns += self.delay_ns
        return None


class PiecewiseDelay:
    """Extra delay from points (t_i, d_i), held before the first and after the last point,
    stepping (held until the next point) or linear in between. Call with a time in ns."""

    def __init__(self, times_s: Sequence[float], delays_s: Sequence[float], interpolation: str = "linear") -> None:
        if len(times_s) != len(delays_s) or not times_s:
            raise ValueError(f"need as many times as delays, at least one; got {len(times_s)} and {len(delays_s)}")
        if any(b <= a for a, b in itertools.pairwise(times_s)):
            raise ValueError("times must be strictly increasing")
        if any(not d >= 0.0 for d in delays_s):
            raise ValueError("delays must be >= 0")
        if interpolation not in ("linear", "step"):
            raise ValueError(f"interpolation must be linear or step, got {interpolation!r}")
        self._t = [round(t * 1e9) for t in times_s]
        self._d = [d * 1e9 for d in delays_s]
        self._linear = interpolation == "linear"

    def __call__(self, t_ns: int) -> float:
        ts, ds = self._t, self._d
        i = bisect.bisect_right(ts, t_ns)
        if i == 0:
            return ds[0]
        if i == len(ts) or not self._linear:
            return ds[i - 1]
        t0, t1 = ts[i - 1], ts[i]
        return ds[i - 1] + (ds[i] - ds[i - 1]) * (t_ns - t0) / (t1 - t0)


class SinusoidDelay:
    """Extra delay swinging between min and max: d(t) = mid - amp cos(2 pi (t + phase) / period),
    so it starts at the minimum at t = -phase."""

    def __init__(self, min_delay_s: float, max_delay_s: float, period_s: float, phase_s: float = 0.0) -> None:
        if not (0.0 <= min_delay_s <= max_delay_s and period_s > 0.0):
            raise ValueError("need 0 <= min_delay_s <= max_delay_s and period_s > 0")
        self._mid = (min_delay_s + max_delay_s) / 2 * 1e9
        self._amp = (max_delay_s - min_delay_s) / 2 * 1e9
        self._w = 2.0 * math.pi / (period_s * 1e9)
        self._phase_ns = phase_s * 1e9

    def __call__(self, t_ns: int) -> float:
        return self._mid - self._amp * math.cos(self._w * (t_ns + self._phase_ns))


class Delay:
    """Delay with jitter, a time-varying part, optional ordering and netem-style reordering.

    delay = delay_s + profile(t) + jitter_s * J, J from the jitter distribution (correlated as
    configured), clamped at 0; t is when the packet reaches this stage. With `keep_order` a
    packet cannot arrive before the one delivered before it (netem with a pfifo child or `rate`).
    With `reorder` a fraction of packets skips the delay entirely ("sent immediately"), netem's
    `reorder p [corr] gap g`.
    """

    name = "delay"

    def __init__(
        self,
        delay_s: float,
        *,
        jitter_s: float = 0.0,
        distribution: str = "normal",
        rng: np.random.Generator | None = None,
        correlation: float = 0.0,
        correlation_model: str = "netem",
        profile: Callable[[int], float] | None = None,
        keep_order: bool = False,
        reorder_probability: float = 0.0,
        reorder_correlation: float = 0.0,
        reorder_gap_packets: int = 1,
        reorder_rng: np.random.Generator | None = None,
        copy_rng: np.random.Generator | None = None,
    ) -> None:
        if not delay_s >= 0.0 or not jitter_s >= 0.0:
            raise ValueError(f"delay_s and jitter_s must be >= 0, got {delay_s}, {jitter_s}")
        if distribution not in DISTRIBUTIONS:
            raise ValueError(f"distribution must be one of {', '.join(DISTRIBUTIONS)}, got {distribution!r}")
        if not 0.0 <= reorder_probability <= 1.0 or reorder_gap_packets < 1:
            raise ValueError("need 0 <= reorder_probability <= 1 and reorder_gap_packets >= 1")
        self._base_ns = delay_s * 1e9
        self._sigma_ns = jitter_s * 1e9
        self._quantile = jitter_quantile(distribution)
        self._profile = profile
        self._keep_order = keep_order
        self._last_arrival = -(1 << 62)
        parent = rng if rng is not None else reorder_rng
        if copy_rng is None and parent is not None:
            copy_rng = parent.spawn(1)[0]  # copies never shift the originals' draws
        self._copy_rng = copy_rng
        self._copy_u: Callable[[], float] | None = None
        self._ju: Callable[[], float] | None = None
        if jitter_s > 0.0:
            if rng is None:
                raise ValueError("jitter needs a random generator")
            self._ju = uniform_source(rng, correlation, correlation_model)
        self._reorder_p = reorder_probability
        self._gap = reorder_gap_packets
        self._counter = 0
        self._ru: Callable[[], float] | None = None
        if reorder_probability > 0.0:
            if reorder_rng is None:
                raise ValueError("reorder needs a random generator")
            self._ru = uniform_source(reorder_rng, reorder_correlation, correlation_model)
        self.reordered = 0

    def _copy_draw(self) -> float:
        if self._copy_u is None:
            assert self._copy_rng is not None  # only called when jitter or reorder draws
            self._copy_u = UniformSource(self._copy_rng).next
        return self._copy_u()

    def apply(self, packet: Packet) -> Packet | None:
        t = packet.arrival_time_ns
        copy = packet.duplicate
        d = self._base_ns
        if self._profile is not None:
            d += self._profile(t)
        if self._ju is not None:
            d += self._sigma_ns * self._quantile(self._copy_draw() if copy else self._ju())
        if self._ru is not None:
            if copy:
                skip = self._copy_draw() < self._reorder_p
            else:
                r = self._ru()  # drawn for every packet, see the module docstring
                if self._counter < self._gap - 1 or r >= self._reorder_p:
                    self._counter += 1
                    skip = False
                else:
                    self._counter = 0
                    skip = True
            if skip:
                # "Sent immediately": no delay and not held behind earlier packets.
                if packet.fate == DELIVERED:
                    self.reordered += 1
                return None
        arrival = t + int(d + 0.5) if d > 0.0 else t
        if self._keep_order and packet.fate == DELIVERED:
            if arrival < self._last_arrival:  # noqa: PLR1730 (an if is cheaper than max() per packet)
                arrival = self._last_arrival
            self._last_arrival = arrival
        packet.arrival_time_ns = arrival
        return None


# --------------------------------------------------------------------------------------------
# The link.


class Link:
    """One direction: effects in order at send time, then a time-ordered in-flight queue."""

    def __init__(self, effects: Sequence[Effect]) -> None:
        self.effects = tuple(effects)
        self._applies = tuple(e.apply for e in self.effects)
        # In-order arrivals go to a deque (O(1)); only packets that overtake go to a heap.
        self._fifo: deque[tuple[int, int, Packet]] = deque()
        self._heap: list[tuple[int, int, Packet]] = []
        self._order = 0
        self.sent = 0
        self.lost = 0  # originals lost in the network (not counting copies or late packets)
        self.duplicates = 0
        self.log: list[Packet] = []  # every packet (and copy) with its fate, for the bag (its reader may drain it)
        self._one_by_one = False  # a packet went through `send`: `schedule_all` would not continue it

    def send(self, packet: Packet) -> None:
        packet.arrival_time_ns = packet.send_time_ns
        self.sent += 1
        self._one_by_one = True
        self.log.append(packet)
        for i, apply in enumerate(self._applies, 1):
            extra = apply(packet)
            if extra is not None:
                self._send_copy(extra, i)
        if packet.fate == DELIVERED:
            self._enqueue(packet)
        else:
            self.lost += 1

    def _send_copy(self, copy: Packet, start: int) -> None:
        self.duplicates += 1
        self.log.append(copy)
        for apply in self._applies[start:]:
            apply(copy)
        if copy.fate == DELIVERED:
            self._enqueue(copy)

    def _enqueue(self, p: Packet) -> None:
        a = p.arrival_time_ns
        entry = (a, self._order, p)  # the counter keeps equal arrival times in send order
        self._order += 1
        fifo = self._fifo
        if not fifo or a >= fifo[-1][0]:
            fifo.append(entry)
        else:
            heapq.heappush(self._heap, entry)

    def deliver(self, now_ns: int) -> list[Packet]:
        """Packets that have arrived by `now_ns`, in arrival order."""
        fifo, heap = self._fifo, self._heap
        out: list[Packet] = []
        if not heap:
            while fifo and fifo[0][0] <= now_ns:
                out.append(fifo.popleft()[2])
            return out
        while True:
            if fifo and (not heap or fifo[0] < heap[0]):
                if fifo[0][0] > now_ns:
                    break
                out.append(fifo.popleft()[2])
            elif heap:
                if heap[0][0] > now_ns:
                    break
                out.append(heapq.heappop(heap)[2])
            else:
                break
        return out

    @property
    def in_flight(self) -> int:
        return len(self._fifo) + len(self._heap)

    def oldest_in_flight_seq(self) -> int | None:
        """The lowest sequence number among the packets still in flight, or None if none is."""
        seqs = [e[2].seq for e in self._fifo] + [e[2].seq for e in self._heap]
        return min(seqs) if seqs else None

    @property
    def vectorized(self) -> bool:
        """True if `schedule_all` can decide the link's packets in batches (none went through `send`,
        and every effect has an `apply_all` whose decisions do not depend on the packets before)."""
        return not self._one_by_one and all(getattr(e, "vectorized", False) for e in self.effects)

    def schedule_all(self, send_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Fates and arrival times of original packets sent at `send_ns`, decided all at once.

        The same decisions, from the same random numbers, as `send` on each packet in turn
        (test_vectorized_schedule_equals_send). Consecutive calls continue one another (each
        effect's random stream goes on where the last call left it), so a run can be decided in
        windows of any size with the same result. Only for a link whose effects are all
        `vectorized` and that no packet went through `send` on (see the property); the packets
        are not queued or logged. Updates `sent` and `lost`. Returns (arrival_ns, fate) arrays.
        """
        if not self.vectorized:
            raise ValueError(
                "this link cannot decide a run at once (packets went through send, or an effect without apply_all)"
            )
        send_ns = np.asarray(send_ns, dtype=np.int64)
        arrival = send_ns.copy()
        fate = np.full(len(send_ns), DELIVERED, dtype=np.int64)
        for e in self.effects:
            e.apply_all(send_ns, arrival, fate)  # type: ignore[attr-defined]
        self.sent += len(send_ns)
        self.lost += int(np.count_nonzero(fate != DELIVERED))
        return arrival, fate

    def fate_counts(self, include_duplicates: bool = False) -> dict[str, int]:
        """Packets in the log per fate name (originals only unless `include_duplicates`)."""
        counts = dict.fromkeys(FATE_NAMES.values(), 0)
        for p in self.log:
            if include_duplicates or not p.duplicate:
                counts[FATE_NAMES[p.fate]] += 1
        return counts

    def loss_rate(self) -> float:
        """Fraction of original packets lost in the network so far (late ones are not counted)."""
        return self.lost / self.sent if self.sent else 0.0


# --------------------------------------------------------------------------------------------
# Traces.


def _trace_rows(path: str | os.PathLike[str], columns: int, header: tuple[str, ...]) -> list[tuple[int, list[str]]]:
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise ValueError(f"{p}: cannot read trace file ({exc.strerror or exc})") from None
    rows: list[tuple[int, list[str]]] = []
    first = True
    for lineno, row in enumerate(csv.reader(text.splitlines()), start=1):
        cells = [c.strip() for c in row]
        if not cells or all(not c for c in cells) or cells[0].startswith("#"):
            continue
        if first:
            first = False
            if tuple(c.lower() for c in cells) == header:
                continue
        if len(cells) != columns:
            raise ValueError(f"{p}: row {lineno}: expected {columns} column(s) {','.join(header)}, got {len(cells)}")
        rows.append((lineno, cells))
    if not rows:
        raise ValueError(f"{p}: no data rows (expected {','.join(header)})")
    return rows


def load_delay_trace(path: str | os.PathLike[str]) -> tuple[np.ndarray, np.ndarray]:
    """Read a delay trace CSV `time_s,delay_s` (optional header, `#` comments) into two arrays.

    Raises ValueError naming the file, the row and the problem: wrong column count, a value
    that is not a finite number, time not strictly increasing or negative, negative delay."""
    times: list[float] = []
    delays: list[float] = []
    for lineno, (ts, ds) in _trace_rows(path, 2, ("time_s", "delay_s")):
        try:
            t, d = float(ts), float(ds)
        except ValueError:
            raise ValueError(f"{path}: row {lineno}: {ts!r}, {ds!r} are not two numbers time_s,delay_s") from None
        if not (math.isfinite(t) and math.isfinite(d)):
            raise ValueError(f"{path}: row {lineno}: values must be finite, got {ts}, {ds}")
        if t < 0.0:
            raise ValueError(f"{path}: row {lineno}: time_s must be >= 0, got {t}")
        if times and t <= times[-1]:
            raise ValueError(f"{path}: row {lineno}: time_s must increase strictly, got {t} after {times[-1]}")
        if d < 0.0:
            raise ValueError(f"{path}: row {lineno}: delay_s must be >= 0, got {d}")
        times.append(t)
        delays.append(d)
    return np.asarray(times), np.asarray(delays)


def load_loss_trace(path: str | os.PathLike[str]) -> np.ndarray:
    """Read a loss trace: one `lost` value per row, 0 (delivered) or 1 (lost), optional header
    and `#` comments. Returns a bool array; raises ValueError naming file, row and problem."""
    out: list[bool] = []
    for lineno, (v,) in _trace_rows(path, 1, ("lost",)):
        if v not in ("0", "1"):
            raise ValueError(f"{path}: row {lineno}: expected 0 or 1, got {v!r}")
        out.append(v == "1")
    return np.asarray(out, dtype=bool)


# --------------------------------------------------------------------------------------------
# Configuration (see haptic_teleop/schema.py for the conventions).

_P = {"min": 0.0, "max": 1.0}
_CORR = {"min": 0.0, "lt": 1.0, "help": "netem correlation with the previous draw, as a fraction (25% = 0.25)"}


@dataclass(frozen=True)
class BlackoutConfig:
    starts_s: tuple[float, ...] = field(metadata={"min": 0.0, "help": "start of each link-down window"})
    ends_s: tuple[float, ...] = field(metadata={"min": 0.0, "help": "end of each window (exclusive)"})

    def __post_init__(self) -> None:
        if not self.starts_s or len(self.starts_s) != len(self.ends_s):
            raise ValueError(
                f"starts_s and ends_s need the same number of entries (at least one), "
                f"got {len(self.starts_s)} and {len(self.ends_s)}"
            )
        prev_end = None
        for a, b in zip(self.starts_s, self.ends_s, strict=True):
            if b <= a:
                raise ValueError(f"window [{a}, {b}) s ends before it starts")
            if prev_end is not None and a < prev_end:
                raise ValueError(f"windows must be in time order without overlap: {a} s starts before {prev_end} s")
            prev_end = b


@dataclass(frozen=True)
class RateLimitConfig:
    rate_bps: float = field(metadata={"min": 1.0, "max": 1e12, "help": "token rate in bits per second, wire bytes"})
    burst_bytes: int = field(
        default=1500, metadata={"min": 1, "max": 1 << 30, "help": "bucket depth; must hold the largest packet"}
    )
    queue_limit_packets: int = field(
        default=1000,
        metadata={"min": 0, "max": 1 << 24, "help": "packets that may wait for tokens; more are dropped; 0 polices"},
    )
    overhead_bytes: int = field(
        default=DEFAULT_OVERHEAD_BYTES,
        metadata={
            "min": 0,
            "max": 65535,
            "help": "bytes per packet besides the message: IPv4 20+UDP 8+RTPS 20+DATA 24",
        },
    )

    def __post_init__(self) -> None:
        if self.burst_bytes < self.overhead_bytes + 1:
            raise ValueError(
                f"burst_bytes ({self.burst_bytes}) must exceed overhead_bytes ({self.overhead_bytes}): "
                "no packet would ever fit in the bucket"
            )


def _ge_stats(p: float, r: float, loss_bad: float, loss_good: float) -> tuple[float, float]:
    """(stationary loss rate, mean loss-burst length) of netem's Gilbert-Elliott chain."""
    if p == 0.0:
        return loss_good, (1.0 / (1.0 - loss_good) if loss_good < 1.0 else math.inf)  # stays good
    pi_bad = p / (p + r)
    pi_good = r / (p + r)
    rate = pi_good * loss_good + pi_bad * loss_bad
    # A burst starts at packet n when packet n-1 was delivered and packet n is lost.
    starts = pi_good * (1 - loss_good) * ((1 - p) * loss_good + p * loss_bad) + pi_bad * (1 - loss_bad) * (
        r * loss_good + (1 - r) * loss_bad
    )
    return rate, (rate / starts if starts > 0.0 else math.inf)


def _four_state_stats(p13: float, p31: float, p32: float, p23: float, p14: float) -> tuple[float, float]:
    """(stationary loss rate, mean loss-burst length) of netem's 4-state chain."""
    if p13 == 0.0:
        w = (1.0, 0.0, 0.0, p14)
    else:
        w = (1.0, p13 * p32 / (p31 * p23) if p32 > 0.0 else 0.0, p13 / p31, p14)
    total = sum(w)
    pi1, pi2, pi3, pi4 = (x / total for x in w)
    starts = pi1 * (p13 + p14) + pi2 * p23
    rate = pi3 + pi4
    return rate, (rate / starts if starts > 0.0 else math.inf)


LOSS_MODELS = ("bernoulli", "gilbert", "gilbert_elliott", "four_state", "trace")
# Which keys each model uses (besides `model`); a key of another model is a contradiction.
_LOSS_KEYS = {
    "bernoulli": ("probability", "correlation"),
    "gilbert": ("p", "r", "one_minus_h"),
    "gilbert_elliott": ("p", "r", "one_minus_h", "one_minus_k"),
    "four_state": ("p13", "p31", "p32", "p23", "p14"),
    "trace": ("file", "repeat"),
}
_LOSS_REQUIRED = {
    "bernoulli": ("probability",),
    "gilbert": ("p", "r"),
    "gilbert_elliott": ("p", "r"),
    "four_state": ("p13",),
    "trace": ("file",),
}


@dataclass(frozen=True)
class LossConfig:
    """One loss model, with netem's parameters (`loss random`, `gemodel`, `state`) or a trace."""

    model: str = field(default="bernoulli", metadata={"choices": LOSS_MODELS, "help": "which loss model"})
    probability: float | None = field(default=None, metadata={**_P, "help": "bernoulli: loss probability"})
    correlation: float | None = field(default=None, metadata={**_CORR, "help": "bernoulli: netem correlation"})
    p: float | None = field(default=None, metadata={**_P, "help": "gilbert(_elliott): P(good -> bad) per packet"})
    r: float | None = field(default=None, metadata={**_P, "help": "gilbert(_elliott): P(bad -> good) per packet"})
    one_minus_h: float | None = field(
        default=None, metadata={**_P, "help": "gilbert(_elliott): loss probability in bad state (netem 1-h, default 1)"}
    )
    one_minus_k: float | None = field(
        default=None, metadata={**_P, "help": "gilbert_elliott: loss probability in good state (netem 1-k, default 0)"}
    )
    p13: float | None = field(default=None, metadata={**_P, "help": "four_state: gap -> burst loss"})
    p31: float | None = field(default=None, metadata={**_P, "help": "four_state: burst loss -> gap (default 1-p13)"})
    p32: float | None = field(default=None, metadata={**_P, "help": "four_state: burst loss -> burst rx (default 0)"})
    p23: float | None = field(default=None, metadata={**_P, "help": "four_state: burst rx -> burst loss (default 1)"})
    p14: float | None = field(default=None, metadata={**_P, "help": "four_state: gap -> isolated loss (default 0)"})
    file: str | None = field(default=None, metadata={"help": "trace: CSV of 0/1 per packet (1 = lost)"})
    repeat: bool | None = field(default=None, metadata={"help": "trace: start over at the end (default true)"})

    def __post_init__(self) -> None:
        m = self.model
        if m not in _LOSS_KEYS:  # build() checks choices; direct construction too
            raise ValueError(f"model must be one of {', '.join(LOSS_MODELS)}, got {m!r}")
        stray = [k for ks in _LOSS_KEYS.values() for k in ks if k not in _LOSS_KEYS[m] and getattr(self, k) is not None]
        if stray:
            raise ValueError(
                f"{', '.join(dict.fromkeys(stray))} not used by loss model {m!r} (uses {', '.join(_LOSS_KEYS[m])})"
            )
        missing = [k for k in _LOSS_REQUIRED[m] if getattr(self, k) is None]
        if missing:
            raise ValueError(f"loss model {m!r} needs {', '.join(missing)}")
        if m in ("gilbert", "gilbert_elliott"):
            assert self.p is not None and self.r is not None
            if self.p > 0.0 and self.r == 0.0:
                raise ValueError(
                    "r = 0 with p > 0 makes the bad state absorbing: every packet after the first burst is lost"
                )
        if m == "four_state":
            if self.p31 is None and any(getattr(self, k) is not None for k in ("p32", "p23", "p14")):
                raise ValueError("give p31 too: its default 1 - p13 (netem's) only applies when p13 is given alone")
            p13, p31, p32, p23, p14 = self.four_state_parameters()
            if p13 + p14 > 1.0:
                raise ValueError(f"p13 + p14 = {p13 + p14} exceeds 1 (both leave state 1)")
            if p31 + p32 > 1.0:
                raise ValueError(f"p31 + p32 = {p31 + p32} exceeds 1 (both leave state 3)")
            if p13 > 0.0 and p31 == 0.0:
                raise ValueError("p31 = 0 with p13 > 0 never ends a burst: every packet after the first burst is lost")
            if p13 > 0.0 and p32 > 0.0 and p23 == 0.0:
                raise ValueError("p23 = 0 with p32 > 0 makes state 2 absorbing: losses stop after the first burst")

    def gilbert_elliott_parameters(self) -> tuple[float, float, float, float]:
        """(p, r, 1-h, 1-k) with netem's defaults filled in (gilbert: 1-k = 0)."""
        assert self.p is not None and self.r is not None
        h = 1.0 if self.one_minus_h is None else self.one_minus_h
        k = 0.0 if self.one_minus_k is None else self.one_minus_k
        return self.p, self.r, h, k

    def four_state_parameters(self) -> tuple[float, float, float, float, float]:
        """(p13, p31, p32, p23, p14) with netem's defaults (p13 alone is Bernoulli)."""
        assert self.p13 is not None
        p13 = self.p13
        p31 = 1.0 - p13 if self.p31 is None else self.p31
        p32 = 0.0 if self.p32 is None else self.p32
        p23 = 1.0 if self.p23 is None else self.p23
        p14 = 0.0 if self.p14 is None else self.p14
        return p13, p31, p32, p23, p14

    def expected_loss_rate(self) -> float:
        """Long-run fraction of packets lost (NaN for a trace; for correlated bernoulli exact only
        with the gaussian_copula correlation model). See docs/network.md for the derivations."""
        m = self.model
        if m == "bernoulli":
            assert self.probability is not None
            return self.probability
        if m in ("gilbert", "gilbert_elliott"):
            return _ge_stats(*self.gilbert_elliott_parameters())[0]
        if m == "four_state":
            return _four_state_stats(*self.four_state_parameters())[0]
        return math.nan

    def expected_mean_burst_packets(self) -> float:
        """Mean length of a run of consecutive lost packets (1/r for simple Gilbert)."""
        m = self.model
        if m == "bernoulli":
            assert self.probability is not None
            return 1.0 / (1.0 - self.probability) if self.probability < 1.0 else math.inf
        if m in ("gilbert", "gilbert_elliott"):
            return _ge_stats(*self.gilbert_elliott_parameters())[1]
        if m == "four_state":
            return _four_state_stats(*self.four_state_parameters())[1]
        return math.nan


@dataclass(frozen=True)
class DuplicateConfig:
    probability: float = field(metadata={**_P, "help": "probability a delivered packet gets a copy"})
    correlation: float = field(default=0.0, metadata=_CORR)


@dataclass(frozen=True)
class CorruptConfig:
    probability: float = field(metadata={**_P, "help": "probability of a bit error (the receiver discards it)"})
    correlation: float = field(default=0.0, metadata=_CORR)


@dataclass(frozen=True)
class DelayScheduleConfig:
    times_s: tuple[float, ...] = field(metadata={"min": 0.0, "help": "points in time, strictly increasing"})
    delays_s: tuple[float, ...] = field(metadata={"min": 0.0, "max": 3600.0, "help": "extra delay at each point"})
    interpolation: str = field(default="linear", metadata={"choices": ("linear", "step"), "help": "ramps or steps"})

    def __post_init__(self) -> None:
        if not self.times_s or len(self.times_s) != len(self.delays_s):
            raise ValueError(
                f"times_s and delays_s need the same number of entries (at least one), "
                f"got {len(self.times_s)} and {len(self.delays_s)}"
            )
        for a, b in itertools.pairwise(self.times_s):
            if b <= a:
                raise ValueError(f"times_s must increase strictly: {b} after {a}")


@dataclass(frozen=True)
class DelaySinusoidConfig:
    min_delay_s: float = field(metadata={"min": 0.0, "max": 3600.0, "help": "lowest extra delay (at t = -phase_s)"})
    max_delay_s: float = field(metadata={"min": 0.0, "max": 3600.0, "help": "highest extra delay"})
    period_s: float = field(metadata={"gt": 0.0, "max": 1e6, "help": "one full cycle, min -> max -> min"})
    phase_s: float = field(default=0.0, metadata={"min": 0.0, "max": 1e6, "help": "time shift of the cycle"})

    def __post_init__(self) -> None:
        if self.max_delay_s < self.min_delay_s:
            raise ValueError(f"max_delay_s ({self.max_delay_s}) is below min_delay_s ({self.min_delay_s})")


@dataclass(frozen=True)
class DelayTraceConfig:
    file: str = field(metadata={"help": "CSV time_s,delay_s (extra delay); relative to the scene folder"})
    interpolation: str = field(
        default="linear", metadata={"choices": ("linear", "step"), "help": "between rows: ramps or steps"}
    )


@dataclass(frozen=True)
class DelayConfig:
    delay_s: float = field(default=0.0, metadata={"min": 0.0, "max": 3600.0, "help": "constant one-way delay"})
    jitter_s: float = field(
        default=0.0, metadata={"min": 0.0, "max": 3600.0, "help": "netem jitter (sigma for normal, half-width uniform)"}
    )
    distribution: str = field(default="normal", metadata={"choices": DISTRIBUTIONS, "help": "jitter shape"})
    correlation: float = field(default=0.0, metadata=_CORR)
    schedule: DelayScheduleConfig | None = None
    sinusoid: DelaySinusoidConfig | None = None
    trace: DelayTraceConfig | None = None
    keep_order: bool = field(default=False, metadata={"help": "no overtaking (netem with rate or a pfifo child)"})

    def __post_init__(self) -> None:
        named = [k for k in ("schedule", "sinusoid", "trace") if getattr(self, k) is not None]
        if len(named) > 1:
            raise ValueError(f"name at most one time-varying delay (schedule, sinusoid, trace), got {', '.join(named)}")

    @property
    def is_zero(self) -> bool:
        """True when every packet gets no delay at all."""
        if self.delay_s > 0.0 or self.jitter_s > 0.0 or self.trace is not None:
            return False
        if self.schedule is not None:
            return not any(d > 0.0 for d in self.schedule.delays_s)
        if self.sinusoid is not None:
            return self.sinusoid.max_delay_s == 0.0
        return True


@dataclass(frozen=True)
class ReorderConfig:
    probability: float = field(metadata={**_P, "help": "fraction of eligible packets sent at once, skipping the delay"})
    correlation: float = field(default=0.0, metadata=_CORR)
    gap_packets: int = field(
        default=1,
        metadata={"min": 1, "max": 1 << 20, "help": "netem gap: packets delayed after each reordered one + 1"},
    )


@dataclass(frozen=True)
class NetworkEffectsConfig:
    """Effects of one direction; absent (None) effects are not built. Applied in CANONICAL_ORDER."""

    blackout: BlackoutConfig | None = None
    rate_limit: RateLimitConfig | None = None
    loss: LossConfig | None = None
    duplicate: DuplicateConfig | None = None
    corrupt: CorruptConfig | None = None
    delay: DelayConfig | None = None
    reorder: ReorderConfig | None = None
    correlation_model: str = field(
        default="netem",
        metadata={
            "choices": CORRELATION_MODELS,
            "help": "netem: (1-rho) fresh + rho last (shrinks the spread); gaussian_copula keeps the marginal",
        },
    )

    def __post_init__(self) -> None:
        if self.reorder is not None and (self.delay is None or self.delay.is_zero):
            raise ValueError(
                "reorder needs a delay: it sends some packets at once while the others keep the delay "
                "(netem refuses reorder without a delay too)"
            )


def canonical_order(cfg: NetworkEffectsConfig | None = None) -> tuple[str, ...]:
    """Names of the effects `cfg` configures, in the order a packet meets them (all if None)."""
    if cfg is None:
        return CANONICAL_ORDER
    return tuple(name for name in CANONICAL_ORDER if getattr(cfg, name) is not None)


def _resolve(path: str, base_dir: str | os.PathLike[str] | None) -> Path:
    p = Path(path)
    if not p.is_absolute() and base_dir is not None:
        p = Path(base_dir) / p
    return p


def resolve_trace_paths(cfg: NetworkEffectsConfig, base_dir: str | os.PathLike[str]) -> NetworkEffectsConfig:
    """Make trace paths absolute (relative to `base_dir`, the scene's folder) and check that each
    trace reads cleanly, so a bad trace is reported before anything runs. Returns the new config."""
    delay, loss = cfg.delay, cfg.loss
    if delay is not None and delay.trace is not None:
        p = _resolve(delay.trace.file, base_dir).resolve()
        load_delay_trace(p)
        delay = replace(delay, trace=replace(delay.trace, file=str(p)))
    if loss is not None and loss.model == "trace" and loss.file is not None:
        p = _resolve(loss.file, base_dir).resolve()
        load_loss_trace(p)
        loss = replace(loss, file=str(p))
    return replace(cfg, delay=delay, loss=loss)


def _build_loss(
    cfg: LossConfig, rng: np.random.Generator, model: str, base_dir: str | os.PathLike[str] | None
) -> Effect:
    m = cfg.model
    if m == "bernoulli":
        assert cfg.probability is not None
        return BernoulliLoss(cfg.probability, rng, cfg.correlation or 0.0, model)
    if m in ("gilbert", "gilbert_elliott"):
        return GilbertElliottLoss(*cfg.gilbert_elliott_parameters(), rng)
    if m == "four_state":
        return FourStateLoss(*cfg.four_state_parameters(), rng=rng)
    assert cfg.file is not None
    return TraceLoss(load_loss_trace(_resolve(cfg.file, base_dir)), cfg.repeat is not False)


def build_link(
    cfg: NetworkEffectsConfig,
    seed: int,
    direction: str,
    *,
    base_dir: str | os.PathLike[str] | None = None,
) -> Link:
    """A `Link` with exactly the effects `cfg` names, in CANONICAL_ORDER, each on its own stream.

    Trace files are read here (through `load_delay_trace` / `load_loss_trace`); relative paths
    are taken from `base_dir` (or the working directory): see `resolve_trace_paths`."""

    def rng(name: str) -> np.random.Generator:
        return effect_rng(seed, direction, name)

    model = cfg.correlation_model
    effects: list[Effect] = []
    if cfg.blackout is not None:
        b = cfg.blackout
        effects.append(Blackout([(round(a * 1e9), round(e * 1e9)) for a, e in zip(b.starts_s, b.ends_s, strict=True)]))
    if cfg.rate_limit is not None:
        r = cfg.rate_limit
        effects.append(TokenBucket(r.rate_bps, r.burst_bytes, r.queue_limit_packets, r.overhead_bytes))
    if cfg.loss is not None:
        effects.append(_build_loss(cfg.loss, rng("loss"), model, base_dir))
    if cfg.duplicate is not None:
        d = cfg.duplicate
        effects.append(Duplicate(d.probability, rng("duplicate"), d.correlation, model))
    if cfg.corrupt is not None:
        c = cfg.corrupt
        effects.append(Corrupt(c.probability, rng("corrupt"), c.correlation, model, copy_rng=rng("corrupt:copy")))
    if cfg.delay is not None:
        effects.append(_build_delay(cfg.delay, cfg.reorder, rng, model, base_dir))
    return Link(effects)


def _build_delay(
    cfg: DelayConfig,
    reorder: ReorderConfig | None,
    rng: Callable[[str], np.random.Generator],
    model: str,
    base_dir: str | os.PathLike[str] | None,
) -> Effect:
    profile: Callable[[int], float] | None = None
    if cfg.schedule is not None:
        s = cfg.schedule
        profile = PiecewiseDelay(s.times_s, s.delays_s, s.interpolation)
    elif cfg.sinusoid is not None:
        w = cfg.sinusoid
        profile = SinusoidDelay(w.min_delay_s, w.max_delay_s, w.period_s, w.phase_s)
    elif cfg.trace is not None:
        ts, ds = load_delay_trace(_resolve(cfg.trace.file, base_dir))
        profile = PiecewiseDelay(ts.tolist(), ds.tolist(), cfg.trace.interpolation)
    if profile is None and cfg.jitter_s == 0.0 and reorder is None:
        return ConstantDelay(cfg.delay_s)  # order is kept by construction
    return Delay(
        cfg.delay_s,
        jitter_s=cfg.jitter_s,
        distribution=cfg.distribution,
        rng=rng("delay"),
        correlation=cfg.correlation,
        correlation_model=model,
        profile=profile,
        keep_order=cfg.keep_order,
        reorder_probability=reorder.probability if reorder else 0.0,
        reorder_correlation=reorder.correlation if reorder else 0.0,
        reorder_gap_packets=reorder.gap_packets if reorder else 1,
        reorder_rng=rng("reorder") if reorder else None,
        copy_rng=rng("delay:copy"),
    )

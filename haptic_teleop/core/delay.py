"""Effects that move a packet's arrival: the token bucket's queue, constant, time-varying and
jittered delays, with netem's ordering and reordering (docs/network_effects.md)."""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES, DELIVERED, LOST_QUEUE, Packet
from haptic_teleop.core.sorted_search import bisect_right_in
from haptic_teleop.core.uniform import (
    DISTRIBUTIONS,
    NetemCorrelatedUniform,
    UniformSource,
    jitter_quantile,
    jitter_table,
    netem_next,
    uniform_source,
    unit_jitter,
)

_NS_PER_S = 1_000_000_000


# TokenBucket's state (`token_step`), an int64 array: tokens (nano-bits), when they were counted,
# whether the bucket is full, the last departure, the waiting ring's head and count, drops.
TB_TOKENS, TB_T, TB_FULL, TB_LAST, TB_HEAD, TB_COUNT, TB_DROPPED = range(7)
TB_SIZE = 7


def token_step(S: Any, ring: Any, t_ns: int, need: int, depth: int, rate: int, limit: int) -> tuple[int, bool]:
    """One packet reaching the token bucket at `t_ns`, needing `need` nano-bits (at most `depth`):
    (its departure, whether the queue dropped it). `ring` holds the departures of the packets still
    waiting (at least `limit` slots, `limit` at least 1 long). One definition: `TokenBucket.apply`
    and `token_run` (compiled: the compiled loop's network schedule). Integer arithmetic, with the
    refill capped before it is multiplied, so that no product leaves int64 (Python's ints never
    overflow: the same values)."""
    cap = len(ring)
    head = S[TB_HEAD]
    count = S[TB_COUNT]
    while count > 0 and ring[head] <= t_ns:
        head = head + 1 if head + 1 < cap else 0
        count -= 1
    last = S[TB_LAST]
    start = t_ns if t_ns > last else last
    if S[TB_FULL]:
        tokens = depth
    else:
        have = S[TB_TOKENS]
        dt = start - S[TB_T]
        tokens = depth if dt >= (depth - have) // rate + 1 else min(depth, have + dt * rate)
    if tokens >= need:
        departure = start
        tokens -= need
    else:
        wait = -((tokens - need) // rate)  # ceil((need - tokens) / rate)
        departure = start + wait
        tokens = min(depth, tokens + wait * rate) - need
    if departure > t_ns:
        if count >= limit:
            S[TB_HEAD] = head
            S[TB_COUNT] = count
            S[TB_DROPPED] += 1
            return t_ns, True
        k = head + count
        ring[k - cap if k >= cap else k] = departure
        count += 1
    S[TB_TOKENS] = tokens
    S[TB_T] = departure
    S[TB_FULL] = 0
    S[TB_LAST] = departure
    S[TB_HEAD] = head
    S[TB_COUNT] = count
    return departure, False


def token_run(
    S: Any, ring: Any, arrivals: Any, lost: Any, delivered: Any, need: int, depth: int, rate: int, limit: int
) -> None:
    """`token_step` on a window's original packets in turn (each needing `need`): packet i reaches
    the bucket at arrivals[i] (overwritten with its departure) if delivered[i]; lost[i] set when the
    queue drops it."""
    for i in range(arrivals.shape[0]):
        if delivered[i]:
            arrivals[i], lost[i] = token_step(S, ring, arrivals[i], need, depth, rate, limit)


class TokenBucket:
    """Rate limit: a FIFO queue served by a token bucket (tbf), with tail drop.

    Tokens are bits; they accrue at `rate_bps` up to the bucket depth `burst_bytes`. A packet
    needs (size_bytes + overhead_bytes) * 8 tokens and leaves as soon as the packet ahead of it has
    left and the bucket holds enough. A packet that would have to wait while
    `queue_limit_packets` packets are already waiting is dropped (LOST_QUEUE); with a limit of 0
    the bucket polices instead of shaping. The departure time follows from the queue state at
    send time, so it is computed then. Integer arithmetic in nano-bits keeps it exact. The rule
    is `token_step`'s, over an int64 state and a ring of the waiting packets' departures.
    """

    name = "rate_limit"
    vectorized = True
    sized = True  # `apply_all` takes the packets' size (`Link.schedule_all`)

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
        # `token_step`'s state and ring as Python ints (a numpy scalar costs three times a list's
        # item); `apply_all` hands numpy copies to the run
        self._s = [0] * TB_SIZE
        self._s[TB_FULL] = 1  # the bucket starts full
        self._s[TB_LAST] = -(1 << 62)
        self._r = [0] * max(1, queue_limit_packets)

    @property
    def dropped(self) -> int:
        return int(self._s[TB_DROPPED])

    def transmit_time_ns(self, size_bytes: int) -> float:
        """Time one packet of `size_bytes` message bytes takes at the token rate."""
        return (size_bytes + self.overhead_bytes) * 8 * 1e9 / self.rate_bps

    def _need(self, size_bytes: int) -> int:
        need = (size_bytes + self.overhead_bytes) * 8 * _NS_PER_S
        if need > self._depth:
            raise ValueError(
                f"rate_limit: a packet of {size_bytes} + {self.overhead_bytes} overhead bytes "
                f"exceeds burst_bytes={self.burst_bytes}; it could never be sent"
            )
        return need

    def apply(self, packet: Packet) -> Packet | None:
        if packet.fate != DELIVERED:
            return None
        departure, dropped = token_step(
            self._s, self._r, packet.arrival_time_ns, self._need(packet.size_bytes), self._depth, self.rate_bps,
            self.queue_limit_packets,
        )  # fmt: skip
        if dropped:
            packet.fate = LOST_QUEUE
        else:
            packet.arrival_time_ns = departure
        return None

    def apply_all(
        self,
        send_ns: np.ndarray,
        arrival_ns: np.ndarray,
        fate: np.ndarray,
        runs: Mapping[str, Any] | None = None,
        size_bytes: int | None = None,
    ) -> None:
        """`apply` on every original packet of a window (all `size_bytes` long) at once
        (`Link.schedule_all`), by `token_run` (or `runs["token_run"]`, compiled) on the same state."""
        if size_bytes is None:
            raise ValueError("a rate limit decides a window only for packets of a known size (schedule_all size_bytes)")
        S = np.array(self._s, dtype=np.int64)
        ring = np.array(self._r, dtype=np.int64)
        lost = np.zeros(len(arrival_ns), dtype=np.bool_)
        run = token_run if runs is None else runs.get("token_run", token_run)
        run(S, ring, arrival_ns, lost, fate == DELIVERED, self._need(size_bytes), self._depth, self.rate_bps,
            self.queue_limit_packets)  # fmt: skip
        fate[lost] = LOST_QUEUE
        self._s, self._r = S.tolist(), ring.tolist()

    @property
    def queue_length(self) -> int:
        """Packets waiting after the last send (before time moves on)."""
        return int(self._s[TB_COUNT])


class ConstantDelay:
    """Fixed one-way delay."""

    name = "delay"

    def __init__(self, delay_s: float) -> None:
        if not delay_s >= 0.0:
            raise ValueError(f"delay_s must be >= 0, got {delay_s}")
        self.delay_ns = round(delay_s * 1e9)

    vectorized = True

    def apply_all(self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: object = None) -> None:
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
        return piecewise_at(self._t, self._d, self._linear, t_ns)

    def profile_args(self) -> tuple[int, np.ndarray, np.ndarray, bool, float, float, float, float]:
        """`profile_run`'s description of this profile."""
        return (
            PROFILE_PIECEWISE, np.array(self._t, dtype=np.int64), np.array(self._d, dtype=np.float64),
            self._linear, 0.0, 0.0, 0.0, 0.0,
        )  # fmt: skip


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
        return sinusoid_at(self._mid, self._amp, self._w, self._phase_ns, t_ns)

    def profile_args(self) -> tuple[int, np.ndarray, np.ndarray, bool, float, float, float, float]:
        """`profile_run`'s description of this profile."""
        none_i, none_f = np.zeros(0, dtype=np.int64), np.zeros(0)
        return PROFILE_SINUSOID, none_i, none_f, False, self._mid, self._amp, self._w, self._phase_ns


def piecewise_at(ts: Any, ds: Any, linear: bool, t_ns: int) -> float:
    """`PiecewiseDelay` at `t_ns` (points at times ts, ns, with delays ds, ns): held before the
    first and after the last point, linear or a step in between (bisect_right's index)."""
    i = bisect_right_in(ts, len(ts), t_ns)
    if i == 0:
        return ds[0]  # type: ignore[no-any-return]
    if i == len(ts) or not linear:
        return ds[i - 1]  # type: ignore[no-any-return]
    t0, t1 = ts[i - 1], ts[i]
    return ds[i - 1] + (ds[i] - ds[i - 1]) * (t_ns - t0) / (t1 - t0)  # type: ignore[no-any-return]


def sinusoid_at(mid: float, amp: float, w: float, phase_ns: float, t_ns: int) -> float:
    """`SinusoidDelay` at `t_ns`: mid - amp cos(w (t + phase))."""
    return mid - amp * math.cos(w * (t_ns + phase_ns))


PROFILE_PIECEWISE = 1
PROFILE_SINUSOID = 2


def profile_run(
    kind: int, ts: Any, ds: Any, linear: bool, mid: float, amp: float, w: float, phase_ns: float,
    times: Any, out: Any,
) -> None:  # fmt: skip
    """A time-varying delay's extra delay at each of `times` into `out` (`piecewise_at` or
    `sinusoid_at`, as `profile_args` describes the profile). One definition with the profiles'
    `__call__`; compiled in engine/compiled/link_runs.py."""
    for i in range(times.shape[0]):
        if kind == PROFILE_PIECEWISE:
            out[i] = piecewise_at(ts, ds, linear, times[i])
        else:
            out[i] = sinusoid_at(mid, amp, w, phase_ns, times[i])


def delayed_ns(t_ns: int, delay_ns: float) -> int:
    """A packet's arrival after a delay of `delay_ns` from `t_ns`: rounded to the ns, none if not
    positive. One definition: `Delay` and the compiled links (engine/compiled/codec_link.py)."""
    return t_ns + int(delay_ns + 0.5) if delay_ns > 0.0 else t_ns


def in_order_ns(arrival_ns: int, last_ns: int) -> int:
    """An arrival kept in order: no earlier than the one delivered before it (netem with a pfifo
    child or `rate`). One definition: `Delay` and the compiled links."""
    return arrival_ns if arrival_ns >= last_ns else last_ns


def delay_value_ns(base_ns: float, extra_ns: float, sigma_ns: float, unit: float) -> float:
    """A packet's delay: the base, the time-varying part at its time, and the jitter, `sigma_ns`
    times the distribution's value `unit` of its number (docs/network_effects.md). Not yet clamped:
    `delayed_ns` takes a delay that is not positive as none. One definition: `Delay` and the
    compiled links."""
    return base_ns + extra_ns + sigma_ns * unit


def arrival_ns(t_ns: int, delay_ns: float, keep_order: bool, delivered: bool, last_ns: int) -> tuple[int, int]:
    """A packet reaching the delay at `t_ns` and held `delay_ns`: its arrival (`delayed_ns`), with
    `keep_order` no earlier than the last delivered packet's (`in_order_ns`; a lost packet moves
    nothing); and the last delivered packet's arrival after it. One definition: `Delay` and the
    compiled links."""
    arrival = delayed_ns(t_ns, delay_ns)
    if keep_order and delivered:
        arrival = in_order_ns(arrival, last_ns)
        return arrival, arrival
    return arrival, last_ns


def reorder_skip(counter: int, r: float, p: float, gap: int) -> tuple[int, bool]:
    """netem's reorder decision for an original packet from its number `r` (`reorder p gap g`):
    after at least gap - 1 packets kept since the last skip, the packet skips the delay with
    probability p. `counter`: the packets kept since the last skip. Returns (the counter after
    it, whether it skips). One definition: `Delay.apply` and `delay_run`."""
    if counter < gap - 1 or r >= p:
        return counter + 1, False
    return 0, True


def delay_run(
    arrivals: np.ndarray,
    delivered: np.ndarray,
    fresh: np.ndarray,
    rho: float,
    last_u: float,
    table: np.ndarray,
    n_table: int,
    base_ns: float,
    sigma_ns: float,
    keep_order: bool,
    last_arrival: int,
    reorder_fresh: np.ndarray,
    reorder_rho: float,
    reorder_last: float,
    reorder_p: float,
    gap: int,
    counter: int,
    extra: np.ndarray,
) -> tuple[float, int, float, int, int]:
    """`Delay.apply` without a time-varying part on a window's original packets in turn: packet i
    reaches the delay at arrivals[i] (overwritten with its arrival), delivered[i] as it stands
    then, its fresh uniform number fresh[i] (netem-correlated with the last one, `last_u`, if
    rho > 0), its jitter `unit_jitter` of it (`table` of `n_table` values, 0: netem's uniform).
    Without jitter `fresh` is empty and every unit 0. Then, with reordering, its reorder number
    from reorder_fresh[i] (netem-correlated with `reorder_last` if reorder_rho > 0) and
    `reorder_skip` (`counter`, `reorder_p`, `gap`): a packet that skips keeps the arrival it came
    with (no delay, not held behind others, the last delivered arrival unchanged). Without
    reordering `reorder_fresh` is empty. `extra`: a time-varying delay's part at each packet's time
    (`profile_run`; empty: none). Returns the jitter stream's last number, the last
    delivered arrival (`keep_order`), the reorder stream's last number, the counter, and how many
    delivered packets skipped. One definition for `Delay.apply_all` and, compiled, the compiled
    loop's network schedule (engine/compiled/link_runs.py)."""
    jitter = fresh.shape[0] > 0
    reorder = reorder_fresh.shape[0] > 0
    varying = extra.shape[0] > 0
    reordered = 0
    for i in range(arrivals.shape[0]):
        unit = 0.0
        if jitter:
            u = fresh[i]
            if rho > 0.0:
                u = netem_next(u, rho, last_u)
                last_u = u
            unit = unit_jitter(u, table, n_table)
        d = delay_value_ns(base_ns, extra[i] if varying else 0.0, sigma_ns, unit)
        if reorder:
            r = reorder_fresh[i]
            if reorder_rho > 0.0:
                r = netem_next(r, reorder_rho, reorder_last)
                reorder_last = r
            counter, skip = reorder_skip(counter, r, reorder_p, gap)
            if skip:
                if delivered[i]:
                    reordered += 1
                continue
        arrivals[i], last_arrival = arrival_ns(arrivals[i], d, keep_order, delivered[i], last_arrival)
    return last_u, last_arrival, reorder_last, counter, reordered


def _window_numbers(draw: Callable[[], float] | None, n: int) -> tuple[np.ndarray, float, float, Any]:
    """The next `n` numbers of an effect's stream (its draw function, None: no stream) as a run
    takes them: the fresh uniforms (`UniformSource.take`), netem's correlation (0: none), its last
    number, and the `NetemCorrelatedUniform` to write the last number back to (or None)."""
    if draw is None:
        return np.zeros(0), 0.0, 0.0, None
    src = draw.__self__  # type: ignore[attr-defined]
    if type(src) is NetemCorrelatedUniform:
        return src._fresh.__self__.take(n), src._rho, src._last, src  # type: ignore[attr-defined]
    return src.take(n), 0.0, 0.0, None


def _generator(draw: Callable[[], float]) -> Any:
    """The bit generator behind a plain or netem-correlated draw function (else None)."""
    src = getattr(draw, "__self__", None)
    if type(src) is NetemCorrelatedUniform:
        src = src._fresh.__self__  # type: ignore[attr-defined]
    return src._rng.bit_generator if type(src) is UniformSource else None


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
        self.distribution = distribution
        self._quantile = jitter_quantile(distribution)
        # the same values as `_quantile`'s table, for `delay_run` (empty: netem's uniform, 2 u - 1)
        self._table = np.array(() if distribution == "uniform" else jitter_table(distribution), dtype=np.float64)
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

    @property
    def vectorized(self) -> bool:
        """True if `apply_all` decides a window at once: a time-varying part (if any) a schedule, a
        trace or a sinusoid (`PiecewiseDelay`, `SinusoidDelay`), and the jitter and
        the reordering (if any) uncorrelated or netem-correlated (not the Gaussian copula), each
        on its own generator (else their blocks of numbers interleave packet by packet)."""
        if self._profile is not None and type(self._profile) not in (PiecewiseDelay, SinusoidDelay):
            return False
        draws = [d for d in (self._ju, self._ru) if d is not None]
        gens = [_generator(d) for d in draws]
        return None not in gens and len({id(g) for g in gens}) == len(gens)

    def apply_all(
        self, send_ns: np.ndarray, arrival_ns: np.ndarray, fate: np.ndarray, runs: Mapping[str, Any] | None = None
    ) -> None:
        """`apply` on every original packet of a window at once (`Link.schedule_all`): the same
        numbers (`UniformSource.take`: each packet's jitter number, then its reorder number), the
        same arrivals and skips, bit for bit, by `delay_run` (or `runs["delay_run"]`, compiled). A
        packet reaches the delay at `arrival_ns` as the effects before it left it, with the fate
        they gave it."""
        if not self.vectorized:
            raise ValueError(
                "a time-varying delay given as a function, or copula-correlated jitter or reordering, "
                "has no vectorized form"
            )
        n = len(arrival_ns)
        fresh, rho, last_u, netem = _window_numbers(self._ju, n)
        r_fresh, r_rho, r_last, r_netem = _window_numbers(self._ru, n)
        extra = np.zeros(0)
        if self._profile is not None:
            extra = np.empty(n)
            at: Callable[..., None] = profile_run if runs is None else runs.get("profile_run", profile_run)
            profile: PiecewiseDelay | SinusoidDelay = self._profile  # type: ignore[assignment]
            at(*profile.profile_args(), arrival_ns, extra)
        run = delay_run if runs is None else runs.get("delay_run", delay_run)
        last_u, last, r_last, counter, reordered = run(
            arrival_ns, fate == DELIVERED, fresh, rho, last_u, self._table, len(self._table),
            self._base_ns, self._sigma_ns, bool(self._keep_order), int(self._last_arrival),
            r_fresh, r_rho, r_last, float(self._reorder_p), int(self._gap), int(self._counter), extra,
        )  # fmt: skip
        if netem is not None:
            netem._last = float(last_u)
        if r_netem is not None:
            r_netem._last = float(r_last)
        self._last_arrival = int(last)
        self._counter = int(counter)
        self.reordered += int(reordered)

    def apply(self, packet: Packet) -> Packet | None:
        t = packet.arrival_time_ns
        copy = packet.duplicate
        extra = self._profile(t) if self._profile is not None else 0.0
        unit = 0.0
        if self._ju is not None:
            unit = self._quantile(self._copy_draw() if copy else self._ju())
        d = delay_value_ns(self._base_ns, extra, self._sigma_ns, unit)
        if self._ru is not None:
            if copy:
                skip = self._copy_draw() < self._reorder_p
            else:  # drawn for every original packet, lost or not (core/link.py)
                self._counter, skip = reorder_skip(self._counter, self._ru(), self._reorder_p, self._gap)
            if skip:
                # "Sent immediately": no delay and not held behind earlier packets.
                if packet.fate == DELIVERED:
                    self.reordered += 1
                return None
        packet.arrival_time_ns, self._last_arrival = arrival_ns(
            t, d, self._keep_order, packet.fate == DELIVERED, self._last_arrival
        )
        return None

"""Haptic synchronization (playout) buffers: which received sample a side uses at each tick.

Policies share one interface: `push(packet, now_ns)` on arrival, `release(now_ns)` once per tick,
returning the packet to use from this tick on, or None to keep using the last one (hold).
No synchronized clocks are assumed between the sides: every schedule is built from relative
delays (receiver clock at arrival minus the sender's stamp), which carry the unknown clock offset
as a constant that cancels. Formulas, derivations and parameters are in docs/playout.md.

Policies: `none` (play on arrival), `fixed` (minimum relative delay + a fixed buffering time),
`adaptive` (Ramjee et al. 1994, algorithm 1: d + 4 v), `percentile` (NetEq-like quantile of a
sliding window), `transparency` (the buffering time that minimises the EBA force error of
seed 000 under its allowable-delay cap, with a contact horizon) and `network_adaptive` (seed 000's
network-adaptive buffering as the seed describes it: the buffering time from the transparency
analysis' allowable delay and loss time and the minimum network delay, no free horizon).

The tick path is plain Python on ints: a heap of held packets, a ring of recently seen sequence
numbers (duplicates), and per-policy estimators that cost O(1) or O(log window) per packet.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from array import array
from bisect import bisect_left, bisect_right, insort
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from haptic_teleop.core.link import LOST_LATE, Packet

POLICIES = ("none", "fixed", "adaptive", "percentile", "transparency", "network_adaptive")
GAP_MODES = ("hold", "extrapolate")
RAMJEE_SMOOTHING = 0.998002  # alpha of Ramjee et al. (1994), algorithm 1

# Duplicate detection remembers the last _SEEN_SLOTS sequence numbers in a ring (32 s at 1 kHz):
# an arrival that repeats a sequence number older than that is counted late, not duplicate.
_SEEN_SLOTS = 1 << 15
_SEEN_MASK = _SEEN_SLOTS - 1
_NO_SEQ = -(1 << 63)
# Transparency policy: a new decision (O(window)) every _RETARGET_PACKETS arrivals, and at
# arrivals 1, 2, 4, ... while the window fills.
_RETARGET_PACKETS = 64


@dataclass(slots=True)
class ExtrapolatedPacket(Packet):
    """A sample the buffer made up for an empty slot (`gap: extrapolate`), never received.

    `seq` and `send_time_ns` are those of the slot it stands in for; test with
    `isinstance(p, ExtrapolatedPacket)` or `getattr(p, "extrapolated", False)`.
    """

    extrapolated: bool = True


class PlayoutBuffer(Protocol):
    """What the engine and the sync_buffer node use; every policy implements it."""

    name: str
    late: int  # packets that arrived but were never played (fate LOST_LATE)
    duplicates: int  # arrivals of a sequence number already received (ignored, not lost)
    played: int  # received packets released
    extrapolated: int  # made-up packets released (gap: extrapolate)
    last_buffering_ns: int  # release time - arrival time of the last released packet (-1: extrapolated)

    @property
    def occupancy(self) -> int: ...

    @property
    def extrapolates(self) -> bool: ...

    def push(self, packet: Packet, now_ns: int) -> None: ...

    def oldest_held_seq(self) -> int | None: ...

    def release(self, now_ns: int) -> Packet | None: ...


def contact_force_slope(stiffness_n_per_m: float, speed_m_per_s: float) -> float:
    """Seed 000: in contact the felt force rises at about c * v_m (N/s)."""
    return abs(stiffness_n_per_m * speed_m_per_s)


class _BufferBase:
    """Accounting shared by every policy: duplicates, late marking, played / gap bookkeeping."""

    name = "base"

    def __init__(self, period_ns: int, gap: str, max_extrapolation_ns: int) -> None:
        if gap not in GAP_MODES:
            raise ValueError(f"gap must be one of {GAP_MODES}, got {gap!r}")
        if gap == "extrapolate" and not period_ns > 0:
            raise ValueError(f"gap 'extrapolate' needs period_ns > 0, got {period_ns}")
        if max_extrapolation_ns < 0:
            raise ValueError(f"max_extrapolation_ns must be >= 0, got {max_extrapolation_ns}")
        self.period_ns = period_ns
        self._extrapolate = gap == "extrapolate"
        self._max_extra_slots = max_extrapolation_ns // period_ns if period_ns > 0 else 0
        self.late = 0
        self.duplicates = 0
        self.played = 0
        self.extrapolated = 0
        self.last_buffering_ns = -1
        self._seen = array("q", [_NO_SEQ]) * _SEEN_SLOTS
        self._last_out_seq = _NO_SEQ  # seq of the last released packet, received or made up
        self._last_real: Packet | None = None
        self._prev_real: Packet | None = None

    @property
    def extrapolates(self) -> bool:
        """Whether the buffer makes up samples for empty slots (`gap: extrapolate`): what it
        releases then depends on the payloads it received, not only on sequence numbers."""
        return self._extrapolate

    def _is_duplicate(self, seq: int) -> bool:
        i = seq & _SEEN_MASK
        if self._seen[i] == seq:
            self.duplicates += 1
            return True
        self._seen[i] = seq
        return False

    def _mark_late(self, packet: Packet) -> None:
        packet.fate = LOST_LATE
        self.late += 1

    def _play(self, packet: Packet, arrived_ns: int, now_ns: int) -> Packet:
        self.played += 1
        self.last_buffering_ns = now_ns - arrived_ns
        self._last_out_seq = packet.seq
        self._prev_real = self._last_real
        self._last_real = packet
        return packet

    def _fill(self, slot: int, now_ns: int) -> Packet | None:
        """The linear extrapolation of the last two received samples to `slot`, or None (hold)."""
        last, prev = self._last_real, self._prev_real
        if last is None or prev is None:
            return None
        ahead = slot - last.seq
        if ahead > self._max_extra_slots:
            return None  # past the limit: hold the last made-up value
        k = ahead / (last.seq - prev.seq)
        payload = tuple(b + (b - a) * k for a, b in zip(prev.payload, last.payload, strict=True))
        self.extrapolated += 1
        self.last_buffering_ns = -1
        self._last_out_seq = slot
        return ExtrapolatedPacket(
            seq=slot,
            send_time_ns=last.send_time_ns + ahead * self.period_ns,
            payload=payload,
            arrival_time_ns=now_ns,
        )


class PlayOnArrival(_BufferBase):
    """Policy `none`: play the newest arrival at once; anything older than what was played is late.

    With `gap="extrapolate"`, a tick that brings nothing new extrapolates to the slot that many
    periods after the last received sample was played (dead reckoning between arrivals). There
    is no schedule here, so a made-up sample does not make a received one late: any arrival newer
    than the last received sample played is played, even if an extrapolation ran past its seq.
    """

    name = "none"

    def __init__(self, period_ns: int = 0, gap: str = "hold", max_extrapolation_ns: int = 0) -> None:
        super().__init__(period_ns, gap, max_extrapolation_ns)
        self._pending: Packet | None = None
        self._pending_arrived_ns = 0
        self._last_play_ns = 0

    @property
    def occupancy(self) -> int:
        return 0 if self._pending is None else 1

    def oldest_held_seq(self) -> int | None:
        """The lowest sequence number the buffer holds (its fate may still change), or None."""
        return None if self._pending is None else self._pending.seq

    def push(self, packet: Packet, now_ns: int) -> None:
        if self._is_duplicate(packet.seq):
            return
        pending = self._pending
        last = self._last_real
        if (last is not None and packet.seq <= last.seq) or (pending is not None and packet.seq < pending.seq):
            self._mark_late(packet)
            return
        if pending is not None:
            self._mark_late(pending)
        self._pending = packet
        self._pending_arrived_ns = now_ns

    def release(self, now_ns: int) -> Packet | None:
        p = self._pending
        if p is not None:
            self._pending = None
            self._last_play_ns = now_ns
            return self._play(p, self._pending_arrived_ns, now_ns)
        last = self._last_real
        if self._extrapolate and last is not None:
            slot = last.seq + (now_ns - self._last_play_ns) // self.period_ns
            if slot > self._last_out_seq:
                return self._fill(slot, now_ns)
        return None


class _ScheduledBuffer(_BufferBase):
    """Play sample k at send_time_k + D on the receiver's clock, D the playout delay.

    D includes the unknown clock offset: policies estimate it from relative delays
    n = arrival (receiver clock) - send stamp (sender clock). Estimates are kept relative to the
    first packet's n (an integer), so a constant clock offset changes no computation at all.

    Before the first sample is played D follows the policy's target freely. Afterwards it moves
    towards the target only when they differ by more than the hysteresis, and then by at most
    `max_slew_rate` seconds per second of receiver time: the played timeline (now - D) never runs
    backwards and advances by at most (1 + rate) periods per period, so a change of D stretches
    (holds) or skips at most one sample per `1 / rate` samples.
    """

    def __init__(
        self,
        period_ns: int,
        *,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        if not period_ns > 0:
            raise ValueError(f"period_ns must be > 0, got {period_ns}")
        if not 0.0 < max_slew_rate <= 1.0:
            raise ValueError(f"max_slew_rate must be in (0, 1], got {max_slew_rate}")
        if hysteresis_ns < 0:
            raise ValueError(f"hysteresis_ns must be >= 0, got {hysteresis_ns}")
        super().__init__(period_ns, gap, max_extrapolation_ns)
        self._slew = max_slew_rate
        self._hysteresis_ns = hysteresis_ns
        self._heap: list[tuple[int, int, Packet]] = []  # (seq, arrival now_ns, packet)
        self._ref: int | None = None  # relative delay of the first packet
        self._target_rel = 0  # the policy's target D, relative to _ref
        self.playout_delay_ns: int | None = None  # D in use (receiver clock - send stamp)
        self._started = False
        self._moving = False
        self._last_release_ns = 0

    @property
    def occupancy(self) -> int:
        return len(self._heap)

    def oldest_held_seq(self) -> int | None:
        """The lowest sequence number the buffer holds (its fate may still change), or None."""
        return self._heap[0][0] if self._heap else None

    @property
    def target_delay_ns(self) -> int | None:
        """The policy's current choice of D (receiver clock - send stamp, clock offset included)."""
        return None if self._ref is None else self._ref + self._target_rel

    def _observe(self, rel_ns: int) -> None:
        """Update the estimator with one relative delay (relative to the first packet's)."""
        raise NotImplementedError

    def push(self, packet: Packet, now_ns: int) -> None:
        if self._is_duplicate(packet.seq):
            return
        rel = now_ns - packet.send_time_ns
        ref = self._ref
        if ref is None:
            ref = self._ref = rel
        self._observe(rel - ref)
        if packet.seq <= self._last_out_seq:
            self._mark_late(packet)
            return
        heapq.heappush(self._heap, (packet.seq, now_ns, packet))
        if not self._started:
            self.playout_delay_ns = ref + self._target_rel

    def release(self, now_ns: int) -> Packet | None:
        delay = self.playout_delay_ns
        if delay is None:
            return None
        if self._started:
            target = self._target_rel + (self._ref or 0)
            if target == delay:
                self._moving = False
            elif self._moving or abs(target - delay) > self._hysteresis_ns:
                step = int((now_ns - self._last_release_ns) * self._slew)
                delay = min(target, delay + step) if target > delay else max(target, delay - step)
                self._moving = delay != target
                self.playout_delay_ns = delay
        self._last_release_ns = now_ns
        cutoff = now_ns - delay
        heap = self._heap
        best: tuple[int, int, Packet] | None = None
        while heap and heap[0][2].send_time_ns <= cutoff:
            entry = heapq.heappop(heap)
            if entry[0] <= self._last_out_seq:
                self._mark_late(entry[2])  # only if send stamps are not seq * period
                continue
            if best is not None:
                self._mark_late(best[2])  # skipped: a newer sample is due too
            best = entry
        if best is not None:
            self._started = True
            return self._play(best[2], best[1], now_ns)
        last = self._last_real
        if self._extrapolate and last is not None:
            slot = last.seq + (cutoff - last.send_time_ns) // self.period_ns
            if slot > self._last_out_seq:
                return self._fill(slot, now_ns)
        return None


class FixedBuffer(_ScheduledBuffer):
    """Policy `fixed`: D = min relative delay seen until playout starts + buffering time; then frozen.

    The base is the minimum over the packets that arrive before the first one is played (the
    first packet waits `buffering_ns`, so that is the first buffering interval): after that D
    never changes, so the playout latency is constant, and a later, smaller minimum (or clock
    drift) is not followed. That is what `adaptive` and `percentile` are for.
    """

    name = "fixed"

    def __init__(self, period_ns: int, buffering_ns: int, gap: str = "hold", max_extrapolation_ns: int = 0) -> None:
        if buffering_ns < 0:
            raise ValueError(f"buffering_ns must be >= 0, got {buffering_ns}")
        super().__init__(period_ns, gap=gap, max_extrapolation_ns=max_extrapolation_ns)
        self.buffering_ns = buffering_ns
        self._min_rel: int | None = None

    def _observe(self, rel_ns: int) -> None:
        if self._started:
            return
        if self._min_rel is None or rel_ns < self._min_rel:
            self._min_rel = rel_ns
            self._target_rel = rel_ns + self.buffering_ns


class AdaptiveBuffer(_ScheduledBuffer):
    """Policy `adaptive`: Ramjee et al. (1994) algorithm 1, adapted continuously.

        d_i = a d_(i-1) + (1 - a) n_i
        v_i = a v_(i-1) + (1 - a) |d_i - n_i|
        D   = d_i + beta v_i              (beta = 4)

    n_i are relative delays; d_1 = n_1, v_1 = 0. Every arrival (late ones too, duplicates not)
    updates the estimate; D follows it through the slew-rate limit and hysteresis.
    """

    name = "adaptive"

    def __init__(
        self,
        period_ns: int,
        *,
        smoothing: float = RAMJEE_SMOOTHING,
        variation_factor: float = 4.0,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        if not 0.0 < smoothing < 1.0:
            raise ValueError(f"smoothing must be in (0, 1), got {smoothing}")
        if not variation_factor >= 0.0:
            raise ValueError(f"variation_factor must be >= 0, got {variation_factor}")
        super().__init__(
            period_ns,
            gap=gap,
            max_extrapolation_ns=max_extrapolation_ns,
            max_slew_rate=max_slew_rate,
            hysteresis_ns=hysteresis_ns,
        )
        self._a = smoothing
        self._b = 1.0 - smoothing
        self._beta = variation_factor
        self._d = 0.0
        self._v = 0.0
        self._n = 0

    @property
    def delay_estimate_ns(self) -> float | None:
        """d_hat on the receiver's clock (clock offset included)."""
        return None if self._ref is None else self._ref + self._d

    @property
    def variation_estimate_ns(self) -> float:
        """v_hat (a difference of delays: the clock offset cancels)."""
        return self._v

    def _observe(self, rel_ns: int) -> None:
        if self._n == 0:
            d = float(rel_ns)
            v = 0.0
        else:
            a, b = self._a, self._b
            d = a * self._d + b * rel_ns
            v = a * self._v + b * abs(d - rel_ns)
        self._n += 1
        self._d = d
        self._v = v
        self._target_rel = round(d + self._beta * v)


class _Window:
    """The last `size` relative delays, also kept sorted (insort / bisect: O(log n) + a memmove)."""

    __slots__ = ("order", "size", "sorted")

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"window_packets must be >= 1, got {size}")
        self.size = size
        self.order: deque[int] = deque()
        self.sorted: list[int] = []

    def add(self, x: int) -> None:
        order, srt = self.order, self.sorted
        order.append(x)
        insort(srt, x)
        if len(order) > self.size:
            del srt[bisect_left(srt, order.popleft())]


class PercentileBuffer(_ScheduledBuffer):
    """Policy `percentile` (NetEq-like): D = the q-quantile of the window's relative delays.

    That is the window minimum (the clock offset plus the smallest network delay) plus the
    q-quantile of the delays above it. Nearest rank: the smallest window value with at least a
    fraction q of the window at or below it, so about 1 - q of the packets arrive after D.
    """

    name = "percentile"

    def __init__(
        self,
        period_ns: int,
        *,
        quantile: float = 0.95,
        window_packets: int = 1000,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        if not 0.0 < quantile < 1.0:
            raise ValueError(f"quantile must be in (0, 1), got {quantile}")
        super().__init__(
            period_ns,
            gap=gap,
            max_extrapolation_ns=max_extrapolation_ns,
            max_slew_rate=max_slew_rate,
            hysteresis_ns=hysteresis_ns,
        )
        self.quantile = quantile
        self._window = _Window(window_packets)

    def _observe(self, rel_ns: int) -> None:
        w = self._window
        w.add(rel_ns)
        srt = w.sorted
        n = len(srt)
        rank = math.ceil(self.quantile * n - 1e-9)  # 1-based nearest rank
        self._target_rel = srt[min(n, max(1, rank)) - 1]


class TransparencyBuffer(_ScheduledBuffer):
    """Policy `transparency` (seed 000): the buffering time that minimises the EBA force error.

    Seed 000: in contact the felt force rises at slope s = c * v_m; a latency D lowers it by
    s * D and every hold (the due sample missing) lowers it by s * the hold time. With b the
    buffering above the window's minimum relative delay, d0 the smallest one-way delay, x the
    relative delays above the window minimum and H the contact horizon, the expected force error
    at the end of a contact is (derivation in docs/playout.md)

        e(b) = s * (d0 + b + H * P(x > b))

    b is the minimiser of e over {0} and the window's values, subject to the allowable-latency
    cap d0 + b <= D_allow = allowed_force_error / s (b = 0 when the cap is below d0).
    """

    name = "transparency"

    def __init__(
        self,
        period_ns: int,
        *,
        allowed_force_error_n: float = 0.1,
        force_slope_n_per_s: float | None = None,
        min_one_way_delay_ns: int = 0,
        contact_horizon_ns: int = 1_000_000_000,
        window_packets: int = 1000,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        if not allowed_force_error_n > 0.0:
            raise ValueError(f"allowed_force_error_n must be > 0, got {allowed_force_error_n}")
        if not contact_horizon_ns > 0:
            raise ValueError(f"contact_horizon_ns must be > 0, got {contact_horizon_ns}")
        super().__init__(
            period_ns,
            gap=gap,
            max_extrapolation_ns=max_extrapolation_ns,
            max_slew_rate=max_slew_rate,
            hysteresis_ns=hysteresis_ns,
        )
        self.allowed_force_error_n = allowed_force_error_n
        self.contact_horizon_ns = contact_horizon_ns
        self._slope: float | None = None
        self._d0 = 0
        self.set_force_slope(force_slope_n_per_s)
        self.set_min_one_way_delay(min_one_way_delay_ns)
        self._window = _Window(window_packets)
        self._count = 0
        self._dirty = False
        self.buffering_ns = 0  # b: the chosen buffering above the minimum relative delay
        self.expected_hold_ns = 0  # H * P(x > b) at the last decision
        self.expected_force_error_n: float | None = None  # e(b) at the last decision (None: no slope)

    def set_force_slope(self, slope_n_per_s: float | None) -> None:
        """The engine's current s (e.g. `contact_force_slope(stiffness, speed)`); None: no cap.

        Cheap enough to call every tick: the next decision (at the next arrival) uses it.
        """
        if slope_n_per_s is not None and not (slope_n_per_s >= 0.0 and math.isfinite(slope_n_per_s)):
            raise ValueError(f"force slope must be a finite value >= 0, got {slope_n_per_s}")
        if slope_n_per_s != self._slope:
            self._slope = slope_n_per_s
            self._dirty = True

    def set_min_one_way_delay(self, delay_ns: int) -> None:
        """d0: the smallest one-way delay (e.g. half the minimum round trip); not observable here."""
        if delay_ns < 0:
            raise ValueError(f"min one-way delay must be >= 0, got {delay_ns}")
        if delay_ns != self._d0:
            self._d0 = delay_ns
            self._dirty = True

    @property
    def allowed_latency_ns(self) -> int | None:
        """D_allow = allowed_force_error / s, or None when s is unknown or 0 (no cap)."""
        s = self._slope
        if not s:
            return None
        return min(round(self.allowed_force_error_n / s * 1e9), 1 << 62)

    def _observe(self, rel_ns: int) -> None:
        self._window.add(rel_ns)
        self._count += 1
        c = self._count
        if self._dirty or c % _RETARGET_PACKETS == 0 or (c < _RETARGET_PACKETS and c & (c - 1) == 0):
            self._decide()

    def _decide(self) -> None:
        self._dirty = False
        srt = self._window.sorted
        w = len(srt)
        lo = srt[0]
        per_packet = self.contact_horizon_ns / w  # H * P(x > b) drops by this per value covered
        cap = math.inf
        allow = self.allowed_latency_ns
        if allow is not None:
            cap = max(0, allow - self._d0)
        # e(b) / s - d0 = b + H * P(x > b): linear between window values, a step down at each, so
        # the minimum is at b = 0 or at a window value (the last of a run of equal values).
        first_above = bisect_right(srt, lo)
        best_b, best_cost = 0, (w - first_above) * per_packet
        for i in range(first_above, w):
            b = srt[i] - lo
            if b > cap or b >= best_cost:
                break  # the cost is at least b: no larger b can win
            if i + 1 < w and srt[i + 1] == srt[i]:
                continue
            cost = b + (w - 1 - i) * per_packet
            if cost < best_cost:
                best_b, best_cost = b, cost
        self.buffering_ns = best_b
        self.expected_hold_ns = round(best_cost) - best_b
        self._target_rel = lo + best_b
        s = self._slope
        self.expected_force_error_n = None if s is None else s * (self._d0 + best_cost) * 1e-9


class NetworkAdaptiveBuffer(_ScheduledBuffer):
    """Policy `network_adaptive`: seed 000's network-adaptive buffering time control, read as the
    seed states it (docs/playout.md, "The haptic-synchronization claim, tested fairly").

    From the transparency analysis of the scene (core/transparency.py) it takes the allowable
    delay D_a (the largest one-way delay whose force drop stays within the required distortion E)
    and the allowable loss time L_a = T_tr + E / s (the transparent loss time, then as long as the
    undisturbed force takes to rise by E); from the network, the minimum one-way delay d0. With x
    the relative delays above the window's minimum, a sample x late is held about x - b past its
    slot; the buffering time is the least that keeps every hold the window predicts within L_a,
    as long as the latency d0 + b stays within D_a:

        b = min( max(0, max(x) - L_a), max(0, D_a - d0) )

    No free parameter decides between latency and holds: both bounds come from the analysis.
    `requirement_met` is False when the window's holds need more buffering than D_a - d0 allows
    (the seed's requirement cannot be met at this jitter; the latency bound wins).
    """

    name = "network_adaptive"

    def __init__(
        self,
        period_ns: int,
        *,
        allowable_delay_ns: int | None = None,
        allowable_loss_time_ns: int = 0,
        min_one_way_delay_ns: int = 0,
        window_packets: int = 1000,
        gap: str = "hold",
        max_extrapolation_ns: int = 0,
        max_slew_rate: float = 0.05,
        hysteresis_ns: int = 0,
    ) -> None:
        super().__init__(
            period_ns,
            gap=gap,
            max_extrapolation_ns=max_extrapolation_ns,
            max_slew_rate=max_slew_rate,
            hysteresis_ns=hysteresis_ns,
        )
        self._window = _Window(window_packets)
        self._allow_delay: int | None = None
        self._allow_loss = 0
        self._d0 = 0
        self.set_allowable(allowable_delay_ns, allowable_loss_time_ns)
        self.set_min_one_way_delay(min_one_way_delay_ns)
        self.buffering_ns = 0  # b: the chosen buffering above the window's minimum relative delay
        self.requirement_met = True

    def set_allowable(self, delay_ns: int | None, loss_time_ns: int) -> None:
        """D_a (None: no delay bound) and L_a, from the transparency analysis (the engine passes
        them, `assembly.build_network`); the next arrival's decision uses them."""
        if delay_ns is not None and delay_ns < 0:
            raise ValueError(f"allowable delay must be >= 0, got {delay_ns}")
        if loss_time_ns < 0:
            raise ValueError(f"allowable loss time must be >= 0, got {loss_time_ns}")
        self._allow_delay = delay_ns
        self._allow_loss = loss_time_ns

    def set_min_one_way_delay(self, delay_ns: int) -> None:
        """d0: the smallest one-way delay (the engine: the link's; a node: half the minimum round trip)."""
        if delay_ns < 0:
            raise ValueError(f"min one-way delay must be >= 0, got {delay_ns}")
        self._d0 = delay_ns

    @property
    def delay_budget_ns(self) -> int | None:
        """D_a - d0 (at least 0): the most buffering the allowable delay leaves; None: no bound."""
        a = self._allow_delay
        return None if a is None else max(0, a - self._d0)

    def _observe(self, rel_ns: int) -> None:
        w = self._window
        w.add(rel_ns)
        srt = w.sorted
        need = srt[-1] - srt[0] - self._allow_loss
        need = max(need, 0)
        cap = self.delay_budget_ns
        if cap is not None and need > cap:
            self.requirement_met = False
            need = cap
        else:
            self.requirement_met = True
        self.buffering_ns = need
        self._target_rel = srt[0] + need


@dataclass(frozen=True)
class BufferConfig:
    """One receiving side's sync buffer. Parameters a policy does not use are ignored."""

    policy: str = field(default="none", metadata={"choices": POLICIES, "help": "sync buffer policy"})
    gap: str = field(
        default="hold",
        metadata={
            "choices": GAP_MODES,
            "help": "empty slot: hold the last sample or extrapolate the last two",
        },
    )
    max_extrapolation_s: float = field(
        default=0.05, metadata={"min": 0.0, "max": 10.0, "help": "extrapolate at most this far, then hold"}
    )
    buffering_time_s: float = field(
        default=0.01,
        metadata={"min": 0.0, "max": 10.0, "help": "fixed: buffering above the minimum relative delay"},
    )
    smoothing: float = field(
        default=RAMJEE_SMOOTHING,
        metadata={"gt": 0.0, "lt": 1.0, "help": "adaptive: alpha of the delay estimates"},
    )
    variation_factor: float = field(
        default=4.0, metadata={"min": 0.0, "max": 100.0, "help": "adaptive: beta in D = d + beta v"}
    )
    quantile: float = field(
        default=0.95, metadata={"gt": 0.0, "lt": 1.0, "help": "percentile: fraction of packets in time"}
    )
    window_packets: int = field(
        default=1000,
        metadata={"min": 1, "max": 100_000, "help": "percentile, transparency, network_adaptive: delay window"},
    )
    allowed_force_error_n: float = field(
        default=0.1, metadata={"gt": 0.0, "max": 1e4, "help": "transparency: allowed felt-force distortion"}
    )
    force_slope_n_per_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 1e9,
            "help": "transparency: contact force slope c*vm (unset: engine passes it)",
        },
    )
    min_one_way_delay_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 100.0,
            "help": "transparency, network_adaptive: smallest one-way delay d0 (unset: 0 for transparency, "
            "the link's minimum for network_adaptive)",
        },
    )
    allowable_delay_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 3600.0,
            "help": "network_adaptive: allowable one-way delay D_a (unset: from the scene's transparency analysis)",
        },
    )
    allowable_loss_time_s: float | None = field(
        default=None,
        metadata={
            "min": 0.0,
            "max": 3600.0,
            "help": "network_adaptive: allowable loss time L_a (unset: from the scene's transparency analysis)",
        },
    )
    contact_horizon_s: float = field(
        default=1.0,
        metadata={"gt": 0.0, "max": 3600.0, "help": "transparency: contact length the error builds over"},
    )
    max_slew_rate: float = field(
        default=0.05,
        metadata={"gt": 0.0, "max": 1.0, "help": "adaptive policies: playout delay change, s per s"},
    )
    hysteresis_s: float = field(
        default=0.002,
        metadata={"min": 0.0, "max": 10.0, "help": "adaptive policies: ignore target changes this small"},
    )

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _check_field(f.name, getattr(self, f.name), f.metadata)
        if self.gap == "extrapolate" and self.max_extrapolation_s == 0.0:
            raise ValueError("gap 'extrapolate' with max_extrapolation_s 0 never extrapolates: use gap 'hold'")
        if self.policy == "percentile" and self.window_packets * (1.0 - self.quantile) < 1.0 - 1e-9:
            need = math.ceil(1.0 / (1.0 - self.quantile) - 1e-9)
            raise ValueError(
                f"window_packets {self.window_packets} cannot resolve quantile {self.quantile} "
                f"(it would be the window maximum): use at least {need} packets"
            )


def _check_field(name: str, value: object, meta: Mapping[str, Any]) -> None:
    """The schema's metadata checks, for configs built in code rather than from YAML."""
    if value is None:
        return
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(choices)}, got {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value}")
        lo, hi, gt, lt = meta.get("min"), meta.get("max"), meta.get("gt"), meta.get("lt")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            raise ValueError(f"{name} must be in [{lo}, {hi}], got {value}")
        if (gt is not None and not value > gt) or (lt is not None and not value < lt):
            raise ValueError(f"{name} must be > {gt} and < {lt}, got {value}")


def _ns(seconds: float) -> int:
    return round(seconds * 1e9)


def build_buffer(cfg: BufferConfig, period_ns: int) -> PlayoutBuffer:
    """The buffer `cfg` names, for a stream with one sample every `period_ns` (seq = send / period)."""
    if not period_ns > 0:
        raise ValueError(f"period_ns must be > 0, got {period_ns}")
    gap, extra_ns = cfg.gap, _ns(cfg.max_extrapolation_s)
    slew, hyst_ns = cfg.max_slew_rate, _ns(cfg.hysteresis_s)
    if cfg.policy == "none":
        return PlayOnArrival(period_ns, gap, extra_ns)
    if cfg.policy == "fixed":
        return FixedBuffer(period_ns, _ns(cfg.buffering_time_s), gap, extra_ns)
    if cfg.policy == "adaptive":
        return AdaptiveBuffer(
            period_ns,
            smoothing=cfg.smoothing,
            variation_factor=cfg.variation_factor,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    if cfg.policy == "percentile":
        return PercentileBuffer(
            period_ns,
            quantile=cfg.quantile,
            window_packets=cfg.window_packets,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    if cfg.policy == "transparency":
        return TransparencyBuffer(
            period_ns,
            allowed_force_error_n=cfg.allowed_force_error_n,
            force_slope_n_per_s=cfg.force_slope_n_per_s,
            min_one_way_delay_ns=_ns(cfg.min_one_way_delay_s or 0.0),
            contact_horizon_ns=_ns(cfg.contact_horizon_s),
            window_packets=cfg.window_packets,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    if cfg.policy == "network_adaptive":
        return NetworkAdaptiveBuffer(
            period_ns,
            allowable_delay_ns=None if cfg.allowable_delay_s is None else _ns(cfg.allowable_delay_s),
            allowable_loss_time_ns=_ns(cfg.allowable_loss_time_s or 0.0),
            min_one_way_delay_ns=_ns(cfg.min_one_way_delay_s or 0.0),
            window_packets=cfg.window_packets,
            gap=gap,
            max_extrapolation_ns=extra_ns,
            max_slew_rate=slew,
            hysteresis_ns=hyst_ns,
        )
    raise ValueError(f"unknown policy {cfg.policy!r}; allowed: {', '.join(POLICIES)}")

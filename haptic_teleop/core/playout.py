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

import heapq
import math
from array import array
from bisect import bisect_left, insort
from collections import deque
from dataclasses import dataclass
from typing import Protocol

from haptic_teleop.core.link import LOST_LATE, Packet

POLICIES = ("none", "fixed", "adaptive", "percentile", "transparency", "network_adaptive")


GAP_MODES = ("hold", "extrapolate")


RAMJEE_SMOOTHING = 0.998002  # alpha of Ramjee et al. (1994), algorithm 1


# Duplicate detection remembers the last _SEEN_SLOTS sequence numbers in a ring (32 s at 1 kHz):
# an arrival that repeats a sequence number older than that is counted late, not duplicate.
_SEEN_SLOTS = 1 << 15


_SEEN_MASK = _SEEN_SLOTS - 1


_NO_SEQ = -(1 << 63)


# Transparency policy: a new decision (O(window)) every RETARGET_PACKETS arrivals, and at
# arrivals 1, 2, 4, ... while the window fills.
RETARGET_PACKETS = 64


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


class BufferBase:
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


class PlayOnArrival(BufferBase):
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


class ScheduledBuffer(BufferBase):
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


class FixedBuffer(ScheduledBuffer):
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


class AdaptiveBuffer(ScheduledBuffer):
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


class Window:
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


class PercentileBuffer(ScheduledBuffer):
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
        self._window = Window(window_packets)

    def _observe(self, rel_ns: int) -> None:
        w = self._window
        w.add(rel_ns)
        srt = w.sorted
        n = len(srt)
        rank = math.ceil(self.quantile * n - 1e-9)  # 1-based nearest rank
        self._target_rel = srt[min(n, max(1, rank)) - 1]

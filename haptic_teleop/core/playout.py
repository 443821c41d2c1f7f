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

The rules of `none`'s duplicates and of the scheduled policies (the held packets, late marking,
the slewed playout delay, the `fixed` and `adaptive` estimators) are core/playout_rules.py's
functions over arrays, which the compiled loops run too; `percentile`, `transparency` and
`network_adaptive` set their target from Python (O(log window) per packet).
"""

from __future__ import annotations

from array import array
from bisect import bisect_left, insort
from collections import deque
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from haptic_teleop.core import playout_rules as rules
from haptic_teleop.core.link import LOST_LATE, Packet
from haptic_teleop.core.playout_rules import (
    adaptive_observe,
    fixed_observe,
    none_push,
    none_release,
    percentile_target,
    push_begin,
    push_hold,
    sched_release,
)

POLICIES = ("none", "fixed", "adaptive", "percentile", "transparency", "network_adaptive")


GAP_MODES = ("hold", "extrapolate")


RAMJEE_SMOOTHING = 0.998002  # alpha of Ramjee et al. (1994), algorithm 1


# Duplicate detection remembers the last SEEN_SLOTS sequence numbers in a ring (32 s at 1 kHz):
# an arrival that repeats a sequence number older than that is counted late, not duplicate.
_NO_SEQ = rules.NO_SEQ


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
    extrapolated: int  # made-up packets released (gap: extrapolate)

    @property
    def late(self) -> int:
        """Packets that arrived but were never played (fate LOST_LATE)."""

    @property
    def duplicates(self) -> int:
        """Arrivals of a sequence number already received (ignored, not lost)."""

    @property
    def played(self) -> int:
        """Received packets released."""

    @property
    def last_buffering_ns(self) -> int:
        """Release time - arrival time of the last released packet (-1: made up)."""

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
    """What every policy shares: the duplicates ring, the gap mode and extrapolation."""

    name = "base"
    policy = rules.POLICY_OTHER  # the estimator, when core/playout_rules.py has it
    extrapolated: int
    Q: list[int]  # the rules' integer state (core/playout_rules.py)
    E: list[float]
    R: array[int]

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
        self.extrapolated = 0
        self._seen = rules.new_seen()
        self._last_real: Packet | None = None
        self._prev_real: Packet | None = None

    def rule_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        """The rules' state as numpy copies (core/playout_rules.py: Q, E, the duplicates ring, the
        held ring) and the size of the policy's window (1 without one), for a compiled schedule
        that goes on from here (engine/compiled/buffer_schedule.py)."""
        window = getattr(self, "_window", None)
        return (*rules.as_arrays(self.Q, self.E, self._seen, self.R), 1 if window is None else window.size)

    @property
    def extrapolates(self) -> bool:
        """Whether the buffer makes up samples for empty slots (`gap: extrapolate`): what it
        releases then depends on the payloads it received, not only on sequence numbers."""
        return self._extrapolate

    def _played(self, packet: Packet) -> Packet:
        self._prev_real = self._last_real
        self._last_real = packet
        return packet

    def _made_up(self, slot: int) -> None:
        """A made-up sample for `slot` was released."""
        self.Q[rules.Q_LAST_BUFFERING] = -1
        self.Q[rules.Q_LAST_OUT] = slot

    # Counters and state, read from the arrays.
    @property
    def late(self) -> int:
        """Packets that arrived but were never played (fate LOST_LATE)."""
        return int(self.Q[rules.Q_LATE])

    @property
    def duplicates(self) -> int:
        return int(self.Q[rules.Q_DUPLICATES])

    @property
    def played(self) -> int:
        return int(self.Q[rules.Q_PLAYED])

    @property
    def last_buffering_ns(self) -> int:
        return int(self.Q[rules.Q_LAST_BUFFERING])

    @property
    def occupancy(self) -> int:
        return int(self.Q[rules.Q_COUNT])

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
        self._made_up(slot)
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

    The rules are core/playout_rules.py's `none_push` and `none_release` (the compiled loops run
    them too); this class keeps the pending packet and gives packets their fates.
    """

    name = "none"
    policy = rules.POLICY_NONE

    def __init__(self, period_ns: int = 0, gap: str = "hold", max_extrapolation_ns: int = 0) -> None:
        super().__init__(period_ns, gap, max_extrapolation_ns)
        self.Q, self.E = rules.new_state(self.policy, 0, 1.0)
        self.R = array("q")  # (no held ring: one pending packet)
        self._late = array("q", [0])
        self._pending: Packet | None = None
        self._last_play_ns = 0

    def oldest_held_seq(self) -> int | None:
        """The lowest sequence number the buffer holds (its fate may still change), or None."""
        return None if self._pending is None else self._pending.seq

    def push(self, packet: Packet, now_ns: int) -> None:
        code = none_push(self.Q, self._seen, self._late, packet.seq, now_ns)
        if code == rules.PUSH_LATE:
            packet.fate = LOST_LATE
        elif code == rules.PUSH_HELD:
            if self.Q[rules.Q_NLATE]:
                assert self._pending is not None  # the displaced one
                self._pending.fate = LOST_LATE
            self._pending = packet

    def release(self, now_ns: int) -> Packet | None:
        p = self._pending
        if p is not None:
            none_release(self.Q, now_ns)
            self._pending = None
            self._last_play_ns = now_ns
            return self._played(p)
        last = self._last_real
        if self._extrapolate and last is not None:
            slot = last.seq + (now_ns - self._last_play_ns) // self.period_ns
            if slot > self.Q[rules.Q_LAST_OUT]:
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

    The rules are core/playout_rules.py's, over this buffer's arrays (the compiled loops run the
    same functions); this class keeps the packets themselves and gives them their fates.
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
        self.Q, self.E = rules.new_state(self.policy, hysteresis_ns, max_slew_rate)
        self.R = rules.new_held()
        self._late = array("q", bytes(8 * rules.SEEN_SLOTS))
        self._held: dict[int, Packet] = {}

    @property
    def playout_delay_ns(self) -> int | None:
        """D in use (receiver clock - send stamp), None before the first packet is held."""
        Q = self.Q
        return int(Q[rules.Q_DELAY]) if Q[rules.Q_HAS_DELAY] else None

    def oldest_held_seq(self) -> int | None:
        """The lowest sequence number the buffer holds (its fate may still change), or None."""
        Q = self.Q
        return int(Q[rules.Q_MIN]) if Q[rules.Q_COUNT] else None

    @property
    def target_delay_ns(self) -> int | None:
        """The policy's current choice of D (receiver clock - send stamp, clock offset included)."""
        Q = self.Q
        return int(Q[rules.Q_REF] + Q[rules.Q_TARGET]) if Q[rules.Q_HAS_REF] else None

    def _observe(self, rel_ns: int) -> None:
        """Update the estimator with one relative delay (relative to the first packet's)."""
        raise NotImplementedError

    def _set_target(self, rel_ns: int) -> None:
        """The policy's target D, relative to the first packet's relative delay."""
        self.Q[rules.Q_TARGET] = rel_ns

    def push(self, packet: Packet, now_ns: int) -> None:
        Q, seq, send = self.Q, packet.seq, packet.send_time_ns
        rel = push_begin(Q, self._seen, seq, send, now_ns)
        if rel == _NO_SEQ:
            return
        self._observe(rel)
        if push_hold(Q, self.R, seq, send, now_ns) == rules.PUSH_LATE:
            packet.fate = LOST_LATE
        else:
            self._held[seq] = packet

    def release(self, now_ns: int) -> Packet | None:
        Q = self.Q
        s = sched_release(Q, self.E, self.R, now_ns, self._late)
        n_late = Q[rules.Q_NLATE]
        if n_late:
            held, late = self._held, self._late
            for i in range(n_late):
                held.pop(late[i]).fate = LOST_LATE
        if s != _NO_SEQ:
            return self._played(self._held.pop(s))
        last = self._last_real
        if self._extrapolate and last is not None and Q[rules.Q_HAS_DELAY]:
            cutoff = now_ns - int(Q[rules.Q_DELAY])
            slot = last.seq + (cutoff - last.send_time_ns) // self.period_ns
            if slot > Q[rules.Q_LAST_OUT]:
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
    policy = rules.POLICY_FIXED

    def __init__(self, period_ns: int, buffering_ns: int, gap: str = "hold", max_extrapolation_ns: int = 0) -> None:
        if buffering_ns < 0:
            raise ValueError(f"buffering_ns must be >= 0, got {buffering_ns}")
        super().__init__(period_ns, gap=gap, max_extrapolation_ns=max_extrapolation_ns)
        self.buffering_ns = buffering_ns
        self.Q[rules.Q_BUFFERING] = buffering_ns

    def _observe(self, rel_ns: int) -> None:
        fixed_observe(self.Q, rel_ns)


class AdaptiveBuffer(ScheduledBuffer):
    """Policy `adaptive`: Ramjee et al. (1994) algorithm 1, adapted continuously.

        d_i = a d_(i-1) + (1 - a) n_i
        v_i = a v_(i-1) + (1 - a) |d_i - n_i|
        D   = d_i + beta v_i              (beta = 4)

    n_i are relative delays; d_1 = n_1, v_1 = 0. Every arrival (late ones too, duplicates not)
    updates the estimate; D follows it through the slew-rate limit and hysteresis.
    """

    name = "adaptive"
    policy = rules.POLICY_ADAPTIVE

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
        E = self.E
        E[rules.E_A] = smoothing
        E[rules.E_B] = 1.0 - smoothing
        E[rules.E_BETA] = variation_factor

    @property
    def delay_estimate_ns(self) -> float | None:
        """d_hat on the receiver's clock (clock offset included)."""
        Q = self.Q
        return float(Q[rules.Q_REF] + self.E[rules.E_D]) if Q[rules.Q_HAS_REF] else None

    @property
    def variation_estimate_ns(self) -> float:
        """v_hat (a difference of delays: the clock offset cancels)."""
        return float(self.E[rules.E_V])

    def _observe(self, rel_ns: int) -> None:
        adaptive_observe(self.Q, self.E, rel_ns)


class Window:
    """The last `size` relative delays, also kept sorted (insort / bisect: O(log n) + a memmove).
    The compiled schedule keeps the same window over arrays (core/playout_rules.py `window_add`:
    the same insertion and removal, written as loops; C's list moves are what the interpreter
    can afford)."""

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
    policy = rules.POLICY_PERCENTILE

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
        self.E[rules.E_QUANTILE] = quantile
        self._window = Window(window_packets)

    def _observe(self, rel_ns: int) -> None:
        w = self._window
        w.add(rel_ns)
        srt = w.sorted
        self._set_target(percentile_target(srt, len(srt), self.quantile))

"""One direction's network schedule when its link is decided in batches (`Link.schedule_all`:
jitter, loss chains, blackouts, constant delay) and its playout buffer's rules are written over
arrays (every policy: `none`, `fixed`, `adaptive`, `percentile`, `network_adaptive`,
`transparency`; core/playout_rules.py), without a codec. (A link that
keeps its packets' order into a `none` buffer has the simpler `axis_host.VectorizedSchedule`.)

Window by window: the link decides every packet's fate and arrival at once; the delivered ones
wait in flight, in the order `Link.deliver` hands them over (arrival time, then send order);
`playout_rules.buffer_window`, compiled from its one definition, pushes them at the tick they
arrive in and releases, tick by tick, in the engine's order. The result is what `TickedSchedule`
gets from the very `Link` and buffer objects ticked one by one: the same released sequence
numbers, occupancy and packet records, bit for bit (test_buffer_schedule.py), at some tens of
nanoseconds a packet instead of about 6 us.

The buffer object's integer and float state (its counters, playout delay, target and estimates)
is copied back after each window: what it says after a run is the state at the end of the last
window decided.

Records: a packet's row is handed over once its fate is final at the tick the loop has reached
(neither in flight nor held then), as `stages.settled_records` does; a window decided further
ahead keeps the lowest held sequence number after each tick for that, and its late marks' ticks,
so that a run stopped mid-window records what had happened by its last tick.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from haptic_teleop.compiling import compile_tree
from haptic_teleop.core import playout_rules as rules
from haptic_teleop.core.link import DELIVERED, LOST_LATE, Link, taken_tick
from haptic_teleop.core.playout import AdaptiveBuffer, FixedBuffer, PercentileBuffer, PlayOnArrival, PlayoutBuffer
from haptic_teleop.core.playout_seed import NetworkAdaptiveBuffer, TransparencyBuffer
from haptic_teleop.engine.compiled.records import packet_rows

buffer_window = compile_tree(rules.buffer_window, inline=True, counted=False)


def warm() -> None:
    """Compile (or load from numba's cache) `buffer_window` now, on a tick without packets."""
    buf = AdaptiveBuffer(1)
    Q, E, seen, R, _ = buf.rule_arrays()
    i = np.zeros(1, dtype=np.int64)
    w = np.zeros(2, dtype=np.int64)
    buffer_window(Q, E, seen, R, w[:1], w, i, i[:0], i[:0], i[:0], 0, 1, 1, i, np.zeros(1), i, i, i)


# The policies whose rules core/playout_rules.py has whole (every policy; the seed's and any that
# extrapolates are not compiled: buffered()).
COMPILED_BUFFERS = (
    PlayOnArrival,
    FixedBuffer,
    AdaptiveBuffer,
    PercentileBuffer,
    NetworkAdaptiveBuffer,
    TransparencyBuffer,
)


def buffered(link: Link, buf: PlayoutBuffer) -> bool:
    """Whether `BufferedSchedule` runs this direction."""
    return link.vectorized and type(buf) in COMPILED_BUFFERS and not buf.extrapolates


class BufferedSchedule:
    """The schedule of module docstring; `window` and `settled` as `axis_host.TickedSchedule`'s."""

    vectorized = True  # decided a long window ahead

    def __init__(self, link: Link, buf: Any, period_ns: int, size_bytes: int, runs: Any) -> None:
        self.link, self.buf, self.period_ns, self.size_bytes, self.runs = link, buf, period_ns, size_bytes, runs
        # the buffer's state as it is now (no packet yet), as numpy arrays the compiled rules act on
        self.Q, self.E, self.seen, self.R, size = buf.rule_arrays()
        self.late = np.zeros(rules.SEEN_SLOTS, dtype=np.int64)
        # the window of `percentile`, `network_adaptive` and `transparency` (its ring and its sorted copy)
        self.wv = np.zeros(size, dtype=np.int64)
        self.ws = np.zeros(size + 1, dtype=np.int64)
        # delivered packets on their way, in seq order: seq, send, arrival ns, arrival tick
        self._p = np.zeros((4, 0), dtype=np.int64)
        # records not handed over yet (rows in seq order from self._first), and of the delivered
        # ones among them: seq and the tick they arrive in (seq order)
        self._rows: list[np.ndarray] = []
        self._first = 0
        self._dseq = np.zeros(0, dtype=np.int64)
        self._dtick = np.zeros(0, dtype=np.int64)
        self._late_seq = np.zeros(0, dtype=np.int64)
        self._late_tick = np.zeros(0, dtype=np.int64)
        self._held_min: list[tuple[int, np.ndarray]] = []  # (first tick, lowest held seq after each tick)

    def window(self, n0: int, n1: int) -> tuple[np.ndarray, np.ndarray]:
        """For ticks [n0, n1) (following the last window): the seq the buffer releases at each
        tick (-1: none) and its occupancy after the release."""
        period = self.period_ns
        send = np.arange(n0, n1, dtype=np.int64) * period
        arrival, fate = self.link.schedule_all(send, self.runs, self.size_bytes)
        self._rows.append(packet_rows(send, arrival, fate, self.size_bytes, first_seq=n0))
        got = np.flatnonzero(fate == DELIVERED)
        seq = got + n0
        tick = taken_tick(arrival[got], period)
        self._dseq = np.concatenate((self._dseq, seq))
        self._dtick = np.concatenate((self._dtick, tick))
        # on their way, in seq order (those of earlier windows first); pushed in Link.deliver's
        # order: arrival time, then send order (a stable sort)
        p = np.concatenate((self._p, np.stack((seq, send[got], arrival[got], tick))), axis=1)
        order = np.argsort(p[2], kind="stable")
        released = np.empty(n1 - n0, dtype=np.int64)
        occupancy = np.empty(n1 - n0)
        held_min = np.empty(n1 - n0, dtype=np.int64)
        room = p.shape[1] + int(self.Q[rules.Q_COUNT]) + 1
        late_seq = np.empty(room, dtype=np.int64)
        late_tick = np.empty(room, dtype=np.int64)
        pushed, k = buffer_window(
            self.Q, self.E, self.seen, self.R, self.wv, self.ws, self.late,
            p[0, order], p[1, order], p[3, order],
            n0, n1, period, released, occupancy, held_min, late_seq, late_tick,
        )  # fmt: skip
        self._p = p[:, np.sort(order[pushed:])]
        # the buffer object's counters, playout delay and estimates as they are after the window
        # (its held packets and window stay empty: the packets are the schedule's)
        self.buf.Q[:] = self.Q.tolist()
        self.buf.E[:] = self.E.tolist()
        if k:
            self._late_seq = np.concatenate((self._late_seq, late_seq[:k]))
            self._late_tick = np.concatenate((self._late_tick, late_tick[:k]))
        self._held_min = [*self._held_min[-1:], (n0, held_min)]
        return released, occupancy

    def _mark(self, sent: int) -> int:
        """The lowest seq in flight or held after tick sent - 1 (or `sent`)."""
        mark = sent
        i = int(np.searchsorted(self._dseq, sent))
        on_way = np.flatnonzero(self._dtick[:i] >= sent)
        if len(on_way):
            mark = min(mark, int(self._dseq[on_way[0]]))
        if sent == 0:
            return mark
        for t0, held_min in self._held_min:
            if t0 <= sent - 1 < t0 + len(held_min):
                return min(mark, int(held_min[sent - 1 - t0]))
        raise AssertionError(f"tick {sent - 1} is not in the last two windows")  # the loop settles as it goes

    def settled(self, sent: int, final: bool) -> np.ndarray | None:
        """`settled_records` of this direction at tick `sent` (the loop has run the ticks before
        it; the window may reach further)."""
        mark = sent if final else self._mark(sent)
        k = mark - self._first
        if k <= 0:
            return None
        rows = self._rows[0] if len(self._rows) == 1 else np.concatenate(self._rows)
        out = rows[:k].copy()
        mine = self._late_seq < mark
        if final:  # a late mark after the last tick run did not happen
            mine &= self._late_tick < sent
        out[self._late_seq[mine] - self._first, 3] = LOST_LATE
        keep = self._late_seq >= mark
        self._late_seq, self._late_tick = self._late_seq[keep], self._late_tick[keep]
        i = int(np.searchsorted(self._dseq, mark))
        self._dseq, self._dtick = self._dseq[i:], self._dtick[i:]
        self._rows = [rows[k:]]
        self._first = mark
        return out

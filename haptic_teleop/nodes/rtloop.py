"""The real-time loop of the live nodes: ticks on an absolute deadline grid with bounded catch-up
(`next_tick`), one thread per node (`LoopThread`) or one for all nodes of a process (`SharedLoop`),
its figures (`LoopStats`) and the lateness histogram (docs/live.md)."""

from __future__ import annotations

import array
import ctypes
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

# ---------------------------------------------------------------------------------------------
# The absolute-deadline loop.

_PR_SET_TIMERSLACK = 29
_WAIT_MARGIN_NS = 150_000
# How many whole periods a tick may lag its deadline and still run (late) rather than be skipped.
# 10: a stall of up to 10 ms (a preempted vCPU, a slow pass) is made up by running the backlog at
# once; the cost is lateness, reported (docs/live.md, "Late ticks").
DEFAULT_MAX_CATCH_UP = 10
# Diagnostics are published by the loop thread itself, after a tick, when the next deadline is at
# least this share of a period away (or the report is overdue by REPORT_OVERDUE_S): a reporting
# thread of its own would hold the GIL the loop needs, for milliseconds a second (docs/live.md).
IDLE_SHARE = 0.4
REPORT_PERIOD_S = 1.0
REPORT_OVERDUE_S = 2.0
IdleFn = Callable[[bool], bool]  # idle(room): background work if due (and room, unless overdue); did it?


def next_tick(k: int, now_ns: int, period_ns: int, phase_ns: int, max_catch_up: int | None) -> tuple[int, int]:
    """The tick a loop runs at `now_ns` when tick `k` (deadline k * period + phase) is the next one
    due: `(index, skipped)`.

    A tick less than `max_catch_up` + 1 whole periods past its deadline runs, late if need be, so a
    stall is made up by running the backlog back to back. Further behind, the backlog is dropped:
    the loop runs the newest deadline already passed and the ticks in between are skipped
    (overruns). `max_catch_up` 0 skips whenever a whole period was missed; None never skips
    (simulated time, where a deadline is only a label).
    """
    if max_catch_up is None:
        return k, 0
    late = now_ns - (k * period_ns + phase_ns)
    if late < (max_catch_up + 1) * period_ns:
        return k, 0
    newest = (now_ns - phase_ns) // period_ns
    return newest, newest - k


class Every:
    """True on the first tick and then once `ticks` ticks on, counted from the index a tick ran
    at: a test of `index % ticks == 0` would miss its turn whenever the loop skips that index
    (a busy machine; next_tick), and may then miss it for many turns."""

    def __init__(self, ticks: int) -> None:
        self.ticks = ticks
        self.next = 0

    def __call__(self, index: int) -> bool:
        if index < self.next:
            return False
        self.next = index + self.ticks
        return True


def _tight_timer_slack() -> None:
    """Ask Linux for 1 us timer slack on this thread (default 50 us): sleeps end closer to the deadline."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_TIMERSLACK, 1000, 0, 0, 0)
    except (OSError, AttributeError):
        pass


def _enter_realtime(priority: int, on_warning: Callable[[str], None] | None) -> bool:
    """Tight timer slack, and SCHED_FIFO `priority` for this thread (as ros2_control's control
    thread has) if allowed and > 0. Returns whether the thread runs real-time."""
    _tight_timer_slack()
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (OSError, AttributeError) as exc:
        if on_warning is not None:
            on_warning(
                f"no SCHED_FIFO priority {priority} for the loop ({exc}); running with normal "
                "scheduling, which misses deadlines under load (docs/live.md: real-time priority)"
            )
        return False


# Lateness histogram: bin b counts lateness in [2^(b/8), 2^((b+1)/8)) us (9 % wide), bin 0 also
# everything below 1 us, the last bin everything from 2^(127/8) us = 60 ms up.
LATENESS_BINS = 128
_BINS_PER_OCTAVE = 8


def lateness_bin_edges_us() -> Any:
    """Edges of the lateness histogram's bins in us (LATENESS_BINS + 1 values; the last is open)."""
    import numpy as np

    edges = 2.0 ** (np.arange(LATENESS_BINS + 1) / _BINS_PER_OCTAVE)
    edges[0] = 0.0
    return edges


def lateness_bins(lateness_ns: Any) -> Any:
    """Histogram bin of each lateness (ns, numpy array)."""
    import numpy as np

    us = np.maximum(np.asarray(lateness_ns, dtype=np.float64) * 1e-3, 1.0)
    return np.minimum((np.log2(us) * _BINS_PER_OCTAVE).astype(np.int64), LATENESS_BINS - 1)


def hist_percentiles_us(hist: Sequence[int], qs: Sequence[float] = (50.0, 99.0)) -> list[float]:
    """Percentiles (us) of the lateness a histogram counts, interpolated inside the bin (so to
    within a bin's 9 %); NaN for an empty histogram."""
    import numpy as np

    counts = np.zeros(LATENESS_BINS)
    counts[: len(hist)] = np.asarray(hist, dtype=np.float64)[:LATENESS_BINS]
    n = counts.sum()
    if n <= 0:
        return [math.nan for _ in qs]
    edges = lateness_bin_edges_us()
    cum = np.cumsum(counts)
    out = []
    for q in qs:
        rank = q / 100.0 * n
        b = min(int(np.searchsorted(cum, rank, side="left")), LATENESS_BINS - 1)
        below = cum[b] - counts[b]
        frac = (rank - below) / counts[b] if counts[b] > 0 else 0.0
        out.append(float(edges[b] + frac * (edges[b + 1] - edges[b])))
    return out


class LoopStats:
    """Counters of one loop, written (`record`) and reported (`report`) by the loop's own thread, so
    without locks. Lateness (wake time - deadline) is kept in a ring."""

    RING = 1 << 17  # 131 s at 1 kHz

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.ticks = 0  # ticks run
        self.overruns = 0  # deadlines skipped (not run at all)
        self.late_ticks = 0  # ticks run a whole period or more after their deadline (caught up)
        self.busy_ns = 0  # wall time spent in this loop's ticks
        self.end_late_max_ns = 0  # the most a tick's work ended after its deadline (its work's lateness)
        self.first_ns = 0
        self.last_ns = 0  # wake time of the newest tick
        self.lateness_ns = array.array("q", bytes(8 * self.RING))
        # The reporting side: the cumulative lateness histogram, and where the previous report was.
        import numpy as np

        self.hist = np.zeros(LATENESS_BINS, dtype=np.int64)
        self._reported = 0
        self._prev_ticks = 0
        self._prev_last_ns = 0
        self._prev_busy_ns = 0

    def record(self, woke_ns: int, deadline_ns: int) -> None:
        """One tick that woke at `woke_ns` for `deadline_ns`."""
        n = self.ticks
        late = woke_ns - deadline_ns
        self.lateness_ns[n & (self.RING - 1)] = late
        if late >= self.period_ns:
            self.late_ticks += 1
        if n == 0:
            self.first_ns = woke_ns
        self.last_ns = woke_ns
        self.ticks = n + 1  # last: the entry is written before it is counted

    def ended(self, end_ns: int, deadline_ns: int) -> None:
        """The tick for `deadline_ns` ended its work at `end_ns`: whatever it took (inputs, a clock)
        it took at most this late after its deadline, preemption inside the tick included."""
        late = end_ns - deadline_ns
        self.end_late_max_ns = max(self.end_late_max_ns, late)

    def rate_hz(self) -> float:
        """Ticks run per second of wall time since the first."""
        span = self.last_ns - self.first_ns
        return (self.ticks - 1) / (span * 1e-9) if self.ticks > 1 and span > 0 else 0.0

    def report(self) -> dict[str, float | int | str]:
        """Figures since the previous report (rate, lateness p50/p99/max, share of wall time in
        ticks) and cumulative ones (ticks, overruns, late ticks, wake time of the newest tick,
        lateness histogram): two reports' cumulative figures give exact ones over the time between
        them (what `haptic-teleop bench live` does)."""
        import numpy as np

        ticks, last_ns, busy = self.ticks, self.last_ns, self.busy_ns
        start = max(self._reported, ticks - self.RING)
        ring = np.frombuffer(self.lateness_ns, dtype=np.int64)
        i0, i1 = start & (self.RING - 1), ticks & (self.RING - 1)
        if ticks - start == 0:
            late = ring[:0]
        elif i0 < i1:
            late = ring[i0:i1]
        else:  # wrapped around the ring's end
            late = np.concatenate((ring[i0:], ring[:i1]))
        if late.size:
            self.hist += np.bincount(lateness_bins(late), minlength=LATENESS_BINS)
            a = np.sort(late)
            p50, p99 = (_sorted_percentile(a, q) * 1e-3 for q in (50.0, 99.0))
            worst = float(a[-1]) * 1e-3
        else:
            p50 = p99 = worst = math.nan
        if self._prev_ticks > 0:
            span, n = last_ns - self._prev_last_ns, ticks - self._prev_ticks
        else:
            span, n = last_ns - self.first_ns, ticks - 1
        rate = n / (span * 1e-9) if span > 0 else 0.0
        busy_pct = (busy - self._prev_busy_ns) / span * 100.0 if span > 0 else 0.0
        self._reported = ticks
        self._prev_ticks, self._prev_last_ns, self._prev_busy_ns = ticks, last_ns, busy
        used = np.flatnonzero(self.hist)
        top = int(used[-1]) + 1 if used.size else 0
        return {
            "loop_rate_hz": round(rate, 3),
            "lateness_p50_us": round(p50, 1),
            "lateness_p99_us": round(p99, 1),
            "lateness_max_us": round(worst, 1),
            "tick_time_percent": round(busy_pct, 2),
            "ticks": ticks,
            "overruns": self.overruns,
            "late_ticks": self.late_ticks,
            "last_tick_ns": last_ns,
            "end_late_max_us": round(self.end_late_max_ns * 1e-3, 1),
            "tick_time_s": round(busy * 1e-9, 6),
            "lateness_hist": " ".join(map(str, self.hist[:top].tolist())),
        }


def _sorted_percentile(a: Any, q: float) -> float:
    """Percentile q of sorted values `a` (linear interpolation, as numpy's default)."""
    n: int = a.size
    pos = q / 100.0 * (n - 1)
    lo = int(pos)
    hi = min(lo + 1, n - 1)
    return float(a[lo]) + (pos - lo) * (float(a[hi]) - float(a[lo]))


class LoopThread:
    """Runs `tick(index, stamp_ns)` once per period on the absolute grid stamp = index * period.

    Deadlines are absolute (the grid of the clock), so lateness never accumulates into drift. A
    tick that starts late still runs, up to `max_catch_up` whole periods late (next_tick): the
    backlog of a stall is run back to back; further behind, the missed deadlines are skipped and
    counted as overruns (with simulated time every tick runs, late). With a system clock the
    thread sleeps until the deadline; with simulated time (use_sim_time) it follows the node's
    ROS clock, i.e. /clock.
    """

    def __init__(
        self,
        name: str,
        period_ns: int,
        tick: Callable[[int, int], None],
        now_ns: Callable[[], int] | None = None,
        on_error: Callable[[BaseException], None] | None = None,
        simulated: bool = False,
        waiter: Callable[[int], None] | None = None,
        realtime_priority: int = 0,
        on_warning: Callable[[str], None] | None = None,
        phase_ns: int = 0,
        max_catch_up: int = DEFAULT_MAX_CATCH_UP,
        idle: IdleFn | None = None,
    ) -> None:
        if not 0 <= phase_ns < period_ns:
            raise ValueError(f"phase_ns must be in [0, period_ns), got {phase_ns}")
        if max_catch_up < 0:
            raise ValueError(f"max_catch_up must be >= 0 periods, got {max_catch_up}")
        self.name = name
        self.period_ns = period_ns
        self.phase_ns = phase_ns
        self.max_catch_up = max_catch_up
        self._idle = idle
        self._tick = tick
        self._now = now_ns or time.time_ns
        self._simulated = simulated
        # waiter(timeout_ns): block at most that long for input events and handle them; the
        # loop then waits again until its deadline. Without one, the thread just sleeps.
        self._waiter = waiter
        self.realtime_priority = realtime_priority
        self._on_warning = on_warning
        self.realtime = False
        self._on_error = on_error
        self._stop = threading.Event()
        self.stats = LoopStats(period_ns)
        self._thread = threading.Thread(target=self._run, name=f"{name}-loop", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def _wait_until(self, deadline_ns: int) -> int:
        now = self._now
        waiter = self._waiter
        t = now()
        while t < deadline_ns and not self._stop.is_set():
            # Simulated time moves only with /clock: look again every 0.2 ms of wall time.
            remaining = 200_000 if self._simulated else deadline_ns - t
            if waiter is not None and remaining > _WAIT_MARGIN_NS:
                # A DDS wait wakes later than a sleep does: wait for input until shortly
                # before the deadline, then sleep the rest.
                waiter(remaining - _WAIT_MARGIN_NS)
            else:
                time.sleep(remaining * 1e-9)
            t = now()
        if waiter is not None:
            waiter(0)  # input that came in the last stretch, before the tick
        return now()

    def _run(self) -> None:
        # Simulated time has no wall-clock deadlines, and a loop behind /clock runs its ticks back to
        # back: with SCHED_FIFO that would take a whole CPU from every normal thread, its own
        # process's signal handling and DDS threads included. Real-time priority only on wall time.
        self.realtime = _enter_realtime(0 if self._simulated else self.realtime_priority, self._on_warning)
        period = self.period_ns
        stats = self.stats
        tick = self._tick
        stop = self._stop
        bound = None if self._simulated else self.max_catch_up
        idle = self._idle
        try:
            if self._simulated:
                while self._now() <= 0 and not stop.is_set():  # no /clock yet
                    time.sleep(0.001)
            phase = self.phase_ns
            k = (self._now() - phase) // period + 1
            while not stop.is_set():
                t = self._wait_until(k * period + phase)
                if stop.is_set():
                    break
                k, skipped = next_tick(k, t, period, phase, bound)
                stats.overruns += skipped
                stats.record(t, k * period + phase)
                t0 = time.perf_counter_ns()
                tick(k, k * period)  # the stamp is on the grid; the phase only moves the wake-up
                stats.busy_ns += time.perf_counter_ns() - t0
                stats.ended(self._now(), k * period + phase)
                k += 1
                if idle is not None:
                    idle(self._simulated or k * period + phase - self._now() >= IDLE_SHARE * period)
        except BaseException as exc:
            if self._on_error is not None:
                self._on_error(exc)
            else:
                raise


TickFn = Callable[[int, int], None]
ErrorFn = Callable[[BaseException], None]


def member_ticks_between(k0: int, k1: int, every: int) -> int:
    """How many of the base deadlines k0 .. k1 - 1 are ticks of a member that ticks every `every`
    of them (those with k % every == 0)."""
    return (k1 - 1) // every - (k0 - 1) // every


class SharedLoop:
    """One thread ticking every node of a process in pipeline order (`--single-process`).

    Each 1 kHz node with its own thread costs a sleep and a wake-up per period, and on a small VM
    a wake-up is tens of microseconds of CPU (docs/live_measured.md, "CPU per node"). Composed in one
    process, the nodes share one thread instead: at each deadline k * base period it drains every
    node's event subscriptions and runs its tick, in order of loop phase (producers, relays,
    buffers, as the engine orders a tick), each node at its own period (a multiple of the base).
    A pass that starts late still runs, up to the members' smallest `max_catch_up` whole periods
    late (next_tick); further behind, the missed deadlines are skipped for every node and counted
    as its overruns. Members look like LoopThreads to their nodes (stats, start, stop, running,
    realtime). `simulated`: the deadlines are on `now_ns`, a node's ROS clock following /clock
    (use_sim_time): the loop waits for the first /clock, looks again every 0.2 ms of wall time, and
    runs every pass however far behind (none skipped), at normal priority, as a simulated
    LoopThread does; the nodes of a process then stay in step with one another whatever /clock
    does.
    """

    def __init__(
        self,
        base_period_ns: int = 1_000_000,
        realtime_priority: int = 0,
        now_ns: Callable[[], int] | None = None,
        simulated: bool = False,
    ) -> None:
        self.base_period_ns = base_period_ns
        self._now = now_ns or time.time_ns  # the wall clock, or a node's ROS clock (simulated)
        self._simulated = simulated
        self.realtime_priority = realtime_priority
        self.realtime = False
        self.members: list[SharedLoop.Member] = []
        self._stop = threading.Event()
        self._lock = threading.Lock()  # held while a member ticks
        self._thread = threading.Thread(target=self._run, name="shared-loop", daemon=True)
        self._started = False

    class Member:
        def __init__(self, group: SharedLoop, name: str, period_ns: int, phase: float, tick: TickFn,
                     drain: Callable[[], None] | None, on_error: ErrorFn | None,
                     max_catch_up: int = DEFAULT_MAX_CATCH_UP, idle: IdleFn | None = None) -> None:  # fmt: skip
            if period_ns % group.base_period_ns:
                raise ValueError(
                    f"{name}: period {period_ns} ns is not a multiple of the shared loop's {group.base_period_ns}"
                )
            if max_catch_up < 0:
                raise ValueError(f"{name}: max_catch_up must be >= 0 periods, got {max_catch_up}")
            self.group, self.name, self.period_ns, self.phase = group, name, period_ns, phase
            self.every = period_ns // group.base_period_ns
            self.tick, self.drain, self.on_error = tick, drain, on_error
            self.max_catch_up = max_catch_up
            self.idle = idle
            self.stats = LoopStats(period_ns)
            self.active = True

        @property
        def realtime(self) -> bool:
            return self.group.realtime

        @property
        def running(self) -> bool:
            return self.active and self.group._thread.is_alive()

        def start(self) -> None:
            self.group.start()

        def stop(self, timeout_s: float = 2.0) -> None:
            """No more ticks; returns once a tick of this node in progress has finished (its node
            may then release what the tick uses, e.g. its plant)."""
            self.active = False
            if threading.current_thread() is not self.group._thread:
                with self.group._lock:
                    pass

    def add(self, name: str, period_ns: int, phase: float, tick: TickFn,
            drain: Callable[[], None] | None, on_error: ErrorFn | None,
            max_catch_up: int = DEFAULT_MAX_CATCH_UP, idle: IdleFn | None = None) -> SharedLoop.Member:  # fmt: skip
        m = SharedLoop.Member(self, name, period_ns, phase, tick, drain, on_error, max_catch_up, idle)
        self.members.append(m)
        self.members.sort(key=lambda x: x.phase)  # stable: registration order within a phase
        return m

    def start(self) -> None:
        if not self._started:
            self._started = True
            self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        simulated = self._simulated
        self.realtime = _enter_realtime(0 if simulated else self.realtime_priority, None)
        base = self.base_period_ns
        bound = None if simulated else min((m.max_catch_up for m in self.members), default=DEFAULT_MAX_CATCH_UP)
        now = self._now
        stop = self._stop
        while simulated and now() <= 0 and not stop.is_set():  # no /clock yet
            time.sleep(0.001)
        k = now() // base + 1
        lock = self._lock
        members = self.members
        rr = 0  # whose background work is looked at first after the next pass
        while not stop.is_set():
            deadline = k * base
            t = now()
            while t < deadline and not stop.is_set():
                # Simulated time moves only with /clock: look again every 0.2 ms of wall time.
                time.sleep(2e-4 if simulated else (deadline - t) * 1e-9)
                t = now()
            k_run, skipped = next_tick(k, t, base, 0, bound)
            if skipped:
                for m in members:
                    m.stats.overruns += member_ticks_between(k, k_run, m.every)
                k = k_run
                deadline = k * base
            for m in members:
                if k % m.every:
                    continue
                with lock:
                    if m.active:
                        self._tick(m, deadline)
            k += 1
            if k % 4 == 0:  # background work looked at every few passes: it is due once a second
                rr = self._idle_in_turn(simulated or k * base - now() >= IDLE_SHARE * base, rr)

    def _idle_in_turn(self, room: bool, rr: int) -> int:
        """After a pass: at most one member's background work (its due diagnostics), members in
        turn; returns where to start next time."""
        members = self.members
        n = len(members)
        for i in range(n):
            m = members[(rr + i) % n]
            if m.idle is not None and m.active:
                with self._lock:
                    if m.active and m.idle(room):
                        return (rr + i + 1) % n
        return rr

    def _tick(self, m: SharedLoop.Member, deadline: int) -> None:
        st = m.stats
        st.record(self._now(), deadline)
        t0 = time.perf_counter_ns()
        try:
            if m.drain is not None:
                m.drain()
            m.tick(deadline // m.period_ns, deadline)
        except BaseException as exc:  # reported to its node, which exits non-zero
            m.active = False
            if m.on_error is not None:
                m.on_error(exc)
            else:
                raise
        finally:
            st.busy_ns += time.perf_counter_ns() - t0
            st.ended(self._now(), deadline)

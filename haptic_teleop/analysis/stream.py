"""summary.json from a bag in a few streaming passes: memory bounded by a chunk, not by the run.

`metrics.compute_summary(metrics.load_signals(bag))` holds every signal of the bag at once (a
1000 s run: 1e6 ticks of ten streams and 1e6 packet records a direction). `summarize_bag` gives
the same numbers (to float round-off in sums: exact sums (`math.fsum`) where the reference sums
pairwise; medians, percentiles, maxima, minima, counts and the cumulative energies exactly) from
passes over the bag chunk by chunk (`BagReader.blocks`, `BagReader.packet_blocks`):

1. ticks: the count and the duration (log times only);
2. network: per direction, the packet records in the bag's order (the engine writes them in seq
   order; checked) for counts, loss bursts, reorders, wire bits and the first arrival of each seq,
   joined with the released samples (`/<dir>/received`, in seq order) for the buffering delay;
3. for each exact median or percentile (`ExactQuantiles`): none when its ranks are among the
   largest TOP values kept while adding (a high percentile); else one that keeps the values when
   there are at most SMALL of them; else two: a histogram of 65536 bins, then only the values in
   the bins that hold the wanted ranks;
4. ticks again, with the lags: errors (a lag's worth of samples carried between blocks), maxima,
   energies (the cumulative sum carried between blocks).

A bag whose packet records or releases are not in seq order, or whose tick streams are not in
log time order chunk by chunk, is analysed whole (`NotStreamable`, caught by `summarize_bag`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.analysis.metrics import (
    FATE_LATE,
    FATE_LOST,
    initial_energy,
    penetration,
    read_run_info,
    run_counts,
    simulator_damping,
    wall_plane,
)
from haptic_teleop.core.link import DEFAULT_OVERHEAD_BYTES
from haptic_teleop.errors import BagError
from haptic_teleop.record.reader import BagReader

BINS = 65536
# Up to this many values, the order statistics come from one pass that keeps them all (2 MB).
SMALL = 1 << 18
# The largest TOP values are kept as they come (a high percentile's ranks are among them while
# the count is below TOP / (1 - q)): then no further pass is needed for it.
TOP = 1 << 14
# Values kept per quantile bin before they are merged into (value, count) pairs.
_MERGE_AT = 1 << 16

TICK_TOPICS = ("/operator/joint_states", "/master/joint_states", "/slave/joint_states", "/slave/contact_wrench")

Source = Callable[[], Iterable[np.ndarray]]


class NotStreamable(Exception):
    """The bag's order does not allow one streaming pass (see the module docstring)."""


# ------------------------------------------------------------------------------------------------
# Exact quantiles in bounded memory


def _lerp(a: float, b: float, g: float) -> float:
    """numpy's linear interpolation of two order statistics (bit for bit)."""
    d = b - a
    return b - d * (1.0 - g) if g >= 0.5 else a + d * g


@dataclass
class ExactQuantiles:
    """Count, sum, range of a stream of values; then exact order statistics by two more passes
    (one when there are at most SMALL values)."""

    n: int = 0
    nan: bool = False
    lo: float = math.inf
    hi: float = -math.inf
    _sums: list[float] = field(default_factory=list)
    _top: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def add(self, v: np.ndarray) -> None:
        if not v.size:
            return
        if np.isnan(v).any():
            self.nan = True
            v = v[~np.isnan(v)]
            if not v.size:
                return
        self.n += int(v.size)
        self._sums.append(math.fsum(v.tolist()))
        self.lo = min(self.lo, float(np.min(v)))
        self.hi = max(self.hi, float(np.max(v)))
        # Every value dropped here had TOP values at least as large kept, so the TOP largest of
        # what is kept are the TOP largest of all.
        top = np.concatenate([self._top, v])
        if top.size > 2 * TOP:
            top = np.partition(top, top.size - TOP)[top.size - TOP :] if TOP else top[:0]
        self._top = top

    def mean(self) -> float:
        if self.nan:
            return math.nan
        return math.fsum(self._sums) / self.n if self.n else math.nan

    def _bin(self, v: np.ndarray) -> np.ndarray:
        scale = BINS / (self.hi - self.lo)
        return np.clip(((v - self.lo) * scale).astype(np.int64), 0, BINS - 1)

    def order_stats(self, source: Source, ranks: Iterable[int]) -> dict[int, float]:
        """The values of 0-based ranks (in ascending order) of what `add` saw, `source` giving the
        same values again (two passes)."""
        want = sorted(set(ranks))
        if not want or self.n == 0:
            return {}
        if self.lo == self.hi or not math.isfinite(self.hi - self.lo):
            if self.lo == self.hi:
                return dict.fromkeys(want, self.lo)
            raise NotStreamable("infinite values")
        top = np.sort(self._top)[max(self._top.size - TOP, 0) :]
        base = self.n - top.size  # the rank of top[0]
        if want[0] >= base:
            return {r: float(top[r - base]) for r in want}
        if self.n <= SMALL:
            parts = [raw[~np.isnan(raw)] for raw in source()]
            allv = np.sort(np.concatenate(parts)) if parts else np.zeros(0)
            return {r: float(allv[r]) for r in want}
        counts = np.zeros(BINS, dtype=np.int64)
        for raw in source():
            v = raw[~np.isnan(raw)]
            counts += np.bincount(self._bin(v), minlength=BINS)
        before = np.concatenate([[0], np.cumsum(counts)])
        bin_of = {r: int(np.searchsorted(before, r, side="right")) - 1 for r in want}
        bins = np.array(sorted(set(bin_of.values())), dtype=np.int64)
        vals: list[np.ndarray] = []
        cnts: list[np.ndarray] = []
        kept = 0
        for raw in source():
            v = raw[~np.isnan(raw)]
            sel = v[np.isin(self._bin(v), bins)]
            if not sel.size:
                continue
            u, c = np.unique(sel, return_counts=True)
            vals.append(u)
            cnts.append(c)
            kept += u.size
            if kept > _MERGE_AT:
                vals, cnts = _merge(vals, cnts)
                kept = vals[0].size
        if vals:
            vals, cnts = _merge(vals, cnts)
        allv = vals[0] if vals else np.zeros(0)
        cum = np.cumsum(cnts[0]) if cnts else np.zeros(0, dtype=np.int64)
        # Every collected value lies in a wanted bin; the values below bin b number before[b].
        out = {}
        for r in want:
            b = bin_of[r]
            in_b = self._bin(allv) == b
            local = r - int(before[b])
            cb = np.cumsum(cnts[0][in_b]) if cnts else cum
            out[r] = float(allv[in_b][int(np.searchsorted(cb, local, side="right"))])
        return out

    def percentiles(self, source: Source, qs: Iterable[float]) -> list[float]:
        """np.percentile(values, q) (method linear) for each q, exactly."""
        qs = list(qs)
        if self.n == 0 or self.nan:
            return [math.nan] * len(qs)
        plan = []
        for q in qs:
            v = (self.n - 1) * (q / 100)
            if v >= self.n - 1:
                plan.append((self.n - 1, self.n - 1, v + 1.0))
            else:
                k = math.floor(v)
                plan.append((k, k + 1, v - k))
        stats = self.order_stats(source, [r for p in plan for r in p[:2]])
        return [_lerp(stats[a], stats[b], g) for a, b, g in plan]

    def median(self, source: Source) -> float:
        """np.median(values), exactly (the mean of the two middle values when their count is even)."""
        if self.n == 0 or self.nan:
            return math.nan
        k = (self.n - 1) // 2
        if self.n % 2:
            return self.order_stats(source, [k])[k]
        s = self.order_stats(source, [k, k + 1])
        return float(np.mean(np.array([s[k], s[k + 1]])))


def _merge(vals: list[np.ndarray], cnts: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    v = np.concatenate(vals)
    c = np.concatenate(cnts)
    u, inv = np.unique(v, return_inverse=True)
    return [u], [np.bincount(inv, weights=c, minlength=u.size).astype(np.int64)]


# ------------------------------------------------------------------------------------------------
# Tick streams


def _aligned_blocks(streams: list[Iterator[np.ndarray]]) -> Iterator[list[np.ndarray]]:
    """Blocks of equal length from streams of row blocks of different lengths; stops at the
    shortest stream's end."""
    bufs: list[np.ndarray | None] = [None] * len(streams)
    while True:
        for i, st in enumerate(streams):
            while bufs[i] is None or bufs[i].shape[0] == 0:  # type: ignore[union-attr]
                nxt = next(st, None)
                if nxt is None:
                    return
                b = bufs[i]
                bufs[i] = nxt if b is None or not b.shape[0] else np.concatenate([b, nxt])
        full = [b for b in bufs if b is not None]
        m = min(b.shape[0] for b in full)
        yield [b[:m] for b in full]
        bufs = [b[m:] for b in full]


def _tick_rows(r: BagReader, topic: str) -> Iterator[np.ndarray]:
    """The values of a tick topic, block by block (checked to be in log time order)."""
    last = None
    for d in r.blocks(topic):
        if d.log_ns.size:
            if last is not None and int(d.log_ns[0]) < last:
                raise NotStreamable(f"{topic} is not in log time order chunk by chunk")
            last = int(d.log_ns[-1])
        yield d.values


class _Lagged:
    """felt[i] - source[i - lag] over a stream of blocks (lag <= 0: felt[i] - source[i])."""

    def __init__(self, lag: int) -> None:
        self.lag = max(lag, 0)
        self.tail = np.zeros(0)

    def feed(self, felt: np.ndarray, source: np.ndarray) -> np.ndarray:
        if self.lag == 0:
            same: np.ndarray = felt - source
            return same
        ext = np.concatenate([self.tail, source])
        p = self.tail.size
        k0 = max(0, self.lag - p)
        self_tail = ext[-self.lag :]
        if k0 >= felt.size:  # still within the first `lag` samples
            self.tail = self_tail
            return np.zeros(0)
        out: np.ndarray = felt[k0:] - ext[k0 - self.lag + p : felt.size - self.lag + p]
        self.tail = self_tail
        return out


@dataclass
class _Err:
    """RMS and peak of an error stream."""

    n: int = 0
    sums: list[float] = field(default_factory=list)
    peak: float = -math.inf

    def add(self, e: np.ndarray) -> None:
        if not e.size:
            return
        self.n += int(e.size)
        self.sums.append(math.fsum((e * e).tolist()))
        self.peak = float(np.max(np.array([self.peak, float(np.max(np.abs(e)))])))

    def rms(self) -> float:
        return math.sqrt(math.fsum(self.sums) / self.n) if self.n else math.nan


@dataclass
class _Energy:
    """port_energy of a stream, its running total and minimum carried between blocks."""

    damping: float
    period_s: float
    total: float = 0.0
    low: float = 0.0
    x_prev: float | None = None
    f_prev: float | None = None

    def add(self, x: np.ndarray, f: np.ndarray) -> np.ndarray:
        if self.x_prev is not None:
            x = np.concatenate([[self.x_prev], x])
            f = np.concatenate([[self.f_prev], f])
        self.x_prev, self.f_prev = float(x[-1]), float(f[-1])
        dx = np.diff(x)
        step = (self.damping / self.period_s) * dx * dx - f[:-1] * dx
        cum = np.cumsum(np.concatenate([[self.total], step]))
        self.total = float(cum[-1])
        self.low = float(np.min(np.array([self.low, float(np.min(cum))])))
        return cum[1:]


def _max_abs(cur: float, v: np.ndarray) -> float:
    return float(np.max(np.array([cur, float(np.max(np.abs(v)))]))) if v.size else cur


# ------------------------------------------------------------------------------------------------
# Packet records


@dataclass
class _Direction:
    """Per-direction statistics of packet records seen in seq order."""

    duration_s: float
    overhead: float
    sent: int = 0
    lost: int = 0
    late: int = 0
    dups: int = 0
    runs: int = 0
    prev_lost: bool = False
    reordered: int = 0
    pending_arrivals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    wire: list[float] = field(default_factory=list)
    any_rows: bool = False
    last_seq: float = -math.inf
    last_send: float = -math.inf
    delay: ExactQuantiles = field(default_factory=ExactQuantiles)
    # first arrival of the last seq of the previous block (its copies may go on in the next)
    carry_seq: float | None = None
    carry_arrival: float = math.inf

    def rows(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Take one block of records; return (seq, first arrival) of the seqs that are complete."""
        if not rows.size:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        self.any_rows = True
        seq = rows[:, 0]
        fate, dup, arr, send = rows[:, 3], rows[:, 4], rows[:, 2], rows[:, 1]
        orig = dup == 0.0
        osend = send[orig]
        if (
            seq[0] < self.last_seq
            or np.any(np.diff(seq) < 0)
            or (osend.size and (osend[0] < self.last_send or np.any(np.diff(osend) < 0)))
        ):
            raise NotStreamable("packet records are not in seq order (or their send times are not)")
        self.last_seq = float(seq[-1])
        if osend.size:
            self.last_send = float(osend[-1])
        lost = np.isin(fate, FATE_LOST)
        self.sent += int(np.count_nonzero(orig))
        self.lost += int(np.count_nonzero(orig & lost))
        self.late += int(np.count_nonzero(fate == FATE_LATE))
        self.dups += int(np.count_nonzero(dup == 1.0))
        # Loss bursts: runs of lost originals in seq order.
        ol = lost[orig]
        if ol.size:
            prev = np.concatenate([[self.prev_lost], ol[:-1]])
            self.runs += int(np.count_nonzero(ol & ~prev))
            self.prev_lost = bool(ol[-1])
        self._reorder(
            arr[orig & ~np.isnan(arr)], send[orig & ~np.isnan(arr)], float(send[orig][-1]) if orig.any() else None
        )
        on_wire = (fate == 1.0) | (fate == 3.0) | (arr <= self.duration_s)
        self.wire.append(math.fsum((rows[on_wire, 5] + self.overhead).tolist()))
        dmask = arr <= self.duration_s  # NaN compares False
        self.delay.add(arr[dmask] - send[dmask])
        return self._first_arrivals(seq[dmask], arr[dmask], float(seq[-1]))

    def _reorder(self, arr: np.ndarray, send: np.ndarray, last_send: float | None) -> None:
        """Arrivals with a higher seq arriving strictly earlier (RFC 4737 style, as `_reordered`).

        A packet is reordered iff a later seq arrives before it. Packets sent after `last_send`
        arrive at or after it, so a packet that arrived by then is settled; the others wait."""
        ext = np.concatenate([self.pending_arrivals, arr])
        if not ext.size:
            return
        # minimum arrival of every later element (in seq order)
        later = np.concatenate([np.minimum.accumulate(ext[::-1])[::-1][1:], [math.inf]])
        hit = later < ext
        # (a pending packet was not hit before, else it would not be pending)
        self.reordered += int(np.count_nonzero(hit))
        keep = ~hit
        if last_send is not None:
            keep &= ext > last_send
        self.pending_arrivals = ext[keep]

    def _first_arrivals(self, seq: np.ndarray, arr: np.ndarray, block_last_seq: float) -> tuple[np.ndarray, np.ndarray]:
        if self.carry_seq is not None:
            seq = np.concatenate([[self.carry_seq], seq])
            arr = np.concatenate([[self.carry_arrival], arr])
        if not seq.size:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        starts = np.flatnonzero(np.concatenate([[True], seq[1:] != seq[:-1]]))
        first = np.minimum.reduceat(arr, starts)
        useq = seq[starts]
        # The last seq may continue in the next block unless the block went past it.
        if useq[-1] == block_last_seq:
            self.carry_seq, self.carry_arrival = float(useq[-1]), float(first[-1])
            useq, first = useq[:-1], first[:-1]
        else:
            self.carry_seq = None
        return useq.astype(np.int64), first

    def flush(self) -> tuple[np.ndarray, np.ndarray]:
        if self.carry_seq is None:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        out = np.array([int(self.carry_seq)]), np.array([self.carry_arrival])
        self.carry_seq = None
        return out

    def stats(self, prefix: str, source: Source, buffering: float) -> dict[str, float | int]:
        mean = self.delay.mean()
        p50, p99 = self.delay.percentiles(source, (50, 99))
        sent = self.sent
        return {
            f"packets_sent_{prefix}": sent,
            f"packets_lost_{prefix}": self.lost,
            f"packets_late_{prefix}": self.late,
            f"loss_rate_{prefix}": self.lost / sent if sent else math.nan,
            f"loss_burst_mean_{prefix}_packets": (self.lost / self.runs if self.runs else 0.0) if sent else math.nan,
            f"delay_{prefix}_mean_s": mean,
            f"delay_{prefix}_p50_s": p50,
            f"delay_{prefix}_p99_s": p99,
            f"reorder_count_{prefix}": self.reordered,
            f"duplicates_{prefix}": self.dups,
            f"late_loss_{prefix}": self.late,
            f"late_loss_rate_{prefix}": self.late / sent if sent else math.nan,
            f"buffering_delay_{prefix}_mean_s": buffering,
            f"wire_bits_per_s_{prefix}": (math.fsum(self.wire) * 8.0 if self.any_rows else 0.0) / self.duration_s
            if self.duration_s > 0
            else math.nan,
        }


# ------------------------------------------------------------------------------------------------
# The summary


def _tick_count(r: BagReader) -> tuple[int, int]:
    """(ticks, log time of the last tick (ns)): the shortest of the tick streams."""
    counts = []
    for topic in TICK_TOPICS:
        n = 0
        for log in r.log_blocks(topic):
            n += int(log.size)
        counts.append(n)
    n = min(counts)
    if n < 2:
        raise BagError(f"{r.path}: fewer than two ticks recorded; nothing to analyse")
    seen = 0
    for log in r.log_blocks("/master/joint_states"):
        if seen + log.size >= n:
            return n, int(log[n - 1 - seen])
        seen += int(log.size)
    raise NotStreamable("tick count")  # not reached


def _received(r: BagReader, topic: str, period_ns: int) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """(delay s, played seq, release s) of a /<dir>/received topic, block by block."""
    last = None
    for d in r.blocks(topic):
        if d.stamp_ns is None or not d.log_ns.size:
            continue
        if last is not None and int(d.log_ns[0]) < last:
            raise NotStreamable(f"{topic} is not in log time order chunk by chunk")
        last = int(d.log_ns[-1])
        yield (d.log_ns - d.stamp_ns) * 1e-9, d.stamp_ns // period_ns, d.log_ns * 1e-9


def summarize_bag(bag: str | Path) -> dict[str, Any]:
    """summary.json of a bag (the keys and values of `metrics.compute_summary`), in bounded memory."""
    try:
        summary = _summarize(bag)
    except NotStreamable:
        summary = _whole(bag)
    from haptic_teleop.analysis.codec_wire import codec_wire_summary

    # the codec stage's wire accounting, only when the scene names a codec (docs/codec_channels.md)
    summary.update(codec_wire_summary(bag, int(summary.get("ticks", 0))))
    from haptic_teleop.analysis.transparency import transparency_summary

    # seed 000's predicted against measured, only for contact scenes it applies to (docs/transparency.md)
    summary.update(transparency_summary(bag))
    return summary


def _whole(bag: str | Path) -> dict[str, Any]:
    """summary.json of a bag the streaming pass cannot take (`metrics.compute_summary`)."""
    from haptic_teleop.analysis.metrics import compute_summary, load_signals

    with BagReader(bag) as r:
        single = r.schema.single_axis
    if not single:
        from haptic_teleop.analysis.taskmetrics import compute_task_summary, load_task_signals

        return compute_task_summary(load_task_signals(bag))
    return compute_summary(load_signals(bag))


@dataclass
class NetworkPass:
    """What the network passes give the tick pass and the summary."""

    nets: dict[str, Any]
    forward_lag: int
    backward_lag: int
    net_lag: int
    lat_f: tuple[float, float]
    lat_b: tuple[float, float]


def network_pass(r: BagReader, sc: dict[str, Any], T: float, duration: float) -> NetworkPass:
    """Per-direction packet and playout statistics, and the lags, in bounded memory."""
    period_ns = round(T * 1e9)
    net = sc.get("network", {})
    nets: dict[str, Any] = {}
    played_q: dict[str, ExactQuantiles] = {}
    for prefix in ("forward", "backward"):
        rl = (net.get(prefix) or {}).get("effects", {}).get("rate_limit") or {}
        overhead = float(rl.get("overhead_bytes", DEFAULT_OVERHEAD_BYTES))
        d = _Direction(duration, overhead)
        ptopic = f"/{prefix}/packets"
        pblocks: Iterator[np.ndarray] = r.packet_blocks(ptopic) if r.has(ptopic) else iter(())
        fa_seq, fa_arr = np.zeros(0, dtype=np.int64), np.zeros(0)
        buf: list[float] = []
        nbuf = 0
        pq = ExactQuantiles()
        exhausted = False
        prev_top = -1
        for delays, played, release in _received(r, f"/{prefix}/received", period_ns):
            pq.add(delays)
            if int(played[0]) < prev_top or np.any(np.diff(played) < 0):
                raise NotStreamable("released samples are not in seq order")
            top = prev_top = int(played[-1])
            while not exhausted and (not fa_seq.size or fa_seq[-1] < top):
                rows = next(pblocks, None)
                if rows is None:
                    exhausted = True
                    s, a = d.flush()
                else:
                    s, a = d.rows(rows)
                fa_seq, fa_arr = np.concatenate([fa_seq, s]), np.concatenate([fa_arr, a])
            j = np.searchsorted(fa_seq, played)
            ok = j < fa_seq.size
            ok[ok] = fa_seq[j[ok]] == played[ok]
            vals = release[ok] - fa_arr[j[ok]]
            if vals.size:
                buf.append(math.fsum(vals.tolist()))
                nbuf += int(vals.size)
            # the releases go on in seq order: drop first arrivals below this block's last seq
            cut = int(np.searchsorted(fa_seq, top))
            fa_seq, fa_arr = fa_seq[cut:], fa_arr[cut:]
        for rows in pblocks:
            d.rows(rows)
        d.flush()

        def delays_src(topic: str = ptopic) -> Iterator[np.ndarray]:
            if not r.has(topic):
                return
            for rows in r.packet_blocks(topic):
                arr = rows[:, 2]
                m = arr <= duration
                yield arr[m] - rows[m, 1]

        nets.update(d.stats(prefix, delays_src, math.fsum(buf) / nbuf if nbuf else math.nan))
        played_q[prefix] = pq

    def played_src(topic: str) -> Source:
        return lambda: (dl for dl, _, _ in _received(r, topic, period_ns))

    fsrc, bsrc = played_src("/forward/received"), played_src("/backward/received")
    fq, bq = played_q["forward"], played_q["backward"]
    fmed, bmed = fq.median(fsrc), bq.median(bsrc)
    forward_lag = int(round(fmed / T)) if fq.n else 0
    backward_lag = (int(round(bmed / T)) if bq.n else 0) + 1
    lat_f = (fq.mean(), *fq.percentiles(fsrc, (99,)))
    lat_b = (bq.mean(), *bq.percentiles(bsrc, (99,)))
    p50 = nets.get("delay_backward_p50_s", math.nan)
    net_lag = int(round(p50 / T)) + 1 if math.isfinite(p50) else backward_lag
    return NetworkPass(nets, forward_lag, backward_lag, net_lag, (lat_f[0], lat_f[1]), (lat_b[0], lat_b[1]))


def _summarize(bag: str | Path) -> dict[str, Any]:

    import yaml

    with BagReader(bag) as r:
        sc = yaml.safe_load(r.string("/haptic_teleop/scene"))
        run_info = read_run_info(r)
        for topic in (*TICK_TOPICS, "/forward/received", "/backward/received"):
            if not r.has(topic):
                r._messages(topic)  # raises the reader's missing-topic error
        T = float(sc["scene"]["period_s"])
        n, last_log = _tick_count(r)
        duration = float(last_log * 1e-9 + T)
        if not r.schema.single_axis:
            return stream_task_summary(r, sc, run_info, n, duration)
        np_ = network_pass(r, sc, T, duration)
        nets = np_.nets
        forward_lag, backward_lag, net_lag = np_.forward_lag, np_.backward_lag, np_.net_lag
        lat_f, lat_b = np_.lat_f, np_.lat_b

        # The tick pass.
        e, e0, en, pos = _Err(), _Err(), _Err(), _Err()
        le, len_, lpos = _Lagged(backward_lag), _Lagged(net_lag), _Lagged(forward_lag)
        m_en = _Energy(float(sc["master"]["damping_n_s_per_m"]), T)
        s_en = _Energy(float(sc["slave"]["damping_n_s_per_m"]), T)
        # The true margins, with the simulator's damping (run facts; one joint per side here).
        m_sim, s_sim = simulator_damping(run_info, "master"), simulator_damping(run_info, "slave")
        m_true = _Energy(m_sim[0], T) if m_sim is not None and len(m_sim) == 1 else None
        s_true = _Energy(s_sim[0], T) if s_sim is not None and len(s_sim) == 1 else None
        if (m_sim is not None and m_true is None) or (s_sim is not None and s_true is None):
            raise NotStreamable("more than one joint per side")
        contact_max = master_max = -math.inf
        two_port_low = 0.0
        depth = 0.0
        plane = wall_plane(sc, run_info, 1)
        finite = True
        seen = 0
        streams = [_tick_rows(r, t) for t in TICK_TOPICS]
        for _op, mb, sb, cb in _aligned_blocks(streams):
            take = min(mb.shape[0], n - seen)
            seen += take
            mx, mf, sx, sf, cf = mb[:take, 0], mb[:take, 2], sb[:take, 0], sb[:take, 2], cb[:take, 0]
            e.add(le.feed(mf, cf))
            e0.add(mf - cf)
            en.add(len_.feed(mf, cf))
            pos.add(lpos.feed(sx, mx))
            contact_max = _max_abs(contact_max, cf)
            master_max = _max_abs(master_max, mf)
            depth = max(depth, float(np.max(penetration(sx[:, None], plane)))) if take else depth
            both = m_en.add(mx, mf) + s_en.add(sx, sf)  # the two ports, tick by tick
            if both.size:
                two_port_low = min(two_port_low, float(np.min(both)))
            for true_en, x, f in ((m_true, mx, mf), (s_true, sx, sf)):
                if true_en is not None:
                    true_en.add(x, f)
            finite = finite and all(bool(np.all(np.isfinite(a))) for a in (mx, sx, mf, sf, cf))
            if seen >= n:
                break

    me0 = initial_energy(sc, run_info, "master")
    se0 = initial_energy(sc, run_info, "slave")
    return {
        "scene": sc["scene"]["name"],
        "seed": sc["scene"]["seed"],
        "duration_s": duration,
        "ticks": n,
        "interrupted": bool(run_info.get("interrupted", False)),
        "realtime_factor": run_info.get("realtime_factor", math.nan),
        "force_rms_error_n": e.rms(),
        "force_peak_error_n": e.peak if e.n else math.nan,
        "force_rms_error_unaligned_n": e0.rms(),
        "force_alignment_lag_s": backward_lag * T,
        "force_rms_error_network_lag_n": en.rms(),
        "force_network_lag_s": net_lag * T,
        "position_rms_error_m": pos.rms(),
        "contact_force_max_n": contact_max,
        "master_force_max_n": master_max,
        "penetration_max_m": depth,
        **{k: nets.pop(k) for k in [k for k in nets if k.startswith("packets_")]},
        "playout_latency_forward_mean_s": lat_f[0],
        "playout_latency_forward_p99_s": lat_f[1],
        "playout_latency_backward_mean_s": lat_b[0],
        "playout_latency_backward_p99_s": lat_b[1],
        **nets,
        "master_energy_margin_min_j": float(me0 + m_en.low),
        "slave_energy_margin_min_j": float(se0 + s_en.low),
        "two_port_energy_margin_min_j": float(me0 + se0 + two_port_low),
        "master_port_energy_min_j": m_en.low,
        "slave_port_energy_min_j": s_en.low,
        "master_initial_energy_j": me0,
        "slave_initial_energy_j": se0,
        "master_energy_margin_simulator_min_j": float(me0 + m_true.low) if m_true is not None else math.nan,
        "master_joint_damping_simulator": m_sim,
        "slave_energy_margin_simulator_min_j": float(se0 + s_true.low) if s_true is not None else math.nan,
        "slave_joint_damping_simulator": s_sim,
        "all_finite": finite,
        **run_counts(run_info),
    }


def stream_task_summary(
    r: BagReader, sc: dict[str, Any], run_info: dict[str, Any], n: int, duration: float
) -> dict[str, Any]:
    """summary.json of an n-DoF bag chunk by chunk (the keys and values of
    `taskmetrics.compute_task_summary`)."""
    from haptic_teleop.analysis.taskmetrics import TASK_TOPICS, TaskAccumulator, measured_topics, side_joints

    schema = r.schema
    topics = (*TASK_TOPICS, *measured_topics(schema))  # a hardware side's measured effort: its energy's torque
    for topic in topics:
        if not r.has(topic):
            r._messages(topic)  # raises the reader's missing-topic error
    T = float(sc["scene"]["period_s"])
    np_ = network_pass(r, sc, T, duration)
    nets = dict(np_.nets)
    counts = {k: nets.pop(k) for k in [k for k in nets if k.startswith("packets_")]}
    acc = TaskAccumulator(schema, sc, run_info, T, np_.forward_lag, np_.backward_lag, np_.net_lag)
    a = schema.task_axes
    seen = 0
    for hx, tx, rf, af, cw, mj, sj, *measured in _aligned_blocks([_tick_rows(r, t) for t in topics]):
        take = min(hx.shape[0], n - seen)
        seen += take
        acc.add(
            hx[:take, :a],
            tx[:take, :a],
            rf[:take, :a],
            af[:take, :a],
            cw[:take, :a],
            cw[:take, a : 2 * a],
            *side_joints(schema, mj[:take], sj[:take], measured),
        )
        if seen >= n:
            break
    return acc.summary(run_info, n, duration, counts, nets, np_.lat_f, np_.lat_b)

"""The plot data of a bag, read in one streaming pass (`from_bag`): every signal decimated into
envelopes as it is read, the played samples and buffer occupancy per direction, the packets'
fates, so memory stays bounded whatever the run's length (analysis/plotdata.py holds the series
types and `from_signals` for runs held in memory).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from haptic_teleop.analysis.metrics import initial_energy
from haptic_teleop.analysis.plotdata import (
    GROUPS,
    DirectionData,
    EnergySide,
    Envelope,
    Events,
    PlotData,
    TaskPlotData,
    Thin,
    cause_times,
    delay_ylim,
    from_signals,
    group_masks,
    loss_labels,
    task_from_bag,
)
from haptic_teleop.analysis.timeline import (
    ARRIVAL,
    DUPLICATE,
    FATE,
    SEND,
)
from haptic_teleop.core.link import LOST_LATE


def from_bag(bag: str | Path, alignment_lag_s: float | None = None) -> PlotData | TaskPlotData:
    """PlotData of a bag in streaming passes (the module docstring); whole if it cannot stream.
    An n-DoF bag gives its TaskPlotData (`task_from_bag`).

    `alignment_lag_s`: summary.json's `force_alignment_lag_s` of this bag, if known (saves the
    passes that find it)."""
    from haptic_teleop.analysis.stream import NotStreamable
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        single = r.schema.single_axis
    if not single:
        return task_from_bag(bag, alignment_lag_s)

    try:
        return _from_bag(bag, alignment_lag_s)
    except NotStreamable:
        from haptic_teleop.analysis.metrics import load_signals

        return from_signals(load_signals(bag))


class _PlayedLine:
    """The released samples of one direction as they stream by: their delay line (release - send),
    the ones above the delay axis, the release lane."""

    def __init__(self, n: int, t_lim: tuple[float, float], top: float, clipped: bool, over: Events) -> None:
        self.env = Envelope(n)
        self.releases = Events(t_lim)
        self.top, self.clipped, self.over = top, clipped, over
        self.last_ps = -math.inf
        self.over_max = -math.inf

    def add(self, dl: np.ndarray, rel: np.ndarray) -> None:
        from haptic_teleop.analysis.stream import NotStreamable

        ps = rel - dl
        ms = dl * 1e3
        if ps.size and (ps[0] < self.last_ps or np.any(np.diff(ps) < 0)):
            raise NotStreamable("released samples' send times are not in order")
        if ps.size:
            self.last_ps = float(ps[-1])
            self.over_max = max(self.over_max, float(np.max(ms)))
        self.env.add(ps, np.minimum(ms, self.top))
        self.releases.add(rel)
        if self.clipped:
            self.over.add(ps[ms > self.top])


class _Played:
    """The released samples of one direction as a window over their stream, in seq order, for
    `timeline.buffer_exits` of packets queried in increasing seq."""

    def __init__(self, blocks: Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]], line: _PlayedLine) -> None:
        self.blocks = blocks
        self.line = line
        self.seq = np.zeros(0, dtype=np.int64)
        self.rel = np.zeros(0)
        self.done = False
        self.top = -1

    def _pull(self) -> bool:
        nxt = next(self.blocks, None)
        if nxt is None:
            self.done = True
            return False
        dl, played, release = nxt
        self.line.add(dl, release)
        from haptic_teleop.analysis.stream import NotStreamable

        if played.size and (int(played[0]) < self.top or np.any(np.diff(played) < 0)):
            raise NotStreamable("released samples are not in seq order")
        if played.size:
            self.top = int(played[-1])
        self.seq = np.concatenate([self.seq, played])
        self.rel = np.concatenate([self.rel, release])
        return True

    def exits(self, seq: np.ndarray, arrival: np.ndarray) -> np.ndarray:
        """buffer_exits(seq, arrival, played, release) for seq ascending, at or above any earlier query."""
        if not seq.size:
            return np.zeros(0)
        while not self.done and (not self.seq.size or self.seq[-1] < seq[-1]):
            self._pull()
        j = np.searchsorted(self.seq, seq, side="left")
        rel = np.concatenate([self.rel, [np.inf]])[j]
        # no release at all: the whole-array function says inf for every packet
        out: np.ndarray = np.maximum(arrival, rel)
        return out

    def drain(self) -> None:
        while not self.done:
            self._pull()

    def drop_below(self, s: float) -> None:
        cut = int(np.searchsorted(self.seq, s, side="left"))
        self.seq, self.rel = self.seq[cut:], self.rel[cut:]


class _Occupancy:
    """`timeline.buffer_occupancy` at each tick, in tick order: the ticks before a time by which
    every arrival and exit is known (`until`) are counted and handed to an Envelope."""

    def __init__(self, n: int, ticks: Iterator[np.ndarray]) -> None:
        self.n, self.ticks = n, ticks
        self.env = Envelope(n)
        self.arrivals: list[np.ndarray] = []
        self.exits: list[np.ndarray] = []
        self.counted_a = self.counted_x = self.done = 0
        self.buf = np.zeros(0)

    def until(self, limit: float, final: bool) -> None:
        """Occupancy at every tick before `limit` (every tick left if `final`)."""
        while self.done < self.n:
            if not self.buf.size:
                nxt = next(self.ticks, None)
                if nxt is None:
                    return
                self.buf = nxt[: self.n - self.done]
                continue
            ts = self.buf if final else self.buf[self.buf < limit]
            if not ts.size:
                return
            a = np.sort(np.concatenate(self.arrivals)) if self.arrivals else np.zeros(0)
            x = np.sort(np.concatenate(self.exits)) if self.exits else np.zeros(0)
            value = (self.counted_a + np.searchsorted(a, ts, side="right")) - (
                self.counted_x + np.searchsorted(x, ts, side="right")
            )
            self.env.add(ts, value.astype(np.int64).astype(np.float64))
            ka = int(np.searchsorted(a, ts[-1], side="right"))
            kx = int(np.searchsorted(x, ts[-1], side="right"))
            self.counted_a += ka
            self.counted_x += kx
            self.arrivals, self.exits = [a[ka:]], [x[kx:]]
            self.done += int(ts.size)
            self.buf = self.buf[ts.size :]


def _from_bag(bag: str | Path, alignment_lag_s: float | None = None) -> PlotData:
    import yaml

    from haptic_teleop.analysis.metrics import read_run_info
    from haptic_teleop.analysis.stream import (
        TICK_TOPICS,
        ExactQuantiles,
        NotStreamable,
        _aligned_blocks,
        _Energy,
        _Lagged,
        _received,
        _tick_count,
        _tick_rows,
    )
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        sc = yaml.safe_load(r.string("/haptic_teleop/scene"))
        run_info = read_run_info(r)
        T = float(sc["scene"]["period_s"])
        period_ns = round(T * 1e9)
        n, last_log = _tick_count(r)
        t_end = float(last_log * 1e-9)
        t_lim = (0.0, float(t_end + T))

        def received(direction: str) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
            topic = f"/{direction}/received"
            return _received(r, topic, period_ns) if r.has(topic) else iter(())

        def packets(direction: str) -> Iterator[np.ndarray]:
            topic = f"/{direction}/packets"
            return r.packet_blocks(topic) if r.has(topic) else iter(())

        # The lag of the forces figure (metrics: median playout delay of the backward samples + 1).
        if alignment_lag_s is not None:
            lag = int(round(alignment_lag_s / T))
        else:
            bq = ExactQuantiles()
            for dl, _, _ in received("backward"):
                bq.add(dl)
            lag = (int(round(bq.median(lambda: (x for x, _, _ in received("backward"))) / T)) if bq.n else 0) + 1

        # Delay axis limits: the arrived packets' and the released samples' delays (ms).
        limits: dict[str, tuple[float, float, bool]] = {}
        counts: dict[str, int] = {}
        for direction in ("forward", "backward"):

            def delays(direction: str = direction) -> Iterator[np.ndarray]:
                for rows in packets(direction):
                    a = rows[~np.isnan(rows[:, ARRIVAL])]
                    yield (a[:, ARRIVAL] - a[:, SEND]) * 1e3
                for dl, _, _ in received(direction):
                    yield dl * 1e3

            def finite(direction: str = direction) -> Iterator[np.ndarray]:
                for v in delays(direction):
                    yield v[np.isfinite(v)]

            q = ExactQuantiles()
            for v in finite():
                q.add(v)
            topic = f"/{direction}/received"
            counts[direction] = sum(int(x.size) for x in r.log_blocks(topic)) if r.has(topic) else 0
            (q999,) = q.percentiles(finite, (99.9,)) if q.n else (0.0,)
            limits[direction] = delay_ylim(q.lo, q.hi, q999, q.n == 0)

        # The tick pass: forces, positions, energy.
        names = ("contact", "master_force", "operator", "master", "slave", "m_margin", "s_margin", "m_res", "s_res")
        env = {k: Envelope(n) for k in (*names, "m_diff", "s_diff")}
        shifted = 0 < lag < n
        env["delayed"] = Envelope(n - lag if shifted else n)
        env["error"] = Envelope(n - lag if shifted else n)
        delay_src, err_src = _Lagged(lag if shifted else 0), _Lagged(lag if shifted else 0)
        energies = {side: _Energy(float(sc[side]["damping_n_s_per_m"]), T) for side in ("master", "slave")}
        e0 = {side: initial_energy(sc, run_info, side) for side in ("master", "slave")}
        low = {side: (math.inf, 0.0, math.nan, 0.0) for side in ("master", "slave")}  # (min, at t, first, t0)
        rng: dict[str, list[float]] = {side: [math.inf, -math.inf] for side in ("master", "slave")}
        gap = {side: -math.inf for side in ("master", "slave")}
        gap_any = {side: False for side in ("master", "slave")}
        has_res = {side: r.has(f"/{side}/eba") for side in ("master", "slave")}

        def logs(topic: str) -> Iterator[np.ndarray]:
            for d in r.blocks(topic):
                yield d.log_ns.reshape(-1, 1)

        streams = [_tick_rows(r, t) for t in TICK_TOPICS] + [logs("/master/joint_states")]
        streams += [_tick_rows(r, f"/{side}/eba") for side in ("master", "slave") if has_res[side]]
        seen = 0
        for blocks in _aligned_blocks(streams):
            op, m, s, c, lg = blocks[:5]
            extra = list(blocks[5:])
            take = min(m.shape[0], n - seen)
            t = lg[:take, 0] * 1e-9
            mx, mf, sx, sf, cf = m[:take, 0], m[:take, 2], s[:take, 0], s[:take, 2], c[:take, 0]
            env["contact"].add(t, cf)
            env["master_force"].add(t, mf)
            env["operator"].add(t, op[:take, 0] * 1e3)
            env["master"].add(t, mx * 1e3)
            env["slave"].add(t, sx * 1e3)
            # delayed contact: contact[i - lag] at t[i] (-(0 - c) is c exactly); error: master[i] - contact[i - lag]
            e = err_src.feed(mf, cf)
            env["error"].add(t[t.size - e.size :], e)
            if shifted:
                dc = -delay_src.feed(np.zeros(take), cf)
                env["delayed"].add(t[t.size - dc.size :], dc)
            for side, x, f, key in (("master", mx, mf, "m"), ("slave", sx, sf, "s")):
                cum = energies[side].add(x, f)
                if seen == 0:
                    cum = np.concatenate([[0.0], cum])
                margin = e0[side] + cum
                env[f"{key}_margin"].add(t, margin)
                fin = np.isfinite(margin)
                if fin.any():
                    mm = margin[fin]
                    j = int(np.argmin(mm))
                    if mm[j] < low[side][0]:
                        low[side] = (float(mm[j]), float(t[fin][j]), low[side][2], low[side][3])
                    rng[side][0] = min(rng[side][0], float(np.min(mm)))
                    rng[side][1] = max(rng[side][1], float(np.max(mm)))
                if seen == 0:
                    low[side] = (low[side][0], low[side][1], float(margin[0]), float(t[0]))
                if has_res[side]:
                    res = extra.pop(0)[:take, 0]
                    env[f"{key}_res"].add(t, res)
                    rf = res[np.isfinite(res)]
                    if rf.size:
                        rng[side][0] = min(rng[side][0], float(np.min(rf)))
                        rng[side][1] = max(rng[side][1], float(np.max(rf)))
                    diff = res - margin
                    env[f"{key}_diff"].add(t, diff)
                    ad = np.abs(diff)
                    if np.any(~np.isnan(ad)):
                        gap[side] = max(gap[side], float(np.nanmax(ad)))
                        gap_any[side] = True
            seen += take
            if seen >= n:
                break

        energy = {}
        for side, key in (("master", "m"), ("slave", "s")):
            lo_j, lo_t, first, t0 = low[side]
            if not math.isfinite(lo_j):  # no finite margin: the first sample
                lo_j, lo_t = first, t0
            y_range = (rng[side][0], rng[side][1]) if math.isfinite(rng[side][0]) else (0.0, 1.0)
            energy[side] = EnergySide(
                reservoir=env[f"{key}_res"].result() if has_res[side] else None,
                margin=env[f"{key}_margin"].result(),
                low_t=lo_t,
                low_j=lo_j,
                y_range=y_range,
                diff=env[f"{key}_diff"].result() if has_res[side] else None,
                gap_j=(gap[side] if gap_any[side] else math.nan) if has_res[side] else 0.0,
            )

        # The network passes, one direction at a time.
        network = {}
        for direction in ("forward", "backward"):
            bottom, top, clipped = limits[direction]
            effects = ((sc.get("network") or {}).get(direction) or {}).get("effects")
            labels = loss_labels(effects)
            thins = [Thin(t_lim, (bottom, top)) for _ in GROUPS]
            group_n = [0] * len(GROUPS)
            over = Events(t_lim)
            over_max = -math.inf
            any_delay = False
            causes = [Events(t_lim) for _ in labels]
            skips = Events(t_lim)
            occ = _Occupancy(n, (d.log_ns * 1e-9 for d in r.blocks("/master/joint_states")))
            line = _PlayedLine(counts[direction], t_lim, top, clipped, over)
            played_w = _Played(received(direction), line)
            any_rows = False
            carry: tuple[float, float] | None = None
            last_send = -math.inf
            last_seq = -math.inf
            for rows in packets(direction):
                if not rows.size:
                    continue
                any_rows = True
                seq = rows[:, 0]
                if seq[0] < last_seq or np.any(np.diff(seq) < 0):
                    raise NotStreamable("packet records are not in seq order")
                last_seq = float(seq[-1])
                orig = rows[:, DUPLICATE] == 0.0
                osend = rows[orig, SEND]
                if osend.size and (osend[0] < last_send or np.any(np.diff(osend) < 0)):
                    raise NotStreamable("send times are not in seq order")
                arrived = rows[~np.isnan(rows[:, ARRIVAL])]
                send = arrived[:, SEND]
                delay_ms = (arrived[:, ARRIVAL] - arrived[:, SEND]) * 1e3
                if delay_ms.size:
                    any_delay = True
                    over_max = max(over_max, float(np.max(delay_ms)))
                for g, mask in enumerate(group_masks(arrived, t_end)):
                    thins[g].add(send[mask], np.minimum(delay_ms[mask], top))
                    group_n[g] += int(np.count_nonzero(mask))
                if clipped:
                    over.add(send[delay_ms > top])
                for acc, times in zip(causes, cause_times(rows, effects), strict=True):
                    acc.add(times)
                # first arrivals (by t_end) and the buffer's exits, for the occupancy
                got = arrived[arrived[:, ARRIVAL] <= t_end]
                if np.any(arrived[:, ARRIVAL] < send):
                    raise NotStreamable("a packet arrived before it was sent")
                gs, ga = got[:, 0], got[:, ARRIVAL]
                if carry is not None:
                    gs = np.concatenate([[carry[0]], gs])
                    ga = np.concatenate([[carry[1]], ga])
                if gs.size:
                    order = np.lexsort((ga, gs))
                    gs, ga = gs[order], ga[order]
                    keep = np.concatenate([[True], gs[1:] != gs[:-1]])
                    gs, ga = gs[keep], ga[keep]
                    if gs[-1] == last_seq:
                        carry = (float(gs[-1]), float(ga[-1]))
                        gs, ga = gs[:-1], ga[:-1]
                    else:
                        carry = None
                late = rows[rows[:, FATE] == LOST_LATE]
                query_s = np.concatenate([gs, late[:, 0]]).astype(np.int64)
                query_a = np.concatenate([ga, late[:, ARRIVAL]])
                qo = np.argsort(query_s, kind="stable")
                ex = np.empty(query_s.size)
                ex[qo] = played_w.exits(query_s[qo], query_a[qo])
                fa_exit, late_exit = ex[: gs.size], ex[gs.size :]
                skips.add(late_exit[np.isfinite(late_exit)])
                occ.arrivals.append(ga)
                occ.exits.append(fa_exit[np.isfinite(fa_exit)])
                played_w.drop_below(carry[0] if carry is not None else last_seq)
                if osend.size:
                    last_send = float(osend[-1])
                    occ.until(last_send, False)
            if carry is not None:
                ex = played_w.exits(np.array([int(carry[0])]), np.array([carry[1]]))
                occ.arrivals.append(np.array([carry[1]]))
                occ.exits.append(ex[np.isfinite(ex)])
            occ.until(math.inf, True)
            played_w.drain()  # the released samples after the last packet's
            played_env, releases, played_over_max = line.env, line.releases, line.over_max
            groups = [(name, th.result(), cnt) for name, th, cnt in zip(GROUPS, thins, group_n, strict=True)]
            lanes: list[tuple[str, np.ndarray, str]] = []
            for label, acc in zip(labels, causes, strict=True):
                if acc.n:
                    lanes.append((f"lost: {label} ({acc.n})", acc.result(), label))
            if not lanes:
                lanes.append(("lost: none", np.zeros(0), "none"))
            lanes.append((f"skipped, late ({skips.n})", skips.result(), "skip"))
            lanes.append((f"released ({releases.n})", releases.result(), "release"))
            hi = max(over_max if any_delay else 0.0, played_over_max if counts[direction] else 0.0)
            network[direction] = DirectionData(
                groups=groups,
                played=played_env.result() if counts[direction] else None,
                bottom=bottom,
                top=top,
                clipped=clipped,
                over_n=over.n if clipped else 0,
                over_max_ms=hi if clipped else 0.0,
                over_shown=over.result() if clipped else np.zeros(0),
                lanes=lanes,
                occupancy=occ.env.result(),
                empty=not any_rows and counts[direction] == 0,
            )

    return PlotData(
        scene=sc,
        period_s=T,
        ticks=n,
        t_end_s=t_end,
        lag_ticks=lag,
        contact=env["contact"].result(),
        master_force=env["master_force"].result(),
        delayed_contact=env["delayed"].result() if shifted else None,
        force_error=env["error"].result(),
        positions_mm={k: env[k].result() for k in ("operator", "master", "slave")},
        energy=energy,
        network=network,
    )

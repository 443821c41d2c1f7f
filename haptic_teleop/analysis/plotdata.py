"""What the plots of a run draw, already reduced to the plot's width (`decimate.py`).

`from_signals(sig)` reduces whole arrays (`metrics.load_signals`) with `decimate.py` and
`timeline.py` as they are; `from_bag(bag)` gives the same `PlotData` in streaming passes over the
bag (memory of a chunk and of the plot's columns, not of the run): each series goes through an
accumulator that keeps what the whole-array reduction would keep (`Envelope`: the first minimum
and maximum of each index bin, the bins fixed up front from the series' length; `Thin`: every point
up to `max_points`, else the first of each cell; `Events`: the same for sorted event times).
A bag whose order does not allow it (`stream.NotStreamable`) is reduced whole.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from haptic_teleop.analysis.decimate import DEFAULT_COLUMNS, SCATTER_COLUMNS, SCATTER_ROWS, minmax_envelope
from haptic_teleop.analysis.metrics import Signals, initial_energy, port_energy
from haptic_teleop.analysis.timeline import (
    _LOSS_MODEL_KIND,
    ARRIVAL,
    DUPLICATE,
    FATE,
    SEND,
    buffer_occupancy,
    loss_causes,
    skip_times,
)
from haptic_teleop.core.link import DELIVERED, LOST_LATE

MAX_POINTS = 20_000


Series = tuple[np.ndarray, np.ndarray]


class Envelope:
    """`minmax_envelope(t, y, columns)` of a series of known length `n`, fed block by block."""

    def __init__(self, n: int, columns: int = DEFAULT_COLUMNS) -> None:
        self.n = n
        self.whole = n <= 2 * columns
        self.k = 1 if self.whole else -(-n // columns)
        self.seen = 0
        self._t: list[np.ndarray] = []
        self._y: list[np.ndarray] = []
        self._i: list[np.ndarray] = []
        self._ct = np.zeros(0)
        self._cy = np.zeros(0)
        self._ends: list[tuple[int, float, float]] = []  # the first and the last sample

    def add(self, t: np.ndarray, y: np.ndarray) -> None:
        if self.whole:
            self._t.append(np.asarray(t, dtype=np.float64).copy())
            self._y.append(np.asarray(y, dtype=np.float64).copy())
            self.seen += int(t.size)
            return
        if not t.size:
            return
        if self.seen == 0:
            self._ends.append((0, float(t[0]), float(y[0])))
        self._last = (self.seen + int(t.size) - 1, float(t[-1]), float(y[-1]))
        ct = np.concatenate([self._ct, t])
        cy = np.concatenate([self._cy, y])
        base = self.seen - self._ct.size  # global index of ct[0], a multiple of k
        full = (ct.size // self.k) * self.k
        if full:
            self._bins(ct[:full], cy[:full], base)
        self._ct, self._cy = ct[full:], cy[full:]
        self.seen += int(t.size)

    def _bins(self, t: np.ndarray, y: np.ndarray, base: int) -> None:
        blocks = y.reshape(-1, self.k)
        local = np.arange(0, t.size, self.k)
        lo = local + np.argmin(blocks, axis=1)
        hi = local + np.argmax(blocks, axis=1)
        idx = np.concatenate([lo, hi])
        self._i.append(idx + base)
        self._t.append(t[idx])
        self._y.append(y[idx])

    def result(self) -> Series:
        if self.whole:
            t = np.concatenate(self._t) if self._t else np.zeros(0)
            y = np.concatenate(self._y) if self._y else np.zeros(0)
            return t, y
        if self._ct.size:  # the tail bin
            base = self.seen - self._ct.size
            idx = np.array([int(np.argmin(self._cy)), int(np.argmax(self._cy))])
            self._i.append(idx + base)
            self._t.append(self._ct[idx])
            self._y.append(self._cy[idx])
        # the first and last samples are kept as the whole-array envelope keeps them
        for k, tt, yy in [*self._ends, self._last]:
            self._i.append(np.array([k]))
            self._t.append(np.array([tt]))
            self._y.append(np.array([yy]))
        i = np.concatenate(self._i)
        t = np.concatenate(self._t)
        y = np.concatenate(self._y)
        i, first = np.unique(i, return_index=True)
        t, y = t[first], y[first]
        return t, y


class Thin:
    """`thin_points(x, y, x_lim, y_lim, columns, rows, max_points)` applied, fed block by block."""

    def __init__(
        self,
        x_lim: tuple[float, float],
        y_lim: tuple[float, float],
        columns: int = SCATTER_COLUMNS,
        rows: int = SCATTER_ROWS,
        max_points: int = MAX_POINTS,
    ) -> None:
        self.x_lim, self.y_lim, self.columns, self.rows, self.max_points = x_lim, y_lim, columns, rows, max_points
        self.n = 0
        self._all: list[tuple[np.ndarray, np.ndarray]] = []
        # the first point of each cell: made when the points pass max_points
        self._cell_i = np.zeros(0, dtype=np.int64)
        self._cell_x = np.zeros(0)
        self._cell_y = np.zeros(0)

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        if not x.size:
            return
        if self.n + x.size <= self.max_points:
            self._all.append((x.copy(), y.copy()))
            self.n += int(x.size)
            return
        if self._all or not self._cell_i.size:
            kept, self._all = self._all, []
            self._cell_i = np.full(self.columns * self.rows, -1, dtype=np.int64)
            self._cell_x = np.zeros(self.columns * self.rows)
            self._cell_y = np.zeros(self.columns * self.rows)
            self.n = 0
            for a, b in kept:
                self._cells(a, b)
        self._cells(x, y)

    def _cells(self, x: np.ndarray, y: np.ndarray) -> None:
        x0, x1 = self.x_lim
        y0, y1 = self.y_lim
        cx = np.clip(((x - x0) * (self.columns / max(x1 - x0, 1e-300))).astype(np.int64), 0, self.columns - 1)
        cy = np.clip(((y - y0) * (self.rows / max(y1 - y0, 1e-300))).astype(np.int64), 0, self.rows - 1)
        cell, first = np.unique(cx * self.rows + cy, return_index=True)
        new = self._cell_i[cell] < 0
        self._cell_i[cell[new]] = self.n + first[new]
        self._cell_x[cell[new]] = x[first[new]]
        self._cell_y[cell[new]] = y[first[new]]
        self.n += int(x.size)

    def result(self) -> Series:
        if self.n <= self.max_points:
            if not self._all:
                return np.zeros(0), np.zeros(0)
            return np.concatenate([a for a, _ in self._all]), np.concatenate([b for _, b in self._all])
        used = np.flatnonzero(self._cell_i >= 0)
        order = np.argsort(self._cell_i[used], kind="stable")
        return self._cell_x[used][order], self._cell_y[used][order]


class Events:
    """`thin_events(np.sort(times), t_lim)` of event times fed block by block in any order."""

    def __init__(self, t_lim: tuple[float, float], columns: int = DEFAULT_COLUMNS, max_points: int = MAX_POINTS):
        self.t_lim, self.columns, self.max_points = t_lim, columns, max_points
        self.n = 0
        self._all: list[np.ndarray] = []
        self._min = np.full(columns, np.inf)

    def add(self, t: np.ndarray) -> None:
        if not t.size:
            return
        if self.n + t.size <= self.max_points:
            self._all.append(t.copy())
        else:
            self._all = []
        x0, x1 = self.t_lim
        c = np.clip(((t - x0) * (self.columns / max(x1 - x0, 1e-300))).astype(np.int64), 0, self.columns - 1)
        np.minimum.at(self._min, c, t)
        self.n += int(t.size)

    def result(self) -> np.ndarray:
        if self.n <= self.max_points:
            return np.sort(np.concatenate(self._all)) if self._all else np.zeros(0)
        shown: np.ndarray = self._min[np.isfinite(self._min)]
        return shown


@dataclass
class EnergySide:
    reservoir: Series | None
    margin: Series
    low_t: float
    low_j: float
    y_range: tuple[float, float]
    diff: Series | None
    gap_j: float


@dataclass
class DirectionData:
    groups: list[tuple[str, Series, int]]  # (name, (x, y) shown, count)
    played: Series | None
    bottom: float
    top: float
    clipped: bool
    over_n: int
    over_max_ms: float
    over_shown: np.ndarray
    lanes: list[tuple[str, np.ndarray, str]]  # (label, shown times, cause or kind)
    occupancy: Series
    empty: bool


@dataclass
class PlotData:
    scene: dict[str, Any]
    period_s: float
    ticks: int
    t_end_s: float  # the last tick's time
    lag_ticks: int
    contact: Series
    master_force: Series
    delayed_contact: Series | None
    force_error: Series
    positions_mm: dict[str, Series]
    energy: dict[str, EnergySide]
    network: dict[str, DirectionData] = field(default_factory=dict)


def loss_labels(effects: dict[str, Any] | None) -> list[str]:
    loss = (effects or {}).get("loss")
    if loss:
        model = str(loss.get("model", "bernoulli"))
        model_label = f"{_LOSS_MODEL_KIND.get(model, 'loss')} ({model})"
    else:
        model_label = "network"
    return ["blackout", model_label, "queue overflow (rate limit)", "corruption"]


def delay_ylim(lo: float, hi: float, q999: float, empty: bool) -> tuple[float, float, bool]:
    """(bottom, top, clipped) of a delay axis from the minimum, maximum and 99.9th percentile of
    its finite delays (ms): a top that a few extreme delays (a queue after a blackout, a trace
    spike) do not stretch. Top = 1.25 x the 99.9th percentile when the maximum is more than twice
    that, else 1.08 x the maximum; at least 1 ms."""
    if empty:
        return 0.0, 1.0, False
    if hi > 2.0 * q999 and q999 > 0:
        top, clipped = 1.25 * q999, True
    else:
        top, clipped = 1.08 * hi, False
    bottom = min(0.0, lo * 1.08)
    return bottom, max(top, bottom + 1.0), clipped


GROUPS = ("delivered", "duplicate copy", "arrived late, skipped", "in flight at the end")


def group_masks(arrived: np.ndarray, end_s: float) -> list[np.ndarray]:
    delivered = arrived[:, FATE] == DELIVERED
    in_time = arrived[:, ARRIVAL] <= end_s
    return [
        delivered & (arrived[:, DUPLICATE] == 0.0) & in_time,
        delivered & (arrived[:, DUPLICATE] == 1.0) & in_time,
        arrived[:, FATE] == LOST_LATE,
        delivered & ~in_time,
    ]


def cause_times(rows: np.ndarray, effects: dict[str, Any] | None) -> list[np.ndarray]:
    """Send times of lost originals per cause, in `loss_labels` order (rows of one block)."""
    got = loss_causes(rows, effects)
    return [got.get(label, np.zeros(0)) for label in loss_labels(effects)]


def _env(t: np.ndarray, y: np.ndarray) -> Series:
    return minmax_envelope(t, y)


def from_signals(sig: Signals) -> PlotData:
    """PlotData of whole-array signals (the reference `from_bag` is tested against)."""
    from haptic_teleop.analysis.decimate import thin_events, thin_points

    t = sig.t_s
    n = t.size
    lag = sig.backward_lag_ticks
    sc = sig.scene
    delayed = _env(t[lag:], sig.contact_n[:-lag]) if 0 < lag < n else None
    err = sig.master_force_n[lag:] - sig.contact_n[: n - lag] if 0 < lag < n else sig.master_force_n - sig.contact_n
    energy = {}
    for side, x, f, res in (
        ("master", sig.master_x_m, sig.master_force_n, sig.master_reservoir_j),
        ("slave", sig.slave_x_m, sig.slave_force_n, sig.slave_reservoir_j),
    ):
        b = float(sc[side]["damping_n_s_per_m"])
        e0 = initial_energy(sc, sig.run_info, side)
        margin = e0 + port_energy(x, f, b, sig.period_s)
        ok = np.flatnonzero(np.isfinite(margin))
        i = int(ok[np.argmin(margin[ok])]) if ok.size else 0
        finite = margin[np.isfinite(margin)]
        vals = [finite] if res is None else [finite, res[np.isfinite(res)]]
        both = np.concatenate(vals)
        y_range = (float(np.min(both)), float(np.max(both))) if both.size else (0.0, 1.0)
        gap = (float(np.nanmax(np.abs(res - margin))) if res.size else 0.0) if res is not None else 0.0
        energy[side] = EnergySide(
            reservoir=_env(t, res) if res is not None else None,
            margin=_env(t, margin),
            low_t=float(t[i]),
            low_j=float(margin[i]),
            y_range=y_range,
            diff=_env(t, res - margin) if res is not None else None,
            gap_j=gap,
        )
    t_lim = (0.0, float(t[-1] + sig.period_s) if n else 1.0)
    network = {}
    for direction in ("forward", "backward"):
        rows = sig.forward_packets if direction == "forward" else sig.backward_packets
        played_delay = sig.forward_delays_s if direction == "forward" else sig.backward_delays_s
        release = sig.forward_release_s if direction == "forward" else sig.backward_release_s
        played_seq = sig.forward_played_seq if direction == "forward" else sig.backward_played_seq
        effects = ((sc.get("network") or {}).get(direction) or {}).get("effects")
        arrived = rows[~np.isnan(rows[:, ARRIVAL])] if rows.size else np.zeros((0, 6))
        send = arrived[:, SEND]
        delay_ms = (arrived[:, ARRIVAL] - arrived[:, SEND]) * 1e3
        played_send = release - played_delay
        played_ms = played_delay * 1e3
        d = np.concatenate([x[np.isfinite(x)] for x in (delay_ms, played_ms)])
        bottom, top, clipped = delay_ylim(
            float(np.min(d)) if d.size else 0.0,
            float(np.max(d)) if d.size else 0.0,
            float(np.percentile(d, 99.9)) if d.size else 0.0,
            d.size == 0,
        )
        end = float(t[-1]) if n else t_lim[1]
        groups = []
        for name, mask in zip(GROUPS, group_masks(arrived, end), strict=True):
            x, y = send[mask], np.minimum(delay_ms[mask], top)
            idx = thin_points(x, y, t_lim, (bottom, top))
            groups.append((name, (x[idx], y[idx]), int(mask.sum())))
        played = None
        if played_ms.size:
            order = np.argsort(played_send, kind="stable")
            played = _env(played_send[order], np.minimum(played_ms[order], top))
        over_n, over_max, over_shown = 0, 0.0, np.zeros(0)
        if clipped:
            over = delay_ms > top
            over_n = int(np.count_nonzero(over)) + int(np.count_nonzero(played_ms > top))
            over_max = max(
                float(np.max(delay_ms)) if delay_ms.size else 0.0, float(np.max(played_ms)) if played_ms.size else 0.0
            )
            over_shown = thin_events(np.sort(np.concatenate([send[over], played_send[played_ms > top]])), t_lim)
        lanes: list[tuple[str, np.ndarray, str]] = []
        causes = loss_causes(rows, effects)
        for name, times in causes.items():
            lanes.append((f"lost: {name} ({times.size})", thin_events(times, t_lim), name))
        if not causes:
            lanes.append(("lost: none", np.zeros(0), "none"))
        skips = skip_times(rows, played_seq, release)
        lanes.append((f"skipped, late ({skips.size})", thin_events(skips, t_lim), "skip"))
        lanes.append((f"released ({release.size})", thin_events(release, t_lim), "release"))
        occ = buffer_occupancy(rows, played_seq, release, t)
        network[direction] = DirectionData(
            groups=groups,
            played=played,
            bottom=bottom,
            top=top,
            clipped=clipped,
            over_n=over_n,
            over_max_ms=over_max,
            over_shown=over_shown,
            lanes=lanes,
            occupancy=_env(t, occ.astype(np.float64)),
            empty=rows.size == 0 and played_ms.size == 0,
        )
    return PlotData(
        scene=sc,
        period_s=sig.period_s,
        ticks=n,
        t_end_s=float(t[-1]) if n else 0.0,
        lag_ticks=lag,
        contact=_env(t, sig.contact_n),
        master_force=_env(t, sig.master_force_n),
        delayed_contact=delayed,
        force_error=_env(t[n - err.size :], err),
        positions_mm={
            "operator": _env(t, sig.operator_x_m * 1e3),
            "master": _env(t, sig.master_x_m * 1e3),
            "slave": _env(t, sig.slave_x_m * 1e3),
        },
        energy=energy,
        network=network,
    )


@dataclass
class TaskPlotData:
    """What the plots of an n-DoF run draw (a bag whose tick schema has 2 or 3 task axes)."""

    scene: dict[str, Any]
    period_s: float
    ticks: int
    axes: tuple[str, ...]
    lag_ticks: int
    handle_path_m: np.ndarray  # (M, axes): every k-th tick's handle point (task frame), M <= MAX_POINTS
    tool_path_m: np.ndarray
    wall: tuple[np.ndarray, np.ndarray] | None  # point, unit normal out of the wall
    rendered: dict[str, Series]  # per axis: force rendered at the handle
    contact: dict[str, Series]  # per axis: contact force at the tool
    penetration_mm: Series
    joint_energy: dict[str, dict[str, Series]]  # side -> joint -> energy absorbed since tick 0 (J)
    pooled_margin: dict[str, Series]  # side -> initial energy + what all its ports absorbed (J)


def task_from_bag(bag: str | Path, alignment_lag_s: float | None = None) -> TaskPlotData:
    """TaskPlotData of an n-DoF bag in one streaming pass over its tick topics (memory of a chunk
    and of the plot's columns); the path keeps every k-th tick, at most MAX_POINTS of them."""
    import yaml

    from haptic_teleop.analysis.metrics import penetration, read_run_info, wall_plane
    from haptic_teleop.analysis.stream import _aligned_blocks, _tick_count, _tick_rows
    from haptic_teleop.analysis.taskmetrics import TASK_TOPICS, _Ports, _side_energy, measured_topics, side_joints
    from haptic_teleop.record.reader import BagReader

    with BagReader(bag) as r:
        schema = r.schema
        sc = yaml.safe_load(r.string("/haptic_teleop/scene"))
        run_info = read_run_info(r)
        T = float(sc["scene"]["period_s"])
        n, _ = _tick_count(r)
        a = schema.task_axes
        if alignment_lag_s is None:
            from haptic_teleop.analysis.stream import network_pass

            alignment_lag_s = network_pass(r, sc, T, n * T).backward_lag * T
        lag = int(round(alignment_lag_s / T))
        plane = wall_plane(sc, run_info, a)
        stride = max(1, -(-n // MAX_POINTS))
        paths: dict[str, list[np.ndarray]] = {"handle": [], "tool": []}
        rendered = [Envelope(n) for _ in range(a)]
        contact = [Envelope(n) for _ in range(a)]
        depth = Envelope(n)
        sides = {"master": schema.master_joints, "slave": schema.slave_joints}
        ports: dict[str, _Ports] = {}
        e0: dict[str, float] = {}
        joint_env = {side: [Envelope(n) for _ in joints] for side, joints in sides.items()}
        pooled_env = {side: Envelope(n) for side in sides}
        for side, joints in sides.items():
            damping, e0[side] = _side_energy(sc, run_info, side, len(joints))
            ports[side] = _Ports(damping, T, schema.measured(side))  # a hardware side: its measured effort
        seen = 0
        topics = (*TASK_TOPICS, *measured_topics(schema))
        for hx, tx, rf, _af, cw, mj, sj, *measured in _aligned_blocks([_tick_rows(r, t) for t in topics]):
            take = min(hx.shape[0], n - seen)
            if take <= 0:
                break
            t = np.arange(seen, seen + take) * T
            first = (-seen) % stride
            paths["handle"].append(hx[first:take:stride, :a])
            paths["tool"].append(tx[first:take:stride, :a])
            for k in range(a):
                rendered[k].add(t, rf[:take, k])
                contact[k].add(t, cw[:take, k])
            depth.add(t, penetration(tx[:take, :a], plane) * 1e3)
            port_rows = dict(zip(sides, side_joints(schema, mj[:take], sj[:take], measured), strict=True))
            for side in sides:
                cum = ports[side].absorbed(*port_rows[side])
                for j, env in enumerate(joint_env[side]):
                    env.add(t, cum[:, j])
                pooled_env[side].add(t, e0[side] + np.sum(cum, axis=1))
            seen += take
    return TaskPlotData(
        scene=sc,
        period_s=T,
        ticks=n,
        axes=schema.axes,
        lag_ticks=lag,
        handle_path_m=np.concatenate(paths["handle"]) if paths["handle"] else np.zeros((0, a)),
        tool_path_m=np.concatenate(paths["tool"]) if paths["tool"] else np.zeros((0, a)),
        wall=plane,
        rendered={ax: rendered[k].result() for k, ax in enumerate(schema.axes)},
        contact={ax: contact[k].result() for k, ax in enumerate(schema.axes)},
        penetration_mm=depth.result(),
        joint_energy={s: {j: env.result() for j, env in zip(sides[s], joint_env[s], strict=True)} for s in sides},
        pooled_margin={s: pooled_env[s].result() for s in sides},
    )

"""PNG plots of one run, from the bag's signals alone: forces, positions, energy, network timeline.

Each plot is built by a `*_figure(sig)` function that returns the matplotlib Figure (tests inspect
its axes and artists), and `write_plots` saves them all. Figures are plain `matplotlib.figure.Figure`
objects (no pyplot state). Long runs are decimated for drawing (`decimate.py`): the drawing cost is
bounded by the plot's width, not by the run's length.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator, ScalarFormatter

from haptic_teleop.analysis.decimate import minmax_envelope, thin_events, thin_points
from haptic_teleop.analysis.metrics import Signals, port_energy
from haptic_teleop.analysis.timeline import (
    ARRIVAL,
    DUPLICATE,
    FATE,
    SEND,
    buffer_occupancy,
    loss_causes,
    skip_times,
)
from haptic_teleop.core.network import CANONICAL_ORDER, DELIVERED, LOST_LATE

DPI = 100

# One colour per loss cause and event, the same in every run.
CAUSE_COLORS = {
    "blackout": "black",
    "queue overflow (rate limit)": "tab:brown",
    "corruption": "tab:pink",
}
LOSS_MODEL_COLOR = "tab:red"
SKIP_COLOR = "tab:orange"
RELEASE_COLOR = "tab:green"


def _title(sig: Signals) -> str:
    return f"{sig.scene['scene']['name']} (seed {sig.scene['scene']['seed']})"


def _plot(ax: Any, t: np.ndarray, y: np.ndarray, **kw: Any) -> Any:
    """ax.plot of a tick signal, decimated to its min/max envelope per pixel column."""
    td, yd = minmax_envelope(t, y)
    return ax.plot(td, yd, **kw)[0]


def forces_figure(sig: Signals) -> Figure:
    t = sig.t_s
    lag = sig.backward_lag_ticks
    fig = Figure(figsize=(11, 6.5))
    ax = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    _plot(ax[0], t, sig.contact_n, label="wall force on robot", color="tab:red", lw=1.2)
    _plot(ax[0], t, sig.master_force_n, label="force rendered to operator", color="tab:blue", lw=1.2)
    if 0 < lag < t.size:
        _plot(
            ax[0],
            t[lag:],
            sig.contact_n[:-lag],
            label=f"wall force delayed {lag * sig.period_s * 1e3:.0f} ms",
            color="tab:red",
            ls="--",
            lw=0.8,
            alpha=0.7,
        )
    ax[0].set_ylabel("force along x (N)")
    ax[0].legend(loc="best")
    ax[0].set_title(f"Forces: {_title(sig)}")
    ax[0].grid(alpha=0.3)
    err = (
        sig.master_force_n[lag:] - sig.contact_n[: t.size - lag]
        if 0 < lag < t.size
        else sig.master_force_n - sig.contact_n
    )
    _plot(ax[1], t[t.size - err.size :], err, color="k", lw=0.8)
    ax[1].set_ylabel("felt - wall (N)")
    ax[1].set_xlabel("time (s)")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    return fig


def positions_figure(sig: Signals) -> Figure:
    t = sig.t_s
    fig = Figure(figsize=(11, 4.5))
    ax = fig.subplots()
    _plot(ax, t, sig.operator_x_m * 1e3, label="operator intended", color="tab:gray", ls=":")
    _plot(ax, t, sig.master_x_m * 1e3, label="master", color="tab:blue")
    _plot(ax, t, sig.slave_x_m * 1e3, label="slave", color="tab:green")
    ax.axhline(float(sig.scene["slave"]["wall"]["position_m"]) * 1e3, color="tab:red", lw=0.8, label="wall")
    ax.set_ylabel("position (mm)")
    ax.set_xlabel("time (s)")
    ax.set_title(f"Positions: {_title(sig)}")
    ax.legend(loc="best")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def energy_margins(sig: Signals) -> dict[str, np.ndarray]:
    """Energy margin of each port from plant signals (J): initial energy + port_energy, per tick."""
    sc = sig.scene
    out = {}
    for side, x, f in (("master", sig.master_x_m, sig.master_force_n), ("slave", sig.slave_x_m, sig.slave_force_n)):
        b = float(sc[side]["damping_n_s_per_m"])
        e0 = float(sc["controllers"][side]["eba"]["initial_energy_j"])
        out[side] = e0 + port_energy(x, f, b, sig.period_s)
    return out


def energy_figure(sig: Signals) -> Figure:
    """Per side (columns): the margin and the controller's reservoir (top), their difference (bottom).

    The reservoir the controller keeps and the margin computed from the plant's signals agree to
    rounding in a run without faults, so on one axis one hides the other: the reservoir is a wide
    translucent band under the margin's thin line, and the bottom panel shows reservoir - margin.
    The y-limits follow each side's own range (no forced zero), with a dotted zero line when zero
    is in view, and the margin's minimum is marked and labelled.
    """
    t = sig.t_s
    margins = energy_margins(sig)
    fig = Figure(figsize=(12, 6.5))
    axes = fig.subplots(2, 2, sharex=True, height_ratios=(3, 1.3))
    for k, (side, res) in enumerate((("master", sig.master_reservoir_j), ("slave", sig.slave_reservoir_j))):
        ax, dax = axes[0][k], axes[1][k]
        margin = margins[side]
        if res is not None:
            _plot(ax, t, res, label="controller reservoir (wide band)", color="tab:orange", lw=6, alpha=0.45,
                  solid_capstyle="butt", zorder=2)  # fmt: skip
        _plot(ax, t, margin, label="energy margin from plant signals", color="tab:purple", lw=1.1, zorder=3)
        ok = np.flatnonzero(np.isfinite(margin))
        i = int(ok[np.argmin(margin[ok])]) if ok.size else 0
        lo = float(margin[i])
        ax.plot([t[i]], [lo], "v", color="tab:red", ms=8, zorder=4, label=f"margin minimum {lo:.4g} J at {t[i]:.3g} s")
        finite = margin[np.isfinite(margin)]
        vals = [finite] if res is None else [finite, res[np.isfinite(res)]]
        both = np.concatenate(vals) if vals else np.zeros(1)
        ymin, ymax = (float(np.min(both)), float(np.max(both))) if both.size else (0.0, 1.0)
        pad = max((ymax - ymin) * 0.08, 1e-6 * max(abs(ymax), 1.0), 1e-9)
        ax.set_ylim(ymin - pad, ymax + pad)
        if ymin - pad <= 0.0 <= ymax + pad:
            ax.axhline(0.0, color="k", lw=0.6, ls=":")
        fmt = ScalarFormatter(useOffset=False)
        fmt.set_powerlimits((-3, 4))
        ax.yaxis.set_major_formatter(fmt)
        ax.set_ylabel(f"{side} energy (J)")
        ax.grid(alpha=0.3)
        ax.legend(loc="best", fontsize=8)
        verdict = "stayed passive" if lo >= 0 else "NOT passive"
        ax.set_title(f"{side} port: min margin {lo:.4g} J ({verdict})")
        if res is not None:
            _plot(dax, t, res - margin, color="tab:orange", lw=0.9)
            dax.set_ylabel("reservoir - margin (J)", fontsize=9)
            gap = float(np.nanmax(np.abs(res - margin))) if res.size else 0.0
            dax.set_title(f"controller reservoir - plant margin: at most {gap:.3g} J apart", loc="right", fontsize=9)
        else:
            dax.text(0.5, 0.5, "no controller reservoir in the bag", ha="center", va="center", transform=dax.transAxes)
        dax.grid(alpha=0.3)
        dax.set_xlabel("time (s)")
    fig.suptitle(f"Energy: {_title(sig)}")
    fig.tight_layout()
    return fig


def _direction_cfg(sig: Signals, direction: str) -> dict[str, Any]:
    net = sig.scene.get("network") or {}
    return dict(net.get(direction) or {})


def _delay_ylim(delays_ms: list[np.ndarray]) -> tuple[float, float, bool]:
    """(bottom, top, clipped): a top that a few extreme delays (a queue after a blackout, a trace
    spike) do not stretch. Top = 1.25 x the 99.9th percentile when the maximum is more than twice
    that, else 1.08 x the maximum; at least 1 ms."""
    d = np.concatenate([x[np.isfinite(x)] for x in delays_ms]) if delays_ms else np.zeros(0)
    if d.size == 0:
        return 0.0, 1.0, False
    hi = float(np.max(d))
    q = float(np.percentile(d, 99.9))
    if hi > 2.0 * q and q > 0:
        top, clipped = 1.25 * q, True
    else:
        top, clipped = 1.08 * hi, False
    bottom = min(0.0, float(np.min(d)) * 1.08)
    return bottom, max(top, bottom + 1.0), clipped


def _delay_panel(ax: Any, sig: Signals, direction: str, t_lim: tuple[float, float]) -> None:
    rows = sig.forward_packets if direction == "forward" else sig.backward_packets
    played_delay = sig.forward_delays_s if direction == "forward" else sig.backward_delays_s
    release = sig.forward_release_s if direction == "forward" else sig.backward_release_s
    arrived = rows[~np.isnan(rows[:, ARRIVAL])] if rows.size else np.zeros((0, 6))
    send = arrived[:, SEND]
    delay_ms = (arrived[:, ARRIVAL] - arrived[:, SEND]) * 1e3
    played_send = release - played_delay
    played_ms = played_delay * 1e3
    bottom, top, clipped = _delay_ylim([delay_ms, played_ms])
    delivered = arrived[:, FATE] == DELIVERED
    in_time = arrived[:, ARRIVAL] <= (float(sig.t_s[-1]) if sig.t_s.size else t_lim[1])
    groups = (
        ("delivered", delivered & (arrived[:, DUPLICATE] == 0.0) & in_time, "tab:blue", 4),
        ("duplicate copy", delivered & (arrived[:, DUPLICATE] == 1.0) & in_time, "tab:purple", 4),
        ("arrived late, skipped", arrived[:, FATE] == LOST_LATE, SKIP_COLOR, 7),
        ("in flight at the end", delivered & ~in_time, "0.6", 4),
    )
    for name, mask, color, size in groups:
        if not np.any(mask):
            continue
        x, y = send[mask], np.minimum(delay_ms[mask], top)
        idx = thin_points(x, y, t_lim, (bottom, top))
        ax.scatter(x[idx], y[idx], s=size, color=color, lw=0, label=f"{name} ({int(mask.sum())})", zorder=2,
                   rasterized=True)  # fmt: skip
    if played_ms.size:
        order = np.argsort(played_send, kind="stable")
        _plot(ax, played_send[order], np.minimum(played_ms[order], top), color="k", lw=0.7, zorder=3,
              label="released samples: release - send")  # fmt: skip
    if clipped:
        over = delay_ms > top
        n_over = int(np.count_nonzero(over)) + int(np.count_nonzero(played_ms > top))
        hi = max(float(np.max(delay_ms)) if delay_ms.size else 0.0, float(np.max(played_ms)) if played_ms.size else 0.0)
        xs = np.concatenate([send[over], played_send[played_ms > top]])
        xs = thin_events(np.sort(xs), t_lim)
        ax.scatter(xs, np.full(xs.size, top), marker="^", s=18, color="tab:red", zorder=4, clip_on=False,
                   label=f"above the axis: {n_over} (max {hi:.0f} ms)")  # fmt: skip
    ax.set_ylim(bottom, top)
    ax.set_ylabel("one-way delay (ms)\nby send time")
    ax.grid(alpha=0.3)
    if rows.size == 0 and played_ms.size == 0:
        ax.text(0.5, 0.5, f"no {direction} packet records in the bag", ha="center", va="center", transform=ax.transAxes)
    else:
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8, markerscale=2, frameon=False)


def _events_panel(ax: Any, sig: Signals, direction: str, t_lim: tuple[float, float]) -> None:
    rows = sig.forward_packets if direction == "forward" else sig.backward_packets
    played = sig.forward_played_seq if direction == "forward" else sig.backward_played_seq
    release = sig.forward_release_s if direction == "forward" else sig.backward_release_s
    causes = loss_causes(rows, _direction_cfg(sig, direction).get("effects"))
    lanes: list[tuple[str, np.ndarray, str]] = []
    for name, times in causes.items():
        lanes.append((f"lost: {name} ({times.size})", times, CAUSE_COLORS.get(name, LOSS_MODEL_COLOR)))
    if not causes:
        lanes.append(("lost: none", np.zeros(0), LOSS_MODEL_COLOR))
    skips = skip_times(rows, played, release)
    lanes.append((f"skipped, late ({skips.size})", skips, SKIP_COLOR))
    lanes.append((f"released ({release.size})", release, RELEASE_COLOR))
    for k, (label, times, color) in enumerate(lanes):
        shown = thin_events(times, t_lim)
        y = len(lanes) - 1 - k
        ax.scatter(shown, np.full(shown.size, y), marker="|", s=60, lw=0.8, color=color, label=label, rasterized=True)
    ax.set_yticks(range(len(lanes)), [lab for lab, _, _ in reversed(lanes)], fontsize=8)
    ax.set_ylim(-0.6, len(lanes) - 0.4)
    ax.grid(axis="x", alpha=0.3)
    ax.set_ylabel("events")


def _occupancy_panel(ax: Any, sig: Signals, direction: str) -> None:
    rows = sig.forward_packets if direction == "forward" else sig.backward_packets
    played = sig.forward_played_seq if direction == "forward" else sig.backward_played_seq
    release = sig.forward_release_s if direction == "forward" else sig.backward_release_s
    occ = buffer_occupancy(rows, played, release, sig.t_s)
    td, od = minmax_envelope(sig.t_s, occ.astype(np.float64))
    ax.step(td, od, where="post", color="tab:cyan", lw=0.9, label="packets in the playout buffer")
    ax.set_ylabel("buffer\n(packets)")
    ax.set_ylim(bottom=-0.5, top=max(float(np.max(od)) if od.size else 1.0, 1.0) * 1.15 + 0.5)
    ax.yaxis.set_major_locator(MaxNLocator(nbins=4, integer=True))
    ax.grid(alpha=0.3)


def network_figure(sig: Signals) -> Figure:
    """Forward and backward direction, each as three panels on one shared time axis:

    1. one-way delay (arrival - send, ms) of every packet that arrived, at its send time, coloured
       by fate (delivered, duplicate copy, arrived late and skipped by the buffer), and the delay
       at which the buffer released each sample (release - send, black line); a few extreme
       delays are clipped to the top edge and marked (see `_delay_ylim`);
    2. events: lost packets by cause at their send time (`timeline.loss_causes`), late packets at
       the time the buffer skipped them and every release of a new sample (`timeline.skip_times`;
       a gap in the release lane is the buffer holding its last sample);
    3. buffer occupancy: packets arrived and not yet released or skipped (`timeline.buffer_occupancy`).
    """
    t = sig.t_s
    t_lim = (0.0, float(t[-1] + sig.period_s) if t.size else 1.0)
    fig = Figure(figsize=(12.5, 11.5))
    axes = fig.subplots(6, 1, sharex=True, height_ratios=(3, 1.4, 1.1, 3, 1.4, 1.1))
    for k, direction in enumerate(("forward", "backward")):
        a_delay, a_events, a_occ = axes[3 * k : 3 * k + 3]
        _delay_panel(a_delay, sig, direction, t_lim)
        _events_panel(a_events, sig, direction, t_lim)
        _occupancy_panel(a_occ, sig, direction)
        cfg = _direction_cfg(sig, direction)
        policy = (cfg.get("buffer") or {}).get("policy", "none")
        arrow = "master -> slave" if direction == "forward" else "slave -> master"
        effects = ", ".join(k for k in CANONICAL_ORDER if (cfg.get("effects") or {}).get(k)) or "no effects"
        bo = (cfg.get("effects") or {}).get("blackout")
        if bo:
            for n, (a, b) in enumerate(zip(bo["starts_s"], bo["ends_s"], strict=True)):
                for ax in (a_delay, a_events, a_occ):
                    ax.axvspan(float(a), float(b), color="0.85", zorder=0, lw=0,
                               label="blackout window" if n == 0 and ax is a_delay else None)  # fmt: skip
            a_delay.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8, markerscale=2, frameon=False)
        a_delay.set_title(f"{direction} ({arrow}): {effects}; playout buffer {policy}", loc="left", fontsize=10)
    axes[-1].set_xlim(*t_lim)
    axes[-1].set_xlabel("time (s)")
    fig.suptitle(f"Network timeline: {_title(sig)}")
    fig.tight_layout()
    return fig


FIGURES: dict[str, Callable[[Signals], Figure]] = {
    "forces.png": forces_figure,
    "positions.png": positions_figure,
    "energy.png": energy_figure,
    "network.png": network_figure,
}


def write_plots(sig: Signals, out_dir: Path) -> list[Path]:
    """Every figure of FIGURES as a PNG in out_dir; the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, build in FIGURES.items():
        fig = build(sig)
        p = out_dir / name
        fig.savefig(p, dpi=DPI)
        paths.append(p)
    return paths

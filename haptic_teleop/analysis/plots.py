"""PNG plots of one run, from the bag's signals alone: forces, positions, energy, network timeline.

Each plot is built by a `*_figure(data)` function that returns the matplotlib Figure (tests inspect
its axes and artists), and `write_plots` saves them all. Figures are plain `matplotlib.figure.Figure`
objects (no pyplot state). They draw a `plotdata.PlotData`: every series already reduced to the
plot's width (`decimate.py`), from whole signals (`plotdata.from_signals`) or streamed from the bag
(`bag_plotdata.from_bag`, what `run` and `analyze` use), so neither the drawing cost nor the memory
grows with the run's length. A `Signals` given instead is reduced first.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter, MaxNLocator, ScalarFormatter

from haptic_teleop.analysis.metrics import Signals, initial_energy, port_energy
from haptic_teleop.analysis.plotdata import PlotData, Series, TaskPlotData, from_signals
from haptic_teleop.core.link import CANONICAL_ORDER

DPI = 100
ROUNDOFF_J = 1e-9  # the energy check passes when reservoir and margin differ by less, per joule of range

# One colour per loss cause and event, the same in every run.
CAUSE_COLORS = {
    "blackout": "black",
    "queue overflow (rate limit)": "tab:brown",
    "corruption": "tab:pink",
}
LOSS_MODEL_COLOR = "tab:red"
SKIP_COLOR = "tab:orange"
RELEASE_COLOR = "tab:green"


GROUP_STYLE = {
    "delivered": ("tab:blue", 4),
    "duplicate copy": ("tab:purple", 4),
    "arrived late, skipped": (SKIP_COLOR, 7),
    "in flight at the end": ("0.6", 4),
}

Data = Signals | PlotData


def _data(d: Data) -> PlotData:
    return d if isinstance(d, PlotData) else from_signals(d)


def _title(d: PlotData) -> str:
    return f"{d.scene['scene']['name']} (seed {d.scene['scene']['seed']})"


def _plot(ax: Any, series: Series, **kw: Any) -> Any:
    """ax.plot of a reduced series (min/max envelope per pixel column)."""
    return ax.plot(series[0], series[1], **kw)[0]


def forces_figure(data: Data) -> Figure:
    d = _data(data)
    lag = d.lag_ticks
    fig = Figure(figsize=(11, 6.5))
    ax = fig.subplots(2, 1, sharex=True, height_ratios=(3, 1))
    _plot(ax[0], d.contact, label="wall force on robot", color="tab:red", lw=1.2)
    _plot(ax[0], d.master_force, label="force rendered to operator", color="tab:blue", lw=1.2)
    if d.delayed_contact is not None:
        _plot(
            ax[0],
            d.delayed_contact,
            label=f"wall force delayed {lag * d.period_s * 1e3:.0f} ms",
            color="tab:red",
            ls="--",
            lw=0.8,
            alpha=0.7,
        )
    ax[0].set_ylabel("force along x (N)")
    ax[0].legend(loc="best")
    ax[0].set_title(f"Forces: {_title(d)}")
    ax[0].grid(alpha=0.3)
    _plot(ax[1], d.force_error, color="k", lw=0.8)
    ax[1].set_ylabel("felt - wall (N)")
    ax[1].set_xlabel("time (s)")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    return fig


def positions_figure(data: Data) -> Figure:
    d = _data(data)
    fig = Figure(figsize=(11, 4.5))
    ax = fig.subplots()
    _plot(ax, d.positions_mm["operator"], label="operator intended", color="tab:gray", ls=":")
    _plot(ax, d.positions_mm["master"], label="master", color="tab:blue")
    _plot(ax, d.positions_mm["slave"], label="slave", color="tab:green")
    ax.axhline(float(d.scene["slave"]["wall"]["position_m"]) * 1e3, color="tab:red", lw=0.8, label="wall")
    ax.set_ylabel("position (mm)")
    ax.set_xlabel("time (s)")
    ax.set_title(f"Positions: {_title(d)}")
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
        e0 = initial_energy(sc, sig.run_info, side)
        out[side] = e0 + port_energy(x, f, b, sig.period_s)
    return out


def energy_figure(data: Data) -> Figure:
    """Per side (columns): the margin and the controller's reservoir (top), their difference (bottom).

    The reservoir the controller keeps and the margin computed from the plant's signals agree to
    rounding in a run without faults, so on one axis one hides the other: the reservoir is a wide
    translucent band under the margin's thin line, and the bottom panel checks reservoir - margin:
    within ROUNDOFF_J per joule of range it says "equal to round-off" on a +-1 nJ axis (a flat line,
    not round-off noise magnified to fill the panel), else "NOT equal" and by how much.
    The y-limits follow each side's own range (no forced zero), with a dotted zero line when zero
    is in view, and the margin's minimum is marked and labelled.
    """
    d = _data(data)
    fig = Figure(figsize=(12, 6.5))
    axes = fig.subplots(2, 2, sharex=True, height_ratios=(3, 1.3))
    for k, side in enumerate(("master", "slave")):
        ax, dax = axes[0][k], axes[1][k]
        e = d.energy[side]
        if e.reservoir is not None:
            _plot(ax, e.reservoir, label="controller reservoir (wide band)", color="tab:orange", lw=6, alpha=0.45,
                  solid_capstyle="butt", zorder=2)  # fmt: skip
        _plot(ax, e.margin, label="energy margin from plant signals", color="tab:purple", lw=1.1, zorder=3)
        lo = e.low_j
        ax.plot([e.low_t], [lo], "v", color="tab:red", ms=8, zorder=4,
                label=f"margin minimum {lo:.4g} J at {e.low_t:.3g} s")  # fmt: skip
        ymin, ymax = e.y_range
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
        if e.diff is not None:
            _plot(dax, e.diff, color="tab:orange", lw=0.9)
            dax.set_ylabel("reservoir - margin (J)", fontsize=9)
            scale = max(1.0, abs(ymin), abs(ymax))
            if e.gap_j <= ROUNDOFF_J * scale:  # the check holds: a flat line on a +-1 nJ axis, said in words
                dax.set_ylim(-ROUNDOFF_J * scale, ROUNDOFF_J * scale)
                dax.set_yticks([-ROUNDOFF_J * scale, 0.0, ROUNDOFF_J * scale])
                dax.yaxis.set_major_formatter(FuncFormatter(lambda y, _: f"{y * 1e9:+.3g} nJ" if y else "0"))
                apart = f"at most {e.gap_j:.2g} J apart" if e.gap_j else "to the last bit"
                verdict, color = f"equal to round-off: {apart}", "tab:green"
            else:
                verdict, color = f"NOT equal: up to {e.gap_j:.3g} J apart", "tab:red"
            dax.set_title("check: the controller's reservoir - the margin from plant signals", fontsize=9)
            dax.text(0.98, 0.9, verdict, ha="right", va="top", color=color, fontsize=9, transform=dax.transAxes,
                     bbox={"facecolor": "white", "alpha": 0.8, "edgecolor": "none"})  # fmt: skip
        else:
            dax.text(0.5, 0.5, "no controller reservoir in the bag", ha="center", va="center", transform=dax.transAxes)
        dax.grid(alpha=0.3)
        dax.set_xlabel("time (s)")
    fig.suptitle(f"Energy: {_title(d)}")
    fig.tight_layout()
    return fig


def _direction_cfg(d: PlotData, direction: str) -> dict[str, Any]:
    net = d.scene.get("network") or {}
    return dict(net.get(direction) or {})


def _delay_panel(ax: Any, d: PlotData, direction: str) -> None:
    n = d.network[direction]
    for name, (x, y), count in n.groups:
        if not count:
            continue
        color, size = GROUP_STYLE[name]
        ax.scatter(x, y, s=size, color=color, lw=0, label=f"{name} ({count})", zorder=2,
                   rasterized=True)  # fmt: skip
    if n.played is not None:
        _plot(ax, n.played, color="k", lw=0.7, zorder=3, label="released samples: release - send")
    if n.clipped:
        xs = n.over_shown
        ax.scatter(xs, np.full(xs.size, n.top), marker="^", s=18, color="tab:red", zorder=4, clip_on=False,
                   label=f"above the axis: {n.over_n} (max {n.over_max_ms:.0f} ms)")  # fmt: skip
    ax.set_ylim(n.bottom, n.top)
    ax.set_ylabel("one-way delay (ms)\nby send time")
    ax.grid(alpha=0.3)
    if n.empty:
        ax.text(0.5, 0.5, f"no {direction} packet records in the bag", ha="center", va="center", transform=ax.transAxes)
    else:
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8, markerscale=2, frameon=False)


def _lane_color(kind: str) -> str:
    if kind == "skip":
        return SKIP_COLOR
    if kind == "release":
        return RELEASE_COLOR
    return CAUSE_COLORS.get(kind, LOSS_MODEL_COLOR)


def _events_panel(ax: Any, d: PlotData, direction: str) -> None:
    lanes = d.network[direction].lanes
    for k, (label, shown, kind) in enumerate(lanes):
        y = len(lanes) - 1 - k
        ax.scatter(shown, np.full(shown.size, y), marker="|", s=60, lw=0.8, color=_lane_color(kind), label=label,
                   rasterized=True)  # fmt: skip
    ax.set_yticks(range(len(lanes)), [lab for lab, _, _ in reversed(lanes)], fontsize=8)
    ax.set_ylim(-0.6, len(lanes) - 0.4)
    ax.grid(axis="x", alpha=0.3)
    ax.set_ylabel("events")


def _occupancy_panel(ax: Any, d: PlotData, direction: str) -> None:
    td, od = d.network[direction].occupancy
    ax.step(td, od, where="post", color="tab:cyan", lw=0.9, label="packets in the playout buffer")
    ax.set_ylabel("buffer\n(packets)")
    ax.set_ylim(bottom=-0.5, top=max(float(np.max(od)) if od.size else 1.0, 1.0) * 1.15 + 0.5)
    ax.yaxis.set_major_locator(MaxNLocator(nbins=4, integer=True))
    ax.grid(alpha=0.3)


def network_figure(data: Data) -> Figure:
    """Forward and backward direction, each as three panels on one shared time axis:

    1. one-way delay (arrival - send, ms) of every packet that arrived, at its send time, coloured
       by fate (delivered, duplicate copy, arrived late and skipped by the buffer), and the delay
       at which the buffer released each sample (release - send, black line); a few extreme
       delays are clipped to the top edge and marked (see `plotdata.delay_ylim`);
    2. events: lost packets by cause at their send time (`timeline.loss_causes`), late packets at
       the time the buffer skipped them and every release of a new sample (`timeline.skip_times`;
       a gap in the release lane is the buffer holding its last sample);
    3. buffer occupancy: packets arrived and not yet released or skipped (`timeline.buffer_occupancy`).
    """
    d = _data(data)
    t_lim = (0.0, d.t_end_s + d.period_s if d.ticks else 1.0)
    fig = Figure(figsize=(12.5, 11.5))
    axes = fig.subplots(6, 1, sharex=True, height_ratios=(3, 1.4, 1.1, 3, 1.4, 1.1))
    for k, direction in enumerate(("forward", "backward")):
        a_delay, a_events, a_occ = axes[3 * k : 3 * k + 3]
        _delay_panel(a_delay, d, direction)
        _events_panel(a_events, d, direction)
        _occupancy_panel(a_occ, d, direction)
        cfg = _direction_cfg(d, direction)
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
    fig.suptitle(f"Network timeline: {_title(d)}")
    fig.tight_layout()
    return fig


FIGURES: dict[str, Callable[[Data], Figure]] = {
    "forces.png": forces_figure,
    "positions.png": positions_figure,
    "energy.png": energy_figure,
    "network.png": network_figure,
}


def write_plots(data: Data | TaskPlotData, out_dir: Path) -> list[Path]:
    """Every figure of FIGURES (TASK_FIGURES for an n-DoF run) as a PNG in out_dir; the paths written."""
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    if isinstance(data, TaskPlotData):
        for name, build_task in TASK_FIGURES.items():
            p = out_dir / name
            build_task(data).savefig(p, dpi=DPI)
            paths.append(p)
        return paths
    d = _data(data)
    for name, build in FIGURES.items():
        fig = build(d)
        p = out_dir / name
        fig.savefig(p, dpi=DPI)
        paths.append(p)
    return paths


# ------------------------------------------------------------------------------------------------
# n-DoF runs

HANDLE_COLOR, TOOL_COLOR, WALL_COLOR = "tab:blue", "tab:green", "tab:red"


def _task_title(d: TaskPlotData) -> str:
    return f"{d.scene['scene']['name']} (seed {d.scene['scene']['seed']})"


def _wall_patch(d: TaskPlotData, lo: np.ndarray, hi: np.ndarray) -> np.ndarray | None:
    """Corners (k, 3) of the wall plane's cut through the box [lo, hi] (its intersections with the
    box's 12 edges, in order around the plane), in mm; None if it misses the box."""
    if d.wall is None:
        return None
    p, n = d.wall
    corners = np.array([[(lo, hi)[(c >> a) & 1][a] for a in range(3)] for c in range(8)])
    side = (corners - p) @ n
    points = []
    for a in range(8):
        for b in range(a + 1, 8):
            if bin(a ^ b).count("1") == 1 and side[a] * side[b] <= 0 and side[a] != side[b]:
                f = side[a] / (side[a] - side[b])
                points.append(corners[a] + f * (corners[b] - corners[a]))
    if len(points) < 3:
        return None
    pts = np.array(points)
    centre = pts.mean(axis=0)
    u = pts[0] - centre if np.linalg.norm(pts[0] - centre) > 0 else np.cross(n, [1.0, 0.0, 0.0])
    v = np.cross(n, u)
    order = np.argsort(np.arctan2((pts - centre) @ v, (pts - centre) @ u))
    patch: np.ndarray = pts[order] * 1e3
    return patch


def _wall_trace(
    d: TaskPlotData, i: int, j: int, k: int, level: float, lo: np.ndarray, hi: np.ndarray
) -> tuple[np.ndarray, np.ndarray] | None:
    """The wall plane cut at axis k = level, in the (i, j) projection (m), across the box [lo, hi];
    None when the plane is parallel to the projection."""
    if d.wall is None:
        return None
    p, n = d.wall
    rest = n[k] * (level - p[k])
    if abs(n[j]) >= abs(n[i]) and abs(n[j]) > 1e-9:
        u = np.linspace(lo[i], hi[i], 2)
        return u, p[j] - (n[i] * (u - p[i]) + rest) / n[j]
    if abs(n[i]) > 1e-9:
        w = np.linspace(lo[j], hi[j], 2)
        return p[i] - (n[j] * (w - p[j]) + rest) / n[i], w
    return None


PATH_STYLES: tuple[
    tuple[str, str, dict[str, Any], str], ...
] = (  # the handle wide and pale under the tool's thin line: where they coincide, both show
    ("master handle", HANDLE_COLOR, {"lw": 3.2, "alpha": 0.45, "solid_capstyle": "round"}, "s"),
    ("slave tool", TOOL_COLOR, {"lw": 1.1}, "o"),
)


def _box(points: np.ndarray, axes: tuple[int, ...], floor_m: float = 5e-4) -> tuple[np.ndarray, np.ndarray]:
    """A box with equal sides over `axes` around `points` (m): the largest of their spans plus 10 %,
    at least 2 `floor_m`; the other axes as in the points."""
    lo, hi = points.min(axis=0).copy(), points.max(axis=0).copy()
    mid = (lo + hi) / 2
    half = max(0.55 * float(np.max((hi - lo)[list(axes)])), floor_m)
    for a in axes:
        lo[a], hi[a] = mid[a] - half, mid[a] + half
    return lo, hi


def task_path_figure(d: TaskPlotData) -> Figure:
    """The handle's and the tool's paths in the task frame (mm): a 3-D view and the three
    orthogonal projections, with the wall plane (a patch in 3-D, its trace through the tool's
    point nearest the wall in each projection: where it meets the wall).

    The 3-D view is a cube around both paths and the wall's nearest point; each projection is
    zoomed to what moved in it (equal scales on its two axes, at least 1 mm across), so a path that
    moved 1 mm sideways and 30 mm down shows both. The handle is drawn wide and pale under the
    tool's thin line, so both show where they coincide."""
    fig = Figure(figsize=(12, 10))
    h, tl = d.handle_path_m, d.tool_path_m
    both = np.concatenate([h, tl]) if h.size or tl.size else np.zeros((1, 3))
    near = tl[int(np.argmin(np.abs((tl - d.wall[0]) @ d.wall[1])))] if d.wall is not None and tl.shape[0] else None
    if near is not None and d.wall is not None:  # the wall's point nearest the tool's nearest: in view
        p, n = d.wall
        both = np.concatenate([both, [near - ((near - p) @ n) * n]])
    lo, hi = _box(both, (0, 1, 2), 1e-3)
    ax3 = fig.add_subplot(2, 2, 1, projection="3d")
    for path, (label, color, style, marker) in zip((h, tl), PATH_STYLES, strict=True):
        if path.shape[0]:
            ax3.plot(*(path * 1e3).T, color=color, label=label, **style)
            ax3.scatter(*(path[:1] * 1e3).T, color=color, marker=marker, s=20)
    patch = _wall_patch(d, lo, hi)
    if patch is not None:
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        ax3.add_collection3d(Poly3DCollection([patch], alpha=0.2, facecolor=WALL_COLOR, edgecolor=WALL_COLOR))
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_zlabel("z (mm)")
    ax3.set_xlim(lo[0] * 1e3, hi[0] * 1e3)
    ax3.set_ylim(lo[1] * 1e3, hi[1] * 1e3)
    ax3.set_zlim(lo[2] * 1e3, hi[2] * 1e3)
    ax3.legend(loc="upper left", fontsize=8)
    ax3.set_title("3-D (markers: start)")
    level = near if near is not None else lo
    for pos, (i, j, k, title) in zip(
        (2, 3, 4), ((0, 1, 2, "top (x-y)"), (0, 2, 1, "front (x-z)"), (1, 2, 0, "side (y-z)")), strict=True
    ):
        ax = fig.add_subplot(2, 2, pos)
        vlo, vhi = _box(both, (i, j))
        for path, (label, color, style, marker) in zip((h, tl), PATH_STYLES, strict=True):
            if path.shape[0]:
                ax.plot(path[:, i] * 1e3, path[:, j] * 1e3, color=color, label=label, **style)
                ax.plot(path[0, i] * 1e3, path[0, j] * 1e3, marker, color=color, ms=5)
        trace = _wall_trace(d, i, j, k, float(level[k]), vlo, vhi)
        if trace is not None:
            ax.plot(trace[0] * 1e3, trace[1] * 1e3, color=WALL_COLOR, lw=1.5, label="wall (cut at the contact)")
        ax.set_xlim(vlo[i] * 1e3, vhi[i] * 1e3)
        ax.set_ylim(vlo[j] * 1e3, vhi[j] * 1e3)
        ax.set_aspect("equal", adjustable="box")
        ax.set_xlabel(f"{d.axes[i]} (mm)")
        ax.set_ylabel(f"{d.axes[j]} (mm)")
        ax.set_title(f"{title}: {2e3 * (vhi[i] - vlo[i]) / 2:.3g} mm across")
        ax.grid(alpha=0.3)
        if pos == 2:
            ax.legend(loc="best", fontsize=8)
    fig.suptitle(f"Paths in the task frame: {_task_title(d)}")
    fig.tight_layout()
    return fig


def task_forces_figure(d: TaskPlotData) -> Figure:
    """Per task axis: the force rendered at the master handle and the contact force at the slave
    tool (task frame); below, the tool's penetration into the wall."""
    rows = len(d.axes) + 1
    fig = Figure(figsize=(11, 2.4 * rows))
    axs = fig.subplots(rows, 1, sharex=True, height_ratios=(*([3] * len(d.axes)), 2))
    for ax, a in zip(axs, d.axes, strict=False):
        _plot(ax, d.contact[a], label="contact force at the tool", color="tab:red", lw=1.2)
        _plot(ax, d.rendered[a], label="force rendered at the handle", color="tab:blue", lw=1.2)
        ax.set_ylabel(f"force {a} (N)")
        ax.grid(alpha=0.3)
    axs[0].legend(loc="best", fontsize=8)
    axs[0].set_title(f"Forces per axis (task frame): {_task_title(d)}")
    _plot(axs[-1], d.penetration_mm, color=WALL_COLOR, lw=1.0)
    axs[-1].set_ylabel("penetration (mm)")
    axs[-1].set_xlabel("time (s)")
    axs[-1].grid(alpha=0.3)
    fig.tight_layout()
    return fig


def task_energy_figure(d: TaskPlotData) -> Figure:
    """Per side: the energy each joint port absorbed since the start, and the side's pooled margin
    (initial energy plus what all its ports absorbed; >= 0: passive)."""
    fig = Figure(figsize=(11, 6.5))
    axs = fig.subplots(2, 1, sharex=True)
    for ax, side in zip(axs, ("master", "slave"), strict=True):
        for joint, series in d.joint_energy[side].items():
            _plot(ax, series, label=joint, lw=0.9)
        _plot(ax, d.pooled_margin[side], label="pooled margin", color="k", lw=1.6)
        ax.axhline(0.0, color="0.4", lw=0.8)
        ax.set_ylabel(f"{side} energy (J)")
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=8, frameon=False)
        ax.grid(alpha=0.3)
    axs[0].set_title(f"Energy per port: {_task_title(d)}")
    axs[-1].set_xlabel("time (s)")
    fig.tight_layout()
    return fig


TASK_FIGURES: dict[str, Callable[[TaskPlotData], Figure]] = {
    "paths.png": task_path_figure,
    "forces.png": task_forces_figure,
    "energy.png": task_energy_figure,
}

"""The report's own figures (plain matplotlib Figures, no pyplot state) and PNG bytes of any figure.

The per-run time plots are not drawn here: the drill-down takes analysis/plots.py's figures.
"""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from haptic_teleop.studies.document.inputs import Run
from haptic_teleop.studies.document.stats import Key, Pair, fmt_value, group_by, label_of, points, spread, unit_of

DPI = 90
COLORS = (
    "tab:blue",
    "tab:orange",
    "tab:green",
    "tab:red",
    "tab:purple",
    "tab:brown",
    "tab:pink",
    "tab:gray",
    "tab:olive",
    "tab:cyan",
)


def png(fig: Figure, dpi: int = DPI) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()


def _grid(n: int, columns: int) -> tuple[int, int]:
    cols = min(n, columns)
    return -(-n // cols), cols


def _panels(fig: Figure, n: int, columns: int) -> list[Any]:
    rows, cols = _grid(n, columns)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return list(axes[:n])


def _color(i: int) -> str:
    return COLORS[i % len(COLORS)]


def prediction_figure(runs: Sequence[Run], pairs: Sequence[Pair], color_key: Key | None) -> Figure:
    """One panel per pair: each run's measured value against its prediction, the line y = x; the
    runs coloured by `color_key`'s value (the first swept key), if any."""
    rows, cols = _grid(len(pairs), 3)
    fig = Figure(
        figsize=(4.6 * cols + (1.4 if color_key is not None and color_key.numeric else 0), 4.5 * rows),
        layout="constrained",
    )
    axes = _panels(fig, len(pairs), 3)
    mappable = None
    for ax, pair in zip(axes, pairs, strict=True):
        if color_key is None:
            groups: list[tuple[str, list[Run], str]] = [("runs", list(runs), _color(0))]
        elif color_key.numeric:
            groups = [("runs", list(runs), "")]
        else:
            groups = [
                (fmt_value(v), [r for r in runs if color_key.of(r) == v], _color(i))
                for i, v in enumerate(color_key.values)
            ]
        all_pts = points(runs, pair)
        for name, members, color in groups:
            pts = points(members, pair)
            if not pts:
                continue
            x = np.array([p for p, _ in pts])
            y = np.array([m for _, m in pts])
            if color_key is not None and color_key.numeric:
                c = np.array([float(color_key.of(r)) for r in members if _finite_pair(r, pair)])
                mappable = ax.scatter(
                    x,
                    y,
                    c=c,
                    cmap="viridis",
                    s=28,
                    edgecolors="k",
                    linewidths=0.4,
                    zorder=3,
                    vmin=min(color_key.values),
                    vmax=max(color_key.values),
                )
            else:
                ax.scatter(x, y, color=color, s=28, edgecolors="k", linewidths=0.4, zorder=3, label=name)
        if all_pts:
            lo = min(min(a, b) for a, b in all_pts)
            hi = max(max(a, b) for a, b in all_pts)
            # a tenth of the spread, at least 5 % of the values' size (all equal: a visible window)
            pad = max((hi - lo) * 0.08, 0.05 * max(abs(lo), abs(hi))) or 1.0
            lim = (lo - pad, hi + pad)
            ax.plot(lim, lim, color="k", ls="--", lw=0.9, label="measured = predicted", zorder=2)
            ax.set_xlim(*lim)
            ax.set_ylim(*lim)
            ax.set_aspect("equal", adjustable="box")
        else:
            ax.text(0.5, 0.5, "no run has both numbers", ha="center", va="center", transform=ax.transAxes)
        unit = unit_of(pair.predicted)
        u = f" ({unit})" if unit else ""
        ax.set_xlabel(f"predicted{u}")
        ax.set_ylabel(f"measured{u}")
        ax.set_title(f"{pair.stem}: {len(all_pts)} runs", fontsize=10)
        ax.grid(alpha=0.3)
        title = label_of(color_key.name, wrap=True) if color_key and not color_key.numeric else None
        ax.legend(loc="upper left", fontsize=8, title=title, title_fontsize=7)
    if mappable is not None and color_key is not None:
        bar = fig.colorbar(mappable, ax=axes, shrink=0.9)
        bar.set_label(label_of(color_key.name, wrap=True), fontsize=8)
    fig.suptitle("Measured against predicted (dashed: measured = predicted)")
    return fig


def _finite_pair(r: Run, pair: Pair) -> bool:
    return math.isfinite(r.metrics.get(pair.predicted, math.nan)) and math.isfinite(
        r.metrics.get(pair.measured, math.nan)
    )


def parameter_figure(runs: Sequence[Run], key: Key, line_key: Key | None, metrics: Sequence[str]) -> Figure:
    """One panel per metric against `key`: the mean over the runs at each value (seeds, and any
    other swept key), error bars of one sample standard deviation, the band from minimum to
    maximum; one line per value of `line_key`."""
    rows, cols = _grid(len(metrics), 2)
    fig = Figure(figsize=(6.2 * cols, 4.1 * rows + 0.6), layout="constrained")
    axes = _panels(fig, len(metrics), 2)
    lines = list(line_key.values) if line_key is not None else [None]
    keys = [line_key, key] if line_key is not None else [key]
    groups = group_by(runs, keys)
    for ax, m in zip(axes, metrics, strict=True):
        for i, lv in enumerate(lines):
            xs, mean, std, lo, hi = [], [], [], [], []
            for combo, members in groups.items():
                if line_key is not None and combo[0] != lv:
                    continue
                x = combo[-1]
                if x is None:
                    continue
                s = spread([r.metrics.get(m, math.nan) for r in members])
                if s.n == 0:
                    continue
                xs.append(float(x))
                mean.append(s.mean)
                std.append(0.0 if math.isnan(s.std) else s.std)
                lo.append(s.lo)
                hi.append(s.hi)
            if not xs:
                continue
            color = _color(i)
            name = f"{fmt_value(lv)}" if line_key is not None else "mean"
            ax.errorbar(xs, mean, yerr=std, color=color, marker="o", ms=4, capsize=3, lw=1.4, label=name)
            ax.fill_between(xs, lo, hi, color=color, alpha=0.15, lw=0)
        ax.set_xlabel(label_of(key.name, wrap=True), fontsize=9)
        ax.set_ylabel(label_of(m))
        ax.set_title(m, fontsize=10)
        ax.grid(alpha=0.3)
        if line_key is not None:
            ax.legend(fontsize=8, title=label_of(line_key.name, wrap=True), title_fontsize=7, loc="best")
    fig.suptitle(
        f"Metrics against {label_of(key.name, wrap=True)}\n(mean over runs, ± 1 std bars, min-max band)", fontsize=11
    )
    return fig


def category_figure(runs: Sequence[Run], key: Key, metrics: Sequence[str], baseline: Any) -> Figure:
    """One panel per metric: a bar per category (the mean over its runs, ± 1 std), each run a dot."""
    rows, cols = _grid(len(metrics), 3)
    fig = Figure(figsize=(max(4.2, 0.9 * len(key.values) + 1.8) * cols, 3.9 * rows + 0.6), layout="constrained")
    axes = _panels(fig, len(metrics), 3)
    cats = list(key.values)
    rng = np.random.default_rng(0)  # the dots' horizontal jitter only
    for ax, m in zip(axes, metrics, strict=True):
        for i, c in enumerate(cats):
            vals = [r.metrics.get(m, math.nan) for r in runs if key.of(r) == c]
            s = spread(vals)
            if s.n == 0:
                continue
            ax.bar(
                i,
                s.mean,
                width=0.65,
                color=_color(i),
                alpha=0.75,
                edgecolor="k",
                lw=0.6,
                hatch="//" if c == baseline else None,
                yerr=None if math.isnan(s.std) else s.std,
                capsize=4,
            )
            finite = [v for v in vals if math.isfinite(v)]
            ax.scatter(i + rng.uniform(-0.18, 0.18, len(finite)), finite, s=10, color="k", zorder=3)
        ax.set_xticks(
            range(len(cats)),
            [fmt_value(c) + (" (baseline)" if c == baseline else "") for c in cats],
            rotation=20 if len(cats) > 3 else 0,
            ha="right" if len(cats) > 3 else "center",
            fontsize=8,
        )
        ax.set_ylabel(label_of(m))
        ax.set_title(m, fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(
        f"Per {label_of(key.name, wrap=True)}:\nmean ± 1 std over runs (dots: each run; hatched: baseline)", fontsize=11
    )
    return fig

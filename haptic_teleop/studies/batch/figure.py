"""The figure of `haptic-teleop sweep` (sweep.png): one panel per metric against the swept values.

Labels are made for reading: several key paths set together are written once with the part that
differs in braces (`network.{forward,backward}.buffer.policy`), long labels wrap, metric names
lose their underscores and gain a unit from their suffix (`_s` seconds, shown in ms when small;
`_n` newtons; `_rate_` fractions, shown in %), tick labels of categorical values stack one line
per parameter and turn 45 degrees when there are many. Layouts:

- one numeric parameter: that parameter on x (log when its positive values span 100x or more);
- two parameters, one of them numeric: the numeric one on x (the one with more values if both
  are), one series per value of the other (colour, marker and line style; later series drawn
  smaller, so equal series stay visible), with a legend titled by it;
- anything else: one slot per combination, every parameter's value in the tick label.

Every run is a dot; the mean over seeds is a marker with the sample standard deviation as an
error bar.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Sequence
from typing import Any

from matplotlib.figure import Figure

# Series of a two-parameter sweep differ in colour, marker and line style, and later ones are drawn
# smaller, so series with equal values stay visible one over another.
_MARKERS = ("s", "o", "^", "D", "v", "P", "X", "*")
_STYLES = ("-", "--", "-.", ":")

Agg = Sequence[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]]


def as_number(text: str) -> float | None:
    try:
        x = float(text)
    except ValueError:
        return None
    return x if math.isfinite(x) else None


def key_label(keys: Sequence[str]) -> str:
    """Key paths set together, written once: the common leading and trailing parts, the rest in braces.

    key_label(["a.fwd.b.c", "a.bwd.b.c"]) == "a.{fwd,bwd}.b.c"; a single key is returned as is.
    """
    if len(keys) == 1:
        return keys[0]
    parts = [k.split(".") for k in keys]
    n = min(len(p) for p in parts)
    head = 0
    while head < n and all(p[head] == parts[0][head] for p in parts):
        head += 1
    tail = 0
    while tail < n - head and all(p[-1 - tail] == parts[0][-1 - tail] for p in parts):
        tail += 1
    if head + tail == 0:
        return " + ".join(keys)
    middles = [".".join(p[head : len(p) - tail]) for p in parts]
    pieces = [*parts[0][:head], "{" + ",".join(middles) + "}", *parts[0][len(parts[0]) - tail :]]
    return ".".join(pieces)


def wrap_key(label: str, width: int = 40) -> str:
    """Wrap a key path at its dots (kept at line ends) so no line is much longer than `width`."""
    if len(label) <= width:
        return label
    lines: list[str] = []
    cur = ""
    for part in label.split("."):
        piece = part if not cur else "." + part
        if cur and len(cur) + len(piece) > width:
            lines.append(cur + ".")
            cur = part
        else:
            cur += piece
    lines.append(cur)
    return "\n".join(lines)


def metric_unit(name: str, values: Sequence[float]) -> tuple[str, float, str]:
    """(unit, scale, name without its unit suffix) of a summary key; plotted value = value * scale."""
    finite = [abs(v) for v in values if math.isfinite(v)]
    big = max(finite) if finite else 0.0
    tokens = name.split("_")
    last = tokens[-1]
    if "per" in tokens and "bits" in tokens:
        stem = name.replace("_per_s", "")
        if big >= 1e6:
            return "Mbit/s", 1e-6, stem
        return ("kbit/s", 1e-3, stem) if big >= 1e3 else ("bit/s", 1.0, stem)
    if last == "s":
        return ("ms", 1e3, name[:-2]) if big < 10.0 else ("s", 1.0, name[:-2])
    if last == "m":
        return ("mm", 1e3, name[:-2]) if big < 1.0 else ("m", 1.0, name[:-2])
    if last in ("n", "j"):
        return last.upper(), 1.0, name[:-2]
    if "rate" in tokens:
        return "%", 100.0, name
    if last == "factor":
        return "x", 1.0, name
    if last == "packets" or tokens[0] in ("packets", "duplicates", "reorder", "rejected", "ticks"):
        return "count", 1.0, name
    return "", 1.0, name


def metric_label(name: str, unit: str, width: int = 24) -> str:
    text = name.replace("_", " ") + (f" ({unit})" if unit else "")
    return "\n".join(textwrap.wrap(text, width=width)) or name


def _metric_values(rows: Sequence[dict[str, Any]], m: str) -> list[float]:
    out = []
    for r in rows:
        v = r["summary"].get(m, math.nan)
        out.append(float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan)
    return out


def sweep_figure(
    param_keys: Sequence[Sequence[str]],
    param_values: Sequence[Sequence[str]],
    rows: Sequence[dict[str, Any]],
    agg: Agg,
    metrics: Sequence[str],
) -> Figure:
    """The sweep figure; `param_keys[i]`/`param_values[i]` describe parameter i, rows and agg are
    those of haptic_teleop.cli.sweep (rows: {"combo", "summary", ...}; agg: (combo, runs, {metric:
    (mean, std)}) in sweep order)."""
    labels = [key_label(list(k)) for k in param_keys]
    numeric = [all(as_number(v) is not None for v in vals) for vals in param_values]
    combos = [c for c, _, _ in agg]
    n_p = len(param_keys)
    if n_p == 1 and numeric[0]:
        mode, xi = "numeric", 0
    elif n_p == 2 and any(numeric):
        mode = "series"
        xi = 0 if numeric[0] and (not numeric[1] or len(param_values[0]) >= len(param_values[1])) else 1
    else:
        mode, xi = "slots", -1
    if mode == "slots":
        width = min(16.0, max(8.0, 0.6 * len(combos) + 3.5))
    else:
        width = 10.0 if mode == "series" else 9.0
    fig = Figure(figsize=(width, 2.3 * len(metrics) + 1.4))
    axes_arr = fig.subplots(len(metrics), 1, sharex=True, squeeze=False)
    axes = [a[0] for a in axes_arr]
    log_x = False
    if mode != "slots":
        xs_all = [as_number(v) or 0.0 for v in param_values[xi]]
        log_x = min(xs_all) > 0 and max(xs_all) / min(xs_all) >= 100.0
    for ax, m in zip(axes, metrics, strict=True):
        run_vals = _metric_values(rows, m)
        means_all = [s[m][0] for _, _, s in agg]
        unit, scale, base = metric_unit(m, [*run_vals, *means_all])
        if mode == "slots":
            index = {c: float(i) for i, c in enumerate(combos)}
            px = [index[tuple(r["combo"])] for r in rows]
            ax.plot(px, [v * scale for v in run_vals], "o", color="0.6", ms=3, label="runs")
            ax.errorbar(
                list(index.values()),
                [s[m][0] * scale for _, _, s in agg],
                yerr=[(s[m][1] if math.isfinite(s[m][1]) else 0.0) * scale for _, _, s in agg],
                fmt="s",
                color="tab:blue",
                capsize=4,
                label="mean ± std over seeds",
            )
        else:
            si = 1 - xi if mode == "series" else -1
            groups = list(param_values[si]) if si >= 0 else [""]
            for g_i, g in enumerate(groups):
                color = f"C{g_i % 10}" if si >= 0 else "tab:blue"
                sel = [k for k, c in enumerate(combos) if si < 0 or c[si] == g]
                gx = [float(combos[k][xi]) for k in sel]
                order = sorted(range(len(sel)), key=lambda i: gx[i])
                rx = [float(r["combo"][xi]) for r in rows if si < 0 or r["combo"][si] == g]
                ry = [v * scale for r, v in zip(rows, run_vals, strict=True) if si < 0 or r["combo"][si] == g]
                ax.plot(rx, ry, "o", color=color, alpha=0.45, ms=3, label="runs" if g_i == 0 else None)
                stats = [agg[sel[i]][2][m] for i in order]
                ax.errorbar(
                    [gx[i] for i in order],
                    [s[0] * scale for s in stats],
                    yerr=[(s[1] if math.isfinite(s[1]) else 0.0) * scale for s in stats],
                    fmt=_MARKERS[g_i % len(_MARKERS)],
                    ls=_STYLES[g_i % len(_STYLES)],
                    color=color,
                    capsize=3,
                    ms=max(7.0 - 1.3 * g_i, 3.0),
                    lw=max(2.2 - 0.35 * g_i, 0.9),
                    label=g if si >= 0 else "mean ± std over seeds",
                )
            if log_x:
                ax.set_xscale("log")
        ax.set_ylabel(metric_label(base, unit), fontsize=9)
        ax.grid(alpha=0.3)
    top = axes[0]
    if mode == "series":
        si = 1 - xi
        top.legend(title=wrap_key(labels[si], 28), loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8,
                   title_fontsize=8, frameon=False)  # fmt: skip
    else:
        top.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
    bottom = axes[-1]
    if mode == "slots":
        ticks = ["\n".join(c) for c in combos]
        bottom.set_xticks(range(len(combos)))
        longest = max((len(x) for c in combos for x in c), default=0)
        if len(combos) > 10 or longest * len(combos) > 90:
            bottom.set_xticklabels([", ".join(c) for c in combos], rotation=45, ha="right", fontsize=8)
        else:
            bottom.set_xticklabels(ticks, fontsize=8)
        bottom.set_xlim(-0.6, len(combos) - 0.4)
        bottom.set_xlabel("\n".join(wrap_key(lab, 70) for lab in labels), fontsize=9)
    else:
        xs = sorted({as_number(v) or 0.0 for v in param_values[xi]})
        if len(xs) <= 12:
            bottom.set_xticks(xs, [f"{x:g}" for x in xs], fontsize=8)
            bottom.minorticks_off()
        bottom.set_xlabel(wrap_key(labels[xi], 70), fontsize=9)
    fig.suptitle("sweep: mean ± sample std over seeds, every run a dot", fontsize=10)
    fig.tight_layout()
    return fig

"""A sweep's tables from its points: the metrics it tabulates by default, the mean and sample
standard deviation over seeds per combination (`aggregate`), sweep.md and sweep.png."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from haptic_teleop.errors import ConfigError
from haptic_teleop.studies.batch.plan import Param, combinations

DEFAULT_METRICS = (
    "force_rms_error_n",
    "buffering_delay_backward_mean_s",
    "late_loss_rate_backward",
    "buffering_delay_forward_mean_s",
    "late_loss_rate_forward",
)
MAX_PLOT_COMBOS = 60  # a random sample of more points than this: no sweep.png (the table has them all)


def _mean_std(values: Sequence[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (n - 1); std is nan for a single value."""
    finite = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    if not finite:
        return math.nan, math.nan
    n = len(finite)
    mean = sum(finite) / n
    if n < 2:
        return mean, math.nan
    return mean, math.sqrt(sum((v - mean) ** 2 for v in finite) / (n - 1))


def _fmt(x: float) -> str:
    return f"{x:.4g}" if math.isfinite(x) else "n/a"


def _fmt_pm(mean: float, std: float) -> str:
    if not math.isfinite(std):
        return _fmt(mean)
    if std <= 1e-12 * abs(mean):
        std = 0.0  # equal values whose mean rounded
    return f"{_fmt(mean)} ± {_fmt(std)}"


def aggregate(
    params: Sequence[Param], rows: Sequence[dict[str, Any]], metrics: Sequence[str]
) -> list[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]]:
    """Per combination (in sweep order): seeds run and (mean, std) of each metric over them."""
    out = []
    for combo in combinations(params):
        group = [r for r in rows if tuple(r["combo"]) == combo]
        if not group:
            continue
        stats = {m: _mean_std([r["summary"].get(m, math.nan) for r in group]) for m in metrics}
        out.append((combo, len(group), stats))
    return out


def write_markdown(
    path: Path,
    command: str,
    params: Sequence[Param],
    agg: Sequence[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]],
    metrics: Sequence[str],
    seeds: Sequence[int],
) -> str:
    lines = [
        f"`{command}`",
        "",
        f"Mean ± sample standard deviation over seeds {', '.join(map(str, seeds))}.",
        "",
        "| " + " | ".join([*(p.label for p in params), "runs", *metrics]) + " |",
        "|" + "---|" * (len(params) + 1 + len(metrics)),
    ]
    for combo, n, stats in agg:
        cells = [*combo, str(n), *(_fmt_pm(*stats[m]) for m in metrics)]
        lines.append("| " + " | ".join(cells) + " |")
    text = "\n".join(lines) + "\n"
    path.write_text(text)
    return text


def write_plot(
    path: Path,
    params: Sequence[Param],
    rows: Sequence[dict[str, Any]],
    agg: Sequence[tuple[tuple[str, ...], int, dict[str, tuple[float, float]]]],
    metrics: Sequence[str],
) -> None:
    """sweep.png: one panel per metric, every run a dot, the mean over seeds with its std as an error
    bar; layouts and labels in haptic_teleop.studies.batch.figure."""
    from haptic_teleop.studies.batch.figure import sweep_figure

    fig = sweep_figure([p.keys for p in params], [p.values for p in params], rows, agg, metrics)
    fig.savefig(path, dpi=100)


def default_metrics(config: Any) -> list[str]:
    """A sweep's metrics when neither the file nor --metrics names them: `DEFAULT_METRICS`, or for
    an NVE scene each client's force (RMS, peak) and median round trip, as the sweep's table
    names them (`sweeps.store.flat_scalars`)."""
    if not config.is_nve:
        return list(DEFAULT_METRICS)
    return [
        f"clients.{c.name}.{m}"
        for c in config.nve.clients
        for m in ("force_rms_n", "force_peak_n", "round_trip_s.median")
    ]


def check_metrics(metrics: Sequence[str], summary: dict[str, Any]) -> None:
    from haptic_teleop.studies.batch.store import flat_scalars

    flat = flat_scalars(summary)
    numeric = sorted(k for k, v in flat.items() if isinstance(v, (int, float)) and not isinstance(v, bool))
    for m in metrics:
        if m not in numeric:
            raise ConfigError("--metrics", m, m, f"allowed: numeric summary keys: {', '.join(numeric)}")

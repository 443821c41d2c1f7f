"""Tables shared by the experiments: RMS, number formatting, markdown and CSV; finishing a figure."""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x * x))) if len(x) else math.nan


def fmt(x: float) -> str:
    if isinstance(x, str):
        return x
    return f"{x:.4g}" if math.isfinite(x) else "n/a"


def markdown(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(c) for c in row) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def write_csv(path: Path, header: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for row in rows:
            w.writerow(["" if isinstance(c, float) and not math.isfinite(c) else c for c in row])


def finish_figure(fig: Any, axes: Sequence[Any], path: Path, **legend: Any) -> None:
    """Grid and legend (`legend`: matplotlib's keyword arguments) on every axes, then the figure
    laid out, written to `path` at the experiments' resolution and closed."""
    import matplotlib.pyplot as plt

    for a in axes:
        a.grid(alpha=0.3)
        a.legend(**legend)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

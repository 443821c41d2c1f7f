"""Reduce long signals to what a plot can show, so drawing costs do not grow with a run's length.

A 1000 s run has 1e6 ticks and about 1e6 packets per direction; a plot is about 1000 pixels wide.
Lines keep the minimum and the maximum of each pixel column (the drawn envelope is the same as the
full line's); scatter points and event marks keep one point per occupied pixel cell. Short inputs
come back whole, so small runs are drawn point for point.
"""

from __future__ import annotations

import numpy as np

# Columns of a decimated line or scatter: about twice the pixels of a 10-11 inch, 100-110 dpi axis.
DEFAULT_COLUMNS = 2400
# Cells of a thinned scatter: about one per 1.5 pixels of a 9 x 2.5 inch axis at 100 dpi, the
# size of a 4 pt^2 marker; at most SCATTER_COLUMNS * SCATTER_ROWS points are drawn per series.
SCATTER_COLUMNS = 600
SCATTER_ROWS = 160


def minmax_envelope(t: np.ndarray, y: np.ndarray, columns: int = DEFAULT_COLUMNS) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) reduced to the first, minimum, maximum and last sample of each of `columns` index bins.

    Meant for signals on an even grid (the tick grid), where equal index bins are equal time bins.
    Within a bin the minimum and maximum keep their time order, so the line drawn through the
    result covers the same vertical extent per column as the full line. Inputs of at most
    2 * columns samples are returned unchanged. NaN samples are kept where they fall (argmin and
    argmax pick them), so a gap in the signal stays a gap.
    """
    n = int(t.size)
    if y.size != n:
        raise ValueError(f"t and y differ in length: {n} and {y.size}")
    if columns < 1:
        raise ValueError(f"columns must be >= 1, got {columns}")
    if n <= 2 * columns:
        return t, y
    k = -(-n // columns)  # samples per bin
    full = (n // k) * k
    blocks = y[:full].reshape(-1, k)
    base = np.arange(0, full, k)
    lo = base + np.argmin(blocks, axis=1)
    hi = base + np.argmax(blocks, axis=1)
    parts = [lo, hi]
    if full < n:
        tail = y[full:]
        parts += [np.array([full + int(np.argmin(tail))]), np.array([full + int(np.argmax(tail))])]
    idx = np.unique(np.concatenate([*parts, np.array([0, n - 1])]))
    return t[idx], y[idx]


def thin_points(
    x: np.ndarray,
    y: np.ndarray,
    x_lim: tuple[float, float],
    y_lim: tuple[float, float],
    columns: int = SCATTER_COLUMNS,
    rows: int = SCATTER_ROWS,
    max_points: int = 20_000,
) -> np.ndarray:
    """Indices of the points to draw: all of them up to `max_points`, else one per occupied cell.

    The cells split x_lim into `columns` and y_lim into `rows` equal parts (points outside are
    put in the edge cells); the first point of each occupied cell, in input order, stands for the
    cell. The result is sorted, so it keeps the input's order.
    """
    n = int(x.size)
    if y.size != n:
        raise ValueError(f"x and y differ in length: {n} and {y.size}")
    if n <= max_points:
        return np.arange(n)
    x0, x1 = x_lim
    y0, y1 = y_lim
    cx = np.clip(((x - x0) * (columns / max(x1 - x0, 1e-300))).astype(np.int64), 0, columns - 1)
    cy = np.clip(((y - y0) * (rows / max(y1 - y0, 1e-300))).astype(np.int64), 0, rows - 1)
    _, first = np.unique(cx * rows + cy, return_index=True)
    return np.sort(first)


def thin_events(
    t: np.ndarray, t_lim: tuple[float, float], columns: int = DEFAULT_COLUMNS, max_points: int = 20_000
) -> np.ndarray:
    """Event times to mark: all of them up to `max_points`, else the first one in each column."""
    if t.size <= max_points:
        return t
    idx = thin_points(t, np.zeros_like(t), t_lim, (0.0, 1.0), columns=columns, rows=1, max_points=max_points)
    shown: np.ndarray = t[idx]
    return shown

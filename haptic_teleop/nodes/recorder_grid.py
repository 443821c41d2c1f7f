"""The recorder's pure parts (nodes/recorder.py): late marks on packet records, samples onto the tick grid."""

from __future__ import annotations

import numpy as np

from haptic_teleop.core.link import DELIVERED, LOST_LATE

__all__ = ["_on_grid", "mark_late"]


def mark_late(rows: np.ndarray, late: set[int], f: dict[str, int]) -> int:
    """In place: for each seq in `late`, its first delivered copy in `rows` (packet records, the
    earliest arrival) gets fate LOST_LATE, as the engine's buffer marks the copy it received first.
    Returns how many records were marked."""
    if not late or rows.size == 0:
        return 0
    seq = rows[:, f["seq"]].astype(np.int64)
    cand = np.flatnonzero(
        (rows[:, f["fate"]] == DELIVERED) & np.fromiter((s in late for s in seq.tolist()), dtype=bool, count=seq.size)
    )
    if cand.size == 0:
        return 0
    order = np.lexsort((rows[cand, f["arrival_time_s"]], seq[cand]))
    c = cand[order]
    first = np.ones(c.size, dtype=bool)
    first[1:] = seq[c[1:]] != seq[c[:-1]]
    rows[c[first], f["fate"]] = LOST_LATE
    return int(np.count_nonzero(first))


def _on_grid(
    idx: np.ndarray, vals: np.ndarray, n: int, carry: np.ndarray | None
) -> tuple[np.ndarray, int, np.ndarray | None]:
    """Samples at tick indices -> an (n, k) grid; a tick with no sample holds the previous value
    (`carry`, the last value of the previous block; before any sample at all, the first one).
    Returns the grid, how many ticks were filled, and the carry for the next block."""
    k = vals.shape[1]
    ok = (idx >= 0) & (idx < n)
    have = np.zeros(n, dtype=bool)
    grid = np.zeros((n, k))
    if np.any(ok):
        grid[idx[ok]] = vals[ok]
        have[idx[ok]] = True
    if not have.any():
        if carry is not None:
            grid[:] = carry
        return grid, n, carry
    pos = np.where(have, np.arange(n), -1)
    pos = np.maximum.accumulate(pos)
    head = pos < 0
    grid = grid[np.maximum(pos, 0)]
    if np.any(head):
        grid[head] = carry if carry is not None else grid[int(np.argmax(have))]
    return grid, int(n - np.count_nonzero(have)), grid[-1].copy()

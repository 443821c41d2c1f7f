"""The recorder's pure parts (nodes/recorder.py): late marks on packet records, samples onto the tick grid."""

from __future__ import annotations

import numpy as np

from haptic_teleop.core.link import DELIVERED, LOST_LATE, taken_tick

__all__ = ["_on_grid", "as_delivered", "mark_late"]


def mark_late(rows: np.ndarray, late: set[int], f: dict[str, int]) -> int:
    """In place: for each seq in `late`, its first delivered copy in `rows` (packet records, the
    earliest arrival) gets fate LOST_LATE, as the engine's buffer marks the copy it received first.
    Returns how many records were marked."""
    if not late or rows.size == 0:
        return 0
    seq = rows[:, f["seq"]].astype(np.int64)
    c = _first_copies(
        rows, seq, (rows[:, f["fate"]] == DELIVERED) & np.fromiter((s in late for s in seq.tolist()), bool, seq.size), f
    )
    rows[c, f["fate"]] = LOST_LATE
    return int(c.size)


def _first_copies(rows: np.ndarray, seq: np.ndarray, which: np.ndarray, f: dict[str, int]) -> np.ndarray:
    """Indices of the first arriving copy of each seq among the records `which` selects (the copy
    a buffer took: duplicates share a seq)."""
    cand = np.flatnonzero(which)
    if cand.size == 0:
        return cand
    c = cand[np.lexsort((rows[cand, f["arrival_time_s"]], seq[cand]))]
    first = np.ones(c.size, dtype=bool)
    first[1:] = seq[c[1:]] != seq[c[:-1]]
    return c[first]


def as_delivered(
    rows: np.ndarray, arrived: dict[int, int], start: int, end: int, period_ns: int, f: dict[str, int]
) -> int:
    """In place: a packet record (`rows`, scene seqs and times) whose packet the sync buffer took a
    tick or more after the tick the network delivered it at (`arrived`: node clock seq -> the node
    clock tick the buffer pushed it at; `start`, `end`: the node clock ticks of scene time 0 and of
    the recording's end, after which nothing is taken; late by scheduling: the machine, not the
    network) gets that tick's time as its arrival, on its first arriving copy, the one the buffer
    took. Returns how many records were moved."""
    if not arrived or rows.size == 0:
        return 0
    seq = rows[:, f["seq"]].astype(np.int64)
    fate = rows[:, f["fate"]]
    taken = np.fromiter((s + start in arrived for s in seq.tolist()), bool, seq.size)
    c = _first_copies(rows, seq, ((fate == DELIVERED) | (fate == LOST_LATE)) & taken, f)
    if c.size == 0:
        return 0
    a_ns = np.round(rows[c, f["arrival_time_s"]] * 1e9).astype(np.int64)
    due = taken_tick(a_ns, period_ns)  # the tick the engine's buffer takes it at
    took = np.array([arrived[s + start] - start for s in seq[c].tolist()], dtype=np.int64)
    late = (took > due) & (took < end - start)
    rows[c[late], f["arrival_time_s"]] = took[late] * period_ns * 1e-9
    return int(np.count_nonzero(late))


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

"""Where the recorder puts a sample that has no header: on its writer's tick, not its write time.

The EBA arrays (/<side>/eba, std_msgs/Float64MultiArray) carry no stamp. A side node publishes
its stamped state (/<side>/joint_states, header stamp = the tick) and then, in the same tick
function, its EBA array. Placing the array by its DDS write time (source timestamp) divided by the
period puts it on the wrong tick whenever the node's tick ran late: a tick that starts 3 ms after
its deadline writes its array 3 ticks on, the rows in between keep the previous value, and the
bag's budget is no longer the one the side had at that tick (seen: 1 to 4 rows in a row, about
four times a second, in composed launches, where the recorder's decoding rounds delay the shared
loop; docs/live_launch.md, "Unstamped arrays on their writer's tick").

`WriterTicks` keeps the writer's clock: the write times and stamps of its stamped messages. An
array goes on the tick of the last stamped message the same node wrote at or before it. That is
known only once a stamped message written after the array has been taken (the recorder takes the
two topics at different moments): until then the array waits for the next decoding round, or is
placed with what is known when the recording closes. Before any stamped message of its writer, an
array goes by its write time, as before.
"""

from __future__ import annotations

import numpy as np

KEEP = 8192  # the writer's clock keeps this many of its newest stamped messages (8 s at 1 kHz)


class WriterTicks:
    """The ticks of one writer's stamped messages, by write time (both in ns, as taken)."""

    def __init__(self, period_ns: int) -> None:
        self.period_ns = period_ns
        self.times = np.zeros(0, dtype=np.int64)  # write times (DDS source timestamps), ascending
        self.ticks = np.zeros(0, dtype=np.int64)  # each one's tick (its header stamp // period)

    def stamped(self, times: np.ndarray, stamps: np.ndarray) -> None:
        """The writer's stamped messages just decoded (in the order taken)."""
        if times.size == 0:
            return
        t = np.concatenate([self.times, np.asarray(times, dtype=np.int64)])
        k = np.concatenate([self.ticks, np.asarray(stamps, dtype=np.int64) // self.period_ns])
        order = np.argsort(t, kind="stable")
        self.times, self.ticks = t[order][-KEEP:], k[order][-KEEP:]

    def placeable(self, times: list[int] | np.ndarray, closing: bool) -> int:
        """How many of the arrays written at `times` (ascending) can be placed now: those written
        before the writer's newest known stamped message (all of them when closing)."""
        if closing or not len(times):
            return len(times)
        if self.times.size == 0:
            return 0
        return int(np.searchsorted(np.asarray(times, dtype=np.int64), self.times[-1], side="left"))

    def ticks_of(self, times: np.ndarray) -> np.ndarray:
        """The tick of each array written at `times` (ascending): that of the writer's last stamped
        message written at or before it; by its own write time where none was. Where stamped
        messages are missing between two known ones (lost or not taken: ticks a and b > a + 1
        known) and exactly b - a arrays were written between them, they are the arrays of ticks
        a .. b - 1 in order (each tick writes its state, then its array): on a busy machine the
        recorder lost a state and put the next tick's array on the tick before, one row early."""
        times = np.asarray(times, dtype=np.int64)
        j = np.searchsorted(self.times, times, side="right") - 1
        own = times // self.period_ns
        if self.ticks.size == 0:
            return own
        out = np.where(j >= 0, self.ticks[np.maximum(j, 0)], own)
        inside = (j >= 0) & (j + 1 < self.ticks.size)
        if inside.any() and bool(np.all(np.diff(j) >= 0)):  # (taken out of order: the rule above alone)
            k = np.minimum(np.maximum(j, 0) + 1, self.ticks.size - 1)
            gap = np.where(inside, self.ticks[k] - out, 1)
            first = np.searchsorted(j, j, side="left")  # each array's rank among those after the same state
            count = np.searchsorted(j, j, side="right") - first
            rank = np.arange(j.size) - first
            whole = inside & (gap > 1) & (count == gap)
            out = np.where(whole, out + rank, out)
        return out

"""The recorder's placement of arrays without a header (nodes/recorder_placement.py): on the tick of
the stamped state their node wrote just before them, not at their write time over the period."""

from __future__ import annotations

import numpy as np

from haptic_teleop.nodes.recorder_placement import WriterTicks

MS = 1_000_000


def _writer() -> WriterTicks:
    w = WriterTicks(MS)
    # the node's stamped states of ticks 0, 1, 2 and 3, written 0.1 ms into ticks 0 and 1, then
    # ticks 2 and 3 late: written at 5.0 and 5.2 ms (a composed loop held up by 3 ms)
    w.stamped(np.array([100_000, 1_100_000]), np.array([0, MS]))
    w.stamped(np.array([5_000_000, 5_200_000]), np.array([2 * MS, 3 * MS]))
    return w


def test_an_array_goes_on_its_writers_tick_however_late_it_was_written():
    w = _writer()
    arrays = np.array([150_000, 1_150_000, 5_050_000])  # written right after the states of ticks 0, 1, 2
    assert w.placeable(arrays, closing=False) == 3
    assert w.ticks_of(arrays).tolist() == [0, 1, 2]
    assert (arrays // MS).tolist() == [0, 1, 5]  # by write time, tick 2's array would land on tick 5


def test_an_array_waits_until_a_later_state_of_its_writer_is_known():
    """The array of tick 3 (written after the newest known state) could belong to a tick whose
    state has not been taken yet: it waits, and is placed when the recording closes."""
    w = _writer()
    arrays = [1_150_000, 5_250_000]
    assert w.placeable(arrays, closing=False) == 1
    assert w.placeable(arrays, closing=True) == 2
    assert w.ticks_of(np.array(arrays)).tolist() == [1, 3]
    w.stamped(np.array([6_100_000]), np.array([4 * MS]))  # tick 4's state: now tick 3's array is placed
    assert w.placeable(arrays, closing=False) == 2


def test_before_any_state_of_its_writer_an_array_goes_by_its_write_time():
    w = WriterTicks(MS)
    assert w.placeable([2_500_000], closing=False) == 0
    assert w.ticks_of(np.array([2_500_000])).tolist() == [2]
    w.stamped(np.array([3_100_000]), np.array([3 * MS]))
    assert w.ticks_of(np.array([2_500_000, 3_200_000])).tolist() == [2, 3]


def test_states_taken_out_of_order_are_sorted_by_write_time():
    w = WriterTicks(MS)
    w.stamped(np.array([2_100_000]), np.array([2 * MS]))
    w.stamped(np.array([1_100_000]), np.array([MS]))
    assert w.ticks_of(np.array([1_500_000, 2_500_000])).tolist() == [1, 2]


def test_the_arrays_between_two_known_states_fill_the_ticks_of_the_states_missing_between():
    """Tick 2's state lost (or not taken) on a busy machine: its array, written after it, is tick 2's,
    not tick 1's (which would put it one row early and leave tick 2 to a held-over value)."""
    w = WriterTicks(MS)
    w.stamped(np.array([1_100_000, 3_100_000]), np.array([MS, 3 * MS]))  # ticks 1 and 3; 2 missing
    arrays = np.array([1_150_000, 2_150_000])  # the arrays of ticks 1 and 2
    assert w.ticks_of(arrays).tolist() == [1, 2]
    # a tick the node skipped (no state, no array): the one array after tick 1's state is tick 1's
    assert w.ticks_of(arrays[:1]).tolist() == [1]

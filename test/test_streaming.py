"""The engine streams: what it holds does not grow with the run's length.

Memory is checked structurally, never as RSS: the heap the tick loop allocates (tracemalloc
sees numpy's arrays and every Python object) peaks at the same size for a run four times as long,
in both loops and with either kind of network schedule, and no array handed to the sink is
longer than a block.
"""

import tracemalloc

import pytest

from haptic_teleop.engine.lockstep import Engine
from haptic_teleop.record.streams import BLOCK_TICKS
from haptic_teleop.scene.load import find_scene, load_scene

JITTER = ["network.forward.effects.delay.jitter_s=0.005", "network.backward.buffer.policy=fixed"]


class Discard:
    """A sink that keeps nothing, noting the longest array it was given."""

    def __init__(self):
        self.longest = 0
        self.ticks = 0
        self.packets = 0

    def append(self, rows):
        self.longest = max(self.longest, len(rows))
        self.ticks += len(rows)

    def append_packets(self, direction, rows):
        self.longest = max(self.longest, len(rows))
        self.packets += len(rows)


def _loop_peak_bytes(loop: str, overrides: list[str], duration_s: float) -> tuple[int, Discard]:
    scene = load_scene(find_scene("wall_contact"), overrides=[*overrides, f"scene.duration_s={duration_s}"])
    engine = Engine(scene, loop=loop)  # models, numba's kernel: set up before the count starts
    assert engine.loop_kind == loop
    sink = Discard()
    tracemalloc.start()
    try:
        engine.run(handle_sigint=False, sink=sink)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert sink.ticks == engine.ticks and sink.packets >= 2 * engine.ticks
    return peak, sink


@pytest.mark.parametrize(
    ("loop", "overrides"),
    [("compiled", []), ("compiled", JITTER), ("python", []), ("python", JITTER)],
    ids=["compiled-vectorized", "compiled-jitter", "python", "python-jitter"],
)
def test_loop_memory_does_not_grow_with_duration(loop, overrides):
    # The compiled loop's network windows are 10 s long (jitter's too: buffer_schedule.py): at
    # least two of them in the shorter run too. The Python loop is slow under tracemalloc.
    duration = 25.0 if loop == "compiled" else 2.0
    short, s1 = _loop_peak_bytes(loop, overrides, duration)
    long, s2 = _loop_peak_bytes(loop, overrides, 4 * duration)
    # Whole-run arrays would add 3 x 2000 ticks x 18 columns x 8 B = 0.9 MB or more, packet logs more.
    assert long <= 1.1 * short + 64_000, (short, long)
    assert s1.longest <= BLOCK_TICKS + 200 and s2.longest <= BLOCK_TICKS + 200


class StopAtFirstBlock:
    """A sink that notes the heap's peak when the first block arrives and stops the run there."""

    def __init__(self, engine):
        self.engine = engine
        self.peak = None

    def append(self, rows):
        if self.peak is None:
            self.peak = tracemalloc.get_traced_memory()[1]
        self.engine.request_stop()

    def append_packets(self, direction, rows):
        pass


@pytest.mark.parametrize("loop", ["compiled", "python"])
def test_start_up_does_no_work_for_the_duration(loop):
    """Until its first block is out, a day-long run allocates what a 20-second one does: nothing
    is sized by the duration (whole-run arrays or network schedules were gigabytes here; the
    compiled loop's network window is 10 s, so the shorter run has a whole one too)."""
    peaks = []
    for duration in (20.0, 86400.0):
        scene = load_scene(find_scene("wall_contact"), overrides=[*JITTER, f"scene.duration_s={duration}"])
        engine = Engine(scene, loop=loop)
        sink = StopAtFirstBlock(engine)
        tracemalloc.start()
        try:
            result = engine.run(handle_sigint=False, sink=sink)
        finally:
            tracemalloc.stop()
        assert result.ticks == BLOCK_TICKS and sink.peak is not None
        peaks.append(sink.peak)
    assert peaks[1] <= 1.1 * peaks[0] + 64_000, peaks


@pytest.mark.parametrize("overrides", [[], JITTER], ids=["vectorized", "ticked"])
def test_both_loops_record_the_same_bag_bytes(tmp_path, overrides):
    """The loops hand the recorder the same blocks and packet records at the same points, so
    the bags are byte for byte the same (records wait for packets 1.2 s on their way)."""
    from haptic_teleop.engine.run import record_run

    delay = ["network.backward.effects.delay.delay_s=1.2", "scene.duration_s=3.5"]
    scene = load_scene(find_scene("wall_contact"), overrides=[*overrides, *delay])
    bags = {}
    for loop in ("compiled", "python"):
        record_run(scene, tmp_path / loop / "bag", parallel=False, handle_sigint=False, loop=loop)
        bags[loop] = (tmp_path / loop / "bag" / "bag.mcap").read_bytes()
    assert bags["compiled"] == bags["python"]

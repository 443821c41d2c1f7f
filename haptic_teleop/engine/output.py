"""Where a run's output goes as the loop makes it: the sink protocol (`RunSink`: the recorder, or a
`Collector` in memory), the loops' output path (`Output`: one block of rows handed over when full,
packet records once their fates are final) and the guard around a loop (`loop_guard`: Ctrl-C
stops at a tick boundary, the cycle collector paused). Every loop, Python or compiled, 1-DoF, arm
or NVE, makes the same calls on its sink, so every loop gives the same bag."""

from __future__ import annotations

import contextlib
import gc
import signal
from collections.abc import Callable, Iterator
from types import FrameType
from typing import Protocol

import numpy as np

from haptic_teleop.record.columns import ONE_DOF
from haptic_teleop.record.layouts import PACKET_FIELDS
from haptic_teleop.record.streams import BLOCK_TICKS

COLUMNS = ONE_DOF.columns


@contextlib.contextmanager
def loop_guard(request_stop: Callable[[], None], handle_sigint: bool) -> Iterator[None]:
    """Around a run's loop: SIGINT (if asked) requests a stop at the next tick boundary, and the
    cycle collector is paused. The tick allocates packets, lists and tuples but makes no reference
    cycles, so the collector only rescans the packet logs (it was about 3 % of a tick,
    docs/performance_python_loop.md). Both are put back as they were."""
    previous = None
    if handle_sigint:

        def _on_sigint(signum: int, frame: FrameType | None) -> None:
            request_stop()

        previous = signal.signal(signal.SIGINT, _on_sigint)
    gc_was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if gc_was_enabled:
            gc.enable()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


class RunSink(Protocol):
    """Where a run's output goes as it is made (`Engine.run`): the recorder, or a `Collector`."""

    def append(self, rows: np.ndarray) -> None:
        """The next ticks' columns, (k, len(COLUMNS)) float64, in order; the array is reused after."""

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        """Packet records (record.layouts.PACKET_FIELDS) whose fates are final; "forward" or "backward"."""


class Collector:
    """A sink that keeps a whole run in memory (tests and short runs; never `haptic-teleop run`)."""

    def __init__(self, width: int = len(COLUMNS)) -> None:
        self.width = width
        self._blocks: list[np.ndarray] = []
        self._packets: dict[str, list[np.ndarray]] = {"forward": [], "backward": []}

    def append(self, rows: np.ndarray) -> None:
        self._blocks.append(np.array(rows))

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        self._packets.setdefault(direction, []).append(np.array(rows))

    def data(self) -> np.ndarray:
        """Every tick's columns so far, (ticks, len(COLUMNS))."""
        return np.concatenate(self._blocks) if self._blocks else np.zeros((0, self.width))

    def packets(self, direction: str) -> np.ndarray:
        """Every packet record handed over so far for a direction, in hand-over order."""
        chunks = self._packets.get(direction, [])
        return np.concatenate(chunks) if chunks else np.zeros((0, len(PACKET_FIELDS)))


class Tee:
    """Hands everything to two sinks (record_run's recorder and, if asked, a Collector)."""

    def __init__(self, first: RunSink, second: RunSink) -> None:
        self.first, self.second = first, second

    def append(self, rows: np.ndarray) -> None:
        self.first.append(rows)
        self.second.append(rows)

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        self.first.append_packets(direction, rows)
        self.second.append_packets(direction, rows)


NO_PACKETS = np.zeros((0, len(PACKET_FIELDS)))
Settled = Callable[[int, bool], "np.ndarray | None"]


class Output:
    """The loops' output path: one block of BLOCK_TICKS rows the loop writes into, handed to the
    sink when full, and the packet records settled at each block's end. Both loops make the same
    calls on the sink with the same arrays, so they give the same bag."""

    def __init__(
        self,
        sink: RunSink,
        forward: Settled | None,
        backward: Settled | None,
        width: int = len(COLUMNS),
        directions: tuple[tuple[str, Settled], ...] | None = None,
    ) -> None:
        self.sink = sink
        self.block = np.zeros((BLOCK_TICKS, width))
        self.start = 0  # tick of the block's first row
        # teleoperation's two directions, or any named ones (an NVE run: "<client>/up", ...)
        self._settled: tuple[tuple[str, Settled], ...] = (
            directions
            if directions is not None
            else tuple((d, s) for d, s in (("forward", forward), ("backward", backward)) if s is not None)
        )
        self._ended = False

    def block_done(self, stop: int) -> None:
        """Ticks [start, stop) are in the block: hand them over, then the settled packets."""
        self.sink.append(self.block[: stop - self.start])
        self.start = stop
        self._packets(stop, False)

    def end(self, stop: int) -> None:
        """The run ended after tick `stop - 1`: the last rows, then every packet record left."""
        self._ended = True
        if stop > self.start:
            self.sink.append(self.block[: stop - self.start])
            self.start = stop
        self._packets(stop, True)

    def end_after_error(self, stop: int) -> None:
        """`end` while an exception is on its way: a failure here must not hide it."""
        if not self._ended:
            with contextlib.suppress(Exception):
                self.end(stop)

    def _packets(self, sent: int, final: bool) -> None:
        for direction, settled in self._settled:
            rows = settled(sent, final)
            if rows is not None and len(rows):
                self.sink.append_packets(direction, rows)

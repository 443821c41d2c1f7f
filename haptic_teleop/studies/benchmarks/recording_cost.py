"""What recording costs the loop, as `haptic-teleop run` records (the writer in a second process),
against the same loop with its rows discarded, in paired rounds (part of `bench speed`).

Each round runs the scene twice, back to back: the loop alone (its blocks and packet records
handed to a sink that drops them) and the loop recording a bag (`record_run`). Both runs note
the wall time at every progress call (every chunk of ticks), so a round gives:

- **per tick**: the wall time a tick takes between 20 % and 95 % of the run (the steady state:
  the writer is running beside the loop), recorded over alone;
- **per run**: what the recorded run spends beyond that steady state, minus what the run alone
  does (the writer's fork, whose copy-on-write pages the loop's first writes pay, the last block
  written after the last tick, the summary section, footer and metadata.yaml), in ms;
- **whole run**: loop start to bag closed, over the run alone.

A ratio is taken within a round (the machine's speed drifts between rounds; both runs of a
round see about the same) and printed as the median with the range over rounds.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

STEADY = (0.2, 0.95)  # the part of a run whose ticks are timed for "per tick"


class Discard:
    """A run sink that drops what it is given: the loop alone, with the same calls as recording."""

    def append(self, rows: np.ndarray) -> None:
        pass

    def append_packets(self, direction: str, rows: np.ndarray) -> None:
        pass


class _Marks:
    """The progress callback: the wall time at each tick count it is called with."""

    def __init__(self) -> None:
        self.at: dict[int, float] = {}

    def __call__(self, n: int) -> None:
        self.at[n] = time.perf_counter()

    def steady_s_per_tick(self, ticks: int) -> float:
        ns = sorted(self.at)
        lo = [n for n in ns if n >= STEADY[0] * ticks]
        hi = [n for n in ns if n <= STEADY[1] * ticks]
        if not lo or not hi or hi[-1] <= lo[0]:
            raise ValueError(f"a run of {ticks} ticks has too few progress calls to time its steady state")
        return (self.at[hi[-1]] - self.at[lo[0]]) / (hi[-1] - lo[0])


@dataclass
class RecordingCost:
    per_tick: list[float]  # recorded / alone, per round
    fixed_ms: list[float]  # per round
    whole: list[float]  # recorded / alone, per round
    tick_us: list[float]  # the loop alone, steady state, per round


def measure(scene: Any, rounds: int, loop: str = "auto") -> RecordingCost:
    """`rounds` paired rounds of the scene's loop alone and recording (module docstring)."""
    from haptic_teleop.engine.lockstep import Engine
    from haptic_teleop.engine.run import record_run

    out = RecordingCost([], [], [], [])
    for _ in range(rounds):
        marks = _Marks()
        engine = Engine(scene, loop=loop)
        alone = engine.run(handle_sigint=False, sink=Discard(), progress=marks)
        a_tick = marks.steady_s_per_tick(alone.ticks)
        a_rest = alone.loop_wall_s - a_tick * alone.ticks
        marks = _Marks()
        with tempfile.TemporaryDirectory() as tmp:
            recorded, timing = record_run(scene, Path(tmp) / "bag", handle_sigint=False, loop=loop, progress=marks)
        r_tick = marks.steady_s_per_tick(recorded.ticks_done)
        r_rest = timing.record_wall_s - r_tick * recorded.ticks_done
        out.per_tick.append(r_tick / a_tick)
        out.fixed_ms.append((r_rest - a_rest) * 1e3)
        out.whole.append(timing.record_wall_s / alone.loop_wall_s)
        out.tick_us.append(a_tick * 1e6)
    return out


def _spread(values: list[float], fmt: str) -> str:
    return f"{statistics.median(values):{fmt}} [{min(values):{fmt}} .. {max(values):{fmt}}]"


def report(cost: RecordingCost, duration_s: float) -> list[str]:
    """The lines `bench speed` prints (median [min .. max] over the rounds)."""
    n = len(cost.per_tick)
    return [
        f"recording, as `run` writes the bag, against the loop alone ({n} paired rounds; median [min .. max]):",
        f"  per tick (steady state), recorded / alone  {_spread(cost.per_tick, '.2f')}  (target <= 1.25)",
        f"  the loop alone, per tick                   {_spread(cost.tick_us, '.2f')} us",
        f"  per run (writer start, last block, close)  {_spread(cost.fixed_ms, '+.1f')} ms",
        f"  {f'whole run of {duration_s:g} s, recorded / alone':<42} {_spread(cost.whole, '.2f')}",
    ]
